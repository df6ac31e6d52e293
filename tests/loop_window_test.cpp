// The loop's counting window over a return that changes within it
// (device/loop_window.hpp; thesis Section 4.7, Figs. 4.23, 4.27, 4.28). Oracles:
// reciprocal counting's closed forms built from the loop's own noise-free
// periods (OscillatorLoop::state): a window over two targets reads the
// time-weighted harmonic mean of their periods; a stall between the first and
// the last edge lengthens the mean period by stall / periods; the same stall
// before the first edge only costs periods.
#include "tofkit/device/loop_window.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <stdexcept>
#include <vector>

#include "tofkit/device/accurange_preset.hpp"
#include "tofkit/experiments/thesis_grey_chart.hpp"

using namespace tofkit;

namespace {

// The board counts over the whole window (gate_fraction 1) for long outputs,
// so the 80 MHz count's quantization (c/4 t_clk T / gate) is far below the
// effects measured; no slow delay wander.
device::DeviceConfig quiet_config() {
  auto c = device::accurange_preset();
  c.oscillator.gate_fraction = 1.0;
  c.oscillator.flicker_delay_ps = 0.0;
  c.oscillator.duty_wander = 0.0;
  return c;
}

constexpr int kShots = 1 << 15;  // 105 ms

double window_ns(const device::DeviceConfig& c) {
  return kShots / c.link.laser.repetition_hz * 1e9;
}

double period_ns(const device::OscillatorLoop& loop, const ranging::RawMeasurement& m) {
  return 2.0 * (m.tof_ns + loop.config().oscillator.zero_half_period_ns);
}

const device::Target kWhite = device::Target::plate(0.4826, experiments::grey_reflectance(0));
const device::Target kBlack = device::Target::plate(0.4826, experiments::grey_reflectance(255));

}  // namespace

TEST(LoopWindow, TwoTargetsReadTheTimeWeightedHarmonicMeanOfTheirPeriods) {
  const auto c = quiet_config();
  const device::OscillatorLoop loop(c);
  const double w = window_ns(c);
  const double t_white = loop.state(kWhite, {}).period_ns;
  const double t_black = loop.state(kBlack, {}).period_ns;
  // The walk: the weak return's period is longer (0.28 ns at 360 MHz), so the
  // time-weighted mean moves by 0.07-0.21 ns over the shares, 35x the tolerance.
  ASSERT_GT(t_black - t_white, 0.2);
  for (const double share : {0.25, 0.5, 0.75}) {
    const std::vector<device::LoopStretch> s{{kWhite, {}, share * w, 0.0},
                                             {kBlack, {}, (1 - share) * w, 0.0}};
    const auto m = device::count_loop_window(loop, s, 5, 100, kShots);
    ASSERT_TRUE(m.has_echo());
    // Reciprocal counting: span over periods, periods = time / period per target.
    const double expected = w / (share * w / t_white + (1 - share) * w / t_black);
    EXPECT_NEAR(period_ns(loop, m), expected, 2e-3) << share;
    EXPECT_FALSE(m.flags & ranging::kRawPartialEchoes);
  }
}

TEST(LoopWindow, AStallBetweenEdgesReadsLongAStallBeforeThemDoesNot) {
  const auto c = quiet_config();
  const device::OscillatorLoop loop(c);
  const double w = window_ns(c);
  const double t_black = loop.state(kBlack, {}).period_ns;
  const double stall = 0.1 * w;
  // Locked on white for half the window, then black with a stall at its start:
  // the stall lies between the first edge and the last.
  const double t_white = loop.state(kWhite, {}).period_ns;
  const std::vector<device::LoopStretch> inside{{kWhite, {}, 0.5 * w, 0.0},
                                                {kBlack, {}, 0.5 * w, stall}};
  const auto m = device::count_loop_window(loop, inside, 5, 200, kShots);
  ASSERT_TRUE(m.has_echo());
  const double periods = 0.5 * w / t_white + (0.5 * w - stall) / t_black;
  EXPECT_NEAR(period_ns(loop, m), w / periods, 2e-3);
  EXPECT_GT(period_ns(loop, m), 1.05 * t_black);  // longer than either target's period
  EXPECT_TRUE(m.flags & ranging::kRawPartialEchoes);
  // The same stall at the window's start: the first edge comes after it.
  const std::vector<device::LoopStretch> before{{kBlack, {}, w, stall}};
  const auto b = device::count_loop_window(loop, before, 5, 300, kShots);
  ASSERT_TRUE(b.has_echo());
  EXPECT_NEAR(period_ns(loop, b), t_black, 2e-3);
  EXPECT_TRUE(b.flags & ranging::kRawPartialEchoes);
}

