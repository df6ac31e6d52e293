#include "tofkit/device/front_end.hpp"

#include "tofkit/physics/constants.hpp"
#include "tofkit/physics/link_budget.hpp"

namespace tofkit::device {

FrontEndNoise front_end_noise(const physics::ReceiverConfig& rx, double apd_gain) {
  FrontEndNoise noise;
  const double z_ohm = rx.transimpedance_kohm * 1e3;
  auto floor_var = [&](double background_w) {
    const auto n = physics::noise_currents(rx, 0.0, background_w, apd_gain);
    return z_ohm * z_ohm *
           (n.background_shot_a * n.background_shot_a + n.dark_shot_a * n.dark_shot_a +
            n.thermal_a * n.thermal_a);
  };
  noise.floor_var_v2 = floor_var(0.0);
  noise.floor_var_per_w = floor_var(1.0) - noise.floor_var_v2;
  // Signal shot noise: 2 q I_p M^2 F B with I_p = V / (Z M) -> 2 q M F B Z V.
  noise.shot_var_per_v = 2.0 * physics::kElementaryCharge_c * apd_gain * rx.excess_noise_factor *
                         rx.bandwidth_mhz * 1e6 * z_ohm;
  return noise;
}

}  // namespace tofkit::device
