#pragma once
/// \file The paper's own correction done the paper's way (Section 5,
/// reference/ranging_paper.md), on the measurements of a paper study:
///  - gray value: offset versus echo pulse width at 2.355 m, piecewise linear
///    with its one inflection fixed at 6.5 ns (the paper placed it by
///    inspection of Fig. 6), fitted by least squares on the plates of that one
///    distance only (the paper's first round; tofkit's chain instead finds its
///    knots and uses more distances);
///  - temperature: coefficient 0 below 16 C ("small, non-linear"), one linear
///    coefficient above, fitted on the temperature sweep after the gray-value
///    correction (Fig. 8).
/// The corrected test sets give the paper's Fig. 7, Fig. 9 and Table 2 figures
/// for that method, beside tofkit's chain in PaperStudyResult.

#include <vector>

#include "tofkit/experiments/paper_study.hpp"
#include "tofkit/ranging/piecewise_linear.hpp"

namespace tofkit::experiments {

struct PaperMethodOptions {
  double knee_ns = 6.5;                   ///< Section 5.1, the inflection of Fig. 6
  double temperature_knee_c = 16.0;       ///< Section 5.2: coefficient 0 below
  double grayvalue_distance_m = 2.355;    ///< the plates' distance (Section 5.1)
  double temperature_distance_m = 2.402;  ///< the sweep's distance (Section 5.2)
};

struct PaperMethodResult {
  /// correction g(pulse width) = true - c t / 2 (constant included), metres.
  ranging::PiecewiseLinear grayvalue_correction;
  /// Offset slope (measured - true) below and above the knee, mm/ns: Fig. 6's
  /// two coefficients (paper -36 and 70, units not stated).
  double slope_below_knee_mm_per_ns = ranging::kNaN;
  double slope_above_knee_mm_per_ns = ranging::kNaN;
  /// Drift of the gray-value-corrected reading (measured - true) per degree
  /// of the sensor above and below 16 C, from straight lines through the sweep
  /// (paper: 3.8 mm/C above, "small" below).
  double temperature_slope_above_mm_per_c = ranging::kNaN;
  double temperature_slope_below_mm_per_c = ranging::kNaN;
  double temperature_coefficient_m_per_c = 0;      ///< the correction's coefficient above the knee
  double temperature_reference_c = ranging::kNaN;  ///< sensor temperature of the plates
  double temperature_knee_c = 16.0;
  std::size_t grayvalue_rows = 0, temperature_rows = 0;

  AccuracyFigures grayvalue;    ///< Fig. 7, plates at 2.355 m (first repeat of each)
  AccuracyFigures temperature;  ///< Fig. 9, 20 groups at 2.402 m
  std::vector<VerificationRow> verification_rows;  ///< Table 2, deviation = actual - measured

  /// The corrected distance of one measurement (NaN without an echo).
  [[nodiscard]] double correct_m(const ranging::RawMeasurement& raw,
                                 const ranging::Pipeline& start) const;
};

/// Fits the paper's correction on `study.calibration` and applies it to the
/// study's test sets. Throws std::runtime_error when the plates or the sweep
/// leave too few rows on either side of a knee.
[[nodiscard]] PaperMethodResult run_paper_method(const PaperStudyResult& study,
                                                 const PaperStudyOptions& study_options = {},
                                                 const PaperMethodOptions& options = {});

}  // namespace tofkit::experiments
