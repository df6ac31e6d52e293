// The self-oscillating loop (device/oscillator_loop.hpp; thesis Section 3.1,
// Fig. 3.2, Section 4.4, Fig. 4.4). Oracles: the single-pole step response's
// closed-form crossing times, the thesis's loop periods, the counter's
// resolution c/4 t_clk T / gate, the dispatch against the loop itself, the
// thread-count independence of counter-based randomness, key validation, and
// Rice's level-crossing rate against a simulated band-limited noise.
#include "tofkit/device/oscillator_loop.hpp"

#include <gtest/gtest.h>
#include <tbb/global_control.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <string>
#include <utility>
#include <vector>

#include "tofkit/device/accurange_preset.hpp"
#include "tofkit/experiments/thesis_grey_chart.hpp"
#include "tofkit/physics/air.hpp"
#include "tofkit/physics/link_budget.hpp"

using namespace tofkit;

namespace {

constexpr double kPi = 3.14159265358979323846;

double c_air_m_per_ns(const device::DeviceConfig& c, double ambient_c) {
  physics::AirConditions air{ambient_c, c.link.environment.pressure_hpa,
                             c.link.environment.relative_humidity_pct};
  return physics::speed_of_light_in_air_m_per_s(c.link.laser.wavelength_nm, air) * 1e-9;
}

}  // namespace

TEST(OscillatorLoop, EdgesAreTheStepResponsesClosedForm) {
  const auto c = device::accurange_preset();
  const device::OscillatorLoop loop(c);
  const double tau = 1e3 / (2 * kPi * c.link.receiver.bandwidth_mhz);
  const double vth = c.discriminator.threshold_v, vsat = c.link.receiver.saturation_v;
  const double duty = c.oscillator.coupling_duty;
  for (const int grey : {0, 51, 153, 255}) {
    const double d = 0.48;
    const auto s = loop.state(device::Target::plate(d, experiments::grey_reflectance(grey)), {});
    ASSERT_TRUE(s.oscillates) << grey;
    const double rt = 2 * d / c_air_m_per_ns(c, 20.0);
    const double swing = vsat * std::tanh(s.amplitude_v / vsat);
    const double level = duty * swing + vth;
    // Rising: A (1 - exp(-t / tau)) reaches the level; falling: swing exp(-t / tau) leaves it.
    EXPECT_NEAR(s.on_detect_ns - rt, tau * std::log(s.amplitude_v / (s.amplitude_v - level)), 1e-9)
        << grey;
    EXPECT_NEAR(s.off_detect_ns - rt, tau * std::log(swing / level), 1e-9) << grey;
    EXPECT_EQ(s.saturated, s.amplitude_v > vsat);
  }
}

TEST(OscillatorLoop, WeakReturnsAreSlowerAndTooWeakStopsTheLoop) {
  const device::OscillatorLoop loop(device::accurange_preset());
  // Weak returns: each stronger one is faster (the rising edge's walk dominates).
  double last_latency = 1e9;
  for (const double rho : {0.02, 0.03, 0.06, 0.15}) {
    const auto s = loop.state(device::Target::plate(0.5, rho), {});
    ASSERT_TRUE(s.oscillates) << rho;
    ASSERT_FALSE(s.saturated) << rho;
    const double latency = s.on_detect_ns + s.off_detect_ns;
    EXPECT_LT(latency, last_latency) << rho;
    last_latency = latency;
  }
  // Saturating returns rise ever faster from a swing that no longer grows: they
  // are faster than every unsaturated one (bright reads short).
  for (const double rho : {0.6, 0.93}) {
    const auto s = loop.state(device::Target::plate(0.5, rho), {});
    ASSERT_TRUE(s.saturated) << rho;
    EXPECT_LT(s.on_detect_ns + s.off_detect_ns, last_latency) << rho;
  }
  // Far enough, black's (grey 255) swing no longer lifts above the threshold: no
  // echo. Oracle: the loop runs while (1 - coupling duty) x swing > threshold, the
  // swing (unclipped) falling as 1 / R^2 (extended target, coaxial optics): the
  // limit R = 1 m x sqrt(swing(1 m) (1 - duty) / threshold).
  const auto& c = loop.config();
  const double rho = experiments::grey_reflectance(255);
  const double swing_1m = loop.state(device::Target::plate(1.0, rho), {}).swing_v;
  const double limit_m =
      std::sqrt(swing_1m * (1.0 - c.oscillator.coupling_duty) / c.discriminator.threshold_v);
  EXPECT_TRUE(loop.state(device::Target::plate(0.9 * limit_m, rho), {}).oscillates);
  const auto far = device::Target::plate(1.1 * limit_m, rho);
  EXPECT_FALSE(loop.state(far, {}).oscillates);
  const auto m = loop.measure(far, {}, 1, 0);
  EXPECT_FALSE(m.has_echo());
}

