// Example 1: the paper's link budget (Eqs. 4-9) for the built-in device.
#include <cstdio>

#include "tofkit/device/device_config.hpp"
#include "tofkit/physics/environment.hpp"
#include "tofkit/physics/link_budget.hpp"

int main() {
  const auto config = tofkit::device::preset("paper");
  std::printf("%8s %12s %8s\n", "R (m)", "Pr (W)", "SNR");
  for (double r : {1.0, 2.0, 4.0, 8.0, 10.0}) {
    const auto p = tofkit::physics::link_budget_at(config.link, r, 0.1);
    std::printf("%8.1f %12.4e %8.2f\n", r, p.received_power_w, p.snr);
  }
  std::printf("SNR = 10 at %.2f m (rho = 0.1, indoors: the preset's light)\n",
              tofkit::physics::range_at_snr(config.link, 10.0, 0.1));
  // The paper's Figure 3 (and tofkit demo's headline): Table 1's sunlight, Eq. 9 as printed.
  auto sunlit = config.link;
  sunlit.environment.solar_irradiance_w_per_m2_um =
      tofkit::physics::kTable1SolarIrradiance_w_per_m2_um;
  sunlit.environment.eq9_as_printed = true;
  std::printf("SNR = 10 at %.2f m (rho = 0.1, Table 1's sunlight, as paper Fig. 3)\n",
              tofkit::physics::range_at_snr(sunlit, 10.0, 0.1));
}
