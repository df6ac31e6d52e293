// The physical walk model (issue 8): a pulse shape through a fixed threshold,
// fitted on the paper's protocol (plates at one distance plus a temperature
// run) and judged on a field of distances, reflectances and temperatures
// beyond the plates' pulse widths. The device is reached only through its
// public API and config keys; the fit sees only its records.

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <limits>
#include <nlohmann/json.hpp>
#include <random>
#include <string>
#include <variant>
#include <vector>

#include "cli_runner.hpp"
#include "other_parts_device.hpp"
#include "tofkit/calib/calibration_plan.hpp"
#include "tofkit/calib/chain_fit.hpp"
#include "tofkit/calib/model_fit.hpp"
#include "tofkit/calib/repeatability.hpp"
#include "tofkit/calib/statistics.hpp"
#include "tofkit/calib/walk_fit.hpp"
#include "tofkit/device/device_config.hpp"
#include "tofkit/device/virtual_rangefinder.hpp"
#include "tofkit/experiments/device_plan.hpp"
#include "tofkit/experiments/measurement_grid.hpp"
#include "tofkit/io/model_json.hpp"
#include "tofkit/io/raw_csv.hpp"
#include "tofkit/physics/link_budget.hpp"
#include "tofkit/physics/pulse_template.hpp"
#include "tofkit/ranging/walk_model.hpp"

