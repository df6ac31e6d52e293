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

/// An axis prepared for evaluation: its extended knot vector t_{-3} ..
/// t_{m+3} and, per knot interval, the reciprocals of the six knot differences
/// the Cox-de Boor recurrence divides by, so that a span costs multiplications
/// only. Built once per surface (and per fitted grid); uniform knots are not
/// treated apart.
class BSplineKnots {
 public:
  explicit BSplineKnots(const BSplineAxis& axis)
      : lo_(axis.lo()),
        scale_(axis.intervals() / (axis.hi() - axis.lo())),
        intervals_(axis.intervals()) {
    for (int i = -3; i <= intervals_ + 3; ++i) knots_.push_back(axis.knot(i));
    for (int j = 0; j < intervals_; ++j) {
      for (int k = 1; k <= 3; ++k) {
        for (int r = 0; r < k; ++r) reciprocal_.push_back(1.0 / (t(j + 1 + r) - t(j + 1 + r - k)));
      }
    }
  }

  /// Knot interval j (t_j <= u < t_{j+1}) of an axis coordinate u already
  /// clamped to [lo, hi]; the upper end belongs to the last interval. Guessed
  /// as if the knots were uniform, then walked to the right interval (no step
  /// when they are).
  [[nodiscard]] int interval(double u) const {
    double x = (u - lo_) * scale_;
    x = x >= 0 ? x : 0.0;                                  // also NaN -> 0
    x = std::min(x, static_cast<double>(intervals_ - 1));  // no int overflow past the last knot
    int j = static_cast<int>(x);
    while (j > 0 && u < t(j)) --j;
    while (j < intervals_ - 1 && u >= t(j + 1)) ++j;
    return j;
  }

  /// The cubic B-splines B_j .. B_{j+3} non-zero on the knot interval j of u,
  /// by the Cox-de Boor recurrence in de Boor's triangular form (BSPLVB):
  /// non-negative, summing to 1 (partition of unity) for any knots.
  [[nodiscard]] BSplineSpan span(double u) const {
    const int j = interval(u);
    const double* inv = reciprocal_.data() + 6 * static_cast<std::size_t>(j);
    const double* t = knots_.data() + 3 + j;  // t[i] = t_{j+i}
    // left_k = u - t_{j+1-k}, right_k = t_{j+k} - u; each level k raises the
    // degree by one: temp = N_r / (right_{r+1} + left_{k-r}), the divisor being
    // the knot difference t_{j+1+r} - t_{j+1+r-k} (inv[k (k - 1) / 2 + r]).
    const double left1 = u - t[0], left2 = u - t[-1], left3 = u - t[-2];
    const double right1 = t[1] - u, right2 = t[2] - u, right3 = t[3] - u;
    BSplineSpan span;
    span.first = j;
    // Degree 1.
    double temp = inv[0];
    double n0 = right1 * temp;
    double n1 = left1 * temp;
    // Degree 2.
    temp = n0 * inv[1];
    n0 = right1 * temp;
    double saved = left2 * temp;
    temp = n1 * inv[2];
    n1 = saved + right2 * temp;
    double n2 = left1 * temp;
    // Degree 3.
    temp = n0 * inv[3];
    span.weight[0] = right1 * temp;
    saved = left3 * temp;
    temp = n1 * inv[4];
    span.weight[1] = saved + right2 * temp;
    saved = left2 * temp;
    temp = n2 * inv[5];
    span.weight[2] = saved + right3 * temp;
    span.weight[3] = left1 * temp;
    return span;
  }

 private:
  [[nodiscard]] double t(int i) const { return knots_[static_cast<std::size_t>(i + 3)]; }

  double lo_;
  double scale_;
  int intervals_;
  std::vector<double> knots_;       // t_{-3} .. t_{m+3}
  std::vector<double> reciprocal_;  // 6 per interval
};

/// One span at u on an axis (prepares the axis each call: for tests and
/// single points; evaluate many points through BSplineKnots).
inline BSplineSpan cubic_bspline_span(const BSplineAxis& axis, double u) {
  return BSplineKnots(axis).span(u);
}

}  // namespace tofkit::ranging
