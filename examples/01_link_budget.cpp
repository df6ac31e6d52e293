// Example 1: the paper's link budget (Eqs. 4-9) for the built-in device.
#include <cstdio>

#include "tofkit/device/device_config.hpp"
#include "tofkit/physics/link_budget.hpp"

int main() {
  const auto config = tofkit::device::preset("paper");
  std::printf("%8s %12s %8s\n", "R (m)", "Pr (W)", "SNR");
  for (double r : {1.0, 2.0, 4.0, 8.0, 10.0}) {
    const auto p = tofkit::physics::link_budget_at(config.link, r, 0.1);
    std::printf("%8.1f %12.4e %8.2f\n", r, p.received_power_w, p.snr);
  }
  std::printf("SNR = 10 at %.2f m (rho = 0.1)\n",
              tofkit::physics::range_at_snr(config.link, 10.0, 0.1));
}
