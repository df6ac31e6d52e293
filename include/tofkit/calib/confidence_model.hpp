#pragma once
/// \file Confidence: the expected error (1 sigma) of a corrected range.

#include <array>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "tofkit/calib/correction_surface.hpp"
#include "tofkit/ranging/confidence_model.hpp"

namespace tofkit::calib {

using ranging::CalibratedConfidence;
using ranging::CalibratedConfidenceParams;
using ranging::ConfidenceModel;
using ranging::ThesisConfidence;
using ranging::ThesisConfidenceParams;

/// Data for a confidence fit: residuals of an already corrected range.
struct ConfidenceFitData {
  std::span<const double> range_m;
  std::span<const double> amplitude;
  std::span<const double> residual_m;  ///< true - corrected
};

struct ThesisConfidenceOptions {
  int order = 3;        ///< polynomial order of E^2 vs intensity (thesis: 3)
  double floor_m2 = 0;  ///< floor on E^2; 0: 5 % of the mean squared error
  /// Above this intensity E^2 is floor_m2 alone (thesis: above intensity 72); 0: the
  /// floor is only a lower bound.
  double floor_above_amplitude = 0;
};

/// The thesis's metric (Section 4.8): E^2 = poly(intensity), floored; sigma = sqrt.
[[nodiscard]] std::shared_ptr<const ConfidenceModel> fit_thesis_confidence(
    const ConfidenceFitData& data, const ThesisConfidenceOptions& options = {});

struct CalibratedConfidenceOptions {
  double target_coverage_2sigma = 0.95;  ///< share of |residual| <= 2 sigma to aim for
  int order = 2;  ///< total degree of the log E[e^2] polynomial in (log intensity, range)
  int intensity_bands =
      6;  ///< coverage is calibrated per band of equal counts (fewer with little data)
  bool log_amplitude = true;  ///< model over log intensity (intensity spans decades)
  /// Throws std::invalid_argument naming the bad field.
  void validate() const;
};

/// tofkit's metric: sigma(range, intensity) from a smooth fit of log E[e^2] (a
/// polynomial in log intensity and range, fitted by gamma quasi-likelihood with
/// a log link, so zero residuals and the log's bias do no harm), then rescaled
/// per intensity band, smoothly, so that the 2-sigma coverage on the fitting data
/// (held out from the correction fit) meets the target in every band.
[[nodiscard]] std::shared_ptr<const ConfidenceModel> fit_calibrated_confidence(
    const ConfidenceFitData& data, const CalibratedConfidenceOptions& options = {});

/// Data for a noise-plus-systematic confidence fit: the residuals of the final
/// correction on its own calibration rows, grouped by target (repeats of one
/// truth), and the intensity axis the correction reads.
struct NoiseSystematicFitData {
  std::span<const double> range_m;
  std::span<const double> intensity;   ///< amplitude or pulse width (> 0)
  std::span<const double> residual_m;  ///< true - corrected, in-sample
  std::span<const std::uint32_t> group;
  /// Optional, one per row (empty: none): the leverage h in [0, 1) of the
  /// row's target on its own mean residual (d mean fitted / d mean truth, the
  /// same for every row of a target). With it each target's optimism is its
  /// own, (1 + h) / (1 - h), instead of NoiseSystematicOptions::optimism.
  std::span<const double> leverage = {};
};

struct NoiseSystematicOptions {
  int order = 2;  ///< degree of each log-variance polynomial in log intensity
  /// Prediction error of a new target over the in-sample systematic error of
  /// the calibration targets, >= 1: for a fit of p effective parameters on G
  /// targets, (G + p) / (G - p) (Mallows' C_p / the optimism of the training
  /// error, Hastie, Tibshirani & Friedman, ESL 2nd ed., Eq. 7.24).
  double optimism = 1.0;
  ranging::IntensityInput intensity = ranging::IntensityInput::amplitude;
  /// Throws std::invalid_argument naming the bad field.
  void validate() const;
};

/// sigma^2 = noise^2(I) + optimism * s^2(I), I the intensity (log scale): the
/// noise of one row from the scatter of the targets' repeats (each target's
/// sample variance, a gamma quasi-likelihood fit with its degrees of freedom
/// as weights; averaging noise falls as 1/SNR), the systematic part from the
/// targets' mean residuals less the noise of a mean (noise^2 / n), by the same
/// fit. Needs repeats (>= 10 targets with two or more rows).
///
/// With data.leverage the optimism is pointwise (Mallows' C_p per target: an
/// in-sample mean residual has variance (s^2 + nu)(1 - h), a new target's
/// error s^2 + nu + (s^2 + nu) h): each target's squared mean residual is
/// scaled by (1 + h) / (1 - h) before the fit, so the fitted excess over the
/// noise of a mean is s^2 (1 + h) + nu h, a new row's error variance less its
/// noise, where the correction is flexible (sparse targets, steep curves) and
/// not where it is stiff. The leverages sum to the correction's effective
/// parameters, so on average this is the global (G + p) / (G - p).
/// Leverages above kMaxLeverage are taken as kMaxLeverage.
[[nodiscard]] std::shared_ptr<const ConfidenceModel> fit_noise_systematic_confidence(
    const NoiseSystematicFitData& data, const NoiseSystematicOptions& options = {});

/// The largest leverage used by fit_noise_systematic_confidence (optimism 39):
/// a target that alone determines its fitted value (h -> 1) has a mean
/// residual of zero whatever its error, and says nothing about it.
inline constexpr double kMaxLeverage = 0.95;

/// How well a confidence model's sigma describes residuals: the share with
/// |residual| <= 2 sigma, overall and per intensity tercile of these data.
struct ConfidenceCoverage {
  std::size_t rows = 0;
  double within_2sigma = 0;
  std::array<double, 3> within_2sigma_by_tercile{};  ///< low, middle, high intensity
  std::array<double, 2> tercile_edges{};             ///< intensity between the terciles
  double mean_sigma_m = 0;
  [[nodiscard]] std::string summary() const;
};

[[nodiscard]] ConfidenceCoverage coverage_2sigma(const ConfidenceModel& model,
                                                 const ConfidenceFitData& data);

/// The distances rows were measured at: clusters of sorted ranges parted by
/// gaps wider than 2 cm (far above the noise of a corrected range, far below
/// the spacing of plates). Non-finite ranges are not counted.
[[nodiscard]] int distinct_distances(std::span<const double> range_m);

}  // namespace tofkit::calib
