// Example 2: measure plates on the virtual rangefinder, fit the paper's
// gray-value chain, and correct a measurement it did not see.
#include <cstdio>
#include <vector>

#include "tofkit/calib/chain_fit.hpp"
#include "tofkit/device/virtual_rangefinder.hpp"

using namespace tofkit;

int main() {
  const device::VirtualRangefinder rangefinder(device::preset("paper"));
  std::vector<ranging::Record> calibration;
  std::uint64_t stream = 0;
  for (double distance : {1.3, 2.355, 4.3, 7.3})
    for (double reflectance = 0.02; reflectance <= 1.0; reflectance *= 1.15) {
      const auto raw =
          rangefinder.measure(device::Target::plate(distance, reflectance), {}, 1, stream++);
      calibration.push_back({{distance, reflectance, 0.0, 20.0}, raw});
    }
  calib::ChainFitOptions options;
  options.steps.temperature = false;  // one temperature here: offset + gray value only
  const auto fit = calib::fit_chain(calibration, options);
  std::printf("%s\n", fit.summary().c_str());

  const auto raw = rangefinder.measure(device::Target::plate(5.0, 0.3), {}, 2, 0);
  const auto range = fit.pipeline.apply(raw);
  std::printf("true 5.000 m: raw %.4f m, corrected %.4f m\n", raw.distance_raw_m, range.distance_m);
}