TEST(OscillatorLoop, PeriodsAreTheThesisFig32) {
  // Thesis: ~20 ns at zero range, 280 ns at 20 m (two round trips per period).
  auto c = device::accurange_preset();
  const device::OscillatorLoop near(c);
  const auto s0 = near.state(device::Target::plate(0.01, 0.5), {});
  ASSERT_TRUE(s0.oscillates);
  EXPECT_GT(s0.period_ns, 14.0);
  EXPECT_LT(s0.period_ns, 22.0);
  // At 20 m with the same return amplitude (power raised by (20 / 0.5)^2): 4 d / c more.
  c.link.laser.peak_power_w *= (20.0 / 0.5) * (20.0 / 0.5);
  const device::OscillatorLoop far(c);
  const auto s20 = far.state(device::Target::plate(20.0, 0.5), {});
  ASSERT_TRUE(s20.oscillates);
  EXPECT_NEAR(s20.period_ns, 280.0, 15.0);
}

TEST(OscillatorLoop, ResolutionIsOneClockCountOverTheGate) {
  const auto c = device::accurange_preset();
  const device::OscillatorLoop loop(c);
  const auto target = device::Target::plate(0.508, experiments::grey_reflectance(51));
  const auto s = loop.state(target, {});
  for (const int shots : {8, 64, 2048}) {
    const double gate_ns = c.oscillator.gate_fraction * shots / c.link.laser.repetition_hz * 1e9;
    const double expected = 0.25 * c_air_m_per_ns(c, c.measurement.reference_temperature_c) *
                            (1e3 / c.oscillator.count_clock_mhz) * s.period_ns / gate_ns;
    EXPECT_NEAR(loop.resolution_m(target, {}, shots), expected, 1e-12) << shots;
  }
  // Reported ranges are counts: with the wander and the jitter off, every output
  // of one gate length lies on the grid of (counts x t_clk / M) / 2 - zero.
  auto quiet = c;
  quiet.oscillator.flicker_delay_ps = 0;
  const device::OscillatorLoop q(quiet);
  const double clock_ns = 1e3 / c.oscillator.count_clock_mhz;
  for (std::uint64_t i = 0; i < 50; ++i) {
    const auto m = q.measure(target, {}, 9, i, 8);
    ASSERT_TRUE(m.has_echo());
    const double period = 2 * (m.tof_ns + c.oscillator.zero_half_period_ns);
    const double gate_ns = c.oscillator.gate_fraction * 8 / c.link.laser.repetition_hz * 1e9;
    // Some whole M near gate / T gives an integer count.
    bool on_grid = false;
    for (double whole = std::floor(gate_ns / period) - 2; whole <= gate_ns / period + 1; ++whole) {
      const double counts = period * whole / clock_ns;
      if (std::abs(counts - std::round(counts)) < 1e-6) on_grid = true;
    }
    EXPECT_TRUE(on_grid) << i;
  }
}

TEST(OscillatorLoop, DeviceDispatchesToTheLoopAndIsThreadIndependent) {
  const auto c = device::accurange_preset();
  ASSERT_TRUE(c.oscillator.enabled);
  const device::VirtualRangefinder dev(c);
  const device::OscillatorLoop loop(c);
  std::vector<device::MeasureRequest> req;
  for (int i = 0; i < 64; ++i) {
    req.push_back(
        {device::Target::plate(0.4 + 0.002 * i, experiments::grey_reflectance(51 * (i % 6))),
         {},
         16 << (i % 3)});
  }
  std::vector<ranging::RawMeasurement> one(req.size()), two(req.size());
  {
    tbb::global_control limit(tbb::global_control::max_allowed_parallelism, 1);
    dev.measure_batch(req, 11, one);
  }
  {
    tbb::global_control limit(tbb::global_control::max_allowed_parallelism, 2);
    dev.measure_batch(req, 11, two);
  }
  EXPECT_EQ(0, std::memcmp(one.data(), two.data(), one.size() * sizeof(one[0])));
  for (std::size_t i = 0; i < req.size(); ++i) {
    const auto direct = loop.measure(req[i].target, req[i].conditions, 11, i, req[i].shots);
    EXPECT_EQ(direct.distance_raw_m, one[i].distance_raw_m) << i;
    EXPECT_EQ(direct.amplitude, one[i].amplitude) << i;
  }
  // Another seed, another draw.
  const auto other = dev.measure(req[0].target, {}, 12, 0, req[0].shots);
  EXPECT_NE(other.tof_ns, one[0].tof_ns);
}

