// The thesis's scanning results (issue 9): device memory against its closed
// form, the memory correction's fit, and the thesis's figures (Figs. 4.23,
// 4.27, 4.32-4.33, 3.4-3.5, 4.28) on the AccuRange-like preset.

#include <gtest/gtest.h>
#include <tbb/global_control.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <vector>

#include "tofkit/calib/memory_fit.hpp"
#include "tofkit/device/accurange_preset.hpp"
#include "tofkit/device/echo_memory.hpp"
#include "tofkit/device/oscillator_loop.hpp"
#include "tofkit/experiments/scan_memory.hpp"
#include "tofkit/experiments/thesis_line_scan.hpp"
#include "tofkit/experiments/thesis_protocol.hpp"
#include "tofkit/physics/pulse_template.hpp"
#include "tofkit/ranging/memory_correction.hpp"

namespace tofkit {
namespace {

using experiments::inches_to_m;
using experiments::m_to_inches;

/// A still beam stepping from a dark to a bright plate after `before` outputs,
/// outputs back to back (each window starts where the last ended).
std::vector<device::SequenceItem> step_sequence(const device::VirtualRangefinder& dev, int before,
                                                int after, double rho_a, double rho_b,
                                                double gap_s = 0) {
  const device::EchoMemory memory(dev);
  const double window = memory.window_s(0);
  std::vector<device::SequenceItem> items;
  for (int i = 0; i < before + after; ++i) {
    device::SequenceItem item;
    item.path = {device::Target::plate(0.5, i < before ? rho_a : rho_b)};
    item.time_s = i * (window + gap_s);
    items.push_back(item);
  }
  return items;
}

/// The paper device with an AC coupling of time constant tau_ms before its comparator.
device::DeviceConfig coupled_config(double tau_ms, double share = 1.0) {
  device::DeviceConfig c;
  c.memory.time_constant_ms = tau_ms;
  c.memory.coupling_share = share;
  // The coupling alone: the paper device's slow delay and comparator wander
  // (4.5 mm between outputs far apart; tested in device_test.cpp) would bury
  // its millimetre closed forms.
  c.measurement.delay_wander_ps = 0.0;
  c.discriminator.level_wander_mv = 0.0;
  return c;
}

/// Mean time of flight of one measurement (ns) with the baseline offset `offset_v`.
double mean_tof_ns(const device::VirtualRangefinder& dev, const device::Target& target,
                   double offset_v, int shots = 1000) {
  device::Conditions c;
  c.baseline_offset_v = offset_v;
  return dev.measure(target, c, 21, 4, shots).tof_ns;
}

TEST(ThesisScanMemory, PaperDeviceHasNoMemoryAndMatchesMeasureBatch) {
  const device::VirtualRangefinder dev(device::DeviceConfig{});
  EXPECT_EQ(dev.config().memory.time_constant_ms, 0.0);
  const auto items = step_sequence(dev, 5, 5, 0.05, 0.8);
  std::vector<ranging::RawMeasurement> seq(items.size()), batch(items.size());
  device::EchoMemory(dev).measure_sequence(items, 7, seq);
  std::vector<device::MeasureRequest> req;
  for (const auto& it : items) req.push_back({it.path[0], it.conditions, 0});
  dev.measure_batch(req, 7, batch);
  for (std::size_t i = 0; i < items.size(); ++i) {
    EXPECT_EQ(seq[i].distance_raw_m, batch[i].distance_raw_m) << i;
    EXPECT_EQ(seq[i].amplitude, batch[i].amplitude) << i;
  }
}

TEST(ThesisScanMemory, SettledBaselineIsTheEchoTrainsMean) {
  // A coupling capacitor charges to the mean of what passes it: an unsaturated
  // echo of peak A and a Gaussian pulse (sigma) through the receiver's
  // unit-area filter has the area A sigma sqrt(2 pi) / g (g: the filter's peak
  // gain on the pulse), once per 1 / f_rep.
  const auto cfg = coupled_config(0.5, 0.6);
  const device::VirtualRangefinder dev(cfg);
  const auto target = device::Target::plate(6.0, 0.1);
  const auto e = dev.echo(target, {});
  ASSERT_TRUE(e.detected);
  ASSERT_FALSE(e.saturated);
  const physics::PulseTemplate pulse(cfg.link.laser.pulse_width_ns,
                                     cfg.link.receiver.bandwidth_mhz);
  const double sigma_ns = cfg.link.laser.pulse_width_ns / (2.0 * std::sqrt(2.0 * std::log(2.0)));
  const double area_v_ns = e.peak_v * sigma_ns * std::sqrt(2.0 * M_PI) / pulse.peak_gain();
  const double expected = 0.6 * area_v_ns * cfg.link.laser.repetition_hz * 1e-9;
  EXPECT_NEAR(dev.coupling_baseline_v(target, {}), expected, 0.01 * expected);
  // DC coupled: no baseline.
  EXPECT_EQ(device::VirtualRangefinder(device::DeviceConfig{}).coupling_baseline_v(target, {}),
            0.0);
}

TEST(ThesisScanMemory, StepBaselineIsTheHighPassClosedForm) {
  // A step from a dark to a bright plate: the capacitor relaxes from the dark
  // plate's baseline b_a to the bright one's b_b, so the mean unrecovered
  // offset over output j is (b_a - b_b) exp(-j T / tau) (tau / T)(1 - exp(-T / tau)).
  const double tau_ms = 0.4;
  const device::VirtualRangefinder with(coupled_config(tau_ms));
  const int before = 20, after = 30;
  const auto items = step_sequence(with, before, after, 0.05, 0.8);
  std::vector<ranging::RawMeasurement> a(items.size());
  std::vector<device::MemoryTrace> trace(items.size());
  device::EchoMemory(with).measure_sequence(items, 3, a, trace);
  const double ba = with.coupling_baseline_v(items.front().path[0], {});
  const double bb = with.coupling_baseline_v(items.back().path[0], {});
  ASSERT_GT(bb - ba, 1e-3);  // a real step (volts)
  const double t = device::EchoMemory(with).window_s(0), tau = tau_ms * 1e-3;
  const double mean_share = tau / t * (1 - std::exp(-t / tau));
  for (int i = 0; i < before; ++i) EXPECT_EQ(trace[i].baseline_offset_v, 0.0) << i;
  for (int j = 0; j < after; ++j) {
    const double expected = (ba - bb) * std::exp(-j * t / tau) * mean_share;
    EXPECT_NEAR(trace[before + j].baseline_offset_v, expected, 1e-12) << j;
    EXPECT_EQ(trace[before + j].settled_baseline_v, bb) << j;
  }
  // A step up reads short (a negative range spike, thesis Figs. 3.4-3.5); the
  // settled steady state carries no memory (the same walk as a lone measurement
  // of the coupled device).
  EXPECT_LT(a[before].distance_raw_m - a[before + after - 1].distance_raw_m, -1e-3);
  const auto settled = with.measure(items.back().path[0], {}, 3, before + after - 1);
  EXPECT_NEAR(a[before + after - 1].distance_raw_m, settled.distance_raw_m, 1e-5);
}

TEST(ThesisScanMemory, BaselineMovesTheComparatorLevelInBothModes) {
  // An unrecovered baseline offset d (no decay over the window: tau >> 1 ms) is
  // the comparator at threshold + b + d: the same mean time of flight change as
  // the noise-free echo's rising crossing of a DC-coupled comparator moved from
  // threshold + b to threshold + b + d.
  auto cfg = coupled_config(1e5);
  const device::VirtualRangefinder dev(cfg);
  const auto target = device::Target::plate(3.0, 0.3);
  const double b = dev.coupling_baseline_v(target, {});
  const double d = 0.02;  // 20 mV
  auto rise_at = [&](double level) {
    auto c = device::DeviceConfig{};
    c.discriminator.threshold_v = level;
    return device::VirtualRangefinder(c).echo(target, {}).rise_crossing_ns;
  };
  const double th = cfg.discriminator.threshold_v;
  const double expected = rise_at(th + b + d) - rise_at(th + b);
  ASSERT_GT(expected, 0.03);  // tens of ps: well above the TDC's dithered LSB in the mean
  const double analytic = mean_tof_ns(dev, target, d) - mean_tof_ns(dev, target, 0);
  EXPECT_NEAR(analytic, expected, 0.05 * expected + 0.005);
  // The waveform mode subtracts the baseline from the sampled signal.
  const device::VirtualRangefinder wave(cfg, device::SimulationMode::kWaveform);
  const double sampled = mean_tof_ns(wave, target, d, 300) - mean_tof_ns(wave, target, 0, 300);
  EXPECT_NEAR(sampled, expected, 0.1 * expected + 0.01);
  // A high enough baseline hides a weak echo: missed shots, then no echo at all.
  const auto weak = device::Target::plate(7.0, 0.1);
  const double margin = dev.echo(weak, {}).peak_v - th - dev.coupling_baseline_v(weak, {});
  ASSERT_GT(margin, 0.0);
  device::Conditions high;
  high.baseline_offset_v = margin + 0.05;
  EXPECT_TRUE(dev.measure(weak, {}, 5, 1).has_echo());
  EXPECT_FALSE(dev.measure(weak, high, 5, 1).has_echo());
  const device::VirtualRangefinder wave_weak(cfg, device::SimulationMode::kWaveform);
  EXPECT_FALSE(wave_weak.measure(weak, high, 5, 1, 50).has_echo());
}

// ------------------------------------------------ the loop's memory (accurange)

/// A still beam at 19 in stepping between two greys after `before` outputs.
std::vector<device::SequenceItem> loop_step(const device::VirtualRangefinder& dev, int before,
                                            int after, int grey_a, int grey_b) {
  const double window = device::EchoMemory(dev).window_s(0);
  std::vector<device::SequenceItem> items;
  for (int i = 0; i < before + after; ++i) {
    device::SequenceItem item;
    item.path = {device::Target::plate(
        inches_to_m(19), experiments::grey_reflectance(i < before ? grey_a : grey_b))};
    item.time_s = i * window;
    items.push_back(item);
  }
  return items;
}

TEST(ThesisScanMemory, LoopSettledIsTheLoneMeasurementAndAStepDownLosesLock) {
  auto c = device::accurange_preset();
  c.memory.time_constant_ms = 1.0;  // (the preset's 30 ms would need ~1500 outputs)
  const device::VirtualRangefinder dev(c);
  const device::OscillatorLoop loop(c);
  const int before = 40, after = 200;
  const auto items = loop_step(dev, before, after, 128, 255);  // mid grey to black (Fig. 4.28)
  std::vector<ranging::RawMeasurement> out(items.size());
  std::vector<device::MemoryTrace> trace(items.size());
  device::EchoMemory(dev).measure_sequence(items, 9, out, trace);
  // Settled on mid grey: no memory, the same bytes as a lone measurement.
  for (int i = 0; i < before; ++i) {
    const auto lone = dev.measure(items[i].path[0], {}, 9, static_cast<std::uint64_t>(i));
    EXPECT_EQ(out[i].tof_ns, lone.tof_ns) << i;
    EXPECT_EQ(trace[i].stall_s, 0.0) << i;
  }
  // The coupling's baseline sits at coupling_duty of mid grey's swing; on black the
  // comparator's level (baseline + threshold) is above black's swing until the
  // baseline has relaxed to swing - threshold: lock is lost for
  // tau ln((b_grey - b_black) / (swing_black - threshold - b_black)).
  // (The duty a switch-on starts with, oscillator.duty_wander, has settled in a
  // scan past the laser's turn-on transient: duty_offset is 0 here, kept so the
  // oracle follows the device if a scan is given a switch-on.)
  const double duty = c.oscillator.coupling_duty + loop.duty_offset({}, 9);
  const double vth = c.discriminator.threshold_v;
  const double s_grey =
      loop.state(items.front().path[0], {}, duty - c.oscillator.coupling_duty).swing_v;
  const double s_black =
      loop.state(items.back().path[0], {}, duty - c.oscillator.coupling_duty).swing_v;
  const double tau = c.memory.time_constant_ms * 1e-3;
  const double expected_stall =
      tau * std::log(duty * (s_grey - s_black) / (s_black - vth - duty * s_black));
  ASSERT_GT(expected_stall, 0);
  double stall = 0;
  for (int i = before; i < before + after; ++i) stall += trace[i].stall_s;
  // The loop re-locks when the noise first lifts the swing over the level: the
  // stall is the closed form within a few noise sigmas' worth of the baseline's decay.
  const double noise_v =
      loop.state(items.back().path[0], {}, duty - c.oscillator.coupling_duty).noise_v;
  ASSERT_GT(noise_v, 0);
  EXPECT_NEAR(stall, expected_stall, tau * 5 * noise_v / (s_black - vth - duty * s_black));
  // While lock is lost the windows have no echo; after it the range reads long
  // (the level still high: a late rise) and relaxes to the settled walk.
  const double window = device::EchoMemory(dev).window_s(0);
  const int lost = static_cast<int>(expected_stall / window);
  for (int i = before; i < before + lost; ++i) EXPECT_FALSE(out[i].has_echo()) << i;
  const auto settled = dev.measure(items.back().path[0], {}, 9, before + after - 1);
  const int first = before + lost + 1;
  ASSERT_TRUE(out[first].has_echo());
  EXPECT_GT(out[first].distance_raw_m - settled.distance_raw_m, 0.02);  // > 0.8 in long
  EXPECT_NEAR(out[before + after - 1].distance_raw_m, settled.distance_raw_m, 2e-3);
}

TEST(ThesisScanMemory, LoopNearTheSwingsTopChattersShortOrWaitsLong) {
  // Grey 204 to black at 19 in: the baseline left by grey 204 (half its swing)
  // puts the level ~2 mV (0.6 noise sigma) under black's top, so the first
  // black outputs are near the top (device::near_top_edges); a few time
  // constants' fraction later the margin exceeds 8 sigmas and nothing changes.
  auto c = device::accurange_preset();
  c.memory.time_constant_ms = 1.0;
  c.oscillator.duty_wander = 0.0;  // the baseline at exactly half the swing
  const device::OscillatorLoop loop(c);
  const auto black = device::Target::plate(inches_to_m(19), experiments::grey_reflectance(255));
  const auto grey = device::Target::plate(inches_to_m(19), experiments::grey_reflectance(204));
  const auto sb = loop.state(black, {}), sg = loop.state(grey, {});
  const double margin0 = sb.swing_v * 0.5 - c.discriminator.threshold_v;
  const double offset0 = 0.5 * (sg.swing_v - sb.swing_v);
  ASSERT_GT(margin0 - offset0, 0.0);
  ASSERT_LT(margin0 - offset0, sb.noise_v);
  const int before = 20, after = 60;
  auto run = [&](double hysteresis_mv) {
    auto cc = c;
    cc.oscillator.comparator_hysteresis_mv = hysteresis_mv;
    const device::VirtualRangefinder dev(cc);
    const auto items = loop_step(dev, before, after, 204, 255);
    std::vector<ranging::RawMeasurement> out(items.size());
    device::EchoMemory(dev).measure_sequence(items, 17, out);
    return out;
  };
  const auto chatter = run(0.0);  // every dip below the level is an edge
  const auto waits = run(1e4);    // no dip reaches the level minus 10 V: missed rises only
  const double settled = waits.back().distance_raw_m;
  ASSERT_TRUE(chatter[before].has_echo());
  ASSERT_TRUE(waits[before].has_echo());
  // Extra edges read short (~2 per period at the top: far short of the truth),
  // missed rises long.
  EXPECT_LT(chatter[before].distance_raw_m, settled - 0.1);
  EXPECT_GT(waits[before].distance_raw_m, settled + inches_to_m(0.5));
  // Once the margin is 8 sigmas (tau ln(offset0 / (margin0 - 8 sigma)), < 0.5 ms
  // = 10 outputs) the hysteresis no longer matters: the same bytes.
  const double far_s =
      c.memory.time_constant_ms * 1e-3 * std::log(offset0 / (margin0 - 8 * sb.noise_v));
  const int far =
      before + 1 +
      static_cast<int>(far_s / device::EchoMemory(device::VirtualRangefinder(c)).window_s(0));
  ASSERT_LT(far, before + after);
  for (int i = far; i < before + after; ++i)
    EXPECT_EQ(std::memcmp(&chatter[i].tof_ns, &waits[i].tof_ns, sizeof(double)), 0) << i;
  for (int i = 0; i < before; ++i) EXPECT_EQ(chatter[i].tof_ns, waits[i].tof_ns) << i;
}

TEST(ThesisScanMemory, LoopIntensityReadsLowWhileTheBaselineRecovers) {
  // The intensity output is a peak detector behind the loop's AC coupling
  // (device/oscillator_loop.hpp): after a step down (mid grey to grey 204) each
  // output reads low by offset / (1 - coupling_duty), held at threshold / (1 -
  // duty), the offset being the window's mean unrecovered baseline (the trace);
  // oracle: the ratio to the lone measurement of the same stream (same noise
  // draw). Windows around a short stall are counted apart (loop_window.hpp).
  // Settled outputs are the lone measurement's bytes.
  auto c = device::accurange_preset();
  c.memory.time_constant_ms = 1.0;
  const device::VirtualRangefinder dev(c);
  const device::OscillatorLoop loop(c);
  const int before = 20, after = 60;
  const auto items = loop_step(dev, before, after, 128, 204);
  std::vector<ranging::RawMeasurement> out(items.size());
  std::vector<device::MemoryTrace> trace(items.size());
  device::EchoMemory(dev).measure_sequence(items, 9, out, trace);
  const double share = 1.0 - c.oscillator.coupling_duty;
  const double a = loop.state(items.back().path[0], {}).amplitude_v;
  ASSERT_LT(a, c.link.receiver.amplitude_clip_v);
  const double floor_v = c.discriminator.threshold_v / share;  // locked: above the threshold
  double lowest = 1;
  int checked = 0;
  for (int i = 0; i < before + after; ++i) {
    const auto lone = dev.measure(items[i].path[0], {}, 9, static_cast<std::uint64_t>(i));
    if (i < before) {
      EXPECT_EQ(out[i].amplitude, lone.amplitude) << i;
      continue;
    }
    if (trace[i].stall_s > 0) continue;  // counted around a stall (device/loop_window.hpp)
    ++checked;
    ASSERT_TRUE(out[i].has_echo()) << i;
    const double ratio = out[i].amplitude / lone.amplitude;
    EXPECT_NEAR(ratio, std::max(a - trace[i].baseline_offset_v / share, floor_v) / a, 1e-12) << i;
    lowest = std::min(lowest, ratio);
  }
  // Most windows lock (48 of 60 here; the others are counted around a stall).
  EXPECT_GT(checked, after * 3 / 4);
  EXPECT_LT(lowest, 0.7);  // the first windows after the step: visibly low
}

TEST(ThesisScanMemory, LoopMovingWindowIsCountedOverItsGate) {
  // A DC-coupled loop (no memory) whose beam moves from white onto black during
  // an output: the board counts during the first gate_fraction (0.5) of the
  // window only, so a window split half and half reads the white target's
  // period, not the average of both (device/loop_window.hpp).
  auto c = device::accurange_preset();
  c.memory.time_constant_ms = 0.0;
  c.oscillator.duty_wander = 0.0;  // the noise-free periods below are the oracle
  ASSERT_EQ(c.oscillator.gate_fraction, 0.5);
  const device::VirtualRangefinder dev(c);
  const device::OscillatorLoop loop(c);
  const auto white = device::Target::plate(inches_to_m(19), experiments::grey_reflectance(0));
  const auto black = device::Target::plate(inches_to_m(19), experiments::grey_reflectance(255));
  device::SequenceItem item;
  item.path = {white, black};
  item.shots = 1 << 14;
  std::vector<device::SequenceItem> items{item};
  std::vector<ranging::RawMeasurement> out(1);
  device::EchoMemory(dev).measure_sequence(items, 4, out);
  ASSERT_TRUE(out[0].has_echo());
  const double zero = c.oscillator.zero_half_period_ns;
  const double t_white = loop.state(white, {}).period_ns;
  const double t_black = loop.state(black, {}).period_ns;
  // The walk between them (0.28 ns at 360 MHz) is 7x the tolerance below, so the
  // mean of both periods would fail it.
  ASSERT_GT(t_black - t_white, 0.2);
  EXPECT_NEAR(2 * (out[0].tof_ns + zero), t_white, 0.02);
}

TEST(ThesisScanMemory, SameBytesOnOneAndTwoThreads) {
  const device::VirtualRangefinder dev(device::accurange_preset());
  // Gaps of 100 tau split the sequence into segments that run in parallel.
  auto items = step_sequence(dev, 40, 40, 0.05, 0.8);
  const double gap_s = 100 * dev.config().memory.time_constant_ms * 1e-3;
  for (std::size_t i = 0; i < items.size(); ++i) items[i].time_s += (i / 10) * gap_s;
  ASSERT_GT(device::EchoMemory(dev).segments(items).size(), 4u);
  std::vector<ranging::RawMeasurement> one(items.size()), two(items.size());
  {
    tbb::global_control c(tbb::global_control::max_allowed_parallelism, 1);
    device::EchoMemory(dev).measure_sequence(items, 11, one);
  }
  {
    tbb::global_control c(tbb::global_control::max_allowed_parallelism, 2);
    device::EchoMemory(dev).measure_sequence(items, 11, two);
  }
  EXPECT_EQ(0, std::memcmp(one.data(), two.data(), one.size() * sizeof(one[0])));
}

TEST(ThesisScanMemory, BadSequencesAreRefused) {
  const device::VirtualRangefinder dev(device::accurange_preset());
  auto items = step_sequence(dev, 2, 2, 0.1, 0.2);
  std::vector<ranging::RawMeasurement> out(items.size());
  items[2].time_s = -1;  // time going backwards
  EXPECT_THROW(device::EchoMemory(dev).measure_sequence(items, 1, out), std::invalid_argument);
  items[2].time_s = 1;
  items[1].path.clear();
  EXPECT_THROW(device::EchoMemory(dev).measure_sequence(items, 1, out), std::invalid_argument);
  std::vector<ranging::RawMeasurement> short_out(1);
  EXPECT_THROW(device::EchoMemory(dev).measure_sequence(items, 1, short_out),
               std::invalid_argument);
}

TEST(ThesisScanMemory, MemoryKeysAreValidated) {
  auto c = device::accurange_preset();
  EXPECT_TRUE(device::validate(c).empty());
  c.memory.time_constant_ms = -1;
  c.memory.coupling_share = 2;
  const auto messages = device::validate(c);
  ASSERT_EQ(messages.size(), 2u);
  EXPECT_NE(messages[0].find("memory.time_constant_ms"), std::string::npos);
  EXPECT_NE(messages[1].find("memory.coupling_share"), std::string::npos);
}

TEST(ThesisScanMemory, FitRecoversTheCouplingTimeConstant) {
  // Other devices than the preset: a slower receiver on the pulsed core. With
  // a baseline small against the echoes (a restorer leaving 10 % of the
  // coupling), the walk is linear in the offset and the memory correction's
  // exponential finds the coupling's time constant.
  const double tau_ms = 0.3;
  auto cfg = coupled_config(tau_ms, 0.4);
  cfg.link.receiver.bandwidth_mhz = 40;
  cfg.measurement.shots = 100;
  const device::VirtualRangefinder dev(cfg);
  std::vector<device::SequenceItem> items;
  const double window = device::EchoMemory(dev).window_s(0);
  for (int cycle = 0; cycle < 60; ++cycle) {
    for (int i = 0; i < 60; ++i) {
      device::SequenceItem it;
      it.path = {device::Target::plate(2.0, (i / 30) % 2 ? 0.6 : 0.15)};
      it.time_s = (cycle * 60 + i) * window;
      items.push_back(it);
    }
  }
  std::vector<ranging::RawMeasurement> raw(items.size());
  device::EchoMemory(dev).measure_sequence(items, 8, raw);
  std::vector<double> time, truth;
  for (const auto& it : items) {
    time.push_back(it.time_s);
    truth.push_back(2.0);
  }
  // The fit's grid finer than the tolerance (0.025 decade a step).
  calib::MemoryFitOptions options;
  options.candidates = 241;
  const auto fit = calib::fit_memory_correction(time, raw, truth, options);
  EXPECT_NEAR(fit.correction.time_constant_s, tau_ms * 1e-3, 0.15 * tau_ms * 1e-3);
}

TEST(ThesisScanMemory, MirrorScansAreTheSameOnOneAndTwoThreads) {
  const device::VirtualRangefinder dev(device::accurange_preset());
  experiments::MemoryScanOptions o;
  o.revolutions = 2;
  o.elevation_step_deg = 0.5;
  auto run = [&](int threads) {
    tbb::global_control c(tbb::global_control::max_allowed_parallelism, threads);
    return experiments::run_memory_scans(dev, o, 9);
  };
  const auto one = run(1), two = run(2);
  ASSERT_EQ(one.mirror_records.size(), two.mirror_records.size());
  for (std::size_t i = 0; i < one.mirror_records.size(); ++i) {
    EXPECT_EQ(0, std::memcmp(&one.mirror_records[i].raw, &two.mirror_records[i].raw,
                             sizeof(ranging::RawMeasurement)))
        << i;
  }
  EXPECT_EQ(one.fit.correction.gain_m_per_neper, two.fit.correction.gain_m_per_neper);
}

// --------------------------------------------- the thesis's figures (accurange)

const experiments::LineScanResult& line_result() {
  static const auto r = [] {
    const device::VirtualRangefinder dev(device::accurange_preset());
    return experiments::run_line_scan(dev, {}, 1);
  }();
  return r;
}

const experiments::MemoryScanResult& memory_result() {
  static const auto r = [] {
    const device::VirtualRangefinder dev(device::accurange_preset());
    return experiments::run_memory_scans(dev, {}, 1);
  }();
  return r;
}

/// Mean of true - measured over a chart image's pixels of one grey (NaN: none).
double grey_mean_error_m(const experiments::ChartImages& im, int grey) {
  double sum = 0;
  int n = 0;
  for (std::size_t i = 0; i < im.raw.values.size(); ++i) {
    const double e = double(im.truth.values[i]) - double(im.raw.values[i]);
    if (im.pixel_grey[i] != grey || !std::isfinite(e)) continue;
    sum += e;
    ++n;
  }
  return n > 0 ? sum / n : std::nan("");
}

// One test per experiment (each runs its scans once, about a minute on 2 cores).
// What the scans must show whatever the preset's numbers: the thesis's
// line-scan set-up, its grey ordering, the noise limit and the confidence.
TEST(ThesisScanFigures, LineScanReproducesFigs423To427AndConfidenceImages) {
  const auto& r = line_result();
  // Samples per line vary and exceed the wanted columns (thesis 4.7: 1235-1255).
  EXPECT_GT(*std::max_element(r.samples_per_line.begin(), r.samples_per_line.end()), 1000);
  // No model beats the noise limit (what a perfect systematic correction leaves)
  // on the stripes. The limit comes from one repeat scan: a variance from
  // 6 line pairs, whose 5 % lower chi-square quantile (6 degrees of freedom) is
  // 0.27 of the true one, so a model's RMS is held above sqrt(0.27) = 0.52 of the
  // estimate. (On the checkerboard the loop loses lock on a few pixels after its
  // large random steps, erratically, and differently in the repeat scan: one
  // pair of scans estimates that limit too roughly to hold a model to it.)
  EXPECT_GT(r.checker.noise_limit_m, 0);
  EXPECT_GT(r.line.noise_limit_m, 0);
  for (const auto& row : r.line.rows) EXPECT_GT(row.test.rms_m, 0.52 * r.line.noise_limit_m);
  // Section 4.4 (reference): dark targets read long, very bright (saturating)
  // ones short: on the stripe image white's mean error (true - measured) is the
  // largest and, in the stripes' inner columns (two or more from an edge, the
  // grey's own response), black's the smallest. (Over whole stripes grey 204,
  // between two edges, reads up to 0.4 mm longer than black with its one edge:
  // the coupling's memory after the brighter stripe, Fig. 4.28.)
  const double white = grey_mean_error_m(r.stripe_images, 0);
  for (const int g : r.options.grey_levels)
    EXPECT_LE(grey_mean_error_m(r.stripe_images, g), white + 1e-9) << g;
  ASSERT_EQ(r.per_grey.size(), 6u);
  const double black = r.per_grey.back().centre_mean_m;
  ASSERT_EQ(r.per_grey.back().grey, 255);
  for (const auto& row : r.per_grey) EXPECT_GE(row.centre_mean_m, black - 1e-9) << row.grey;
  // Every grey improves, unless its raw error is already within the noise limit
  // (no correction of (range, intensity) removes the noise).
  for (const auto& row : r.per_grey)
    EXPECT_LT(row.best_rms_m, std::max(row.raw_rms_m, r.line.noise_limit_m)) << row.grey;
  // Figs. 4.32-4.33: tofkit's confidence is fitted on line scans of random-grey
  // charts at the confidence distances, so it has seen the coupling's memory
  // after every size of grey step (white after black reads up to 1.9 in long),
  // and covers 93-98 % of both test images' errors within 2 sigma: the stripes
  // (one grey step at each edge) and the test's own random checkerboard (another
  // draw). Fitted on stripe scans alone it covered 84-87 % of the checkerboard.
  for (const auto* im : {&r.stripe_images, &r.checker_images}) {
    EXPECT_GE(im->within_2_sigma.share, 0.93);
    EXPECT_LE(im->within_2_sigma.share, 0.98);
    EXPECT_LT(im->within_1_sigma.share, im->within_2_sigma.share);
  }
}

TEST(ThesisScanFigures, LineScanPixelNoiseIsNotTheScansNorTheSwitchOnsDuty) {
  // Where a line scan's per-pixel noise comes from. A stripe's inner pixel (two or more columns
  // from an edge) averages ~20 samples of 256 shots, each far finer than thesis Fig. 4.4's
  // single-sample spread at that setting (variance 0.00019 in^2 at 1221 samples/s, sd 0.014 in):
  // the scan's motion, memory and resampling add no noise there, and the pixel
  // reads what a still beam reads on a plate of its grey.
  auto cfg = device::accurange_preset();
  cfg.oscillator.duty_wander = 0.0;
  const device::VirtualRangefinder quiet(cfg);
  const auto r = experiments::run_line_scan(quiet, {}, 3);
  const device::OscillatorLoop loop(cfg);
  const double fig44_sd_m = inches_to_m(std::sqrt(0.00019));
  ASSERT_EQ(r.per_grey.size(), 6u);
  for (const auto& row : r.per_grey) {
    EXPECT_LT(row.centre_noise_m, fig44_sd_m) << row.grey;
    double sum = 0;
    const int n = 50;
    const auto plate =
        device::Target::plate(r.options.test_distance_m, experiments::grey_reflectance(row.grey));
    device::Conditions c;
    c.ambient_c = r.options.ambient_c;
    for (int k = 0; k < n; ++k)
      sum += loop.measure(plate, c, 9, static_cast<std::uint64_t>(k), r.options.shots_per_sample)
                 .distance_raw_m;
    const double still_m = r.options.test_distance_m - sum / n;
    if (row.grey <= 153) {
      EXPECT_NEAR(row.centre_mean_m, still_m, fig44_sd_m) << row.grey;
    } else {
      // The dark stripes follow a brighter one on every other line: the loop's
      // AC coupling (memory.time_constant_ms, 30 ms: 4.5 mm of stage travel)
      // has not quite settled two columns (5 mm) in, so they read long, by
      // less than a millimetre.
      EXPECT_LT(row.centre_mean_m, still_m) << row.grey;
      EXPECT_GT(row.centre_mean_m, still_m - 1e-3) << row.grey;
    }
  }
  // The duty a switch-on starts with (oscillator.duty_wander, which scatters the
  // point-by-point chart's points) has settled in a line scan (the laser stays
  // on, past its turn-on transient): the preset's scan is the same, byte for byte.
  const auto& preset = line_result();
  const auto quiet_again = experiments::run_line_scan(quiet, {}, 1);
  ASSERT_EQ(preset.records.size(), quiet_again.records.size());
  for (std::size_t i = 0; i < preset.records.size(); ++i)
    EXPECT_EQ(0, std::memcmp(&preset.records[i].raw, &quiet_again.records[i].raw,
                             sizeof(ranging::RawMeasurement)))
        << i;
}

TEST(ThesisScanFigures, MirrorEdgeSpikesAndColourTransitionLoseLockAndReadLong) {
  const auto& m = memory_result();
  // The memory correction (a signed lag filter, tofkit's) is still fitted on the
  // step-edge scan; the loop's memory (a baseline that moves the comparator's
  // level, lock lost after a step down) does not have its form, so no claim
  // that it removes the spikes.
  EXPECT_GT(m.fit.correction.time_constant_s, 0.0);
  ASSERT_EQ(m.mirror_edges.edges.size(), 4u);
  // Figs. 3.4-3.5: something at every mirror-swept edge. Onto a block the range
  // reads long (error = true - measured < 0): the loop's period is shortest with
  // the coupling's baseline settled at the duty share of the swing, and a level
  // left low by the weaker wall delays the fall.
  for (const auto& e : m.mirror_edges.edges)
    if (e.rising) EXPECT_LT(e.spike_before_m, -3e-3) << e.elevation_deg;
  // Fig. 4.28, scanned line by line: on black after mid grey the loop loses lock
  // on some outputs, and the others read long and relax.
  const auto& t = m.transition_line;
  ASSERT_GT(t.outputs_first_half, 50u);
  EXPECT_GT(t.no_echo_first_half, 0u);
  EXPECT_LT(t.no_echo_first_half, t.outputs_first_half);
  EXPECT_GT(t.swing_m, 0.0);
}

// The thesis's line-scan figures that the merged AccuRange preset (issue 30:
// hL1's point-scan receiver with hL2's loop memory) does not reproduce yet;
// `tofkit validate --preset accurange` reports the same rows out of band
// (thesis.fig4_23.raw.*, thesis.fig4_27.raw.*, thesis.improvement.*.tofkit,
// thesis.fig4_28.swing, thesis.edge_spikes). Disabled, not loosened: enable
// when the twin reproduces them.
TEST(ThesisScanFigures, DISABLED_LineAndMirrorScansMatchTheThesisTables) {
  const auto& r = line_result();
  // Scanned line by line the raw error spreads more than point by point
  // (thesis: variance 5.0x on the stripes, 10.6x on the checkerboard).
  static const auto point = [] {
    const device::VirtualRangefinder dev(device::accurange_preset());
    return experiments::run_thesis_protocol(dev, {}, 1);
  }();
  const double point_variance = point.row("raw").test.variance_m2;
  EXPECT_GT(r.line.row("raw").test.variance_m2, 2.0 * point_variance);
  EXPECT_GT(r.checker.row("raw").test.variance_m2, 2.0 * point_variance);
  // The best model beats the thesis's best polynomial on both tables.
  EXPECT_GT(r.line.best().rms_improvement_pct, 67.72);     // Fig. 4.23, order 5
  EXPECT_GT(r.checker.best().rms_improvement_pct, 59.74);  // Fig. 4.27, order 5
  // +-2 sigma coverage of the stripe chart's confidence image at most 98 %.
  EXPECT_LE(r.stripe_images.within_2_sigma.share, 0.98);
  // The raw line scans read short, as the thesis's tables do.
  EXPECT_GT(r.line.row("raw").test.bias_m, 0);     // Fig. 4.23: +0.126 in
  EXPECT_GT(r.checker.row("raw").test.bias_m, 0);  // Fig. 4.27: +0.423 in
  EXPECT_NEAR(m_to_inches(r.checker.row("raw").test.rms_m), 1.436, 0.25 * 1.436);
  const auto& m = memory_result();
  // Off a block the level is left high: the range reads long, or the loop
  // loses lock (no reading right after the edge on the first revolution).
  const auto& p = m.mirror_edges;
  for (const auto& e : p.edges) {
    if (e.rising) continue;
    std::size_t k = 0;
    while (k < p.elevation_deg.size() && p.elevation_deg[k] < e.elevation_deg) ++k;
    ASSERT_LT(k, p.single_before_m.size());
    EXPECT_TRUE(e.spike_before_m < -1e-3 || std::isnan(p.single_before_m[k])) << e.elevation_deg;
  }
  // Fig. 4.28: 15.65-23.91 in (8.26 in, the matrix's band +-4 in).
  EXPECT_NEAR(m_to_inches(m.transition_line.swing_m), 8.26, 4.0);
}

}  // namespace
}  // namespace tofkit
