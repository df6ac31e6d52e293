// The discriminator stage, alone (device/discriminator.hpp). Oracle: the
// receiver's noise simulated here as white Gaussian noise through two equal
// one-pole filters (time constant tau_p, step tau_p / 50), then
//  - its counted threshold upcrossings against Rice's rate,
//  - its time above the threshold per excursion against the false alarm's
//    width, and the false alarms' first-crossing times against the
//    exponential law they draw from (mean 1 / nu, truncated to the window),
//  - a ramp through it: crossings per edge against 1 + 2 c(r), the count the
//    chatter limit rests on;
// the crossing level against its defining equation and its mean bias; and the
// sampled comparator (waveform mode) against a noise-free echo's closed-form
// crossings, its arming and clip recovery, jitter = noise / slope, and its
// noise alone firing at Rice's rate at the waveform mode's step (tau_p / 6).
#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <vector>

#include "tofkit/device/discriminator.hpp"

using namespace tofkit;

namespace {

/// Band-limited Gaussian noise of unit variance: white noise through two
/// equal one-pole filters of time constant tau (sampled every dt).
class TwoPoleNoise {
 public:
  TwoPoleNoise(double tau_ns, double dt_ns, unsigned seed)
      : a_(std::exp(-dt_ns / tau_ns)), gen_(seed) {
    // Variance of the cascade for unit white noise: (1-a)^4 (1+a^2) / (1-a^2)^3.
    const double var = std::pow(1.0 - a_, 4) * (1.0 + a_ * a_) / std::pow(1.0 - a_ * a_, 3);
    norm_ = 1.0 / std::sqrt(var);
    for (int k = 0; k < 20 * static_cast<int>(tau_ns / dt_ns); ++k) next();  // settle
  }
  double next() {
    y1_ = a_ * y1_ + (1.0 - a_) * white_(gen_);
    y2_ = a_ * y2_ + (1.0 - a_) * y1_;
    return norm_ * y2_;
  }

 private:
  double a_, norm_ = 1, y1_ = 0, y2_ = 0;
  std::mt19937_64 gen_;
  std::normal_distribution<double> white_;
};

constexpr double kTau = 1.0;  // ns
constexpr double kDt = kTau / 50.0;

}  // namespace

TEST(Discriminator, RiceRateAndExcursionWidthMatchSimulatedNoise) {
  TwoPoleNoise noise(kTau, kDt, 17);
  const std::vector<double> levels{1.5, 2.5, 3.0};
  std::vector<long> ups(levels.size(), 0), above(levels.size(), 0);
  constexpr long kSamples = 20'000'000;  // 400 us: ~2800 upcrossings at u = 2.5
  double previous = noise.next(), sum2 = 0;
  for (long k = 0; k < kSamples; ++k) {
    const double x = noise.next();
    sum2 += x * x;
    for (std::size_t i = 0; i < levels.size(); ++i) {
      ups[i] += previous < levels[i] && x >= levels[i];
      above[i] += x >= levels[i];
    }
    previous = x;
  }
  EXPECT_NEAR(sum2 / kSamples, 1.0, 0.02);  // the simulated noise has unit variance
  const double duration_ns = kSamples * kDt;
  for (std::size_t i = 0; i < levels.size(); ++i) {
    SCOPED_TRACE("u = " + std::to_string(levels[i]));
    const double nu = device::rice_upcrossing_rate_per_ns(levels[i], kTau);
    const double counted = static_cast<double>(ups[i]) / duration_ns;
    // Poisson counting error 1 / sqrt(count): 1 % at u = 1.5, 4 % at u = 3.
    EXPECT_NEAR(counted / nu, 1.0, 4.0 / std::sqrt(static_cast<double>(ups[i])) + 0.01);
    // The false alarm's fall: the mean time above the level per excursion.
    device::FalseAlarms alarms;
    alarms.rate_per_ns = counted;  // the simulation's own rate: the width alone
    alarms.threshold_over_noise = levels[i];
    alarms.armed_ns = 0;
    alarms.set_window(1e12);
    double rise = 0, fall = 0;
    ASSERT_TRUE(alarms.first_crossing(0.5, rise, fall));
    const double width_simulated =
        static_cast<double>(above[i]) * kDt / static_cast<double>(ups[i]);
    EXPECT_NEAR((fall - rise) / width_simulated, 1.0, 0.05);
  }
}