TEST(OscillatorLoop, KeysAreValidatedByName) {
  auto c = device::accurange_preset();
  EXPECT_TRUE(device::validate(c).empty());
  c.oscillator.gate_fraction = 0;
  c.oscillator.count_clock_mhz = -1;
  auto messages = device::validate(c);
  ASSERT_GE(messages.size(), 2u);
  EXPECT_NE(messages[0].find("oscillator.count_clock_mhz"), std::string::npos) << messages[0];
  EXPECT_NE(messages[1].find("oscillator.gate_fraction"), std::string::npos) << messages[1];
  // A threshold above the clipped swing: the loop could never oscillate.
  c = device::accurange_preset();
  c.discriminator.threshold_v = c.link.receiver.saturation_v;
  messages = device::validate(c);
  ASSERT_EQ(messages.size(), 1u);
  EXPECT_NE(messages[0].find("oscillator.enabled"), std::string::npos) << messages[0];
  EXPECT_THROW(device::VirtualRangefinder{c}, std::invalid_argument);
  // The loop has no sampled-waveform evaluation: asking for one is refused.
  try {
    const device::VirtualRangefinder waveform(device::accurange_preset(),
                                              device::SimulationMode::kWaveform);
    ADD_FAILURE() << "waveform mode accepted for the loop";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("oscillator.enabled"), std::string::npos) << e.what();
  }
  // The paper device keeps the pulsed principle.
  EXPECT_FALSE(device::DeviceConfig{}.oscillator.enabled);
}

TEST(OscillatorLoop, DutyWanderIsNoiseThatGrowsOnWeakReturns) {
  // oscillator.duty_wander moves the AC-coupled baseline by d x swing on both
  // edges: the period moves by d swing (1 / rise slope - 1 / fall slope), so the
  // range (c/4 of the period) by that much. The draw is a switch-on's and
  // settles over the laser's turn-on transient: an output of window W starting
  // at the switch-on carries d (1 - exp(-W / tau)) / (W / tau). Oracle: that
  // closed form from the noise-free state's slopes, for small d, against the
  // spread of outputs taken at switch-ons seconds apart; outputs of one
  // switch-on (one session time) share the draw.
  auto c = device::accurange_preset();
  c.oscillator.duty_wander = 0.01;
  c.oscillator.flicker_delay_ps = 0;
  c.link.laser.turn_on_bias_mm = 0;  // the transient's bias is the same for every point
  const device::OscillatorLoop loop(c);
  const double c4 = 0.25 * c_air_m_per_ns(c, c.measurement.reference_temperature_c);
  const int shots = 4096;  // counts finer than 3 um: the wander dominates
  const double x = 1e3 * shots / c.link.laser.repetition_hz / c.link.laser.turn_on_time_constant_ms;
  const double settle = (1.0 - std::exp(-x)) / x;  // 0.85 for a 13 ms window, tau 40 ms
  std::vector<double> sd_of;
  for (const int grey : {255, 153, 0}) {
    const auto target = device::Target::plate(0.4826, experiments::grey_reflectance(grey));
    const auto s = loop.state(target, {});
    ASSERT_TRUE(s.oscillates) << grey;
    const double expected_sd_m =
        c4 * c.oscillator.duty_wander * settle * s.swing_v *
        std::abs(1.0 / s.rise_slope_v_per_ns - 1.0 / s.fall_slope_v_per_ns);
    double sum = 0, sum2 = 0;
    const int n = 400;
    for (int i = 0; i < n; ++i) {
      device::Conditions cond;
      cond.session_time_s = 2.0 * i;  // points seconds apart
      cond.ms_since_laser_on = 0.0;   // the laser switched on at each point
      const double r =
          loop.measure(target, cond, 5, static_cast<std::uint64_t>(i), shots).distance_raw_m;
      sum += r;
      sum2 += r * r;
    }
    const double sd = std::sqrt(sum2 / n - (sum / n) * (sum / n));
    if (expected_sd_m > 20e-6) {
      EXPECT_NEAR(sd, expected_sd_m, 0.2 * expected_sd_m) << grey;
    }
    sd_of.push_back(sd);
    // One acquisition (one session time) shares the draw: two outputs differ by
    // the count and jitter alone.
    device::Conditions same;
    same.session_time_s = 7.0;
    same.ms_since_laser_on = 0.0;
    const double a = loop.measure(target, same, 5, 1000, shots).distance_raw_m;
    const double b = loop.measure(target, same, 5, 1001, shots).distance_raw_m;
    EXPECT_LT(std::abs(a - b), std::max(0.2 * expected_sd_m, 50e-6)) << grey;
  }
  // The wander is noise that depends on intensity: the three greys' spreads
  // differ by more than their sampling error (400 outputs: +-7 %).
  const auto [lo, hi] = std::minmax_element(sd_of.begin(), sd_of.end());
  EXPECT_GT(*hi, 1.5 * *lo);
}

