// The operating point, alone (device/operating_point.hpp). Oracles: the
// tempcos as slopes between two ambient temperatures on a warmed-up device
// without a heater (delay: delay_tempco_ps_per_c; TDC bins:
// bin_tempco_ppm_per_c; laser power: power_temp_coeff_per_c), the APD's
// gain from physics::apd_gain_at at the board's temperature and the gain
// chain volts_per_watt ~ gain x power, the speed of light in air against
// the vacuum's over a group index within 1e-3 of 1, the warm-up gradient's
// extra delay fading as the device warms, and the front end's noise at the
// point's gain.
#include <gtest/gtest.h>

#include <cmath>

#include "tofkit/device/operating_point.hpp"
#include "tofkit/physics/link_budget.hpp"

using namespace tofkit;

TEST(OperatingPoint, TempcosAreTheSlopesBetweenTwoTemperatures) {
  auto cfg = device::preset("paper");
  cfg.thermal.heater_max_rise_c = 0.0;  // the board at the die's temperature
  const double warm = 1e9;              // minutes: settled
  const auto a = device::operating_point(cfg, 10.0, warm, 1.0, 0.2997);
  const auto b = device::operating_point(cfg, 30.0, warm, 1.0, 0.2997);
  const double d_board = b.board_c - a.board_c;
  ASSERT_NEAR(d_board, 20.0, 1e-9);
  EXPECT_NEAR((b.fixed_delay_ns - a.fixed_delay_ns) / d_board,
              cfg.thermal.delay_tempco_ps_per_c * 1e-3, 1e-12);
  EXPECT_NEAR((b.tdc_bin_scale - a.tdc_bin_scale) / d_board, cfg.tdc.bin_tempco_ppm_per_c * 1e-6,
              1e-15);
  EXPECT_NEAR((b.power_scale - a.power_scale) / d_board, cfg.link.laser.power_temp_coeff_per_c,
              1e-12);
  for (const auto& p : {a, b}) {
    EXPECT_DOUBLE_EQ(p.gain, physics::apd_gain_at(cfg.link.receiver, p.board_c));
    EXPECT_NEAR(p.volts_per_watt, p.gain * p.power_scale, 1e-12 * p.volts_per_watt);
    const auto noise = device::front_end_noise(cfg.link.receiver, p.gain);
    EXPECT_EQ(p.noise.floor_var_v2, noise.floor_var_v2);
    EXPECT_EQ(p.noise.shot_var_per_v, noise.shot_var_per_v);
    // Air slows light by its group index, about 1.0003 near the surface.
    const double index = 0.299792458 / p.c_m_per_ns;
    EXPECT_GT(index, 1.0);
    EXPECT_LT(index, 1.001);
  }
  // Warmer air is thinner: light is faster.
  EXPECT_GT(b.c_m_per_ns, a.c_m_per_ns);
}

TEST(OperatingPoint, WarmUpGradientFadesAsTheDeviceSettles) {
  const auto cfg = device::preset("paper");
  const double tau = cfg.thermal.warmup_time_constant_min;
  const auto settled = device::operating_point(cfg, 20.0, 1e9, 1.0, 0.2997);
  double previous = -1;
  for (const double minutes : {0.5 * tau, tau, 3.0 * tau, 10.0 * tau}) {
    const auto p = device::operating_point(cfg, 20.0, minutes, 1.0, 0.2997);
    const double extra = std::abs(p.fixed_delay_ns - settled.fixed_delay_ns);
    if (previous >= 0) EXPECT_LT(extra, previous) << minutes << " min";
    previous = extra;
  }
  EXPECT_LT(previous, 1e-3);  // ps-level after ten time constants
}
