#pragma once
// The "other parts" device of the calibration tests (issue 8): the paper
// preset with a slower receiver, a wider pulse, a lower APD gain, a higher
// threshold and a finer TDC whose firmware calibrates its carry chain's bins by
// a code-density test. Reached only through config keys, as a user would.

#include <gtest/gtest.h>

#include <string>
#include <variant>

#include "tofkit/device/device_config.hpp"

namespace tofkit::test {

/// Sets a config key through the public key table (fails the test if unknown).
inline void set_key(device::DeviceConfig& config, const std::string& key, double value) {
  for (auto& field : device::config_fields(config)) {
    if (field.key != key) continue;
    if (auto* d = std::get_if<double*>(&field.value)) **d = value;
    if (auto* i = std::get_if<int*>(&field.value)) **i = static_cast<int>(value);
    if (auto* b = std::get_if<bool*>(&field.value)) **b = value != 0;
    return;
  }
  FAIL() << "no config key " << key;
}

/// Other parts: slower receiver, wider pulse, lower APD gain, higher threshold,
/// finer TDC with code-density calibrated bins. Its firmware's code-density
/// test (2^20 hits), as carry-chain TDC products do it, leaves the fine codes'
/// INL at the histogram's counting error (~0.06 LSB, 0.4 mm): with the laser
/// fired on the clock, a periodic range error (period c / 2 f_coarse = 0.75 m).
inline device::DeviceConfig other_parts() {
  device::DeviceConfig config = device::preset("paper");
  set_key(config, "receiver.bandwidth_mhz", 100.0);
  set_key(config, "laser.pulse_width_ns", 1.6);
  set_key(config, "receiver.apd_gain", 60.0);
  set_key(config, "discriminator.threshold_v", 0.05);
  set_key(config, "tdc.lsb_ps", 40.0);
  set_key(config, "tdc.code_density_hits", 1 << 20);
  // A quieter timing board than the paper's (whose random wander reproduces
  // the scatter of its repeated tests, Figs. 7 and 9): the slow flicker only.
  set_key(config, "measurement.delay_wander_ps", 0.0);
  set_key(config, "discriminator.level_wander_mv", 0.0);  // and a steadier comparator
  EXPECT_TRUE(device::validate(config).empty());
  return config;
}

}  // namespace tofkit::test