TEST(OscillatorLoop, DutyWanderIsASwitchOnsAndSettlesOverTheTurnOnTransient) {
  // The duty a switch-on starts with settles as the laser's junction heats
  // (laser.turn_on_time_constant_ms): its mean over a window W starting t0 after
  // the switch-on is the draw times exp(-t0 / tau) (1 - exp(-W / tau)) / (W / tau).
  // Oracle: that closed form against the offset at t0 = 0 and W -> 0; a
  // continuous acquisition (thesis Fig. 4.4, past the transient) shows none of
  // it, so its outputs taken seconds apart agree within the count's noise.
  const auto c = device::accurange_preset();
  ASSERT_GT(c.oscillator.duty_wander, 0.0);
  const device::OscillatorLoop loop(c);
  const double tau = c.link.laser.turn_on_time_constant_ms;
  int nonzero = 0;
  for (int i = 0; i < 50; ++i) {
    device::Conditions at_on;
    at_on.session_time_s = 2.0 * i;
    at_on.ms_since_laser_on = 0.0;
    const double d0 = loop.duty_offset(at_on, 11);
    EXPECT_LE(std::abs(d0), 2.5 * c.oscillator.duty_wander + 1e-15);
    nonzero += d0 != 0.0;
    for (const double t0 : {0.0, 10.0, 40.0}) {
      for (const double w : {1.0, 20.0}) {
        device::Conditions cond = at_on;
        cond.ms_since_laser_on = t0;
        const double expected = d0 * std::exp(-t0 / tau) * (1.0 - std::exp(-w / tau)) / (w / tau);
        EXPECT_NEAR(loop.duty_offset(cond, 11, w), expected, 1e-12) << i << " " << t0 << " " << w;
      }
    }
    device::Conditions settled;  // the default: past the transient
    settled.session_time_s = at_on.session_time_s;
    EXPECT_EQ(loop.duty_offset(settled, 11), 0.0);
  }
  EXPECT_EQ(nonzero, 50);
  // Outputs taken seconds apart (each its own draw) on grey 255 (black, whose slow
  // rise turns the duty into the most time): at switch-on they scatter by the
  // draws; in a continuous acquisition only by the loop delay's own wander
  // (oscillator.flicker_delay_ps: c/4 x 2 x 2.2 ps = 0.33 mm rms) and the count
  // (4096 shots: 3 um).
  const auto target = device::Target::plate(0.4826, experiments::grey_reflectance(255));
  auto spread = [&](double ms_since_laser_on) {
    double sum = 0, sum2 = 0;
    const int n = 200;
    for (int i = 0; i < n; ++i) {
      device::Conditions cond;
      cond.session_time_s = 2.0 * i;
      cond.ms_since_laser_on = ms_since_laser_on;
      const double r =
          loop.measure(target, cond, 11, static_cast<std::uint64_t>(i), 4096).distance_raw_m;
      sum += r;
      sum2 += r * r;
    }
    return std::sqrt(sum2 / n - (sum / n) * (sum / n));
  };
  const double flicker_m = 0.25 * c_air_m_per_ns(c, c.measurement.reference_temperature_c) * 2.0 *
                           c.oscillator.flicker_delay_ps * 1e-3;
  const double continuous = spread(1e9), switched_on = spread(0.0);
  EXPECT_NEAR(continuous, flicker_m, 0.15 * flicker_m);  // 200 outputs: +-5 % sampling
  EXPECT_GT(switched_on, 5.0 * continuous);
}

