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
#include "tofkit/experiments/scan_memory.hpp"
#include "tofkit/experiments/thesis_line_scan.hpp"
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

TEST(ThesisScanMemory, SameBytesOnOneAndTwoThreads) {
  const device::VirtualRangefinder dev(device::accurange_preset());
  // Gaps of 100 tau split the sequence into segments that run in parallel.
  auto items = step_sequence(dev, 40, 40, 0.05, 0.8);
  for (std::size_t i = 0; i < items.size(); ++i) items[i].time_s += (i / 10) * 0.1;
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

// One test per experiment (each runs its scans once, about a minute on 2 cores).
TEST(ThesisScanFigures, LineScanReproducesFigs423To427AndConfidenceImages) {
  const auto& r = line_result();
  // Fig. 4.23: the raw row within 25 % of the thesis's 0.949 in.
  EXPECT_NEAR(m_to_inches(r.line.row("raw").test.rms_m), 0.949, 0.25 * 0.949);
  // Samples per line vary and exceed the wanted columns (thesis 4.7: 1235-1255).
  EXPECT_GT(*std::max_element(r.samples_per_line.begin(), r.samples_per_line.end()), 1000);
  // The best model beats the thesis's best polynomial on both tables.
  EXPECT_GT(r.line.best().rms_improvement_pct, 67.72);     // Fig. 4.23, order 5
  EXPECT_GT(r.checker.best().rms_improvement_pct, 59.74);  // Fig. 4.27, order 5
  // No model beats the noise limit (what a perfect systematic correction leaves).
  for (const auto* t : {&r.line, &r.checker}) {
    EXPECT_GT(t->noise_limit_m, 0);
    for (const auto& row : t->rows) EXPECT_GT(row.test.rms_m, 0.9 * t->noise_limit_m);
  }
  // Fig. 4.24 and Section 4.4: the unit reads short overall (positive bias) and the
  // walk makes dark greys read long and saturating ones short, so the darkest
  // grey's (255) raw error is the smallest and the brightest's (0) the largest;
  // every grey improves.
  ASSERT_EQ(r.per_grey.size(), 6u);
  for (const auto& row : r.per_grey) {
    EXPECT_LE(row.raw_rms_m, r.per_grey.front().raw_rms_m) << row.grey;
    EXPECT_GE(row.raw_rms_m, r.per_grey.back().raw_rms_m) << row.grey;
  }
  for (const auto& row : r.per_grey) EXPECT_LT(row.best_rms_m, row.raw_rms_m);
  // Figs. 4.32-4.33: +-2 sigma coverage of each confidence image in 90-98 %.
  for (const auto* im : {&r.stripe_images, &r.checker_images}) {
    EXPECT_GE(im->within_2_sigma.share, 0.90);
    EXPECT_LE(im->within_2_sigma.share, 0.98);
    EXPECT_LT(im->within_1_sigma.share, im->within_2_sigma.share);
  }
}

TEST(ThesisScanFigures, MirrorEdgeSpikesAndColourTransitionAreCorrected) {
  const auto& m = memory_result();
  // The fit finds the preset's time constant (1 ms) from the step-edge scan.
  EXPECT_NEAR(m.fit.correction.time_constant_s, 1e-3, 0.15e-3);
  ASSERT_EQ(m.mirror_edges.edges.size(), 4u);
  for (const auto& e : m.mirror_edges.edges) {
    // error = true - measured: onto a block (strength up) the range reads short
    // (a negative range spike), off it long (positive), Figs. 3.4-3.5.
    if (e.rising) {
      EXPECT_GT(e.spike_before_m, 3e-3);
    } else {
      EXPECT_LT(e.spike_before_m, -3e-3);
    }
  }
  EXPECT_LE(m.mirror_edges.spike_after_m, 0.2 * m.mirror_edges.spike_before_m);
  EXPECT_LT(m.mirror_edges.rms_near_edges_after_m, m.mirror_edges.rms_near_edges_before_m);
  // Fig. 4.28: mid grey into black reads long, the correction tames the swing.
  const auto& t = m.color_transition;
  ASSERT_EQ(t.edges.size(), 1u);
  EXPECT_FALSE(t.edges[0].rising);
  EXPECT_LT(t.edges[0].spike_before_m, -5e-3);
  EXPECT_LT(std::abs(t.edges[0].spike_after_m), 0.5 * std::abs(t.edges[0].spike_before_m));
}

// The raw scans read long, as the thesis's line and checkerboard tables do.
TEST(ThesisScanFigures, RawBiasHasTheThesisSign) {
  EXPECT_GT(line_result().line.row("raw").test.bias_m, 0);     // Fig. 4.23: +0.126 in
  EXPECT_GT(line_result().checker.row("raw").test.bias_m, 0);  // Fig. 4.27: +0.423 in
  EXPECT_NEAR(m_to_inches(line_result().checker.row("raw").test.rms_m), 1.436, 0.25 * 1.436);
}

}  // namespace
}  // namespace tofkit