TEST(Discriminator, FalseAlarmsFollowTheExponentialFirstCrossingLaw) {
  device::FalseAlarms alarms;
  alarms.threshold_over_noise = 3.0;
  alarms.rate_per_ns = device::rice_upcrossing_rate_per_ns(3.0, kTau);  // 1 / (566 ns)
  alarms.armed_ns = -2.5;  // the TDC's start before the pulse's centre
  const double nu = alarms.rate_per_ns;
  for (const double window : {50.0, 566.0, 5000.0}) {
    SCOPED_TRACE("window " + std::to_string(window));
    alarms.set_window(alarms.armed_ns + window);
    EXPECT_DOUBLE_EQ(alarms.window_ns, window);
    EXPECT_NEAR(alarms.probability, 1.0 - std::exp(-nu * window), 1e-15);
    // Uniforms on a fine grid: the fired share and the mean first crossing.
    constexpr int kN = 200'000;
    int fired = 0;
    double sum = 0, earliest = 1e300, latest = -1e300;
    for (int i = 0; i < kN; ++i) {
      double rise = 0, fall = 0;
      if (!alarms.first_crossing((i + 0.5) / kN, rise, fall)) continue;
      ++fired;
      sum += rise - alarms.armed_ns;
      earliest = std::min(earliest, rise);
      latest = std::max(latest, rise);
      EXPECT_GT(fall, rise);
    }
    EXPECT_NEAR(static_cast<double>(fired) / kN, alarms.probability, 1.0 / kN);
    // The exponential law truncated to the window: mean 1/nu - W e^(-nu W) / (1 - e^(-nu W)).
    const double expected = 1.0 / nu - window * std::exp(-nu * window) / alarms.probability;
    EXPECT_NEAR(sum / fired / expected, 1.0, 1e-3);
    EXPECT_GE(earliest, alarms.armed_ns);
    EXPECT_LE(latest, alarms.armed_ns + window);
  }
  // Armed past the window's end: no time, no alarm.
  alarms.set_window(alarms.armed_ns - 1.0);
  EXPECT_EQ(alarms.window_ns, 0.0);
  double rise = 0, fall = 0;
  EXPECT_FALSE(alarms.first_crossing(1e-9, rise, fall));
}

TEST(Discriminator, EdgesThroughNoiseCrossAsRicePredicts) {
  // A ramp of slope a through the noise crosses the level 1 + 2 c(r) times on
  // average, r = sigma / (a tau_p).
  TwoPoleNoise noise(kTau, kDt, 23);
  for (const double r : {1.0, 2.0}) {
    SCOPED_TRACE("r = " + std::to_string(r));
    const double slope = 1.0 / (r * kTau);                     // sigma = 1
    const auto steps = static_cast<long>(16.0 / slope / kDt);  // -8 ... +8 sigma
    constexpr int kEdges = 4000;
    long crossings = 0;
    for (int e = 0; e < kEdges; ++e) {
      for (int k = 0; k < 1000; ++k) noise.next();  // 20 tau apart: independent edges
      double previous = -8.0 + noise.next();
      for (long k = 1; k <= steps; ++k) {
        const double x = -8.0 + slope * static_cast<double>(k) * kDt + noise.next();
        crossings += (previous < 0.0) != (x < 0.0);
        previous = x;
      }
    }
    const double expected = 1.0 + 2.0 * device::extra_edge_crossings(r);
    EXPECT_NEAR(static_cast<double>(crossings) / kEdges / expected, 1.0, 0.04);
  }
  // The chatter limit is where c reaches the tolerance asked for.
  for (const double tolerance : {1e-4, 1e-2}) {
    const double limit = device::chatter_ratio_limit(tolerance);
    EXPECT_NEAR(device::extra_edge_crossings(limit) / tolerance, 1.0, 1e-9);
  }
  EXPECT_LT(device::chatter_ratio_limit(1e-4), device::chatter_ratio_limit(1e-2));
}

TEST(Discriminator, CrossingLevelSolvesItsEquationAndSitsHalfTheShotNoiseLate) {
  const double floor_var = 1e-4, threshold = 0.04;  // sigma_0 10 mV, 40 mV threshold
  // Without shot noise: the threshold shifted by the noise.
  EXPECT_DOUBLE_EQ(device::crossing_level_v(floor_var, 0.0, threshold, 1.5),
                   threshold - 0.01 * 1.5);
  const double k = 1e-3;  // V of variance per V of signal
  std::mt19937_64 gen(3);
  std::normal_distribution<double> normal;
  double sum = 0, sum_z2 = 0;
  constexpr int kN = 200'000;
  for (int i = 0; i < kN; ++i) {
    const double z = normal(gen);
    const double s = device::crossing_level_v(floor_var, k, threshold, z);
    EXPECT_NEAR(s + std::sqrt(floor_var + k * s) * z, threshold, 1e-12);
    // Antithetic pairs cancel the odd orders in z: the mean bias k/2 E[z^2] stays.
    sum += 0.5 * (s + device::crossing_level_v(floor_var, k, threshold, -z)) - threshold;
    sum_z2 += z * z;
  }
  EXPECT_NEAR((sum / kN) / (0.5 * k * sum_z2 / kN), 1.0, 0.02);
}

