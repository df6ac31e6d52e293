#include "tofkit/device/optics.hpp"

#include "random_draws.hpp"

namespace tofkit::device {

double background_power_w(const physics::LinkConfig& link, const Target& target) {
  double w = 0;
  for (const auto& s : target.surfaces)
    w += s.fraction *
         physics::background_power_cos_w(link, s.reflectance,
                                         std::max(s.cos_incidence, detail::kBackgroundCosFloor));
  return w;
}

}  // namespace tofkit::device