TEST(OscillatorLoop, ChipColdShareIsThePeriodicHeatingsMean) {
  // Oracle for OscillatorLoop::chip_cold_share: step the chip's heat share h
  // through many gate / pause cycles (h -> 1 over a gate, -> 0 over a pause,
  // with tau) in small time steps until periodic, and average 1 - h over a gate.
  // Limits: 1/2 for gates far shorter than tau (equal pause), tau / gate for far
  // longer ones.
  for (const auto [gate, off, tau] : {std::array{0.05, 0.05, 0.21}, std::array{0.4, 0.4, 0.21},
                                      std::array{3.3, 3.3, 0.21}, std::array{0.4, 1.2, 0.3}}) {
    const int steps = 20000;
    const double dt_on = gate / steps;
    double h = 0, sum = 0;
    for (int cycle = 0; cycle < 200; ++cycle) {
      sum = 0;
      for (int i = 0; i < steps; ++i) {
        const double h_next = 1.0 - (1.0 - h) * std::exp(-dt_on / tau);
        sum += 1.0 - 0.5 * (h + h_next);
        h = h_next;
      }
      h *= std::exp(-off / tau);
    }
    EXPECT_NEAR(device::OscillatorLoop::chip_cold_share(gate, off, tau), sum / steps, 1e-6)
        << gate << " " << off << " " << tau;
  }
  EXPECT_NEAR(device::OscillatorLoop::chip_cold_share(1e-6, 1e-6, 0.21), 0.5, 1e-5);
  EXPECT_NEAR(device::OscillatorLoop::chip_cold_share(100.0, 100.0, 0.21), 0.21 / 100.0, 1e-9);
}

TEST(OscillatorLoop, IntensityIsTheSwingAboveTheCoupledBaseline) {
  // The intensity output is a peak detector behind the AC coupling, scaled so a
  // settled return reads its step amplitude A. An unrecovered baseline offset dv
  // (a scan, device/echo_memory.hpp) lowers it to A - dv / (1 - coupling_duty),
  // raises it for dv < 0, and floors it at threshold / (1 - duty) (while locked,
  // the swing above the baseline exceeds the threshold). The output's noise draw
  // is the same for the same (seed, stream): ratios are exact.
  auto c = device::accurange_preset();
  c.oscillator.duty_wander = 0;  // the lock margin below is the settled duty's
  const device::OscillatorLoop loop(c);
  const double share = 1.0 - c.oscillator.coupling_duty;
  const auto target = device::Target::plate(0.4826, experiments::grey_reflectance(153));
  const auto s = loop.state(target, {});
  ASSERT_TRUE(s.oscillates);
  ASSERT_LT(s.amplitude_v, c.link.receiver.amplitude_clip_v);
  const auto settled = loop.measure(target, {}, 3, 17);
  const double margin = s.swing_v * share - c.discriminator.threshold_v;
  for (const double dv : {0.5 * margin, 0.1 * margin, -0.2}) {
    device::Conditions cond;
    cond.baseline_offset_v = dv;
    const auto m = loop.measure(target, cond, 3, 17);
    ASSERT_TRUE(m.has_echo()) << dv;
    EXPECT_NEAR(m.amplitude / settled.amplitude, (s.amplitude_v - dv / share) / s.amplitude_v,
                1e-12)
        << dv;
  }
  // A return just locked: its reading is held at the floor, not below.
  auto weak = device::Target::plate(0.4826, experiments::grey_reflectance(255));
  const auto sw = loop.state(weak, {});
  device::Conditions near_lock;
  near_lock.baseline_offset_v = 0.99 * (sw.swing_v * share - c.discriminator.threshold_v);
  const auto m = loop.measure(weak, near_lock, 3, 17);
  ASSERT_TRUE(m.has_echo());
  const double floor_v = c.discriminator.threshold_v / share;
  const double expected =
      std::max(sw.amplitude_v - near_lock.baseline_offset_v / share, floor_v) / sw.amplitude_v;
  EXPECT_NEAR(m.amplitude / loop.measure(weak, {}, 3, 17).amplitude, expected, 1e-12);
}

