#include "tofkit/ranging/piecewise_linear.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

namespace tofkit::ranging {

void PiecewiseLinear::validate() const {
  if (knots.size() != slopes.size()) {
    throw std::invalid_argument("piecewise-linear function: " + std::to_string(knots.size()) +
                                " knots but " + std::to_string(slopes.size()) + " slopes");
  }
  if (!std::isfinite(x0) || !std::isfinite(intercept) || !std::isfinite(slope0)) {
    throw std::invalid_argument(
        "piecewise-linear function: x0, intercept and slope0 must be finite");
  }
  for (std::size_t k = 0; k < knots.size(); ++k) {
    if (!std::isfinite(knots[k]) || !std::isfinite(slopes[k])) {
      throw std::invalid_argument("piecewise-linear function: knot " + std::to_string(k) +
                                  " or its slope is not finite");
    }
    if (k > 0 && !(knots[k] > knots[k - 1])) {
      throw std::invalid_argument("piecewise-linear function: knots must be strictly ascending");
    }
  }
}

double PiecewiseLinear::operator()(double x) const {
  double y = intercept + slope0 * (x - x0);
  for (std::size_t k = 0; k < knots.size(); ++k) {
    y += slopes[k] * std::max(0.0, x - knots[k]);
  }
  return y;
}

double PiecewiseLinear::slope_at(double x) const {
  double slope = slope0;
  for (std::size_t k = 0; k < knots.size(); ++k) {
    if (x >= knots[k]) slope += slopes[k];
  }
  return slope;
}

std::vector<double> PiecewiseLinear::segment_slopes() const {
  std::vector<double> out{slope0};
  for (double s : slopes) out.push_back(out.back() + s);
  return out;
}

void PiecewiseLinear::evaluate(std::span<const double> x, std::span<double> y) const {
  if (x.size() != y.size()) {
    throw std::invalid_argument("PiecewiseLinear::evaluate: x and y sizes differ");
  }
  for (std::size_t i = 0; i < x.size(); ++i) y[i] = (*this)(x[i]);
}

PiecewiseLinear PiecewiseLinear::with_x0(double new_x0) const {
  PiecewiseLinear out = *this;
  out.x0 = new_x0;
  out.intercept = intercept + slope0 * (new_x0 - x0);
  return out;
}

}  // namespace tofkit::ranging
