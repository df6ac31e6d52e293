#include "tofkit/device/discriminator.hpp"

#include <cmath>

#include "tofkit/physics/constants.hpp"

namespace tofkit::device {

double extra_edge_crossings(double jitter_over_correlation) {
  const double r = jitter_over_correlation;
  const double x = 1.0 / r;
  return r * std::exp(-0.5 * x * x) / std::sqrt(2.0 * physics::kPi) -
         0.5 * std::erfc(x / std::sqrt(2.0));
}

double chatter_ratio_limit(double extra_crossings) {
  double lo = 0.05, hi = 5.0;
  for (int i = 0; i < 100; ++i) {
    const double mid = 0.5 * (lo + hi);
    (extra_edge_crossings(mid) < extra_crossings ? lo : hi) = mid;
  }
  return lo;
}

}  // namespace tofkit::device
