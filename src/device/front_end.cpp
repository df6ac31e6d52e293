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

ClippedChargeShare::ClippedChargeShare(const physics::PulseTemplate& pulse) {
  // The template on a 1 ps grid (its own step is 5 ps; the linear
  // interpolation between its samples is what the cores see too).
  constexpr double kDt = 1e-3;
  std::vector<double> p;
  for (double t = pulse.begin_ns(); t < pulse.end_ns(); t += kDt) p.push_back(pulse(t));
  double area = 0;
  for (const double v : p) area += v;
  const int n = static_cast<int>(std::ceil(std::log(1e6) / kLnStep)) + 1;
  share_.resize(static_cast<std::size_t>(n));
  for (int k = 0; k < n; ++k) {
    const double x = std::exp(k * kLnStep);
    double passed = 0;
    for (const double v : p) passed += std::min(x * v, 1.0);
    share_[static_cast<std::size_t>(k)] = passed / (x * area);
  }
}

double ClippedChargeShare::operator()(double overdrive) const {
  if (!(overdrive > 1.0) || share_.empty()) return 1.0;
  const double g = std::log(overdrive) / kLnStep;
  const auto last = static_cast<double>(share_.size() - 1);
  if (g >= last) return share_.back() * std::exp(last * kLnStep) / overdrive;
  const auto i = static_cast<std::size_t>(g);
  const double w = g - static_cast<double>(i);
  return share_[i] + w * (share_[i + 1] - share_[i]);
}

}  // namespace tofkit::device
