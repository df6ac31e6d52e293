#pragma once
/// \file Confidence: the expected error (1 sigma) of a corrected range, as
/// evaluated by the pipeline. The models are fitted by calib/confidence_model.hpp.

#include <array>
#include <cstddef>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "tofkit/ranging/correction_surface.hpp"

namespace tofkit::ranging {

class ConfidenceModel {
 public:
  virtual ~ConfidenceModel() = default;
  /// "thesis" (cubic fit of squared error vs intensity with a floor) or
  /// "calibrated" (tofkit's: expected error over intensity and range, fitted on
  /// data not used for the correction fit).
  [[nodiscard]] virtual std::string kind() const = 0;
  /// What the model's intensity axis reads: the amplitude (default) or the
  /// echo pulse width; the pipeline passes that column as `amplitude`.
  [[nodiscard]] virtual IntensityInput intensity_input() const { return IntensityInput::amplitude; }
  /// sigma_m[i] for each (range, intensity) row.
  virtual void sigma(std::span<const double> range_m, std::span<const double> amplitude,
                     std::span<double> sigma_m) const = 0;
};

// ------------------------------------------------------------------ models

/// Parameters of the thesis's metric.
struct ThesisConfidenceParams {
  std::vector<double> coefficients;  ///< E^2 [m^2] = sum_k c_k x^k, x = scaled intensity
  AxisScaling amplitude_scaling;
  double amplitude_min = 0, amplitude_max = 0;  ///< fitting domain; inputs are clamped to it
  double floor_m2 = 0;                          ///< E^2 never below this
  /// Above this intensity E^2 is the floor, whatever the polynomial gives (thesis
  /// Section 4.8: "above intensity 72 a floor of 0.005 in^2 is used"); 0: none.
  double floor_above_amplitude = 0;
  std::size_t rows = 0;  ///< fitting rows
};

class ThesisConfidence final : public ConfidenceModel {
 public:
  /// Validates (throws std::invalid_argument naming the field).
  explicit ThesisConfidence(ThesisConfidenceParams params);
  [[nodiscard]] std::string kind() const override { return "thesis"; }
  /// sigma = sqrt(max(E^2(clamped intensity), floor)), sqrt(floor) above
  /// floor_above_amplitude (when set); range is not used.
  void sigma(std::span<const double> range_m, std::span<const double> amplitude,
             std::span<double> sigma_m) const override;
  [[nodiscard]] const ThesisConfidenceParams& params() const { return params_; }

 private:
  ThesisConfidenceParams params_;
};

/// Parameters of tofkit's calibrated metric:
/// sigma = k(x) sqrt(exp(sum_j c_j x^a_j y^b_j) + exp(sum_j s_j x^a'_j y^b'_j)),
/// x the scaled (log) intensity, y the scaled range, k piecewise linear in log
/// over the band centres. The second term (systematic_*) is optional: with it
/// the first is the noise of one row and the second the systematic error of
/// the correction (see calib::fit_noise_systematic_confidence).
struct CalibratedConfidenceParams {
  std::vector<std::array<int, 2>> exponents;  ///< powers of (x, y), one per coefficient
  std::vector<double> coefficients;           ///< log E[e^2] in log m^2
  /// Optional systematic term (empty: none): powers of (x, y) and coefficients.
  std::vector<std::array<int, 2>> systematic_exponents;
  std::vector<double> systematic_coefficients;           ///< log m^2
  IntensityInput intensity = IntensityInput::amplitude;  ///< the column read as intensity
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
  [[nodiscard]] IntensityInput intensity_input() const override { return params_.intensity; }
  void sigma(std::span<const double> range_m, std::span<const double> amplitude,
             std::span<double> sigma_m) const override;
  [[nodiscard]] const CalibratedConfidenceParams& params() const { return params_; }

 private:
  CalibratedConfidenceParams params_;
};

/// The calibrated model's log-variance polynomial, sum_k c_k x^a_k y^b_k
/// (exponents a_k, b_k in [0, 7]; x, y the scaled intensity and range).
[[nodiscard]] double polynomial_2d(const std::vector<std::array<int, 2>>& exps,
                                   const std::vector<double>& c, double x, double y);

/// The calibrated model's coverage factor k(u): piecewise-linear interpolation
/// of log k over the band centres (ascending), constant beyond the first and
/// last centre.
[[nodiscard]] double band_factor(const std::vector<double>& centre,
                                 const std::vector<double>& scale, double u);

}  // namespace tofkit::ranging