TEST(OscillatorLoop, TurnOnTransientOfEitherSignIsItsWindowMean) {
  // laser.turn_on_bias_mm b (either sign) decaying with tau: an output whose window
  // W starts t0 after switch-on carries b tau / W exp(-t0 / tau) (1 - exp(-W / tau)).
  // Oracle: that closed form against the mean difference of outputs taken at
  // switch-on and settled (the same seeds and streams, so the same counts' phases).
  for (const double bias_mm : {-29.0, 7.6}) {
    auto c = device::accurange_preset();
    c.link.laser.turn_on_bias_mm = bias_mm;
    c.oscillator.duty_wander = 0;
    c.oscillator.flicker_delay_ps = 0;
    const device::OscillatorLoop loop(c);
    const auto target = device::Target::plate(0.4826, experiments::grey_reflectance(102));
    const int shots = 320;  // 1.02 ms: a chart point's 20 samples of 16 shots
    const double tau = c.link.laser.turn_on_time_constant_ms;
    const double w = 1e3 * shots / c.link.laser.repetition_hz;
    for (const double t0 : {0.0, 40.0}) {
      const double expected_mm = bias_mm * tau / w * std::exp(-t0 / tau) * -std::expm1(-w / tau);
      double sum = 0;
      const int n = 200;
      for (int i = 0; i < n; ++i) {
        device::Conditions on, settled;
        on.ms_since_laser_on = t0;
        const auto s = static_cast<std::uint64_t>(i);
        sum += loop.measure(target, on, 9, s, shots).distance_raw_m -
               loop.measure(target, settled, 9, s, shots).distance_raw_m;
      }
      // One count at 320 shots is ~0.04 mm; the mean of 200 differences is finer.
      EXPECT_NEAR(1e3 * sum / n, expected_mm, 0.02 * std::abs(expected_mm) + 0.02)
          << bias_mm << " " << t0;
    }
  }
}

TEST(OscillatorLoop, NearTopEdgesFollowRicesCrossingRate) {
  // An independent reader of Rice's rate: band-limited Gaussian noise built as a
  // sum of many sinusoids with frequencies spread evenly over (0, B) and random phases
  // (a flat spectrum to B), sampled finely; count its down-crossings of -u.
  const double bandwidth_mhz = 360.0, sigma = 1e-3, high_ns = 10.0;
  const int tones = 100;
  std::vector<double> freq(tones), phase(tones);
  std::uint64_t state = 12345;
  auto uniform = [&state] {
    state = state * 6364136223846793005ull + 1442695040888963407ull;
    return static_cast<double>(state >> 11) * 0x1.0p-53;
  };
  for (int k = 0; k < tones; ++k) {
    freq[k] = bandwidth_mhz * 1e-3 * (k + uniform()) / tones;  // per ns, stratified
    phase[k] = 2 * kPi * uniform();
  }
  const double amp = sigma * std::sqrt(2.0 / tones);
  const double dt = 0.05, span = 4e4;  // ns: 55 samples per period at B; >= 1,100 crossings
  const std::vector<double> u_sigmas{0.0, 1.0, 2.0};
  std::vector<long> down(u_sigmas.size(), 0);
  double prev = 0;
  for (long i = 0; i * dt < span; ++i) {
    double x = 0;
    for (int k = 0; k < tones; ++k) x += amp * std::cos(2 * kPi * freq[k] * i * dt + phase[k]);
    for (std::size_t j = 0; j < u_sigmas.size(); ++j) {
      const double u = u_sigmas[j] * sigma;
      if (i > 0 && prev >= -u && x < -u) ++down[j];
    }
    prev = x;
  }
  for (std::size_t j = 0; j < u_sigmas.size(); ++j) {
    // Extra edges per period: a dip below level - hysteresis while the top is
    // margin above the level, for high_ns: margin + hysteresis = u.
    const double u = u_sigmas[j] * sigma;
    const double counted = static_cast<double>(down[j]) / span * high_ns;
    const auto e = device::near_top_edges(0.4 * u, sigma, bandwidth_mhz, high_ns, 0.6 * u);
    EXPECT_NEAR(e.extra_edges_per_period, counted, 0.06 * counted) << u_sigmas[j];
  }
}

