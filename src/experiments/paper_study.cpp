#include "tofkit/experiments/paper_study.hpp"

#include <algorithm>
#include <cmath>
#include <sstream>

#include "tofkit/device/virtual_rangefinder.hpp"
#include "tofkit/experiments/measurement_grid.hpp"
#include "tofkit/ranging/pipeline.hpp"

namespace tofkit::experiments {
namespace {

using ranging::Record;

/// Seeds of the separate runs: calibration and every test set are independent.
enum RunSeed : std::uint64_t {
  kCalibrationRun = 1,
  kGrayvalueTestRun,
  kTemperatureTestRun,
  kMaxRangeRun,
  kVerificationRun,
  kHoldoutRun,
};

/// `p` taken `seconds` into its protocol (the device's slow wander follows it).
PlannedMeasurement at_time(PlannedMeasurement p, double seconds) {
  p.request.conditions.session_time_s = seconds;
  return p;
}

std::vector<ranging::RawMeasurement> raw_of(const std::vector<Record>& records) {
  std::vector<ranging::RawMeasurement> raw;
  raw.reserve(records.size());
  for (const auto& r : records) raw.push_back(r.raw);
  return raw;
}

std::vector<ranging::Range> correct(const ranging::Pipeline& pipeline,
                                    const std::vector<Record>& records) {
  const auto raw = raw_of(records);
  std::vector<ranging::Range> out(raw.size());
  pipeline.apply(raw, out);
  return out;
}

/// A measurement counts when at least `share` of its shots gave an echo.
bool reliable(const Record& r, int shots, double share) {
  return r.raw.has_echo() && r.raw.shots_valid >= share * shots;
}

/// `group[i]` names the condition record i repeats (equal ids: one condition).
AccuracyFigures accuracy_of(const std::vector<Record>& records, std::span<const double> corrected_m,
                            std::span<const std::size_t> group, const ranging::Pipeline& pipeline,
                            double distance_m) {
  AccuracyFigures f;
  f.distance_m = distance_m;
  std::vector<double> errors, all_errors(records.size(), ranging::kNaN);
  double raw_min = 1e300, raw_max = -1e300;
  for (std::size_t i = 0; i < records.size(); ++i) {
    if (!std::isfinite(corrected_m[i])) continue;
    all_errors[i] = corrected_m[i] - records[i].truth.distance_m;
    // The paper's figures come from one pass over the conditions: the first repeat.
    if (i > 0 && group[i] == group[i - 1]) continue;
    errors.push_back(all_errors[i]);
    const double raw = pipeline.start_distance_m(records[i].raw);
    raw_min = std::min(raw_min, raw);
    raw_max = std::max(raw_max, raw);
  }
  f.rows = errors.size();
  f.split = calib::split_noise_systematic(all_errors, group);
  if (errors.empty()) return f;
  double mean = 0, worst = 0;
  for (double e : errors) {
    mean += e;
    worst = std::max(worst, std::abs(e));
  }
  mean /= static_cast<double>(errors.size());
  double var = 0;
  for (double e : errors) var += (e - mean) * (e - mean);
  f.std_mm = 1e3 * std::sqrt(var / static_cast<double>(errors.size()));
  f.accuracy_mm = 1e3 * worst;
  f.mean_error_mm = 1e3 * mean;
  f.raw_spread_mm = 1e3 * (raw_max - raw_min);
  return f;
}

std::vector<double> distances_of(const std::vector<ranging::Range>& ranges) {
  std::vector<double> d;
  d.reserve(ranges.size());
  for (const auto& r : ranges) d.push_back(r.distance_m);
  return d;
}

}  // namespace

PaperStudyResult run_paper_study(const device::DeviceConfig& config,
                                 const PaperStudyOptions& options,
                                 std::span<const PaperTable2Row> paper_table2) {
  auto progress = [&](std::string_view stage, double done) {
    if (options.progress) options.progress(stage, done);
  };
  PaperStudyResult result;
  const int shots = config.measurement.shots;
  const int repeats = std::max(1, options.repeats);
  const int test_repeats = std::max(1, options.test_repeats);

  // Figure 3: the link budget with Table 1 (sunlit target).
  progress("link budget", 0.0);
  // Fig. 3's budget: Table 1's sunlight (748.5 W/m^2/um at 905 nm), background
  // by Eq. 9 as printed; the measurements below are indoors (Section 5).
  auto fig3_link = config.link;
  fig3_link.environment.solar_irradiance_w_per_m2_um = physics::kTable1SolarIrradiance_w_per_m2_um;
  fig3_link.environment.eq9_as_printed = true;
  for (double r = 0.5; r <= 15.0 + 1e-9; r += 0.5)
    result.link_budget.push_back(physics::link_budget_at(fig3_link, r, 0.1));
  result.range_at_snr10_m = physics::range_at_snr(fig3_link, 10.0, 0.1);

  const device::VirtualRangefinder device(indoors(config), device::SimulationMode::kAnalytic);
  auto run_seed = [&](RunSeed run) { return options.seed * 1000003ULL + run; };

  // Calibration: plates at 2.355 m (and more distances), then the temperature sweep.
  progress("calibration", 0.05);
  const auto reflectances =
      log_spaced(options.reflectance_min, options.reflectance_max, options.grayvalue_groups);
  std::vector<PlannedMeasurement> plan;
  // Test sets: each condition measured test_repeats times; group[i] names the
  // condition of plan[i] so that errors split into noise and systematic.
  std::vector<std::size_t> group;
  auto start_test_plan = [&] {
    plan.clear();
    group.clear();
  };
  // Each condition `step_s` after the previous one, its repeats a plate swap
  // (condition_change_s) apart within it: the mean of the repeats averages the
  // device's slow wander as the paper's readings did, and their spread
  // (the split's noise) holds it.
  auto repeat = [&](const PlannedMeasurement& p, double step_s) {
    const std::size_t id = group.empty() ? 0 : group.back() + 1;
    const double repeat_s = options.condition_change_s;
    const double condition_s = std::max(step_s, test_repeats * repeat_s);
    for (int k = 0; k < test_repeats; ++k) {
      plan.push_back(at_time(p, static_cast<double>(id) * condition_s + k * repeat_s));
      group.push_back(id);
    }
  };
  const double swap_s = options.condition_change_s;
  std::vector<double> calibration_distances{options.grayvalue_distance_m};
  calibration_distances.insert(calibration_distances.end(),
                               options.extra_calibration_distances_m.begin(),
                               options.extra_calibration_distances_m.end());
  double clock_s = 0;  // the calibration's conditions, one after another
  for (double d : calibration_distances)
    for (double rho : reflectances) {
      for (int k = 0; k < repeats; ++k)
        plan.push_back(at_time(plate(d, rho, options.calibration_ambient_c), clock_s));
      clock_s += swap_s;
    }
  const auto ambients =
      lin_spaced(options.ambient_min_c, options.ambient_max_c, options.temperature_groups);
  for (double t : ambients) {
    clock_s += options.temperature_step_s;
    for (int k = 0; k < repeats; ++k)
      plan.push_back(at_time(
          plate(options.temperature_distance_m, options.temperature_reflectance, t), clock_s));
  }
  result.calibration = run(device, plan, run_seed(kCalibrationRun));
  // Keep only measurements a calibration would accept (90 % of shots echoed).
  std::vector<Record> usable;
  for (const auto& r : result.calibration)
    if (reliable(r, shots, options.max_range_min_valid_share)) usable.push_back(r);

  progress("fitting the chain", 0.25);
  calib::ChainFitOptions fit_options;
  fit_options.grayvalue.max_knots = options.grayvalue_max_knots;
  fit_options.temperature.max_knots = options.temperature_max_knots;
  // Most calibration rows share one temperature (the plates); only the sweep
  // spreads it, so a temperature segment needs a few sweep groups, not a share.
  fit_options.temperature.min_segment_fraction = 0.0;
  fit_options.temperature.min_segment_rows = static_cast<std::size_t>(3 * repeats);
  // A robust scale taken from the MAD would come from the plates' single
  // temperature and call the whole sweep an outlier: plain least squares here.
  fit_options.temperature.robust.loss = calib::RobustLoss::kNone;
  // A step the usable rows cannot carry (e.g. with a threshold that leaves
  // only near plates, every reliable row at one ambient) is refused by the fit:
  // the chain is fitted without it, and the step is reported as not fitted.
  for (;;) {
    try {
      result.fit = calib::fit_chain(usable, fit_options);
      break;
    } catch (const calib::ChainStepRefused& e) {
      result.steps_not_fitted.push_back(calib::to_string(e.step()) + ": " + e.what());
      calib::ChainSteps& steps = fit_options.steps;
      steps.grayvalue = steps.grayvalue && !e.step().grayvalue;
      steps.walk = steps.walk && !e.step().walk;
      steps.temperature = steps.temperature && !e.step().temperature;
    }
  }
  const auto& pipeline = result.fit.pipeline;
  result.calibration_corrected = correct(pipeline, result.calibration);

  // Fixed point: averaged TDC codes keep 6 fractional bits (>= 64 shots per output).
  ranging::FixedPointFormat format;
  format.tdc_lsb_ps = config.tdc.lsb_ps / 64.0;
  format.pulse_width_lsb_ps = config.tdc.lsb_ps / 64.0;
  format.temperature_lsb_c = config.thermal.sensor_resolution_c;
  const auto fixed = ranging::FixedPointChain::from_pipeline(pipeline, format);
  result.fixed_point = fixed.coefficients();
  auto fixed_distances = [&](const std::vector<Record>& records) {
    std::vector<double> out;
    for (const auto& r : records) {
      const auto o = fixed.apply(fixed.to_codes(r.raw));
      out.push_back(o.distance_um == ranging::kFixedNoDistance ? ranging::kNaN
                                                               : 1e-6 * o.distance_um);
    }
    return out;
  };
  auto track_fixed_vs_float = [&](const std::vector<Record>& records,
                                  const std::vector<ranging::Range>& ranges) {
    const auto f = fixed_distances(records);
    for (std::size_t i = 0; i < f.size(); ++i)
      if (std::isfinite(f[i]) && std::isfinite(ranges[i].distance_m))
        result.fixed_vs_float_max_diff_mm = std::max(result.fixed_vs_float_max_diff_mm,
                                                     1e3 * std::abs(f[i] - ranges[i].distance_m));
  };
  track_fixed_vs_float(result.calibration, result.calibration_corrected);

  // Gray-value test at 2.355 m through the fixed-point chain (paper Figure 7).
  progress("gray-value test", 0.35);
  start_test_plan();
  for (double rho : reflectances)
    repeat(plate(options.grayvalue_distance_m, rho, options.calibration_ambient_c), swap_s);
  result.grayvalue_test = run(device, plan, run_seed(kGrayvalueTestRun));
  result.grayvalue_corrected = correct(pipeline, result.grayvalue_test);
  track_fixed_vs_float(result.grayvalue_test, result.grayvalue_corrected);
  result.grayvalue_fixed_point_m = fixed_distances(result.grayvalue_test);
  result.grayvalue = accuracy_of(result.grayvalue_test, result.grayvalue_fixed_point_m, group,
                                 pipeline, options.grayvalue_distance_m);

  // Temperature test at 2.402 m (paper Figure 9).
  progress("temperature test", 0.45);
  start_test_plan();
  for (double t : ambients)
    repeat(plate(options.temperature_distance_m, options.temperature_reflectance, t),
           options.temperature_step_s);
  result.temperature_test = run(device, plan, run_seed(kTemperatureTestRun));
  result.temperature_corrected = correct(pipeline, result.temperature_test);
  track_fixed_vs_float(result.temperature_test, result.temperature_corrected);
  const auto temperature_m = distances_of(result.temperature_corrected);
  result.temperature = accuracy_of(result.temperature_test, temperature_m, group, pipeline,
                                   options.temperature_distance_m);

  // Longest achievable distance on the black foam plate (paper Figure 10).
  progress("longest distance", 0.55);
  plan.clear();
  for (double d = 5.0; d <= 12.0 + 1e-9; d += options.max_range_step_m)
    plan.push_back(at_time(plate(d, options.max_range_reflectance, options.calibration_ambient_c),
                           static_cast<double>(plan.size()) * swap_s));
  result.max_range_scan = run(device, plan, run_seed(kMaxRangeRun));
  for (const auto& r : result.max_range_scan) {
    if (!reliable(r, shots, options.max_range_min_valid_share)) break;
    result.max_range_m = r.truth.distance_m;
  }

  // Verification from 1 to 8 m (Table 2).
  progress("verification", 0.65);
  start_test_plan();
  for (double d : options.verification_distances_m)
    repeat(plate(d, options.verification_reflectance, options.calibration_ambient_c), swap_s);
  result.verification = run(device, plan, run_seed(kVerificationRun));
  result.verification_corrected = correct(pipeline, result.verification);
  track_fixed_vs_float(result.verification, result.verification_corrected);
  std::vector<double> errors;
  for (std::size_t i = 0; i < result.verification.size(); ++i)
    errors.push_back(result.verification_corrected[i].distance_m -
                     result.verification[i].truth.distance_m);
  result.verification_split = calib::split_noise_systematic(errors, group);
  for (std::size_t g = 0; g < options.verification_distances_m.size(); ++g) {
    // repeat() puts a condition's measurements next to each other.
    const auto begin = g * static_cast<std::size_t>(test_repeats);
    const auto n = static_cast<std::size_t>(test_repeats);
    const auto split = calib::split_noise_systematic(std::span(errors).subspan(begin, n),
                                                     std::span(group).subspan(begin, n));
    const double d = options.verification_distances_m[g];
    VerificationRow row;
    row.actual_m = d;
    row.repeats = static_cast<int>(split.rows);
    row.measured_m = split.rows > 0 ? d + split.systematic_mean_m : ranging::kNaN;
    row.noise_mm = 1e3 * split.noise_m;
    row.deviation_mm = 1e3 * (d - row.measured_m);  // Table 2's sign: actual - measured
    for (const auto& p : paper_table2) {
      if (std::abs(p.actual_value_m - d) < 0.05) {
        row.paper_measured_m = p.ranging_value_m;
        row.paper_deviation_mm = 1e3 * p.deviation_m;
      }
    }
    result.verification_rows.push_back(row);
  }

  // Held-out grid: distances x reflectances x ambient temperatures, never fitted.
  progress("held-out grid", 0.75);
  start_test_plan();
  for (double d : options.holdout_distances_m)
    for (double rho : options.holdout_reflectances)
      for (double t : options.holdout_ambient_c) repeat(plate(d, rho, t), swap_s);
  result.holdout = run(device, plan, run_seed(kHoldoutRun));
  result.holdout_corrected = correct(pipeline, result.holdout);
  track_fixed_vs_float(result.holdout, result.holdout_corrected);
  std::vector<double> corrected_errors, raw_errors;
  std::vector<double> split_errors(result.holdout.size(), ranging::kNaN);
  for (std::size_t i = 0; i < result.holdout.size(); ++i) {
    const auto& r = result.holdout[i];
    if (!reliable(r, shots, options.max_range_min_valid_share)) {
      ++result.holdout_rows_without_echo;
      continue;
    }
    corrected_errors.push_back(r.truth.distance_m - result.holdout_corrected[i].distance_m);
    raw_errors.push_back(r.truth.distance_m - pipeline.start_distance_m(r.raw));
    split_errors[i] = result.holdout_corrected[i].distance_m - r.truth.distance_m;
  }
  result.holdout_stats = calib::error_stats(corrected_errors);
  result.holdout_raw_stats = calib::error_stats(raw_errors);
  result.holdout_split = calib::split_noise_systematic(split_errors, group);
  progress("done", 1.0);
  return result;
}

std::string PaperStudyResult::summary() const {
  std::ostringstream s;
  s.setf(std::ios::fixed);
  s.precision(2);
  s << "range at SNR 10: " << range_at_snr10_m << " m; longest distance: " << max_range_m << " m\n";
  s << "gray-value at " << grayvalue.distance_m << " m: std " << grayvalue.std_mm
    << " mm, accuracy +-" << grayvalue.accuracy_mm << " mm (raw spread " << grayvalue.raw_spread_mm
    << " mm)\n";
  s << "temperature at " << temperature.distance_m << " m: std " << temperature.std_mm
    << " mm, accuracy +-" << temperature.accuracy_mm << " mm\n";
  s << "held out (" << holdout_stats.rows << " rows): max |error| " << 1e3 * holdout_stats.max_abs_m
    << " mm, RMS " << 1e3 * holdout_stats.rms_m << " mm (uncorrected RMS "
    << 1e3 * holdout_raw_stats.rms_m << " mm)\n";
  s << "fixed point vs float: max " << fixed_vs_float_max_diff_mm << " mm\n";
  for (const std::string& step : steps_not_fitted) s << "chain step not fitted: " << step << "\n";
  return s.str();
}

}  // namespace tofkit::experiments
