// The timing stage's slow drift, alone (device/slow_offsets.hpp). Oracles: the
// configured spectra's variances over many power-ons (seeds) at a fixed time,
// one cause at a time (power-on offset: a normal of rms power_on_offset_ps;
// flicker: eight random-phase octaves of total rms flicker_delay_ps; wander:
// twelve unit-variance levels of total rms delay_wander_ps, and the
// comparator level's of rms level_wander_mv); the wander's correlation in time
// (near 1 well inside its shortest correlation time, near 0 beyond its
// longest); the draws' reproducibility by seed and their independence of the
// grouping of outputs.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <stdexcept>
#include <vector>

#include "tofkit/device/device_config.hpp"
#include "tofkit/device/slow_offsets.hpp"

using namespace tofkit;
using device::SlowOffsets;

namespace {

/// The paper preset with only the named slow causes left on.
device::DeviceConfig only(double power_on_ps, double flicker_ps, double wander_ps,
                          double level_mv) {
  auto c = device::preset("paper");
  c.measurement.power_on_offset_ps = power_on_ps;
  c.measurement.flicker_delay_ps = flicker_ps;
  c.measurement.delay_wander_ps = wander_ps;
  c.discriminator.level_wander_mv = level_mv;
  return c;
}

struct Offset {
  double delay_ns = 0, level_v = 0;
};

/// Output `stream` of the run `seed`, at session time t_s.
Offset offset_at(const SlowOffsets& slow, std::uint64_t seed, std::uint64_t stream, double t_s) {
  device::Conditions cond;
  cond.session_time_s = t_s;
  Offset o;
  slow.offsets_ns(seed, slow.run_draws(seed), stream, 1, &cond, &o.delay_ns, &o.level_v);
  return o;
}

struct Moments {
  double mean = 0, rms = 0;
};
Moments moments(const std::vector<double>& v) {
  Moments m;
  for (const double x : v) m.mean += x;
  m.mean /= static_cast<double>(v.size());
  for (const double x : v) m.rms += (x - m.mean) * (x - m.mean);
  m.rms = std::sqrt(m.rms / static_cast<double>(v.size() - 1));
  return m;
}

constexpr int kPowerOns = 4000;  // rms to 1.1 % (1 / sqrt(2 N)); bands at 5 %

/// The delay offsets (ps) and level offsets (mV) of kPowerOns power-ons at one time.
void over_power_ons(const device::DeviceConfig& cfg, double t_s, std::vector<double>& delay_ps,
                    std::vector<double>& level_mv) {
  const SlowOffsets slow(cfg, 1);
  delay_ps.clear();
  level_mv.clear();
  for (int s = 0; s < kPowerOns; ++s) {
    const auto o = offset_at(slow, 1000 + static_cast<std::uint64_t>(s), 7, t_s);
    delay_ps.push_back(o.delay_ns * 1e3);
    level_mv.push_back(o.level_v * 1e3);
  }
}

}  // namespace

TEST(SlowOffsets, EachCauseHasItsConfiguredRmsOverPowerOns) {
  std::vector<double> delay, level;
  // Power-on offset alone: the same at every time of a run.
  over_power_ons(only(10.0, 0, 0, 0), 3.0, delay, level);
  EXPECT_NEAR(moments(delay).rms, 10.0, 0.5);
  EXPECT_NEAR(moments(delay).mean, 0.0, 4 * 10.0 / std::sqrt(kPowerOns));
  EXPECT_EQ(moments(level).rms, 0.0);
  // Flicker alone: eight octaves, rms flicker_delay_ps / sqrt(8) each.
  for (const double t : {0.0, 37.0, 900.0}) {
    over_power_ons(only(0, 5.0, 0, 0), t, delay, level);
    EXPECT_NEAR(moments(delay).rms, 5.0, 0.25) << "t " << t;
  }
  // Wander alone, the delay's and the comparator level's, at several times
  // (inside a knot interval, w not 0, the quarter-turn weights keep the variance 1).
  for (const double t : {0.0, 0.0123, 5.5, 1234.5}) {
    over_power_ons(only(0, 0, 20.0, 1.0), t, delay, level);
    EXPECT_NEAR(moments(delay).rms, 20.0, 1.0) << "t " << t;
    EXPECT_NEAR(moments(level).rms, 1.0, 0.05) << "t " << t;
  }
}

TEST(SlowOffsets, CausesAddAsIndependentVariances) {
  std::vector<double> delay, level;
  over_power_ons(only(10.0, 5.0, 20.0, 0.0), 42.0, delay, level);
  EXPECT_NEAR(moments(delay).rms, std::sqrt(100.0 + 25.0 + 400.0), 0.05 * 22.9);
}

