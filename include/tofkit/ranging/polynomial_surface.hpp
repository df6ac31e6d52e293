#pragma once
/// \file Total-degree polynomial correction surface (the thesis's Section 4.6):
/// all monomials r^a i^b [t^c] with a + b [+ c] <= N, i.e. the terms of
/// (1 + r + i [+ t])^N, in inputs scaled to [-1, 1] over the fitting domain.

#include <array>
#include <span>
#include <string>
#include <vector>

#include "tofkit/ranging/correction_surface.hpp"

namespace tofkit::ranging {

/// Powers of (range, amplitude, temperature) of one monomial.
using MonomialExponents = std::array<int, 3>;

/// All monomials of total degree <= order, in graded order (degree 0 first,
/// then by decreasing range power); temperature powers are 0 without a temperature axis.
[[nodiscard]] std::vector<MonomialExponents> polynomial_exponents(int order, bool use_temperature);

/// Everything that defines a fitted polynomial surface.
struct PolynomialSurfaceParams {
  int order = 0;
  bool use_temperature = false;
  std::vector<MonomialExponents> exponents;  ///< one per coefficient
  std::vector<double> coefficients;          ///< correction in metres per scaled monomial
  AxisScaling range_scaling, amplitude_scaling, temperature_scaling;
  SurfaceDomain domain;
  SurfaceFitStats fit;
};

class PolynomialSurface final : public CorrectionSurface {
 public:
  /// Validates the parameters (throws std::invalid_argument naming the field).
  explicit PolynomialSurface(PolynomialSurfaceParams params);

  [[nodiscard]] std::string kind() const override { return "poly"; }
  [[nodiscard]] bool uses_temperature() const override { return params_.use_temperature; }
  [[nodiscard]] const SurfaceDomain& domain() const override { return params_.domain; }
  void evaluate(const SurfaceInputs& inputs, std::span<double> correction_m,
                std::span<std::uint8_t> out_of_domain) const override;

  [[nodiscard]] const PolynomialSurfaceParams& params() const { return params_; }

 private:
  PolynomialSurfaceParams params_;
  /// Dense coefficient cube c[a][b][c] of side order + 1 (zeros above the total
  /// degree) for nested Horner evaluation.
  std::vector<double> horner_;
};

}  // namespace tofkit::ranging
