#pragma once
/// \file Cubic B-spline basis on one axis with any strictly increasing knots
/// (de Boor, "A Practical Guide to Splines", 2001, Chapter IX; Eilers & Marx
/// 1996 use the same basis for P-splines). Uniform knots are the special case
/// whose knot vector is evenly spaced: one evaluation path serves both.

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>
#include <vector>

namespace tofkit::ranging {

/// One axis of a tensor-product cubic B-spline. Its breakpoints t_0 < t_1 <
/// ... < t_m (in the axis coordinate: the natural log of the input when
/// log_scale) span the domain [t_0, t_m] in m knot intervals; the knot vector
/// is extended beyond each end by three more knots at the end interval's
/// spacing (t_{-k} = t_0 - k (t_1 - t_0), t_{m+k} = t_m + k (t_m - t_{m-1})),
/// so there are m + 3 basis functions, B_i supported on [t_{i-3}, t_{i+1}],
/// and on [t_0, t_m] they sum to 1. With evenly spaced breakpoints these are
/// the cardinal (uniform) cubic B-splines.
struct BSplineAxis {
  std::vector<double> breakpoints = {0.0, 1.0};
  bool log_scale = false;

  /// `intervals` equal intervals over [lo, hi] (axis coordinates).
  [[nodiscard]] static BSplineAxis uniform(double lo, double hi, int intervals, bool log_scale) {
    BSplineAxis a;
    a.log_scale = log_scale;
    a.breakpoints.resize(static_cast<std::size_t>(std::max(intervals, 1)) + 1);
    const double m = static_cast<double>(a.breakpoints.size() - 1);
    for (std::size_t k = 0; k < a.breakpoints.size(); ++k) {
      a.breakpoints[k] = lo + (hi - lo) * (static_cast<double>(k) / m);
    }
    a.breakpoints.back() = hi;
    return a;
  }

  [[nodiscard]] int intervals() const { return static_cast<int>(breakpoints.size()) - 1; }
  [[nodiscard]] double lo() const { return breakpoints.front(); }
  [[nodiscard]] double hi() const { return breakpoints.back(); }
  [[nodiscard]] int basis_count() const { return intervals() + 3; }
  /// Input -> axis coordinate.
  [[nodiscard]] double coordinate(double x) const { return log_scale ? std::log(x) : x; }

  /// Knot t_i of the extended knot vector, i in [-3, intervals + 3].
  [[nodiscard]] double knot(int i) const {
    const int m = intervals();
    if (i < 0) return breakpoints[0] + i * (breakpoints[1] - breakpoints[0]);
    if (i > m) return breakpoints[m] + (i - m) * (breakpoints[m] - breakpoints[m - 1]);
    return breakpoints[static_cast<std::size_t>(i)];
  }

  /// Greville abscissa of basis function i (the mean of its three inner
  /// knots): a spline with coefficients c_i = a + b xi_i is the line a + b u.
  [[nodiscard]] double greville(int i) const { return (knot(i - 2) + knot(i - 1) + knot(i)) / 3.0; }

  /// Whether the breakpoints are evenly spaced: each within `tolerance`
  /// times the spacing of its uniform place (default: to rounding).
  [[nodiscard]] bool is_uniform(double tolerance = 1e-9) const {
    const int m = intervals();
    const double h = (hi() - lo()) / m;
    for (int k = 1; k < m; ++k) {
      if (std::abs(breakpoints[static_cast<std::size_t>(k)] - (lo() + k * h)) > tolerance * h) {
        return false;
      }
    }
    return true;
  }

  /// Throws std::invalid_argument naming `name` unless there are at least two
  /// finite, strictly increasing breakpoints (at most 1001).
  void validate(const std::string& name) const {
    if (breakpoints.size() < 2 || breakpoints.size() > 1001) {
      throw std::invalid_argument(name + ".knots must hold 2 .. 1001 breakpoints (1 .. 1000 " +
                                  "intervals), not " + std::to_string(breakpoints.size()));
    }
    for (std::size_t k = 0; k < breakpoints.size(); ++k) {
      if (!std::isfinite(breakpoints[k])) {
        throw std::invalid_argument(name + ".knots[" + std::to_string(k) + "] is not finite");
      }
      if (k > 0 && !(breakpoints[k] > breakpoints[k - 1])) {
        throw std::invalid_argument(name + ".knots[" + std::to_string(k) +
                                    "] is not above the one before (knots must be strictly "
                                    "increasing)");
      }
    }
  }
};

/// The four non-zero basis functions at a point: indices first .. first + 3.
struct BSplineSpan {
  int first = 0;
  double weight[4] = {0, 0, 0, 0};
};

/// Knot interval j (t_j <= u < t_{j+1}) of an axis coordinate u already
/// clamped to [lo, hi]; the upper end belongs to the last interval.
inline int bspline_interval(const BSplineAxis& axis, double u) {
  const auto& t = axis.breakpoints;
  const auto it = std::upper_bound(t.begin() + 1, t.end() - 1, u);
  return static_cast<int>(it - t.begin()) - 1;
}

/// The cubic B-splines B_j .. B_{j+3} non-zero on knot interval j at u, by the
/// Cox-de Boor recurrence in de Boor's triangular form (BSPLVB): non-negative,
/// summing to 1 (partition of unity) for any knots.
inline BSplineSpan cubic_bspline_span(const BSplineAxis& axis, double u) {
  const int j = bspline_interval(axis, u);
  // left[k] = u - t_{j+1-k}, right[k] = t_{j+k} - u (k = 1 .. 3).
  double left[4], right[4];
  BSplineSpan span;
  span.first = j;
  double* n = span.weight;
  n[0] = 1.0;
  for (int k = 1; k <= 3; ++k) {
    left[k] = u - axis.knot(j + 1 - k);
    right[k] = axis.knot(j + k) - u;
    double saved = 0.0;
    for (int r = 0; r < k; ++r) {
      const double temp = n[r] / (right[r + 1] + left[k - r]);
      n[r] = saved + right[r + 1] * temp;
      saved = left[k - r] * temp;
    }
    n[k] = saved;
  }
  return span;
}

}  // namespace tofkit::ranging