TEST(OscillatorLoop, NearTopEdgesHaveTheirSignsAndVanishFarFromTheTop) {
  const double b = 360.0, sigma = 3.5e-3, high = 11.0;
  const double rice = b * 1e-3 / std::sqrt(3.0);  // per ns
  // At the top: high x nu(0) extra edges, and the noise is below half the time,
  // waiting Rice's mean excursion 0.5 / nu(0): a quarter of 1 / nu(0) per period.
  const auto top = device::near_top_edges(0.0, sigma, b, high);
  EXPECT_NEAR(top.extra_edges_per_period, high * rice, 1e-12);
  EXPECT_NEAR(top.missed_wait_ns, 0.25 / rice, 1e-12);
  // The hysteresis: a dip must reach the level minus it.
  const auto hyst = device::near_top_edges(0.0, sigma, b, high, 3 * sigma);
  EXPECT_NEAR(hyst.extra_edges_per_period, high * rice * std::exp(-4.5), 1e-12);
  EXPECT_EQ(hyst.missed_wait_ns, top.missed_wait_ns);
  // Above the top chatter falls and waits fall faster; below it waits grow to
  // the wait for one up-crossing, 1 / nu(margin).
  const auto above = device::near_top_edges(2 * sigma, sigma, b, high);
  EXPECT_LT(above.extra_edges_per_period, top.extra_edges_per_period);
  EXPECT_LT(above.missed_wait_ns / top.missed_wait_ns, 0.2);
  const auto below = device::near_top_edges(-4 * sigma, sigma, b, high);
  EXPECT_NEAR(below.missed_wait_ns, 1.0 / (rice * std::exp(-8.0)), 1e-3 / (rice * std::exp(-8.0)));
  // Far above: a clean swing, exactly; far below: no edges at all.
  const auto clean = device::near_top_edges(device::kNearTopSigmas * sigma, sigma, b, high);
  EXPECT_EQ(clean.extra_edges_per_period, 0.0);
  EXPECT_EQ(clean.missed_wait_ns, 0.0);
  EXPECT_TRUE(std::isinf(
      device::near_top_edges(-device::kNearTopSigmas * sigma, sigma, b, high).missed_wait_ns));
}

// Thesis Fig. 4.9: over 10-30 in the chart's range grows more slowly than the
// truth (slope 0.9804) while dark targets read long. A receiver focused at a
// finite distance (here 1.1 m, a 37 mrad stop) passes a growing share of a
// nearer chart's light, so black's echo rises with range from 10 to 19 in
// (Eq. 6's 1 / R^2 times the share) and its walk makes the near chart read
// long; in the far-field view (the preset's) the near chart reads short.
TEST(OscillatorLoop, FocusedReceiverMakesTheNearChartReadLong) {
  const auto preset = device::accurange_preset();
  ASSERT_EQ(preset.link.receiver.focus_distance_m, 0.0);
  auto focused = preset;
  focused.link.receiver.focus_distance_m = 1.1;
  focused.link.receiver.field_of_view_rad = 0.037;
  focused.link.receiver.transimpedance_kohm = 48.9;  // black at 19 in as before (share 0.22)
  const double rho = experiments::grey_reflectance(255);
  const double near_m = 10 * 0.0254, far_m = 19 * 0.0254;
  auto latency = [&](const device::DeviceConfig& c, double r) {
    const auto s = device::OscillatorLoop(c).state(device::Target::plate(r, rho), {});
    EXPECT_TRUE(s.oscillates) << r;
    EXPECT_FALSE(s.saturated) << r;
    return std::pair{s.amplitude_v, s.on_detect_ns + s.off_detect_ns - 4.0 * r / 0.2997};
  };
  const auto [a_near, l_near] = latency(focused, near_m);
  const auto [a_far, l_far] = latency(focused, far_m);
  const auto& rx = focused.link.receiver;
  const double share_ratio = physics::field_stop_share(focused.link.laser, rx, near_m) /
                             physics::field_stop_share(focused.link.laser, rx, far_m);
  EXPECT_LT(share_ratio, 0.25);
  EXPECT_NEAR(a_near / a_far, share_ratio * (far_m * far_m) / (near_m * near_m), 1e-9);
  EXPECT_LT(a_near, a_far);
  EXPECT_GT(l_near, l_far);  // the weaker near echo crosses later: reads long
  EXPECT_LT(latency(preset, near_m).second, latency(preset, far_m).second);
}