namespace {

device::SampledComparator comparator_for_tests() {
  device::SampledComparator c;
  c.threshold_v = 0.04;
  c.step_ns = 0.05;
  c.pole_time_constant_ns = 1.0;
  c.record_begin_ns = 0.0;
  c.record_end_ns = 30.0;
  c.armed_ns = 0.0;
  c.saturation_v = 4.0;
  c.recovery_ns_per_neper = 2.0;
  return c;
}

/// A smooth echo: a Gaussian of amplitude `peak_v` and sigma 1 ns at `at_ns`.
double gaussian_echo(double t, double peak_v, double at_ns) {
  const double x = (t - at_ns) / 1.0;
  return peak_v * std::exp(-0.5 * x * x);
}

}  // namespace

TEST(Discriminator, SampledComparatorWithoutNoiseFindsTheEchosCrossings) {
  auto c = comparator_for_tests();
  auto silent = [](std::size_t) { return 0.0; };
  for (const double phase : {0.0, 0.37, 0.9}) {
    SCOPED_TRACE("phase " + std::to_string(phase));
    auto echo = [](double t, double) { return gaussian_echo(t, 1.0, 12.0); };
    double rise = 0, fall = 0;
    ASSERT_TRUE(c.crossings(phase, silent, echo, rise, fall));
    // exp(-x^2 / 2) = 0.04: x = sqrt(2 ln 25).
    const double half_width = std::sqrt(2.0 * std::log(25.0));
    EXPECT_NEAR(rise, 12.0 - half_width, 1e-6);
    EXPECT_NEAR(fall, 12.0 + half_width, 1e-6);
    // With a baseline of 0.46 V the comparator sees the echo cross 0.5 V.
    c.baseline_v = 0.46;
    ASSERT_TRUE(c.crossings(phase, silent, echo, rise, fall));
    EXPECT_NEAR(rise, 12.0 - std::sqrt(2.0 * std::log(2.0)), 1e-6);
    c.baseline_v = 0.0;
  }
  // Below the threshold: nothing.
  double rise = 0, fall = 0;
  EXPECT_FALSE(c.crossings(
      0.0, silent, [](double t, double) { return gaussian_echo(t, 0.039, 12.0); }, rise, fall));
}

TEST(Discriminator, SampledComparatorIgnoresCrossingsBeforeItsArmingAndRecoversAfterClipping) {
  auto c = comparator_for_tests();
  auto silent = [](std::size_t) { return 0.0; };
  // An early echo (crosstalk at 3 ns) before the arming at 6 ns, then the echo at 15 ns.
  auto two = [](double t, double) {
    return gaussian_echo(t, 0.5, 3.0) + gaussian_echo(t, 0.5, 15.0);
  };
  const double x = std::sqrt(2.0 * std::log(0.5 / 0.04));
  c.armed_ns = 6.0;
  double rise = 0, fall = 0;
  ASSERT_TRUE(c.crossings(0.2, silent, two, rise, fall));
  EXPECT_NEAR(rise, 15.0 - x, 1e-6);
  EXPECT_NEAR(fall, 15.0 + x, 1e-6);
  c.armed_ns = 0.0;
  ASSERT_TRUE(c.crossings(0.2, silent, two, rise, fall));
  EXPECT_NEAR(rise, 3.0 - x, 1e-6);
  // Overdriven 10x: the fall comes the recovery, 2 ns per neper, after the input's.
  auto strong = [](double t, double) { return gaussian_echo(t, 40.0, 12.0); };
  ASSERT_TRUE(c.crossings(0.0, silent, strong, rise, fall));
  const double x_strong = std::sqrt(2.0 * std::log(40.0 / 0.04));
  // (The clip's peak is the largest sample: within 0.05 ns of 12 ns, 40 V to 1e-3.)
  EXPECT_NEAR(fall, 12.0 + x_strong + 2.0 * std::log(10.0), 2.0 * 2e-3);
  EXPECT_NEAR(rise, 12.0 - x_strong, 1e-6);
}