TEST(LoopWindow, ExtraEdgesReadShortMissedRisesReadLong) {
  // count_factor edges per clean period over the same span: the mean period is
  // the clean one over the factor (chatter, > 1: short; missed rises, < 1: long).
  const auto c = quiet_config();
  const device::OscillatorLoop loop(c);
  const double w = window_ns(c);
  const double t_black = loop.state(kBlack, {}).period_ns;
  const std::vector<device::LoopStretch> clean{{kBlack, {}, w, 0.0}};
  const auto m0 = device::count_loop_window(loop, clean, 5, 600, kShots);
  // A factor of exactly 1 is today's window, byte for byte.
  const std::vector<device::LoopStretch> one{{kBlack, {}, w, 0.0, 1.0}};
  const auto m1 = device::count_loop_window(loop, one, 5, 600, kShots);
  EXPECT_EQ(std::memcmp(&m0.tof_ns, &m1.tof_ns, sizeof(double)), 0);
  EXPECT_NEAR(period_ns(loop, m0), t_black, 2e-3);
  for (const double f : {0.9, 1.1}) {
    const std::vector<device::LoopStretch> s{{kBlack, {}, w, 0.0, f}};
    const auto m = device::count_loop_window(loop, s, 5, 600, kShots);
    ASSERT_TRUE(m.has_echo());
    EXPECT_NEAR(period_ns(loop, m), t_black / f, 2e-3) << f;
    if (f > 1)
      EXPECT_LT(m.distance_raw_m, m0.distance_raw_m - 0.1);  // -2.1 ns of period: 0.16 m short
    else
      EXPECT_GT(m.distance_raw_m, m0.distance_raw_m + 0.1);  // +2.6 ns: 0.19 m long
  }
  // No edges counted: no echo; a negative count is refused.
  const std::vector<device::LoopStretch> none{{kBlack, {}, w, 0.0, 0.0}};
  EXPECT_FALSE(device::count_loop_window(loop, none, 5, 600, kShots).has_echo());
  const std::vector<device::LoopStretch> bad{{kBlack, {}, w, 0.0, -0.1}};
  EXPECT_THROW((void)device::count_loop_window(loop, bad, 5, 600, kShots), std::invalid_argument);
}

TEST(LoopWindow, NoLockedTimeInTheGateIsNoEcho) {
  auto c = quiet_config();
  c.oscillator.gate_fraction = 0.5;
  const device::OscillatorLoop loop(c);
  const double w = window_ns(c);
  // Lock lost over the gate (the first half), locked after it: nothing counted.
  const std::vector<device::LoopStretch> s{{kBlack, {}, 0.5 * w, 0.5 * w},
                                           {kBlack, {}, 0.5 * w, 0.0}};
  const auto m = device::count_loop_window(loop, s, 5, 400, kShots);
  EXPECT_FALSE(m.has_echo());
  EXPECT_TRUE(std::isfinite(m.temperature_c));  // the sensor still reads
  // A miss (no surface) is no edges either.
  const std::vector<device::LoopStretch> miss{{device::Target{}, {}, w, 0.0}};
  EXPECT_FALSE(device::count_loop_window(loop, miss, 5, 500, kShots).has_echo());
}

TEST(LoopWindow, BadStretchesAreRefused) {
  const device::OscillatorLoop loop(quiet_config());
  const std::vector<device::LoopStretch> stall_too_long{{kBlack, {}, 10.0, 11.0}};
  EXPECT_THROW((void)device::count_loop_window(loop, stall_too_long, 1, 1, 16),
               std::invalid_argument);
  EXPECT_THROW((void)device::count_loop_window(loop, {}, 1, 1, 16), std::invalid_argument);
}
