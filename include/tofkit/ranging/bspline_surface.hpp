#pragma once
/// \file Tensor-product cubic B-spline correction surface over (range,
/// amplitude [, temperature]); the thesis's suggested future work (Section 4.6),
/// fitted as a P-spline (Eilers & Marx 1996) by calib::fit_bspline_surface.

#include <span>
#include <string>
#include <vector>

#include "tofkit/ranging/bspline_basis.hpp"
#include "tofkit/ranging/correction_surface.hpp"

namespace tofkit::ranging {

/// Everything that defines a fitted B-spline surface.
struct BSplineSurfaceParams {
  BSplineAxis range, amplitude, temperature;  ///< temperature only with use_temperature
  bool use_temperature = false;
  /// The intensity axis ("amplitude" above) reads this column.
  IntensityInput intensity = IntensityInput::amplitude;
  /// Coefficient grid, row-major [range][amplitude][temperature] (temperature
  /// fastest; extent 1 without a temperature axis).
  std::vector<double> coefficients;
  SurfaceDomain domain;
  SurfaceFitStats fit;
};

class BSplineSurface final : public CorrectionSurface {
 public:
  /// Validates the parameters (throws std::invalid_argument naming the field).
  explicit BSplineSurface(BSplineSurfaceParams params);

  [[nodiscard]] std::string kind() const override { return "bspline"; }
  [[nodiscard]] bool uses_temperature() const override { return params_.use_temperature; }
  [[nodiscard]] IntensityInput intensity_input() const override { return params_.intensity; }
  [[nodiscard]] const SurfaceDomain& domain() const override { return params_.domain; }
  void evaluate(const SurfaceInputs& inputs, std::span<double> correction_m,
                std::span<std::uint8_t> out_of_domain) const override;

  [[nodiscard]] const BSplineSurfaceParams& params() const { return params_; }

 private:
  BSplineSurfaceParams params_;
  std::vector<BSplineKnots> knots_;  ///< range, amplitude [, temperature], prepared
};

}  // namespace tofkit::ranging
