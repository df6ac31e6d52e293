// The emitter stage's turn-on transient, alone (device/emitter.hpp). Oracle:
// the exponential decay written out here: the first shot's range bias is
// turn_on_bias_mm (as round-trip time 2 b / c), one time constant later it
// is 1/e of that, and it counts shots at the repetition rate.
#include <gtest/gtest.h>

#include <cmath>

#include "tofkit/device/device_config.hpp"
#include "tofkit/device/emitter.hpp"

using namespace tofkit;

TEST(Emitter, TurnOnBiasDecaysWithTheLasersTimeConstant) {
  auto laser = device::preset("paper").link.laser;
  laser.turn_on_bias_mm = 25.0;
  laser.turn_on_time_constant_ms = 40.0;
  laser.repetition_hz = 1e6;
  constexpr double kC = 0.2998;  // m/ns
  const double first_ns = 2.0 * 25e-3 / kC;
  EXPECT_NEAR(device::turn_on_bias_ns(laser, 0.0, 0, kC), first_ns, 1e-15);
  EXPECT_NEAR(device::turn_on_bias_ns(laser, 40.0, 0, kC), first_ns / std::exp(1.0), 1e-15);
  // 40 000 shots at 1 MHz are the same 40 ms.
  EXPECT_NEAR(device::turn_on_bias_ns(laser, 0.0, 40000, kC), first_ns / std::exp(1.0), 1e-15);
  EXPECT_NEAR(device::turn_on_bias_ns(laser, 20.0, 20000, kC), first_ns / std::exp(1.0), 1e-15);
  // Settled after 30 time constants: exactly none.
  EXPECT_GT(device::turn_on_bias_ns(laser, 1199.0, 0, kC), 0.0);
  EXPECT_EQ(device::turn_on_bias_ns(laser, 1201.0, 0, kC), 0.0);
  EXPECT_EQ(device::turn_on_bias_ns(laser, 1e9, 0, kC), 0.0);  // the default: long on
}