TEST(Discriminator, SampledComparatorsJitterIsNoiseOverSlope) {
  // A ramp through the threshold at 2 V/ns with 10 mV of noise: r = 0.005,
  // no chatter; the rise's spread is sigma / slope = 5 ps.
  auto c = comparator_for_tests();
  c.pole_time_constant_ns = 1.0;
  c.step_ns = 0.02;
  std::mt19937_64 gen(31);
  std::normal_distribution<double> normal;
  auto white = [&](std::size_t) { return normal(gen); };
  constexpr double kSlope = 2.0, kSigma = 0.01, kCross = 10.0;
  auto ramp = [&](double t, double z) {
    return std::min(0.04 + kSlope * (t - kCross), 1.0) + kSigma * z;
  };
  constexpr int kShots = 3000;
  double sum = 0, sum2 = 0;
  for (int i = 0; i < kShots; ++i) {
    double rise = 0, fall = 0;
    ASSERT_TRUE(c.crossings((i % 97) / 97.0, white, ramp, rise, fall));
    sum += rise - kCross;
    sum2 += (rise - kCross) * (rise - kCross);
  }
  const double mean = sum / kShots, sd = std::sqrt(sum2 / kShots - mean * mean);
  EXPECT_NEAR(sd / (kSigma / kSlope), 1.0, 0.06);  // 1.3 % sampling error
  EXPECT_NEAR(mean, 0.0, 4.0 * kSigma / kSlope / std::sqrt(kShots) + 1e-4);
}

TEST(Discriminator, SampledComparatorsNoiseAloneFiresAsTheContinuousNoiseDoes) {
  // No echo: the comparator's first rise is the noise's first upcrossing after
  // the arming; a shot fires with probability p over a record of T. Oracle:
  // the same first passage of the noise simulated 4x finer (tau_p / 25, the
  // TwoPoleNoise above), nearly the continuous process. Rice's nu counts every
  // upcrossing; a first passage misses the ones that follow within the same
  // excursion, so -ln(1 - p) / T sits a few % below nu at these levels (7-9 %
  // at u = 2.5-3). The white draws must be Gaussian: uniform ones make the
  // band-limited noise's tails short (15 % fewer upcrossings at u = 3).
  auto c = comparator_for_tests();
  c.pole_time_constant_ns = kTau;
  c.step_ns = kTau / 6.0;  // the waveform mode's step, kWaveformSamplesPerPole
  c.record_begin_ns = 0.0;
  c.saturation_v = 1e9;
  auto noise_only = [](double, double z) { return z; };  // unit noise, no echo
  std::mt19937_64 gen(97);
  std::normal_distribution<double> normal;
  auto white = [&](std::size_t) { return normal(gen); };
  constexpr double kFineStep = kTau / 25.0;
  TwoPoleNoise fine(kTau, kFineStep, 23);
  constexpr int kShots = 20000;
  for (const double u : {2.5, 3.0}) {
    SCOPED_TRACE("u = " + std::to_string(u));
    const double nu = device::rice_upcrossing_rate_per_ns(u, kTau);
    c.threshold_v = u;
    c.record_end_ns = 0.7 / nu;  // p ~ 0.5
    const double span_ns = c.record_end_ns - c.record_begin_ns - c.step_ns;
    const auto fine_steps = static_cast<long>(span_ns / kFineStep);
    int fired = 0, fired_fine = 0;
    for (int i = 0; i < kShots; ++i) {
      double rise = 0, fall = 0;
      fired += c.crossings((i % 89) / 89.0, white, noise_only, rise, fall);
      double previous = fine.next();
      bool up = false;
      for (long k = 0; k < fine_steps; ++k) {
        const double x = fine.next();
        up = up || (previous < u && x >= u);
        previous = x;
      }
      fired_fine += up;
    }
    auto rate = [&](int n) { return -std::log1p(-static_cast<double>(n) / kShots) / span_ns; };
    // Binomial error of -ln(1 - p), relative: sqrt(p / ((1 - p) N)) / -ln(1 - p), ~1.0 %.
    const double p = static_cast<double>(fired_fine) / kShots;
    const double rel = std::sqrt(p / ((1.0 - p) * kShots)) / -std::log1p(-p);
    EXPECT_NEAR(rate(fired) / rate(fired_fine), 1.0, 3.0 * std::sqrt(2.0) * rel + 0.02);
    EXPECT_LT(rate(fired_fine), nu * (1.0 + 3.0 * rel));
    EXPECT_GT(rate(fired_fine), 0.85 * nu);
  }
}
