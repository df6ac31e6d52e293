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

namespace tofkit::calib {

class ConfidenceModel {
 public:
  virtual ~ConfidenceModel() = default;
  /// "thesis" (cubic fit of squared error vs intensity with a floor) or
  /// "calibrated" (tofkit's: expected error over intensity and range, fitted on
  /// data not used for the correction fit).
  [[nodiscard]] virtual std::string kind() const = 0;
  /// sigma_m[i] for each (range, amplitude) row.
  virtual void sigma(std::span<const double> range_m, std::span<const double> amplitude,
                     std::span<double> sigma_m) const = 0;
};

/// Data for a confidence fit: residuals of an already corrected range.
struct ConfidenceFitData {
  std::span<const double> range_m;
  std::span<const double> amplitude;
  std::span<const double> residual_m;  ///< true - corrected
};

struct ThesisConfidenceOptions {
  int order = 3;        ///< polynomial order of E^2 vs intensity (thesis: 3)
  double floor_m2 = 0;  ///< floor on E^2; 0: 5 % of the mean squared error
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

// ------------------------------------------------------------------ models

/// Parameters of the thesis's metric.
struct ThesisConfidenceParams {
  std::vector<double> coefficients;  ///< E^2 [m^2] = sum_k c_k x^k, x = scaled intensity
  AxisScaling amplitude_scaling;
  double amplitude_min = 0, amplitude_max = 0;  ///< fitting domain; inputs are clamped to it
  double floor_m2 = 0;                          ///< E^2 never below this
  std::size_t rows = 0;                         ///< fitting rows
};

class ThesisConfidence final : public ConfidenceModel {
 public:
  /// Validates (throws std::invalid_argument naming the field).
  explicit ThesisConfidence(ThesisConfidenceParams params);
  [[nodiscard]] std::string kind() const override { return "thesis"; }
  /// sigma = sqrt(max(E^2(clamped intensity), floor)); range is not used.
  void sigma(std::span<const double> range_m, std::span<const double> amplitude,
             std::span<double> sigma_m) const override;
  [[nodiscard]] const ThesisConfidenceParams& params() const { return params_; }

 private:
  ThesisConfidenceParams params_;
};

/// Parameters of tofkit's calibrated metric:
/// sigma = k(x) sqrt(exp(sum_j c_j x^a_j y^b_j)), x the scaled (log) intensity,
/// y the scaled range, k piecewise linear in log over the band centres.
struct CalibratedConfidenceParams {
  std::vector<std::array<int, 2>> exponents;  ///< powers of (x, y), one per coefficient
  std::vector<double> coefficients;           ///< log E[e^2] in log m^2
  bool log_amplitude = true;
  AxisScaling amplitude_scaling;  ///< maps the (log) intensity coordinate to x
  AxisScaling range_scaling;      ///< maps range to y
  SurfaceDomain domain;           ///< range and amplitude of the fitting data; inputs clamped
  std::vector<double>
      band_coordinate;             ///< band centres in the (log) intensity coordinate, ascending
  std::vector<double> band_scale;  ///< coverage factor k at each centre (> 0)
  double target_coverage_2sigma = 0.95;
  std::size_t rows = 0;
  double fit_coverage_2sigma = 0;  ///< on the fitting data
};

class CalibratedConfidence final : public ConfidenceModel {
 public:
  /// Validates (throws std::invalid_argument naming the field).
  explicit CalibratedConfidence(CalibratedConfidenceParams params);
  [[nodiscard]] std::string kind() const override { return "calibrated"; }
  void sigma(std::span<const double> range_m, std::span<const double> amplitude,
             std::span<double> sigma_m) const override;
  [[nodiscard]] const CalibratedConfidenceParams& params() const { return params_; }

 private:
  CalibratedConfidenceParams params_;
};

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

}  // namespace tofkit::calib
