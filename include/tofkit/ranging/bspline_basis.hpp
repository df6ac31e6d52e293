#pragma once
/// \file Uniform cubic B-spline basis on one axis (de Boor, "A Practical Guide to
/// Splines"; Eilers & Marx 1996 use the same basis for P-splines).

#include <algorithm>
#include <cmath>

namespace tofkit::ranging {

/// One axis of a tensor-product cubic B-spline: `intervals` equal knot
/// intervals over [lo, hi] of the axis coordinate (the natural log of the input
/// when log_scale), hence intervals + 3 basis functions.
struct BSplineAxis {
  double lo = 0;  ///< axis coordinate at the domain's lower end
  double hi = 1;  ///< axis coordinate at the domain's upper end
  int intervals = 1;
  bool log_scale = false;

  [[nodiscard]] int basis_count() const { return intervals + 3; }
  /// Input -> axis coordinate.
  [[nodiscard]] double coordinate(double x) const { return log_scale ? std::log(x) : x; }
};

/// The four non-zero basis functions at a point: indices first .. first + 3.
struct BSplineSpan {
  int first = 0;
  double weight[4] = {0, 0, 0, 0};
};

/// Cardinal cubic B-spline weights at local parameter t in [0, 1] of an
/// interval; they are non-negative and sum to 1 (partition of unity).
inline void cubic_bspline_weights(double t, double* w) {
  const double s = 1.0 - t;
  const double t2 = t * t;
  const double t3 = t2 * t;
  w[0] = s * s * s * (1.0 / 6.0);
  w[1] = (3.0 * t3 - 6.0 * t2 + 4.0) * (1.0 / 6.0);
  w[2] = (-3.0 * t3 + 3.0 * t2 + 3.0 * t + 1.0) * (1.0 / 6.0);
  w[3] = t3 * (1.0 / 6.0);
}

/// Span of an axis coordinate u already clamped to [lo, hi]; inv_spacing =
/// intervals / (hi - lo). The upper end belongs to the last interval.
inline BSplineSpan cubic_bspline_span(const BSplineAxis& axis, double inv_spacing, double u) {
  const double x = (u - axis.lo) * inv_spacing;
  int j = static_cast<int>(x);
  j = std::clamp(j, 0, axis.intervals - 1);
  BSplineSpan span;
  span.first = j;
  cubic_bspline_weights(x - j, span.weight);
  return span;
}

}  // namespace tofkit::ranging