namespace tofkit {
namespace {

using test::other_parts;
using test::set_key;

/// The other parts with another receiver bandwidth, pulse width and threshold.
device::DeviceConfig other_parts_with(double bandwidth_mhz, double pulse_width_ns,
                                      double threshold_v) {
  device::DeviceConfig config = other_parts();
  set_key(config, "receiver.bandwidth_mhz", bandwidth_mhz);
  set_key(config, "laser.pulse_width_ns", pulse_width_ns);
  set_key(config, "discriminator.threshold_v", threshold_v);
  EXPECT_TRUE(device::validate(config).empty());
  return config;
}

/// Parts as the random-device sweeps drew them: the other parts' TDC with
/// another receiver bandwidth, pulse width, APD gain and threshold.
device::DeviceConfig swept_parts(double bandwidth_mhz, double pulse_width_ns, double apd_gain,
                                 double threshold_v) {
  device::DeviceConfig config = other_parts_with(bandwidth_mhz, pulse_width_ns, threshold_v);
  set_key(config, "receiver.apd_gain", apd_gain);
  return config;
}

/// A third set of parts: slower receiver, wider pulse, lower threshold.
device::DeviceConfig slow_wide_parts() {
  return other_parts_with(60.0, 3.0, 0.03);
}

/// A fourth: faster receiver, shorter pulse, higher threshold.
device::DeviceConfig fast_parts() {
  return other_parts_with(200.0, 1.0, 0.08);
}

enum class Protocol {
  kPaperAtThreeMetres,  ///< plates at 3.0 m: none clips
  kPlannedOneDistance,  ///< plates at the planner's single distance: the brightest clip
  kCentredOneDistance,  ///< the same, centred whether or not the field clips (no clip power)
};

struct Figures {
  double worst_unclipped_m = 0;                ///< >= 90 % valid rows whose echo did not clip
  double worst_clipped_m = 0;                  ///< >= 90 % valid rows whose echo clipped
  double worst_in_domain_m = 0;                ///< rows without a correction flag
  double worst_outside_unclipped_m = 0;        ///< unclipped rows flagged out of domain
  double hinge_worst_outside_unclipped_m = 0;  ///< the grayvalue chain on those rows
  /// Clipped rows by their clipping depth ln(V / receiver.saturation_v), V
  /// the unclipped peak (the brightest unclipped plate's amplitude reading
  /// scaled by the received power, paper Eq. 6): <= 0, (0, 1], (1, 2], > 2.
  std::array<double, 4> worst_clipped_by_depth_m{};
  std::array<std::size_t, 4> clipped_by_depth{};
  double deepest_plate_clip_nepers = -1;  ///< the plates' deepest clipping
  double deepest_clip_nepers = -1;        ///< the test's deepest clipping
  double plate_distance_m = 0;
  std::size_t rows = 0, clipped = 0, outside = 0, outside_unflagged = 0;
  calib::ChainFitResult fit;
};

/// The test field: 0.7-7.4 m x rho 0.06-0.85 x 8-37 C.
constexpr double kFieldRangeMin = 0.7, kFieldRangeMax = 7.4;
constexpr double kFieldRhoMin = 0.06, kFieldRhoMax = 0.85;

/// The paper protocol, plates at ONE distance plus a temperature run, tested
/// in the same power-on over the field. kPaperAtThreeMetres: the protocol of
/// calib_other_device_test.cpp (plates at 3.0 m, rho 0.04-0.9 x 5 at 20 C; rho
/// 0.3 at 0-45 C). kPlannedOneDistance: the distance and the plates from
/// `calib::plan_calibration` with `single_distance` (what `tofkit plan
/// --single-distance` prints, experiments::plan_for_device) for this field and
/// the device: the distance that centres the log-power span of plates
/// 0.02-0.95 on the field's (paper Eq. 6, Pr ~ rho / R^2: the field spans x1583
/// in power and the plates x47.5, so its strongest and weakest echoes both lie
/// ln(5.8) = 1.75 nepers beyond the plates', at 1.78 m), moved nearer when
/// the field's strong echoes clip until the brightest plate is overdriven by
/// one neper (1.34-1.44 m for the devices here): three plates clip, the
/// field's strongest echoes by more than two nepers.
struct ProtocolRows {
  std::vector<ranging::Record> fit_rows, test_rows;
  double plate_distance_m = 0;
};

/// `temperature_run_m`: the temperature run's distance (0: the plates').
ProtocolRows protocol_rows(const device::DeviceConfig& config, Protocol protocol,
                           double temperature_run_m = 0, std::uint64_t seed = 1) {
  const device::VirtualRangefinder device(config);
  std::vector<experiments::PlannedMeasurement> calibration, test;
  ProtocolRows f;
  if (protocol == Protocol::kPaperAtThreeMetres) {
    f.plate_distance_m = 3.0;
    for (double rho : {0.04, 0.06, 0.1, 0.15, 0.2, 0.3, 0.45, 0.6, 0.75, 0.9}) {
      for (int repeat = 0; repeat < 5; ++repeat)
        calibration.push_back(experiments::plate(3.0, rho, 20.0));
    }
    for (double t = 0; t <= 45; t += 2.5) {
      for (int repeat = 0; repeat < 5; ++repeat)
        calibration.push_back(experiments::plate(3.0, 0.3, t));
    }
  } else {
    calib::CalibrationPlanOptions o;
    o.range_min_m = kFieldRangeMin;
    o.range_max_m = kFieldRangeMax;
    o.reflectance_min = kFieldRhoMin;
    o.reflectance_max = kFieldRhoMax;
    o.single_distance = true;
    o.temperature_min_c = 0;
    o.temperature_max_c = 45;
    o.temperature_step_c = 2.5;
    const calib::CalibrationPlan plan = protocol == Protocol::kCentredOneDistance
                                            ? calib::plan_calibration(config.link, o)
                                            : experiments::plan_for_device(device, o);
    f.plate_distance_m = plan.calibration_distance_m;
    for (const auto& p : plan.plates) {
      EXPECT_EQ(p.distance_m, plan.calibration_distance_m);
      for (int repeat = 0; repeat < 5; ++repeat)
        calibration.push_back(experiments::plate(p.distance_m, p.reflectance, 20.0));
    }
    for (double t : plan.temperatures_c) {
      for (int repeat = 0; repeat < 5; ++repeat) {
        calibration.push_back(experiments::plate(
            temperature_run_m > 0 ? temperature_run_m : plan.temperature_plate.distance_m,
            plan.temperature_plate.reflectance, t));
      }
    }
  }
  for (double d = kFieldRangeMin; d <= kFieldRangeMax + 1e-9; d += 0.67) {
    for (double rho : {kFieldRhoMin, 0.12, 0.25, 0.45, 0.65, kFieldRhoMax}) {
      for (double t = 8; t <= 37 + 1e-9; t += 5.8) test.push_back(experiments::plate(d, rho, t));
    }
  }
  std::vector<experiments::PlannedMeasurement> plan = calibration;
  plan.insert(plan.end(), test.begin(), test.end());
  const auto rows = experiments::run(device, plan, seed);
  const std::vector<ranging::Record> fit_rows(
      rows.begin(), rows.begin() + static_cast<std::ptrdiff_t>(calibration.size()));
  const std::vector<ranging::Record> test_rows(
      rows.begin() + static_cast<std::ptrdiff_t>(calibration.size()), rows.end());
  f.fit_rows = fit_rows;
  f.test_rows = test_rows;
  return f;
}

Figures run_protocol(const device::DeviceConfig& config, Protocol protocol) {
  const ProtocolRows data = protocol_rows(config, protocol);
  const std::vector<ranging::Record>& fit_rows = data.fit_rows;
  const std::vector<ranging::Record>& test_rows = data.test_rows;
  Figures f;
  f.plate_distance_m = data.plate_distance_m;
  // Clipping depth: the amplitude reading is linear below the clip level.
  const auto power_w = [&](const ranging::Record& r) {
    return physics::received_power_extended_w(config.link, r.truth.distance_m, r.truth.reflectance,
                                              0.0);
  };
  double volts_per_watt = 0, reference_w = 0;
  for (const auto& r : fit_rows) {
    if ((r.raw.flags & ranging::kRawSaturated) == 0 && r.truth.ambient_c == 20.0 &&
        power_w(r) > reference_w) {
      reference_w = power_w(r);
      volts_per_watt = r.raw.amplitude / reference_w;
    }
  }
  const auto depth = [&](const ranging::Record& r) {
    return std::log(volts_per_watt * power_w(r) / config.link.receiver.saturation_v);
  };
  for (const auto& r : fit_rows) {
    if (r.raw.flags & ranging::kRawSaturated)
      f.deepest_plate_clip_nepers = std::max(f.deepest_plate_clip_nepers, depth(r));
  }
  calib::ChainFitOptions options;
  options.steps = calib::parse_chain_steps("offset,walk,temperature");
  f.fit = calib::fit_chain(fit_rows, options);
  const calib::ChainFitResult hinge = calib::fit_chain(fit_rows);
  const ranging::Step& walk_step = f.fit.pipeline.steps()[1];
  for (const auto& r : test_rows) {
    if (!(r.raw.shots_valid >= 0.9 * config.measurement.shots)) continue;
    const ranging::Range range = f.fit.pipeline.apply(r.raw);
    const double error = std::fabs(r.truth.distance_m - range.distance_m);
    EXPECT_TRUE(std::isfinite(error));
    ++f.rows;
    const bool clipped = (r.raw.flags & ranging::kRawSaturated) != 0;
    const bool outside = !walk_step.domain.contains(r.raw.pulse_width_ns);
    if (outside) {
      ++f.outside;
      if ((range.correction_flags & ranging::kCorrOutOfDomain) == 0) ++f.outside_unflagged;
    }
    if (range.correction_flags == 0) f.worst_in_domain_m = std::max(f.worst_in_domain_m, error);
    if (clipped) {
      ++f.clipped;
      f.worst_clipped_m = std::max(f.worst_clipped_m, error);
      const double d = depth(r);
      f.deepest_clip_nepers = std::max(f.deepest_clip_nepers, d);
      const auto bin = static_cast<std::size_t>(std::clamp(std::ceil(d), 0.0, 3.0));
      ++f.clipped_by_depth[bin];
      f.worst_clipped_by_depth_m[bin] = std::max(f.worst_clipped_by_depth_m[bin], error);
    } else {
      f.worst_unclipped_m = std::max(f.worst_unclipped_m, error);
      if (outside) {
        f.worst_outside_unclipped_m = std::max(f.worst_outside_unclipped_m, error);
        const ranging::Range h = hinge.pipeline.apply(r.raw);
        f.hinge_worst_outside_unclipped_m = std::max(f.hinge_worst_outside_unclipped_m,
                                                     std::fabs(r.truth.distance_m - h.distance_m));
      }
    }
  }
  std::printf(
      "plates at %.3f m: %zu rows >= 90 %% valid (%zu clipped, %zu outside the plates' widths): "
      "worst unclipped %.3f mm, clipped %.3f mm, in-domain %.3f mm; outside and unclipped: walk "
      "%.3f mm, grayvalue hinge %.3f mm\n  clipping depth ln(V / saturation_v): plates' deepest "
      "%.2f; test rows <=0: %zu rows %.3f mm, 0-1: %zu rows %.3f mm, 1-2: %zu rows %.3f mm, >2: "
      "%zu rows %.3f mm (deepest %.2f)\n  %s\n",
      f.plate_distance_m, f.rows, f.clipped, f.outside, f.worst_unclipped_m * 1e3,
      f.worst_clipped_m * 1e3, f.worst_in_domain_m * 1e3, f.worst_outside_unclipped_m * 1e3,
      f.hinge_worst_outside_unclipped_m * 1e3, f.deepest_plate_clip_nepers, f.clipped_by_depth[0],
      f.worst_clipped_by_depth_m[0] * 1e3, f.clipped_by_depth[1],
      f.worst_clipped_by_depth_m[1] * 1e3, f.clipped_by_depth[2],
      f.worst_clipped_by_depth_m[2] * 1e3, f.clipped_by_depth[3],
      f.worst_clipped_by_depth_m[3] * 1e3, f.deepest_clip_nepers, f.fit.walk->summary().c_str());
  return f;
}

// The plates at 3.0 m never clip, so the clipping onset and recovery are not
// observable from the paper protocol: the walk model then corrects every
// unclipped echo (weaker and stronger than the plates') by the shape, within
// 5 mm, where the hinge's linear continuation does worse.
TEST(WalkModel, PaperProtocolCorrectsUnclippedEchoesBeyondThePlatesWidths) {
  const Figures f = run_protocol(other_parts(), Protocol::kPaperAtThreeMetres);
  EXPECT_EQ(f.fit.walk->saturated_rows, 0u);
  EXPECT_FALSE(std::isfinite(f.fit.walk->shape.saturation_log_overdrive));
  EXPECT_LE(f.worst_unclipped_m, 0.005) << f.fit.summary();
  EXPECT_LE(f.worst_in_domain_m, 0.003) << f.fit.summary();
  EXPECT_GT(f.outside, f.rows / 10);   // the test reaches beyond the plates' widths
  EXPECT_EQ(f.outside_unflagged, 0u);  // and those rows are still flagged
  EXPECT_LT(f.worst_outside_unclipped_m, f.hinge_worst_outside_unclipped_m);
}

void expect_acceptance(const Figures& f) {
  // The brightest plate clips by the neper planned (the test's own estimate
  // of the depth, from the amplitude readings below the clip), the field's
  // strongest echoes by more than two: the recovery is extrapolated.
  EXPECT_GT(f.fit.walk->saturated_rows, 0u);
  EXPECT_GT(f.deepest_plate_clip_nepers, 0.0);
  EXPECT_NEAR(f.deepest_plate_clip_nepers, 1.0, 0.1);
  EXPECT_GT(f.clipped_by_depth[3], 0u);
  EXPECT_LE(f.worst_unclipped_m, 0.005) << f.fit.summary();
  EXPECT_LE(f.worst_clipped_m, 0.005) << f.fit.summary();
  EXPECT_LE(f.worst_in_domain_m, 0.003) << f.fit.summary();
  EXPECT_GT(f.outside, f.rows / 10);
  EXPECT_EQ(f.outside_unflagged, 0u);
}

// Plates at the one distance the planner gives for the field: the brightest
// clip by up to a neper, and the recovery fitted from them carries to
// the field's strongest echoes: every row with >= 90 % valid shots is within
// 5 mm, in-domain rows within 3 mm.
TEST(WalkModel, PlannedOneDistanceProtocolEveryRowIsWithinFiveMillimetres) {
  expect_acceptance(run_protocol(other_parts(), Protocol::kPlannedOneDistance));
}

// A low-gain receiver (159 MHz, 2.15 ns pulse, APD gain 22, threshold
// 0.027 V; one of 24 random devices): plates centred on the field's powers
// clip none, while the field's strong echoes clip by up to 1.6 nepers; the walk
// then has no clipping and reads those rows up to 145 mm off. The planner asks
// the device its clip power and moves the plates nearer until the brightest
// clips by one neper (0.99 m): every row within 5 mm (measured 1.8 mm
// unclipped, 0.9 mm clipped, 1.0 mm in domain; from the widths alone, without
// the amplitude readings, 3.1 / 1.8 / 1.0 mm).
TEST(WalkModel, PlatesClipWhereTheFieldDoes) {
  const device::DeviceConfig config = swept_parts(159.0, 2.15, 22.0, 0.027);
  const Figures centred = run_protocol(config, Protocol::kCentredOneDistance);
  EXPECT_EQ(centred.fit.walk->saturated_rows, 0u);
  EXPECT_GT(centred.deepest_clip_nepers, 1.0);
  EXPECT_GT(centred.worst_clipped_m, 0.05);
  const Figures planned = run_protocol(config, Protocol::kPlannedOneDistance);
  EXPECT_LT(planned.plate_distance_m, centred.plate_distance_m);
  EXPECT_NEAR(planned.deepest_plate_clip_nepers, 1.0, 0.1);
  EXPECT_LE(planned.worst_unclipped_m, 0.005) << planned.fit.summary();
  EXPECT_LE(planned.worst_clipped_m, 0.005) << planned.fit.summary();
  EXPECT_LE(planned.worst_in_domain_m, 0.003) << planned.fit.summary();
}

// A calibration made mostly of rows that lost shots says so. A high APD gain
// in 1.84 x Table 1 sunlight (252 MHz, 2.44 ns, gain 170, threshold 0.034 V;
// one of 24 random devices) loses shots to false alarms on most plates (the
// walk chain leaves 38-62 mm RMS and test rows metres off), and the report
// notes the share of partial rows, whatever the chain (here the hinges: a
// walk fit on such rows runs its 30 backfitting passes without settling, 19 s,
// and took 52-72 s while every pass searched its starts afresh). The other
// parts indoors get no such note.
TEST(WalkModel, ACalibrationOfPartialEchoesSaysSo) {
  device::DeviceConfig sunlit = swept_parts(252.0, 2.44, 170.0, 0.034);
  sunlit.link.environment.solar_irradiance_w_per_m2_um =
      1.84 * physics::kTable1SolarIrradiance_w_per_m2_um;
  calib::ModelFitOptions options;
  options.chain = calib::parse_chain_steps("offset,grayvalue,temperature");
  options.confidence = calib::ConfidenceKind::none;
  const ProtocolRows bad = protocol_rows(sunlit, Protocol::kPlannedOneDistance);
  std::size_t partial = 0;
  for (const auto& r : bad.fit_rows) partial += (r.raw.flags & ranging::kRawPartialEchoes) != 0;
  EXPECT_GT(4 * partial, bad.fit_rows.size());
  const std::string report = calib::fit_model(bad.fit_rows, options).report;
  EXPECT_NE(report.find("rows with an echo lost shots"), std::string::npos) << report;
  const ProtocolRows good = protocol_rows(other_parts(), Protocol::kPlannedOneDistance);
  EXPECT_EQ(calib::fit_model(good.fit_rows, options).report.find("lost shots"), std::string::npos);
}

// Not tuned to one device: slower receiver, twice the pulse width, lower
// threshold; and faster receiver, shorter pulse, higher threshold.
TEST(WalkModel, HoldsOnOtherDevices) {
  for (const device::DeviceConfig& config : {slow_wide_parts(), fast_parts()}) {
    const Figures paper = run_protocol(config, Protocol::kPaperAtThreeMetres);
    EXPECT_LE(paper.worst_unclipped_m, 0.005) << paper.fit.summary();
    EXPECT_LE(paper.worst_in_domain_m, 0.003) << paper.fit.summary();
    EXPECT_GT(paper.outside, paper.rows / 10);
    EXPECT_EQ(paper.outside_unflagged, 0u);
    expect_acceptance(run_protocol(config, Protocol::kPlannedOneDistance));
  }
}

// Pulse widths alone leave the shape's sigma and tau trading off: on a slow
// receiver with a wide pulse (69 MHz, 5.26 ns FWHM, APD gain 89, threshold
// 0.059 V, no sun; device 19 of a sweep of 24 random devices) the plates'
// widths (10.4-23.7 ns) fit sigma 2.99 ns and tau 2.77 ns against the
// device's 2.23 / 1.49 ns, and the field's weakest echoes (4.7-7.4 m, rho
// 0.06-0.12, widths 2.5-6 ns) are read up to 6.46 mm off. The amplitude
// readings (linear below the clip: ln A = ln a + const on unclipped rows) pin
// the shape: the fitted sigma and tau are the device's own pulse (a Gaussian
// of FWHM laser.pulse_width_ns through two equal receiver poles) within 10 %
// (measured within 0.1 %), and every row is within 5 mm (measured 1.7 mm
// unclipped, 2.0 mm clipped, 1.3 mm in domain; plates at 1.78 m). The same
// rows with the amplitude column empty fit from the widths alone, as before.
// (On the sweep's 24 devices: sigma and tau within 10 % on all, within 2 % on
// 23, where the widths alone gave 0.44-27 x; 19 meet the acceptance, 17
// before.)
TEST(WalkModel, AmplitudeReadingsPinThePulseShape) {
  const device::DeviceConfig config = swept_parts(69.0, 5.26, 89.0, 0.059);
  ASSERT_TRUE(device::validate(config).empty());
  const double sigma = config.link.laser.pulse_width_ns / (2.0 * std::sqrt(2.0 * std::log(2.0)));
  const double tau = physics::two_pole_time_constant_ns(config.link.receiver.bandwidth_mhz);

  const Figures f = run_protocol(config, Protocol::kPlannedOneDistance);
  EXPECT_GT(f.fit.walk->amplitude_rows, 0u);
  EXPECT_NEAR(f.fit.walk->shape.pulse_sigma_ns / sigma, 1.0, 0.1) << f.fit.walk->summary();
  EXPECT_NEAR(f.fit.walk->shape.pole_time_constant_ns / tau, 1.0, 0.1) << f.fit.walk->summary();
  EXPECT_LE(f.worst_unclipped_m, 0.005) << f.fit.summary();
  EXPECT_LE(f.worst_clipped_m, 0.005) << f.fit.summary();
  EXPECT_LE(f.worst_in_domain_m, 0.003) << f.fit.summary();

  // The same calibration rows with the amplitude column empty: widths alone.
  const ProtocolRows data = protocol_rows(config, Protocol::kPlannedOneDistance);
  std::vector<ranging::Record> without = data.fit_rows;
  for (ranging::Record& r : without) r.raw.amplitude = std::numeric_limits<double>::quiet_NaN();
  calib::ChainFitOptions options;
  options.steps = calib::parse_chain_steps("offset,walk,temperature");
  const calib::ChainFitResult widths_only = calib::fit_chain(without, options);
  ASSERT_TRUE(widths_only.walk.has_value());
  EXPECT_EQ(widths_only.walk->amplitude_rows, 0u);
  double worst_unclipped = 0;
  for (const auto& r : data.test_rows) {
    if (!(r.raw.shots_valid >= 0.9 * config.measurement.shots) ||
        (r.raw.flags & ranging::kRawSaturated) != 0)
      continue;
    worst_unclipped =
        std::max(worst_unclipped,
                 std::fabs(r.truth.distance_m - widths_only.pipeline.apply(r.raw).distance_m));
  }
  std::printf(
      "device sigma %.3f ns, tau %.3f ns; without amplitudes: %s, worst unclipped %.2f mm\n", sigma,
      tau, widths_only.walk->summary().c_str(), worst_unclipped * 1e3);
  EXPECT_GT(std::fabs(widths_only.walk->shape.pole_time_constant_ns / tau - 1.0), 0.25);
  EXPECT_GT(worst_unclipped, 0.005);
}

/// sigma_m's coverage (|error| <= 2 sigma) on the test rows with >= 90 %
/// valid shots of a model fitted by calib::fit_model with the walk chain.
struct CoverageFigures {
  calib::Coverage all, in_domain, out_of_domain;
  double out_of_domain_error_rms_m = 0, out_of_domain_sigma_rms_m = 0;
  double error_rms_m = 0, sigma_rms_m = 0, largest_sigma_m = 0;  ///< all rows
  double seconds = 0;
};

CoverageFigures walk_chain_coverage(const ProtocolRows& data, const device::DeviceConfig& config,
                                    calib::ConfidenceKind kind) {
  calib::ModelFitOptions options;
  options.chain = calib::parse_chain_steps("offset,walk,temperature");
  options.confidence = kind;
  const auto start = std::chrono::steady_clock::now();
  const calib::ModelFitResult model = calib::fit_model(data.fit_rows, options);
  CoverageFigures c;
  c.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  std::vector<double> error[3], sigma[3], amplitude[3];  // all, in domain, out of domain
  for (const auto& r : data.test_rows) {
    if (!(r.raw.shots_valid >= 0.9 * config.measurement.shots)) continue;
    const ranging::Range range = model.pipeline.apply(r.raw);
    const int part = (range.correction_flags & ranging::kCorrOutOfDomain) ? 2 : 1;
    for (int k : {0, part}) {
      error[k].push_back(range.distance_m - r.truth.distance_m);
      sigma[k].push_back(range.sigma_m);
      amplitude[k].push_back(r.raw.amplitude);
    }
  }
  const calib::TercileEdges edges = calib::amplitude_terciles(amplitude[0]);
  c.all = calib::coverage(error[0], sigma[0], amplitude[0], 2.0, edges);
  c.in_domain = calib::coverage(error[1], sigma[1], amplitude[1], 2.0, edges);
  c.out_of_domain = calib::coverage(error[2], sigma[2], amplitude[2], 2.0, edges);
  const auto rms = [](const std::vector<double>& v) {
    double sum = 0;
    for (double x : v) sum += x * x;
    return std::sqrt(sum / static_cast<double>(v.size()));
  };
  c.out_of_domain_error_rms_m = rms(error[2]);
  c.out_of_domain_sigma_rms_m = rms(sigma[2]);
  c.error_rms_m = rms(error[0]);
  c.sigma_rms_m = rms(sigma[0]);
  for (double s : sigma[0]) c.largest_sigma_m = std::max(c.largest_sigma_m, s);
  const auto line = [](const char* name, const calib::Coverage& v) {
    std::printf("  %-13s %3zu rows: %.1f %% within 2 sigma (terciles %.1f / %.1f / %.1f %%)\n",
                name, v.rows, 100 * v.share, 100 * v.tercile_share[0], 100 * v.tercile_share[1],
                100 * v.tercile_share[2]);
  };
  std::printf("confidence %s, fit %.2f s:\n",
              kind == calib::ConfidenceKind::calibrated ? "calibrated" : "noise-systematic",
              c.seconds);
  line("all", c.all);
  line("in domain", c.in_domain);
  line("out of domain", c.out_of_domain);
  std::printf("  out of domain: error RMS %.3f mm, sigma RMS %.3f mm\n",
              c.out_of_domain_error_rms_m * 1e3, c.out_of_domain_sigma_rms_m * 1e3);
  return c;
}

// sigma_m on the planned protocol's test rows (measured, not the acceptance's
// 93-97 %: one distance at 20 C plus a temperature run at one power cannot show
// the confidence fit the errors of other distances at other temperatures).
// With the plates where the planner now puts them (the brightest overdriven by
// one neper, 1.34 m), the confidence's folds stratified along pulse width and
// the walk fitted to the amplitude readings as well as the widths: calibrated
// 86.6 % within 2 sigma (terciles 80.7 / 85.7 / 93.3 %; in domain 88.7 %,
// flagged 82.5 %), noise-systematic 80.7 % (68.1 / 83.2 / 90.8 %; 84.9 / 72.5
// %); the flagged rows' RMS sigma 0.32 and 0.26 mm against 0.44 mm of error.
// The flagged rows' coverage within 10 points of the in-domain rows' is
// asserted for the calibrated kind only: the noise-systematic kind covers them
// by 72.5 % against 84.9 % in domain (12.4 points). With the amplitude
// readings holding the shape's sigma and tau, the walk rows' leverages sum to
// 6.8 (p = 9 effective parameters) where widths alone gave 11.9 (the shape
// traded sigma for tau along a valley), so its optimism falls from 8.6 to 2.2
// on average: its wider sigma had covered the errors no plate shows (below) by
// the fit's own looseness. The flagged rows lie mostly in the weak tercile,
// which it covers by 71 % in domain as well. Measured from the widths alone:
// calibrated 86.3 % (81.5 / 85.7 / 91.7 %; 88.2 / 82.5 %; seeds 7-10: 79.1 /
// 90.3 / 81.0 / 68.7 %; the slower and faster parts of HoldsOnOtherDevices at
// seeds 1, 7-10: 89.0 / 69.6 / 89.3 / 82.2 / 69.1 % and 83.8 / 65.9 / 84.4 /
// 81.7 / 67.6 %), noise-systematic 91.1 % (85.7 / 93.3 / 94.2 %; 93.3 / 86.7
// %), the flagged rows' RMS sigma 0.31 and 0.32 mm against 0.44 mm of
// error. (With random folds the out-of-fold residuals held out two of the three
// clipped plates together, whose walk then came from one clipped width: 2.6 mm
// RMS, sigma 2-7 mm for errors under 0.7 mm, 96.6 % here but 99 % in the middle
// tercile, 80-98 % at seeds 7-9; such a sigma covered more of the test only by
// being too large where the plates clip.) Earlier figures, plates centred at 1.78 m
// (the brightest clipped by 0.4-0.6 neper), random folds: the default calibrated kind 81 %
// overall, 71 / 87 / 86 % by tercile. Measured with 6 repeats of every test target:
// the test rows' errors (0.54 / 0.35 / 0.34 mm RMS by tercile, sigma 0.29 / 0.27 / 0.33 mm) are
// mostly systematic and seem to grow with distance (4 repeats: by distance +0.18 mm at 1.4 m to
// -0.53 mm at 6.7-7.4 m, by temperature -0.42 mm at 37 C) but are periodic in the time of flight,
// aliased by the test's 0.67 m steps against the coarse clock's 0.75 m: the residual INL of the
// code-density test (temperature-independent) and the fine bins' drift with the board's temperature
// (tdc.bin_tempco_ppm_per_c, 100 ppm/C: a sawtooth of (s - 1) x 0.75 m, 1.3 mm at 37 C, see
// Device.TdcBinTempcoErrorIsPeriodicInRange), neither of which plates at one distance can see. A
// range-proportional temperature term fitted from a second temperature run is therefore not
// physics here: its slope follows the sawtooth's phase at the second distance (+0.39, +0.15, 0.0,
// -0.10 um/(C ns) at 4.5, 4.2, 4.8, 6.0 m). With the INL residual off as well as the bin tempco
// (tdc.inl_lsb 0, no code-density hits; 4 repeats of the test targets) 0.29 mm RMS and 95 % (91 /
// 97 / 97 %). The same device with the bin tempco at 0: 0.36 / 0.28 / 0.39 mm, and
// the calibrated kind covers 92 / 93 / 90 %. Out-of-domain rows (flagged) were covered at least as
// well as in-domain ones with both kinds (now within 6 points): their shortfall is not a sigma kept
// from inside the domain. Nor is their sigma a blanket growth: the walk step adds its own
// extrapolation variance from the fitted shape's bootstrap replicates, so the flagged rows' RMS
// sigma stays within a factor 2 of their RMS error with both kinds (measured 0.38 and 0.35 mm
// against 0.47 mm; 0.84 and 0.82 mm with the walk's Gauss-Newton covariance, whose strong tercile
// had 0.71 mm of RMS sigma for 0.34 mm of error; with the generic growth the calibrated kind gave
// 0.46 mm against 0.56 mm in the weak tercile and 0.80 against 0.30 mm in the strong one, and the
// noise-systematic kind, whose systematic part was then a floored log fit, 12 mm for errors of 0.6
// mm). The noise-systematic kind with each target's own optimism (1 + h) / (1 - h) from its
// leverage: 77.4 % (68.1 / 81.5 / 82.5 %; one optimism (G + p) / (G - p) for all targets: 76.5 %).
// Other run seeds (the test uses 1; seeds 7, 8, 9, 10): calibrated 70.5 / 73.0 / 85.8 / 70.7 %,
// noise-systematic 78.8 / 96.1 / 84.1 / 77.1 % (one optimism: 71.9 / 78.6 / 80.4 / 67.9 %); the
// slower parts of HoldsOnOtherDevices (seeds 1, 7-10): calibrated 93.7 / 84.8 / 82.2 / 92.9 / 85.9
// %, noise-systematic 91.1 / 70.2 / 80.4 / 81.2 / 83.2 % (one optimism: 79.1 / 69.6 / 80.4 / 73.6
// / 74.9 %). With the bin tempco at 0 the calibrated kind gives 91.9 % at seed 1 but 78.0 / 84.1
// / 90.8 / 81.3 % at seeds 7-10. The shortfall is in errors the calibration rows do not show (one
// distance, one plate through the temperature run), so no term fitted from them covers it. Nor is
// it the 1/f wander (measurement.flicker_delay_ps at 0: calibrated 75.1 / 73.0 / 77.2 / 87.2 / 74.0
// % at seeds 1, 7-10; with the wander and the bin tempco both at 0, 83.5 / 77.7 / 86.6 / 89.7
// / 83.5 %: the tempco is not the only error one distance hides).
TEST(WalkModel, SigmaCoverageOnThePlannedProtocol) {
  const device::DeviceConfig config = other_parts();
  const ProtocolRows data = protocol_rows(config, Protocol::kPlannedOneDistance);
  for (auto kind : {calib::ConfidenceKind::calibrated, calib::ConfidenceKind::noise_systematic}) {
    const CoverageFigures c = walk_chain_coverage(data, config, kind);
    EXPECT_GT(c.all.rows, 300u);
    EXPECT_GT(c.out_of_domain.rows, c.all.rows / 10);
    if (kind == calib::ConfidenceKind::calibrated)
      EXPECT_GE(c.out_of_domain.share, c.in_domain.share - 0.1);
    EXPECT_LT(c.out_of_domain_sigma_rms_m, 2.0 * c.out_of_domain_error_rms_m);
    EXPECT_GT(c.out_of_domain_sigma_rms_m, 0.5 * c.out_of_domain_error_rms_m);
  }
}

// The temperature run at another distance than the plates (4.5 m): the
// calibration then has two distances, and the run saw one plate (a narrow
// spread of intensities, from the gain's temperature drift). The calibrated
// confidence may not invent how range and intensity mix: found with a term in
// both, free where no row was, sigma 16-27 mm RMS in the upper terciles for
// errors of 0.4-0.5 mm, 27 m at the domain's far, strong corner. Every sigma
// finite, their RMS within 4 x the errors' and none above 20 x it.
TEST(WalkModel, ATemperatureRunAtAnotherDistanceKeepsSigmaNearTheErrors) {
  const device::DeviceConfig config = other_parts();
  const ProtocolRows data = protocol_rows(config, Protocol::kPlannedOneDistance, 4.5);
  const CoverageFigures c = walk_chain_coverage(data, config, calib::ConfidenceKind::calibrated);
  std::printf("  error RMS %.3f mm, sigma RMS %.3f mm, largest sigma %.3f mm\n",
              c.error_rms_m * 1e3, c.sigma_rms_m * 1e3, c.largest_sigma_m * 1e3);
  EXPECT_GT(c.all.rows, 300u);
  EXPECT_TRUE(std::isfinite(c.largest_sigma_m));
  EXPECT_LE(c.sigma_rms_m, 4.0 * c.error_rms_m);
  EXPECT_LE(c.largest_sigma_m, 20.0 * c.error_rms_m);
}

// Cross-fitting folds start the walk from the full fit's shape instead of
// searching (ChainFitOptions::walk_initial): refitted on the same rows from
// that start, the correction is the same to 0.05 mm on every test row (no
// multistart search: on these plates 27 LM iterations from that start, against
// 17 for the search's best start).
TEST(WalkModel, WarmStartRefitMatchesTheSearchedFit) {
  const device::DeviceConfig config = fast_parts();
  const ProtocolRows data = protocol_rows(config, Protocol::kPlannedOneDistance);
  calib::ChainFitOptions options;
  options.steps = calib::parse_chain_steps("offset,walk,temperature");
  const calib::ChainFitResult searched = calib::fit_chain(data.fit_rows, options);
  options.walk_initial = searched.walk->shape;
  const calib::ChainFitResult warm = calib::fit_chain(data.fit_rows, options);
  EXPECT_TRUE(warm.walk->converged) << warm.walk->summary();
  double worst = 0;
  for (const auto& r : data.test_rows) {
    if (!r.raw.has_echo()) continue;
    worst = std::max(worst, std::fabs(searched.pipeline.apply(r.raw).distance_m -
                                      warm.pipeline.apply(r.raw).distance_m));
  }
  EXPECT_LE(worst, 5e-5) << warm.walk->summary() << "\n" << searched.walk->summary();
}

// ---------------------------------------------------------------------------
// Oracle: rows generated from a known shape over a narrow band of echo
// strengths; the fit must predict the walk far outside it.

constexpr double kMetresPerNs = 0.1499;

double interpolate(const std::vector<double>& x, const std::vector<double>& y, double at) {
  const auto it = std::upper_bound(x.begin(), x.end(), at);
  const auto k = static_cast<std::size_t>(
      std::clamp<std::ptrdiff_t>(it - x.begin(), 1, static_cast<std::ptrdiff_t>(x.size()) - 1));
  return y[k - 1] + (at - x[k - 1]) / (x[k] - x[k - 1]) * (y[k] - y[k - 1]);
}

/// The fitted model predicts the true curve's walk (relative to the fit's
/// reference width) within 1 mm for ln a from 0.2 to `log_a_max`.
void expect_walk_of(const ranging::WalkCurve& curve, const calib::WalkFitResult& fit,
                    double log_a_max) {
  const ranging::WalkModel model(fit.shape, fit.reference_pulse_width_ns);
  const double truth_ref = ranging::rise_at_width(curve, fit.reference_pulse_width_ns);
  for (double log_a = 0.2; log_a <= log_a_max; log_a += 0.2) {
    const double width = interpolate(curve.log_overdrive, curve.width_ns, log_a);
    const double true_walk =
        -kMetresPerNs * (interpolate(curve.log_overdrive, curve.rise_ns, log_a) - truth_ref);
    EXPECT_NEAR(-kMetresPerNs * model.relative_rise_ns(width), true_walk, 0.001)
        << "ln a " << log_a << ", width " << width << " ns";
  }
}

TEST(WalkModel, FitRecoversAKnownShapeAndExtrapolates) {
  const ranging::WalkShape truth{0.6, 1.1};
  const ranging::WalkCurve curve = ranging::walk_curve(truth);
  std::mt19937_64 rng(5);
  std::normal_distribution<double> noise(0.0, 2e-4);
  std::vector<double> w, e;
  for (double log_a = 1.5; log_a <= 3.5; log_a += 0.05) {
    w.push_back(interpolate(curve.log_overdrive, curve.width_ns, log_a));
    e.push_back(-0.2 - kMetresPerNs * interpolate(curve.log_overdrive, curve.rise_ns, log_a) +
                noise(rng));
  }
  const calib::WalkFitResult fit = calib::fit_walk(w, e, {}, {}, 5.0, kMetresPerNs);
  EXPECT_NEAR(fit.shape.pulse_sigma_ns, truth.pulse_sigma_ns, 0.05) << fit.summary();
  EXPECT_NEAR(fit.shape.pole_time_constant_ns, truth.pole_time_constant_ns, 0.1) << fit.summary();
  expect_walk_of(curve, fit, 8.0);  // far beyond 1.5..3.5
}

// The same with clipping: rows above ln a = 4 flagged clipped (2 ns of extra
// width per e-fold), and a few partial-echo rows with a wrong error that must
// not be fitted. The recovery is found and the walk predicted for echoes far
// stronger than any fitted.
// The fitted shape's bootstrap replicates against Monte Carlo: the same known
// shape, rows over a band of echo strengths with 0.3 mm of noise, fitted
// `draws` times on independent noise. The spread of the predicted walk far
// outside the band (where it is the extrapolation's error) must match the
// spread the replicates predict there (WalkModel::relative_rise_variance_ns2)
// within the Monte Carlo's own uncertainty (the SD of `draws` draws is known to
// about +-2 / sqrt(2 draws): +-22 % for 40, +-29 % for 24) and the
// bootstrap's, and the prediction must grow away from the band. Unclipped rows
// (two shape parameters), and rows that clip above ln a = 4 (four: the onset
// and the recovery trade off along a curved valley, where a linearized
// covariance overstated the spread up to 70 x on the twin's plates).
/// `amplitude_noise_nepers` > 0: the rows also carry amplitude readings,
/// V_th a on unclipped rows with that much log-normal noise (the clip level on
/// clipped ones), and the replicates resample them too.
void expect_replicates_predict_the_spread(const ranging::WalkShape& truth, double log_a_max,
                                          const std::vector<double>& at_log_a, int draws,
                                          std::size_t replicates,
                                          double amplitude_noise_nepers = 0) {
  const ranging::WalkCurve curve = ranging::walk_curve(truth);
  constexpr double kNoiseM = 3e-4, kReference = 5.0;
  std::vector<std::vector<double>> predicted(at_log_a.size());
  std::vector<double> predicted_sd(at_log_a.size(), 0.0), inside_sd;
  std::mt19937_64 rng(11);
  std::normal_distribution<double> noise(0.0, kNoiseM);
  std::normal_distribution<double> amplitude_noise(0.0, std::max(amplitude_noise_nepers, 1e-12));
  constexpr double kThresholdV = 0.05;
  const int kDraws = draws;
  const double tolerance = 2.0 / std::sqrt(2.0 * draws);
  for (int draw = 0; draw < kDraws; ++draw) {
    std::vector<double> w, e, amplitude;
    std::vector<std::uint8_t> status;
    for (double log_a = 1.5; log_a <= log_a_max; log_a += 0.05) {
      w.push_back(interpolate(curve.log_overdrive, curve.width_ns, log_a));
      e.push_back(-0.2 - kMetresPerNs * interpolate(curve.log_overdrive, curve.rise_ns, log_a) +
                  noise(rng));
      const bool clipped = log_a > truth.saturation_log_overdrive;
      status.push_back(clipped ? calib::kWalkRowClipped : 0);
      if (amplitude_noise_nepers > 0) {
        amplitude.push_back(kThresholdV * std::exp(clipped ? truth.saturation_log_overdrive
                                                           : log_a + amplitude_noise(rng)));
      }
    }
    calib::WalkFitOptions options;
    options.initial = truth;  // the same valley every draw: the spread is the noise's
    options.multistart = false;
    options.replicates = replicates;
    const calib::WalkFitResult fit =
        calib::fit_walk(w, e, status, amplitude, kReference, kMetresPerNs, options);
    ASSERT_EQ(fit.amplitude_rows > 0, amplitude_noise_nepers > 0) << fit.summary();
    ASSERT_GE(fit.shape_replicates.size(), replicates - replicates / 8) << fit.summary();
    const ranging::WalkModel model(fit.shape, kReference, fit.shape_replicates);
    for (std::size_t k = 0; k < at_log_a.size(); ++k) {
      const double width = interpolate(curve.log_overdrive, curve.width_ns, at_log_a[k]);
      predicted[k].push_back(kMetresPerNs * model.relative_rise_ns(width));
      predicted_sd[k] += kMetresPerNs * std::sqrt(model.relative_rise_variance_ns2(width)) / kDraws;
    }
    inside_sd.push_back(kMetresPerNs *
                        std::sqrt(model.relative_rise_variance_ns2(w[w.size() / 2])));
  }
  for (std::size_t k = 0; k < at_log_a.size(); ++k) {
    double mean = 0, ss = 0;
    for (double v : predicted[k]) mean += v / kDraws;
    for (double v : predicted[k]) ss += (v - mean) * (v - mean);
    const double sd = std::sqrt(ss / (kDraws - 1));
    std::printf("ln a %.1f: Monte Carlo sd %.4f mm, replicates predict %.4f mm\n", at_log_a[k],
                sd * 1e3, predicted_sd[k] * 1e3);
    EXPECT_GT(predicted_sd[k], (1.0 - tolerance) * sd);
    EXPECT_LT(predicted_sd[k], (1.0 + tolerance) * sd);
    // Far outside the band the extrapolation is less certain than inside it.
    EXPECT_GT(predicted_sd[k], 2.0 * inside_sd.front());
  }
}

TEST(WalkModel, ShapeReplicatesPredictTheExtrapolationSpread) {
  // Weaker and much stronger than the band 1.5-3.5.
  expect_replicates_predict_the_spread({0.6, 1.1}, 3.5, {0.4, 6.0, 9.0}, 40, 24);
}

// With amplitude readings (1 % of noise, the peak detector's) the shape is
// held by them too: the replicates resample their residuals as well as the
// walk rows', and still predict the Monte Carlo spread (measured 0.28 / 0.41
// mm against 0.29 / 0.43 mm at ln a 6 / 9, a quarter of the spread from the
// widths alone; at ln a 0.4, just below the band, 0.131 against 0.135 mm, not
// asserted: there the extrapolation is now less than twice as uncertain as
// the band's middle). The readings' own part is small here: kept fixed in
// the replicates they give the same to 0.1 %; with 10 % of reading noise,
// resampled 0.28 / 0.44 mm, fixed 0.28 / 0.41 mm, Monte Carlo 0.30 / 0.48 mm.
TEST(WalkModel, ShapeReplicatesWithAmplitudeReadingsPredictTheExtrapolationSpread) {
  expect_replicates_predict_the_spread({0.6, 1.1}, 3.5, {6.0, 9.0}, 40, 24, 0.01);
}

TEST(WalkModel, ShapeReplicatesPredictTheClippedExtrapolationSpread) {
  // Clipped from ln a = 4 (2 ns per e-fold); fitted up to 5, predicted far beyond.
  expect_replicates_predict_the_spread({0.6, 1.1, 4.0, 2.0}, 5.0, {7.0, 9.0}, 24, 16);
}

// Outside a walk step's domain the row is flagged and its sigma is the
// in-domain sigma with the walk's own variance beyond the domain's edge added
// (not the generic lever-arm growth); inside, sigma is untouched; a walk
// without replicates keeps the generic growth. The model file keeps the
// replicates and refuses a malformed one naming it; an older file's
// covariance becomes replicates whose variance is the delta method's.
TEST(WalkModel, OutOfDomainSigmaAddsTheWalksOwnVariance) {
  const ranging::WalkShape shape{0.6, 1.1};
  const std::vector<ranging::WalkShape> replicates{
      {0.62, 1.1}, {0.58, 1.12}, {0.6, 1.05}, {0.61, 1.16}};
  const ranging::InputDomain domain{4.0, 7.0};
  const auto pipeline_with = [&](std::vector<ranging::WalkShape> r) {
    ranging::Pipeline p;
    p.add_step(ranging::make_walk_step(
        std::make_shared<const ranging::WalkModel>(shape, 5.5, std::move(r)), domain));
    p.set_residual_rms_m(2e-4);
    return p;
  };
  const ranging::Pipeline with = pipeline_with(replicates), without = pipeline_with({});
  const ranging::WalkModel& walk = *with.steps().front().walk;
  const double metres_per_ns = with.start_distance_m(ranging::RawMeasurement{.tof_ns = 1.0});
  for (double width : {2.0, 3.0, 3.99, 4.0, 5.0, 7.0, 7.5, 9.0, 12.0}) {
    ranging::RawMeasurement raw;
    raw.tof_ns = 20.0;
    raw.pulse_width_ns = width;
    raw.amplitude = 0.5;
    raw.shots_valid = 100;
    const ranging::Range r = with.apply(raw), g = without.apply(raw);
    EXPECT_EQ(r.distance_m, g.distance_m);
    const bool outside = width < domain.min || width > domain.max;
    EXPECT_EQ((r.correction_flags & ranging::kCorrOutOfDomain) != 0, outside) << width;
    if (!outside) {
      EXPECT_EQ(r.sigma_m, 2e-4) << width;
      continue;
    }
    // The variance from the replicates' walks, worked out here.
    const auto variance = [&](double w) {
      double sum = 0;
      for (const auto& rep : replicates) {
        const double d =
            ranging::WalkModel(rep, 5.5).relative_rise_ns(w) - walk.relative_rise_ns(w);
        sum += d * d;
      }
      return sum / static_cast<double>(replicates.size());
    };
    EXPECT_NEAR(walk.relative_rise_variance_ns2(width), variance(width), 1e-15) << width;
    const double edge = width < domain.min ? domain.min : domain.max;
    const double excess = variance(width) - variance(edge);
    EXPECT_GT(excess, 0.0) << width;
    EXPECT_NEAR(r.sigma_m, std::sqrt(4e-8 + metres_per_ns * metres_per_ns * excess), 1e-12)
        << width;
    const double lever = std::max(domain.min - width, width - domain.max) / 3.0;
    EXPECT_NEAR(g.sigma_m, 2e-4 * (1 + ranging::Pipeline::kOutOfDomainSigmaGrowth * lever), 1e-12);
  }
  // Model file: kept, and refused when malformed, naming the replicate.
  const nlohmann::json j = io::pipeline_to_json(with);
  const ranging::Pipeline loaded = io::pipeline_from_json(j, "model.json");
  const auto& kept = loaded.steps().front().walk->replicates();
  ASSERT_EQ(kept.size(), replicates.size());
  for (std::size_t r = 0; r < kept.size(); ++r) {
    EXPECT_EQ(kept[r].pulse_sigma_ns, replicates[r].pulse_sigma_ns);
    EXPECT_EQ(kept[r].pole_time_constant_ns, replicates[r].pole_time_constant_ns);
  }
  const auto refused = [&](const nlohmann::json& bad, const char* key, const char* why) {
    try {
      (void)io::pipeline_from_json(bad, "model.json");
      ADD_FAILURE() << "accepted: " << why;
    } catch (const std::runtime_error& e) {
      EXPECT_NE(std::string(e.what()).find(std::string("model.json.steps[0].") + key),
                std::string::npos)
          << e.what();
      EXPECT_NE(std::string(e.what()).find(why), std::string::npos) << e.what();
    }
  };
  nlohmann::json bad = j;
  bad["steps"][0]["shape_replicates"][1]["pulse_sigma_ns"] = -1.0;
  refused(bad, "shape_replicates[1]", "pulse_sigma_ns");
  // A file with more replicates than a walk step holds is refused, not tabulated.
  nlohmann::json many = j;
  many["steps"][0]["shape_replicates"] = nlohmann::json::array();
  for (std::size_t r = 0; r <= ranging::kMaxWalkReplicates; ++r)
    many["steps"][0]["shape_replicates"].push_back(j["steps"][0]["shape_replicates"][0]);
  try {
    (void)io::pipeline_from_json(many, "model.json");
    ADD_FAILURE() << "accepted too many replicates";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("model.json.steps[0]"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("at most 1024 shape_replicates"), std::string::npos)
        << e.what();
  }
  // An older file's covariance (ln sigma, ln tau): replicates at its sigma
  // points, whose variance is the delta method's g^T C g (g by central
  // differences here) to first order.
  const std::vector<double> covariance{4e-6, 1e-6, 1e-6, 9e-6};
  nlohmann::json old = j;
  old["steps"][0].erase("shape_replicates");
  old["steps"][0]["shape_covariance"] = covariance;
  const ranging::Pipeline old_loaded = io::pipeline_from_json(old, "model.json");
  const ranging::WalkModel& converted = *old_loaded.steps().front().walk;
  EXPECT_EQ(converted.replicates().size(), 4u);
  for (double width : {2.0, 9.0, 12.0}) {
    const std::vector<double> q = ranging::walk_parameters(shape);
    std::array<double, 2> g{};
    for (std::size_t k = 0; k < 2; ++k) {
      std::vector<double> plus = q, minus = q;
      plus[k] += 1e-4;
      minus[k] -= 1e-4;
      g[k] = (ranging::WalkModel(ranging::walk_shape_of(plus), 5.5).relative_rise_ns(width) -
              ranging::WalkModel(ranging::walk_shape_of(minus), 5.5).relative_rise_ns(width)) /
             2e-4;
    }
    const double delta =
        g[0] * g[0] * covariance[0] + 2 * g[0] * g[1] * covariance[1] + g[1] * g[1] * covariance[3];
    EXPECT_NEAR(converted.relative_rise_variance_ns2(width), delta, 0.05 * delta) << width;
  }
  nlohmann::json both = old;
  both["steps"][0]["shape_replicates"] = j["steps"][0]["shape_replicates"];
  refused(both, "shape_covariance", "not both");
  const auto refused_covariance = [&](std::vector<double> c, const char* why) {
    nlohmann::json b = old;
    b["steps"][0]["shape_covariance"] = c;
    refused(b, "shape_covariance", why);
  };
  refused_covariance({4e-4, 1e-4, 1e-4}, "2 x 2");
  refused_covariance({4e-4, 1e-4, 2e-4, 9e-4}, "symmetric");
  refused_covariance({4e-4, 1e-3, 1e-3, 9e-4}, "positive semi-definite");
}

// In sunlight (paper Table 1) the bright plates lose shots to false alarms
// before their echo (the background, and with it the noise, follows the
// reflectance), which the firmware's stop gate drops: rows with 97.3-99.9 %
// of their shots, whose kept shots time the echo as a complete row's do (a
// row losing more than 5 % keeps false stops and is left out). They
// were left out of the walk fit with the weak echoes' partial rows (whose
// mean is biased by which shots crossed), so the walk never saw clipping and
// the temperature run's clipped rows bent the temperature step: the fit's own
// rows kept 11.6 mm of RMS error on the paper device (1.6 mm on other parts
// behind an 80 nm filter in twice the sun) and test rows at the plates'
// distance (>= 90 % of shots valid, 8-37 C) were read up to 47 mm off on the
// paper device, against 4.1 mm indoors. Fitted like complete rows where they
// are wider than a row that echoed on every shot: 0.7 (0.5) mm, and 3.9 mm.
TEST(WalkModel, PartialEchoesFromFalseAlarmsInSunlightAreFitted) {
  struct Figures {
    std::size_t false_alarm_rows = 0, tested = 0;
    double rms_m = 0, worst_m = 0;
  };
  // Plates at 2 m plus a temperature run; test rows at 2 m, 8-37 C.
  const auto calibrate = [](const device::DeviceConfig& config) {
    const device::VirtualRangefinder device(config);
    std::vector<experiments::PlannedMeasurement> calibration, test;
    for (double rho : {0.02, 0.05, 0.13, 0.34, 0.87}) {
      for (int repeat = 0; repeat < 5; ++repeat)
        calibration.push_back(experiments::plate(2.0, rho, 20.0));
    }
    for (double t = 0; t <= 40; t += 5) {
      for (int repeat = 0; repeat < 3; ++repeat)
        calibration.push_back(experiments::plate(2.0, 0.34, t));
    }
    for (double rho : {0.06, 0.12, 0.25, 0.45, 0.65, 0.85}) {
      for (double t = 8; t <= 37 + 1e-9; t += 5.8) test.push_back(experiments::plate(2.0, rho, t));
    }
    std::vector<experiments::PlannedMeasurement> plan = calibration;
    plan.insert(plan.end(), test.begin(), test.end());
    const auto rows = experiments::run(device, plan, 1);
    const std::vector<ranging::Record> fit_rows(
        rows.begin(), rows.begin() + static_cast<std::ptrdiff_t>(calibration.size()));
    Figures f;
    for (const auto& r : fit_rows) {
      if ((r.raw.flags & ranging::kRawPartialEchoes) && r.truth.reflectance >= 0.34)
        ++f.false_alarm_rows;
    }
    calib::ChainFitOptions options;
    options.steps = calib::parse_chain_steps("offset,walk,temperature");
    const calib::ChainFitResult fit = calib::fit_chain(fit_rows, options);
    EXPECT_TRUE(fit.walk.has_value());
    if (fit.walk) {
      EXPECT_EQ(fit.walk->partial_rows, 0u) << fit.walk->summary();
      EXPECT_GT(fit.walk->saturated_rows, 0u) << fit.walk->summary();
    }
    double sum2 = 0;
    for (const auto& r : fit_rows) {
      const double e = fit.pipeline.apply(r.raw).distance_m - r.truth.distance_m;
      sum2 += e * e;
    }
    f.rms_m = std::sqrt(sum2 / static_cast<double>(fit_rows.size()));
    for (std::size_t i = calibration.size(); i < rows.size(); ++i) {
      const ranging::Range range = fit.pipeline.apply(rows[i].raw);
      if (!(rows[i].raw.shots_valid >= 0.9 * config.measurement.shots)) continue;
      ++f.tested;
      f.worst_m = std::max(f.worst_m, std::fabs(range.distance_m - rows[i].truth.distance_m));
    }
    return f;
  };
  device::DeviceConfig other = other_parts();
  set_key(other, "receiver.filter_bandwidth_nm", 80.0);
  for (const auto& [config, sun] :
       {std::pair{device::preset("paper"), 1.0}, std::pair{other, 2.0}}) {
    const Figures indoors = calibrate(config);
    device::DeviceConfig sunlit = config;
    sunlit.link.environment.solar_irradiance_w_per_m2_um =
        sun * physics::kTable1SolarIrradiance_w_per_m2_um;
    const Figures outdoors = calibrate(sunlit);
    std::printf(
        "%g x Table 1 sun: %zu false-alarm rows, fit RMS %.3f mm (indoors %.3f), %zu test "
        "rows, worst %.3f mm (indoors %.3f)\n",
        sun, outdoors.false_alarm_rows, outdoors.rms_m * 1e3, indoors.rms_m * 1e3, outdoors.tested,
        outdoors.worst_m * 1e3, indoors.worst_m * 1e3);
    EXPECT_GE(outdoors.false_alarm_rows, 10u);  // the premise
    // The fit leaves at most 1 mm (in quadrature) beyond the same calibration
    // indoors: same seed, so the same delay and comparator wander, which
    // scatter the paper device's readings by a few mm and which no fit removes.
    EXPECT_LT(outdoors.rms_m, std::hypot(1e-3, indoors.rms_m));
    EXPECT_GT(outdoors.tested, 25u);
    EXPECT_LE(outdoors.worst_m, indoors.worst_m + 3e-3);
  }
}

// A small calibration: 12 rows, 4 plates at 2 m (the brightest clipped) x 3
// repeats. Three distinct unclipped widths fit many shapes exactly, among them
// short-tailed ones whose widths end below the clipped plate's; no clipped
// fit started from those reaches it (on the paper device the fit's own rows
// kept 8.1 mm of RMS error against 0.3 mm on the unclipped rows). The walk
// fit must fit its rows: RMS within 2 mm beyond their own noise, on four devices.
TEST(WalkModel, FitsASmallCalibrationWithAClippedPlate) {
  for (const device::DeviceConfig& config :
       {device::preset("paper"), other_parts(), slow_wide_parts(), fast_parts()}) {
    const device::VirtualRangefinder device(config);
    std::vector<experiments::PlannedMeasurement> plan;
    for (double rho : {0.05, 0.13, 0.34, 0.87}) {
      for (int repeat = 0; repeat < 3; ++repeat) plan.push_back(experiments::plate(2.0, rho, 20.0));
    }
    const auto rows = experiments::run(device, plan, 1);
    std::size_t clipped = 0;
    for (const auto& r : rows) clipped += (r.raw.flags & ranging::kRawSaturated) ? 1 : 0;
    // The rows' own noise: the spread of each plate's 3 repeats about their mean.
    std::vector<double> raw_errors;
    std::vector<std::size_t> plate_of;
    for (std::size_t i = 0; i < rows.size(); ++i) {
      raw_errors.push_back(rows[i].raw.distance_raw_m - rows[i].truth.distance_m);
      plate_of.push_back(i / 3);
    }
    const double noise_m = calib::split_noise_systematic(raw_errors, plate_of).noise_m;
    calib::ChainFitOptions options;
    options.steps = calib::parse_chain_steps("offset,walk");
    const calib::ChainFitResult fit = calib::fit_chain(rows, options);
    ASSERT_TRUE(fit.walk.has_value());
    std::printf("%zu clipped rows, noise %.3f mm: %s\n", clipped, noise_m * 1e3,
                fit.walk->summary().c_str());
    // Within 2 mm beyond the rows' own noise (the paper device's readings
    // wander by a few mm; the failure this guards against left 8.1 mm).
    EXPECT_LE(fit.walk->rms_m, std::hypot(2e-3, noise_m)) << fit.walk->summary();
  }
}

TEST(WalkModel, FitRecoversClippingFromFlaggedRows) {
  const ranging::WalkShape truth{0.6, 1.1, 4.0, 2.0};
  const ranging::WalkCurve curve = ranging::walk_curve(truth);
  std::mt19937_64 rng(6);
  std::normal_distribution<double> noise(0.0, 2e-4);
  std::vector<double> w, e;
  std::vector<std::uint8_t> status;
  for (double log_a = 1.5; log_a <= 6.0; log_a += 0.05) {
    w.push_back(interpolate(curve.log_overdrive, curve.width_ns, log_a));
    e.push_back(-0.2 - kMetresPerNs * interpolate(curve.log_overdrive, curve.rise_ns, log_a) +
                noise(rng));
    status.push_back(log_a > 4.0 ? calib::kWalkRowClipped : 0);
  }
  for (int k = 0; k < 5; ++k) {  // partial echoes, 50 mm off: left out
    w.push_back(1.0 + 0.1 * k);
    e.push_back(0.05);
    status.push_back(calib::kWalkRowPartial);
  }
  const calib::WalkFitResult fit = calib::fit_walk(w, e, status, {}, 5.0, kMetresPerNs);
  EXPECT_EQ(fit.partial_rows, 5u);
  EXPECT_GT(fit.saturated_rows, 30u);
  // Only the map width -> walk is observable, not the scale of ln a: the
  // shape and onset trade off a little (e.g. sigma 0.62, tau 1.23, onset 3.5),
  // the recovery (extra width per e-fold) much less.
  EXPECT_NEAR(fit.shape.recovery_ns_per_neper, truth.recovery_ns_per_neper, 0.5) << fit.summary();
  EXPECT_LE(fit.rms_m, 3e-4) << fit.summary();
  expect_walk_of(curve, fit, 9.0);
}

TEST(WalkModel, CurveIsMonotoneAndClippingWidens) {
  ranging::WalkShape shape{0.7, 1.0};
  const ranging::WalkCurve free = ranging::walk_curve(shape);
  for (std::size_t k = 1; k < free.width_ns.size(); ++k) {
    EXPECT_GT(free.width_ns[k], free.width_ns[k - 1]);
    EXPECT_LE(free.rise_ns[k], free.rise_ns[k - 1]);  // stronger: earlier
  }
  shape.saturation_log_overdrive = 4.0;
  shape.recovery_ns_per_neper = 2.0;
  const ranging::WalkCurve clipped = ranging::walk_curve(shape);
  // At ln a = 6 the clipped echo is 2 ns/neper x 2 nepers wider; its rise is unchanged.
  const double w_free = interpolate(free.log_overdrive, free.width_ns, 6.0);
  const double w_clip = interpolate(clipped.log_overdrive, clipped.width_ns, 6.0);
  EXPECT_NEAR(w_clip - w_free, 4.0, 0.01);
  EXPECT_NEAR(interpolate(clipped.log_overdrive, clipped.rise_ns, 6.0),
              interpolate(free.log_overdrive, free.rise_ns, 6.0), 1e-9);
}

// ---------------------------------------------------------------------------
// The command line: `tofkit fit --chain offset,walk,temperature` on a CSV, the
// model file read back, and a bad key refused.

class WalkCli : public test::CliFixture {
 protected:
  WalkCli() : CliFixture("tofkit_walk_cli_") {}
};

/// Records from a known shape (and a temperature line), echo strengths ln a in
/// [lo, hi]: plates at 3 m whose reflectance sets the echo (0.9 at ln a = 7).
std::vector<ranging::Record> shape_records(double log_lo, double log_hi, unsigned seed) {
  const ranging::WalkCurve curve = ranging::walk_curve({0.6, 1.1});
  const double k = ranging::metres_per_ns(ranging::TimeToDistance{});
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> noise(0.0, 2e-4);
  std::vector<ranging::Record> out;
  for (double log_a = log_lo; log_a <= log_hi + 1e-9; log_a += 0.1) {
    for (double t = 0; t <= 40; t += 10) {
      ranging::Record r;
      r.truth = {3.0, 0.9 * std::exp(log_a - 7.0), 0.0, t};
      r.raw.pulse_width_ns = interpolate(curve.log_overdrive, curve.width_ns, log_a);
      r.raw.temperature_c = t;
      r.raw.amplitude = 0.05 * std::exp(log_a);
      const double error = -0.2 - k * interpolate(curve.log_overdrive, curve.rise_ns, log_a) -
                           0.003 * (t - 20.0) + noise(rng);
      r.raw.distance_raw_m = 3.0 - error;
      r.raw.tof_ns = r.raw.distance_raw_m / k;
      r.raw.shots_valid = 100;
      out.push_back(r);
    }
  }
  return out;
}

TEST_F(WalkCli, FitWalkChainCorrectsBeyondItsDomainAndRoundTrips) {
  io::write_raw_csv(path("calib.csv"), shape_records(1.5, 3.5, 1));
  io::write_raw_csv(path("test.csv"), shape_records(0.3, 7.0, 2));
  const test::CliResult fit = run("fit --in " + path("calib.csv") + " --out " + path("model.json") +
                                  " --chain offset,walk,temperature --confidence none");
  ASSERT_EQ(fit.status, 0) << fit.err;
  const ranging::Pipeline model = io::load_pipeline(path("model.json"));
  ASSERT_EQ(model.steps().size(), 3u);
  EXPECT_EQ(model.steps()[1].kind, ranging::StepKind::kWalk);
  // The file round-trips: written again, it is the same text.
  const nlohmann::json again = io::pipeline_to_json(model);
  nlohmann::json file;
  std::ifstream(path("model.json")) >> file;
  file.erase("fit");
  EXPECT_EQ(again.dump(), file.dump());

  const test::CliResult correct = run("correct --model " + path("model.json") + " --in " +
                                      path("test.csv") + " --out " + path("corrected.csv"));
  ASSERT_EQ(correct.status, 0) << correct.err;
  const auto corrected = io::read_corrected_csv(path("corrected.csv"));
  const auto test_rows = shape_records(0.3, 7.0, 2);
  ASSERT_EQ(corrected.size(), test_rows.size());
  std::size_t flagged = 0;
  for (std::size_t i = 0; i < test_rows.size(); ++i) {
    const ranging::Range in_memory = model.apply(test_rows[i].raw);
    EXPECT_NEAR(corrected[i].range.distance_m, in_memory.distance_m, 1e-9);
    EXPECT_NEAR(corrected[i].range.distance_m, 3.0, 0.002)
        << "width " << test_rows[i].raw.pulse_width_ns;
    if (corrected[i].range.correction_flags & ranging::kCorrOutOfDomain) ++flagged;
  }
  EXPECT_GT(flagged, test_rows.size() / 2);

  // A misspelt key in the walk step is refused, naming it; nothing is written.
  file["steps"][1]["shape"]["pulse_sigma"] = 1.0;
  std::ofstream(path("bad.json")) << file.dump(2);
  const test::CliResult bad = run("correct --model " + path("bad.json") + " --in " +
                                  path("test.csv") + " --out " + path("bad.csv"));
  EXPECT_EQ(bad.status, 1);
  EXPECT_NE(bad.err.find("steps[1].shape.pulse_sigma"), std::string::npos) << bad.err;
  EXPECT_FALSE(std::filesystem::exists(path("bad.csv")));
}

}  // namespace
}  // namespace tofkit
