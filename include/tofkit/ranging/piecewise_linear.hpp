#pragma once
/// \file A continuous piecewise-linear ("hinge") function,
///   y(x) = intercept + slope0 (x - x0) + sum_k slopes[k] max(0, x - knots[k]),
/// the shape of the paper's gray-value correction (one inflection at 6.5 ns) and
/// temperature correction (flat below 16 C, linear above; Section 5).

#include <cstddef>
#include <span>
#include <vector>

namespace tofkit::ranging {

struct PiecewiseLinear {
  double x0 = 0;               ///< reference abscissa of `intercept`
  double intercept = 0;        ///< y(x0) when x0 lies left of every knot (the formula's constant)
  double slope0 = 0;           ///< slope left of the first knot
  std::vector<double> knots;   ///< ascending knot positions
  std::vector<double> slopes;  ///< slope *change* at each knot (same size as knots)

  /// Throws std::invalid_argument if sizes differ, knots are unsorted or a value is not finite.
  void validate() const;

  [[nodiscard]] double operator()(double x) const;
  /// dy/dx on the segment holding x (right derivative at a knot).
  [[nodiscard]] double slope_at(double x) const;
  /// Slope of each of the knots.size() + 1 segments, left to right.
  [[nodiscard]] std::vector<double> segment_slopes() const;
  /// y[i] = (*this)(x[i]); sizes must match.
  void evaluate(std::span<const double> x, std::span<double> y) const;
  /// The same function written with another reference abscissa (same values everywhere).
  [[nodiscard]] PiecewiseLinear with_x0(double new_x0) const;
};

}  // namespace tofkit::ranging