TEST(SlowOffsets, WanderIsCorrelatedOverItsTimescales) {
  // Correlation over power-ons of the wander at t and t + lag.
  const SlowOffsets slow(only(0, 0, 20.0, 1.0), 1);
  auto correlation = [&](double lag_s, bool level) {
    double sxy = 0, sxx = 0, syy = 0;
    for (int s = 0; s < kPowerOns; ++s) {
      const auto seed = 5000 + static_cast<std::uint64_t>(s);
      const auto a = offset_at(slow, seed, 0, 100.3);
      const auto b = offset_at(slow, seed, 0, 100.3 + lag_s);
      const double x = level ? a.level_v : a.delay_ns, y = level ? b.level_v : b.delay_ns;
      sxy += x * y;
      sxx += x * x;
      syy += y * y;
    }
    return sxy / std::sqrt(sxx * syy);
  };
  for (const bool level : {false, true}) {
    // Well inside the shortest level's 1 ms: all twelve levels move little.
    EXPECT_GT(correlation(1e-5, level), 0.99);
    // Past the longest level's 4^11 ms (70 min) and its next knot: independent.
    EXPECT_NEAR(correlation(3e4, level), 0.0, 0.06);
    // In between, a 1/f process: after 20 s levels 0..7 (up to 16 s) have
    // decorrelated, and level k >= 8 (s_k = 4^k ms) keeps about 1 - 20 s / s_k
    // (0.69, 0.92, 0.98, 0.995): (0.69 + 0.92 + 0.98 + 0.995) / 12 = 0.30.
    EXPECT_NEAR(correlation(20.0, level), 0.30, 0.06);
  }
}

TEST(SlowOffsets, DrawsAreReproducibleBySeedAndIndependentOfGrouping) {
  const auto cfg = only(10.0, 5.0, 20.0, 1.0);
  const SlowOffsets a(cfg, 11), b(cfg, 12);  // two devices: their own caches
  std::vector<device::Conditions> conds(SlowOffsets::kMaxOutputs);
  for (std::size_t i = 0; i < conds.size(); ++i)
    conds[i].session_time_s = 0.37 * static_cast<double>(i % 5);
  std::vector<double> d(conds.size()), l(conds.size());
  a.offsets_ns(9, a.run_draws(9), 100, conds.size(), conds.data(), d.data(), l.data());
  for (std::size_t i = 0; i < conds.size(); ++i) {
    double d1 = 0, l1 = 0;
    // One at a time, another device, interleaved with another seed's draws.
    (void)b.run_draws(10);
    b.offsets_ns(9, b.run_draws(9), 100 + i, 1, &conds[i], &d1, &l1);
    EXPECT_EQ(d1, d[i]) << i;
    EXPECT_EQ(l1, l[i]) << i;
  }
  const auto other = offset_at(a, 10, 100, conds[0].session_time_s);
  EXPECT_NE(other.delay_ns, d[0]);
  EXPECT_THROW(a.offsets_ns(9, a.run_draws(9), 0, SlowOffsets::kMaxOutputs + 1, conds.data(),
                            d.data(), l.data()),
               std::invalid_argument);
}

// The flicker does not repeat: each octave's frequency lies log-uniformly
// within its octave over power-ons (two chains of x4 steps, even and odd
// octaves, each from a base drawn at power-on), so the change over a lag
// tau has the mean square sum_k A_k^2 (1 - E cos 2 pi f_k tau), A_k^2 = 2
// rms^2 / 8, E over f log-uniform in [f_0 2^k, f_0 2^(k+1)) (integrated
// here). Octaves at exact doublings of f_0 (1 mHz) would repeat every
// 1000 s: the change over 1000 s nil, over 1200 s 1.12x its mean.
TEST(SlowOffsets, FlickerDoesNotRepeat) {
  const auto cfg = only(0, 5, 0, 0);
  const SlowOffsets slow(cfg, 1);
  const double period_s = cfg.measurement.shots / cfg.link.laser.repetition_hz;
  const double rms_ns = cfg.measurement.flicker_delay_ps * 1e-3;
  for (const double lag_s : {1000.0, 1200.0, 1800.0}) {
    double oracle = 0;
    for (int k = 0; k < SlowOffsets::kFlickerOctaves; ++k) {
      // E cos over the octave, midpoint rule in ln f (2000 steps).
      constexpr int kSteps = 2000;
      double e = 0;
      for (int j = 0; j < kSteps; ++j) {
        const double f = SlowOffsets::kFlickerLowestHz * std::exp2(k + (j + 0.5) / kSteps);
        e += std::cos(2 * M_PI * f * lag_s) / kSteps;
      }
      oracle += 2 * rms_ns * rms_ns / SlowOffsets::kFlickerOctaves * (1 - e);
    }
    const auto from = static_cast<std::uint64_t>(600 / period_s);
    const auto to = static_cast<std::uint64_t>((600 + lag_s) / period_s);
    std::vector<double> d2;
    for (int s = 0; s < kPowerOns; ++s) {
      const auto seed = 1000 + static_cast<std::uint64_t>(s);
      const double d =
          offset_at(slow, seed, to, 0).delay_ns - offset_at(slow, seed, from, 0).delay_ns;
      d2.push_back(d * d);
    }
    const Moments m = moments(d2);
    const double se = m.rms / std::sqrt(static_cast<double>(kPowerOns));
    EXPECT_NEAR(m.mean, oracle, 4 * se) << "lag " << lag_s << " s";
    // Well away from nil at a whole period of the lowest octave.
    EXPECT_GT(m.mean, 0.5 * 2 * rms_ns * rms_ns) << "lag " << lag_s << " s";
  }
}
