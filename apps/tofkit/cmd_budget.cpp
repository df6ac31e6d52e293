// tofkit budget [--reflectance R] [--angle DEG] [--json]: the optical link budget
// and noise currents over distance (paper Eqs. 4-9) and the SNR = 10 range.

#include <fmt/format.h>

#include <cmath>
#include <cstdio>
#include <memory>
#include <nlohmann/json.hpp>
#include <stdexcept>
#include <vector>

#include "app.hpp"
#include "tofkit/physics/environment.hpp"
#include "tofkit/physics/link_budget.hpp"

namespace tofkit::app {
namespace {

struct BudgetOptions {
  double reflectance = 0.1;  // paper Table 1
  double angle_deg = 0.0;
  bool json = false;
};

constexpr double kDetectionSnr = 10.0;  // the paper's detection criterion (Figure 3)
constexpr double kFirstDistance_m = 0.5;
constexpr double kStepDistance_m = 0.5;
constexpr int kRowCount = 30;  // 0.5 .. 15 m

// Peak optical power that puts the linear (unshaped) echo at the comparator
// threshold: V = R0 M Z Pr. Ignores the pulse shaping by the receiver bandwidth,
// so it is an upper bound on the reach.
double threshold_power_w(const device::DeviceConfig& config) {
  const auto& rx = config.link.receiver;
  return config.discriminator.threshold_v /
         (rx.responsivity_a_per_w * rx.apd_gain * rx.transimpedance_kohm * 1e3);
}

void run_budget(const BudgetOptions& options, const AppContext& ctx) {
  const device::DeviceConfig config = ctx.load_config();
  const physics::LinkConfig& link = config.link;
  const double temperature_c = link.receiver.nominal_temperature_c;

  std::vector<physics::LinkBudgetPoint> rows;
  for (int i = 0; i < kRowCount; ++i) {
    const double distance_m = kFirstDistance_m + kStepDistance_m * i;
    rows.push_back(physics::link_budget_at(link, distance_m, options.reflectance, options.angle_deg,
                                           temperature_c));
  }
  const double range_snr10_m =
      physics::range_at_snr(link, kDetectionSnr, options.reflectance, options.angle_deg);
  const double min_power_w = threshold_power_w(config);
  const double range_threshold_m =
      physics::max_range_extended_m(link, options.reflectance, options.angle_deg, min_power_w);

  if (options.json) {
    nlohmann::json j;
    j["preset"] = config.name;
    j["reflectance"] = options.reflectance;
    j["angle_deg"] = options.angle_deg;
    j["temperature_c"] = temperature_c;
    j["range_at_snr10_m"] = range_snr10_m;
    j["threshold_power_w"] = min_power_w;
    j["max_range_extended_m"] = range_threshold_m;
    auto& out = j["rows"] = nlohmann::json::array();
    for (const auto& r : rows) {
      out.push_back({{"distance_m", r.distance_m},
                     {"received_power_w", r.received_power_w},
                     {"background_power_w", r.background_power_w},
                     {"signal_current_a", r.signal_current_a},
                     {"signal_shot_a", r.noise.signal_shot_a},
                     {"background_shot_a", r.noise.background_shot_a},
                     {"dark_shot_a", r.noise.dark_shot_a},
                     {"thermal_a", r.noise.thermal_a},
                     {"total_noise_a", r.noise.total_a},
                     {"snr", r.snr}});
    }
    fmt::print("{}\n", j.dump(2));
    return;
  }

  fmt::print("link budget: preset {}, reflectance {}, angle {} deg, APD at {} C\n", config.name,
             options.reflectance, options.angle_deg, temperature_c);
  fmt::print("{:>10} {:>12} {:>12} {:>12} {:>12} {:>12} {:>12} {:>12} {:>12} {:>9}\n", "distance_m",
             "received_w", "background_w", "signal_a", "sig_shot_a", "bg_shot_a", "dark_shot_a",
             "thermal_a", "noise_a", "snr");
  for (const auto& r : rows) {
    fmt::print(
        "{:>10.1f} {:>12.4e} {:>12.4e} {:>12.4e} {:>12.4e} {:>12.4e} {:>12.4e} {:>12.4e} "
        "{:>12.4e} {:>9.2f}\n",
        r.distance_m, r.received_power_w, r.background_power_w, r.signal_current_a,
        r.noise.signal_shot_a, r.noise.background_shot_a, r.noise.dark_shot_a, r.noise.thermal_a,
        r.noise.total_a, r.snr);
  }
  const char* light = link.environment.solar_irradiance_w_per_m2_um > 0
                          ? "this configuration's sunlight"
                          : "indoors, this configuration";
  fmt::print("range at SNR = {} (paper's detection criterion), {}: {:.2f} m\n", kDetectionSnr,
             light, range_snr10_m);
  // The paper's Figure 3 (and the demo's headline): Table 1's sunlight, Eq. 9 as printed.
  auto sunlit = link;
  sunlit.environment.solar_irradiance_w_per_m2_um = physics::kTable1SolarIrradiance_w_per_m2_um;
  sunlit.environment.eq9_as_printed = true;
  fmt::print("range at SNR = {} in Table 1's sunlight (paper Fig. 3, tofkit demo): {:.2f} m\n",
             kDetectionSnr,
             physics::range_at_snr(sunlit, kDetectionSnr, options.reflectance, options.angle_deg));
  fmt::print(
      "range where the echo peak meets the {} V threshold (Eq. 7, unshaped pulse): {:.3f} m\n",
      config.discriminator.threshold_v, range_threshold_m);
}

const bool registered = register_command("budget", [](CLI::App& sub, AppContext& ctx) {
  sub.description("optical link budget, noise currents and SNR over 0.5-15 m (paper Eqs. 4-9)");
  auto options = std::make_shared<BudgetOptions>();
  sub.add_option("--reflectance", options->reflectance, "Lambertian target reflectance")
      ->check(InRange(1e-6, 1.0))
      ->capture_default_str();
  sub.add_option("--angle", options->angle_deg, "incidence angle, degrees")
      ->check(InRange(0.0, 89.9))
      ->capture_default_str();
  sub.add_flag("--json", options->json, "print JSON instead of a table");
  sub.callback([options, &ctx] { run_budget(*options, ctx); });
});

}  // namespace
}  // namespace tofkit::app
