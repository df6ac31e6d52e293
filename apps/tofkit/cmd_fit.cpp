// tofkit fit: fit a ranging pipeline (the paper's chain, a correction surface,
// or the chain followed by a surface on its residual) and optionally a
// confidence model, from a raw CSV with ground truth; write the model file.

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

#include "app.hpp"
#include "tofkit/calib/model_fit.hpp"
#include "tofkit/calib/uncertainty_budget.hpp"
#include "tofkit/io/firmware_export.hpp"
#include "tofkit/io/model_json.hpp"
#include "tofkit/io/raw_csv.hpp"
#include "tofkit/ranging/fixed_point_chain.hpp"

namespace tofkit::app {
namespace {

struct FitOptions {
  std::vector<std::string> inputs;  // --in, repeated: their rows in order
  std::string in;                   // the inputs joined by ", " (messages, the model's source)
  std::string out;
  std::string chain;    // "offset,grayvalue,temperature" (any subset)
  std::string surface;  // "poly:N" or "bspline"
  double rcond = 1e-2;  // thesis: 1e-2
  bool surface_temperature = false;
  bool refine_walk = false;
  bool tdc_periodic = false;
  std::string intensity = "auto";  // bspline: auto (CV) | amplitude | pulse-width
  std::string confidence = "calibrated";
  bool confidence_given = false;
  double confidence_fraction = 0.25;
  bool confidence_fraction_given = false;
  int confidence_folds = 5;
  std::string firmware;  // stem: writes STEM.json and STEM.h
  bool firmware_given = false;
  bool rcond_given = false;
  std::string knots = "auto";      // bspline: "auto" (GCV) or RxA[xT] knot intervals
  std::string smoothing = "auto";  // bspline: "auto" (GCV) or a penalty weight
  // The uncertainty budget (calib/uncertainty_budget.hpp): on with --budget
  // or any of the protocol steps' inputs.
  bool budget = false;
  std::string stability;  // stability record (static target over time)
  double stability_every_s = 0;
  std::vector<std::string> power_on;  // repeats on other power-ons
  std::vector<std::string> spec;      // type B specifications, key=value
};

/// The time-to-distance conversion of the config, checked before any work; a
/// value the conversion cannot use is reported under the config key that set
/// it (not the conversion's internal field name).
ranging::TimeToDistance checked_time_to_distance(const AppContext& ctx) {
  const io::LoadedDeviceConfig loaded = ctx.load_config_traced();
  const ranging::TimeToDistance t = device::nominal_time_to_distance(loaded.config);
  try {
    t.validate();
  } catch (const std::invalid_argument& e) {
    const std::string what = e.what();
    static const std::pair<const char*, const char*> kKeys[] = {
        {"time_to_distance.wavelength_nm", "laser.wavelength_nm"},
        {"time_to_distance.air.temperature_c", "measurement.reference_temperature_c"},
        {"time_to_distance.air.pressure_hpa", "environment.pressure_hpa"},
        {"time_to_distance.air.relative_humidity_pct", "environment.relative_humidity_pct"}};
    for (const auto& [internal, key] : kKeys) {
      if (what.rfind(internal, 0) != 0) continue;
      const std::string origin = origin_of(loaded, key);
      throw io::ConfigError(fmt::format(
          "{}: {}{} for the time-to-distance conversion (air group index) that fit uses", origin,
          key, what.substr(std::string_view(internal).size())));
    }
    throw;
  }
  return t;
}

/// --knots auto|RxA[xT] and --smoothing auto|VALUE -> B-spline options.
calib::BSplineFitOptions bspline_options(const FitOptions& o) {
  calib::BSplineFitOptions b;
  b.use_temperature = o.surface_temperature;
  if (o.knots == "auto") {
    b.choose_intervals_by_gcv = true;
  } else {
    int counts[3] = {0, 0, 0};
    int parsed = 0;
    std::size_t begin = 0;
    bool ok = true;
    while (ok && begin <= o.knots.size() && parsed < 3) {
      const std::size_t x = std::min(o.knots.find('x', begin), o.knots.size());
      const std::string part = o.knots.substr(begin, x - begin);
      std::size_t used = 0;
      try {
        counts[parsed++] = std::stoi(part, &used);
      } catch (const std::exception&) {
        used = 0;
      }
      ok = used == part.size() && !part.empty();
      begin = x + 1;
    }
    const int expected = o.surface_temperature ? 3 : 2;
    if (!ok || parsed != expected || begin <= o.knots.size()) {
      throw std::invalid_argument("--knots " + o.knots + ": expected auto or " +
                                  (o.surface_temperature ? "RxAxT" : "RxA") +
                                  " (knot intervals per axis, e.g. 6x8)");
    }
    b.intervals_range = counts[0];
    b.intervals_amplitude = counts[1];
    b.intervals_temperature = o.surface_temperature ? counts[2] : b.intervals_temperature;
  }
  if (o.smoothing == "auto") {
    b.choose_smoothing_by_gcv = true;
  } else {
    std::size_t used = 0;
    double v = -1;
    try {
      v = std::stod(o.smoothing, &used);
    } catch (const std::exception&) {
      used = 0;
    }
    if (used != o.smoothing.size() || !std::isfinite(v) || v < 0) {
      throw std::invalid_argument("--smoothing " + o.smoothing +
                                  ": expected auto or a finite number >= 0");
    }
    if (v > calib::kMaxBSplineSmoothing) {
      throw std::invalid_argument("--smoothing " + o.smoothing +
                                  ": at most 1e6 (relative to the data term; beyond it the fit is "
                                  "the penalty's planes to rounding)");
    }
    b.smoothing = v;
    b.keep_smoothing = true;  // with --knots auto: the knots are chosen for this smoothing
  }
  b.validate();
  if (!b.choose_intervals_by_gcv) {
    // Bounded in time: the solve's cost grows with the cube of the coefficients.
    std::size_t coefficients = static_cast<std::size_t>(b.intervals_range + 3) *
                               static_cast<std::size_t>(b.intervals_amplitude + 3);
    if (b.use_temperature) coefficients *= static_cast<std::size_t>(b.intervals_temperature + 3);
    const std::size_t limit = calib::bspline_coefficient_limit(b.choose_smoothing_by_gcv);
    if (coefficients > limit) {
      throw std::invalid_argument(
          "--knots " + o.knots + ": " + std::to_string(coefficients) +
          " coefficients, more than the " + std::to_string(limit) + " a fit with " +
          (b.choose_smoothing_by_gcv ? "--smoothing auto" : "a given --smoothing") +
          " solves in bounded time; give fewer knot intervals");
    }
  }
  return b;
}

void run_fit(const FitOptions& o, const AppContext& ctx) {
  if (o.chain.empty() && o.surface.empty()) {
    throw std::invalid_argument("give --chain STEPS and/or --surface poly:N|bspline");
  }
  if (o.rcond_given && o.surface.rfind("poly:", 0) != 0) {
    throw std::invalid_argument("--rcond applies to --surface poly:N only");
  }
  if (o.refine_walk && o.chain.find("grayvalue") == std::string::npos) {
    throw std::invalid_argument(
        "--refine-walk refines the chain's grayvalue step: give --chain "
        "...,grayvalue");
  }
  if (o.refine_walk && !o.firmware.empty()) {
    throw std::invalid_argument(
        "--refine-walk makes a dense grayvalue table; --firmware exports the paper's chain only");
  }
  if (o.surface_temperature && o.surface.empty()) {
    throw std::invalid_argument(
        "--temperature adds a temperature axis to a --surface; the chain's temperature step is "
        "--chain ...,temperature");
  }
  if (!(o.confidence_fraction > 0 && o.confidence_fraction <= 0.5)) {
    throw std::invalid_argument("--confidence-fraction must be in (0, 0.5]");
  }
  if (!o.firmware.empty() && (o.chain.empty() || !o.surface.empty())) {
    throw std::invalid_argument(
        "--firmware exports the chain only: give --chain without --surface");
  }
  calib::ModelFitOptions options;
  try {
    if (!o.chain.empty()) options.chain = calib::parse_chain_steps(o.chain);
  } catch (const std::invalid_argument& e) {
    throw std::invalid_argument("--chain " + o.chain + ": " + e.what());
  }
  if (!o.surface.empty()) {
    try {
      options.surface = calib::parse_surface_spec(o.surface);
    } catch (const std::invalid_argument& e) {
      throw std::invalid_argument("--surface " + o.surface + ": " + e.what());
    }
  }
  options.surface_temperature = o.surface_temperature;
  options.refine_walk = o.refine_walk;
  if (o.tdc_periodic && !o.firmware.empty()) {
    throw std::invalid_argument(
        "--tdc-periodic adds a periodic step; --firmware exports the paper's chain only");
  }
  try {
    options.surface_intensity = calib::parse_surface_intensity(o.intensity);
  } catch (const std::invalid_argument& e) {
    throw std::invalid_argument("--intensity " + o.intensity + ": " + e.what());
  }
  if (o.intensity != "auto" && options.surface.kind != calib::SurfaceKind::bspline) {
    throw std::invalid_argument("--intensity applies to --surface bspline only");
  }
  options.polynomial.rcond = o.rcond;
  if (options.surface.kind == calib::SurfaceKind::bspline) options.bspline = bspline_options(o);
  options.confidence = calib::parse_confidence_kind(o.confidence);
  options.confidence_required = o.confidence_given;
  options.confidence_folds = o.confidence_folds;
  if (o.confidence_fraction_given) options.confidence_hold_out_fraction = o.confidence_fraction;
  const device::DeviceConfig config = ctx.load_config();
  if (o.tdc_periodic) options.tdc_period_ns = 1e3 / config.tdc.coarse_clock_mhz;
  options.time_to_distance = checked_time_to_distance(ctx);
  require_output_directory(o.out, "--out");
  if (o.firmware_given) {
    // A stem names files (STEM.json, STEM.h): not empty, not a directory ('/',
    // 'out/', '.'), which would have made the hidden files '/.json' and '/.h'.
    const std::filesystem::path stem(o.firmware);
    const std::string name = stem.filename().string();
    if (o.firmware.empty() || name.empty() || name == "." || name == "..") {
      throw std::runtime_error(fmt::format(
          "--firmware '{}': not a file stem (give one like out/chain for out/chain.json and "
          "out/chain.h)",
          o.firmware));
    }
    require_output_directory(o.firmware + ".json", "--firmware");
  }

  std::vector<ranging::Record> records;
  std::vector<double> time_s, part_time_s;  // the rows' time since power-on (time_s column)
  for (const std::string& path : o.inputs) {
    const std::vector<ranging::Record> part = io::read_raw_csv(path, &part_time_s);
    records.insert(records.end(), part.begin(), part.end());
    for (const double t : part_time_s)
      if (std::isfinite(t)) time_s.push_back(t);
  }
  // The budget's inputs, all checked before the fit's work.
  const bool budget = o.budget || !o.stability.empty() || !o.power_on.empty() || !o.spec.empty();
  calib::BudgetSpecification specification;
  calib::ProtocolSteps steps;
  std::vector<ranging::Record> stability;
  if (budget) {
    if (options.confidence == calib::ConfidenceKind::none ||
        options.confidence == calib::ConfidenceKind::noise_systematic ||
        o.confidence_fraction_given)
      throw std::invalid_argument(
          "--budget takes each row's cross-validated residual: --confidence calibrated or thesis "
          "without --confidence-fraction");
    // The extrapolation term is sized by refits without the weakest targets.
    options.extrapolation_refit = true;
    for (const std::string& assignment : o.spec) {
      try {
        specification.set(assignment);
      } catch (const std::invalid_argument& e) {
        throw std::invalid_argument("--spec " + assignment + ": " + e.what());
      }
    }
    if (!o.stability.empty()) {
      if (!(o.stability_every_s > 0))
        throw std::invalid_argument(
            "--stability needs --stability-every S (the seconds between its rows, as measured)");
      stability = io::read_raw_csv(o.stability);
    }
    for (const std::string& path : o.power_on)
      steps.power_on_runs.push_back(io::read_raw_csv(path));
    steps.stability = stability;
    steps.stability_every_s = o.stability_every_s;
    steps.tdc_period_ns = 1e3 / config.tdc.coarse_clock_mhz;
  } else if (o.stability_every_s > 0) {
    throw std::invalid_argument("--stability-every applies to --stability");
  }
  calib::ModelFitResult fit;
  calib::BudgetFitResult budget_fit;
  try {
    fit = calib::fit_model(records, options);
    if (budget) budget_fit = calib::fit_model_budget(records, fit, steps, specification);
    if (budget && !time_s.empty()) {
      // When the calibration was taken: its rows' median time since power-on.
      std::nth_element(time_s.begin(), time_s.begin() + time_s.size() / 2, time_s.end());
      budget_fit.budget.calibration_time_s = time_s[time_s.size() / 2];
    }
  } catch (const std::invalid_argument& e) {
    throw std::runtime_error(o.in + ": " + e.what());
  }
  const ranging::Pipeline& pipeline = fit.pipeline;
  const std::string& report = fit.report;
  const nlohmann::json fit_info = io::fit_summary_json(fit.summary, o.in);

  // Quantize before writing anything, so a coefficient that does not fit leaves no files.
  std::optional<ranging::FixedPointChain> firmware;
  if (!o.firmware.empty()) {
    ranging::FixedPointFormat format;
    format.tdc_lsb_ps = config.tdc.lsb_ps;
    format.pulse_width_lsb_ps = config.tdc.lsb_ps;
    format.temperature_lsb_c = config.thermal.sensor_resolution_c;
    firmware = ranging::FixedPointChain::from_pipeline(pipeline, format);
  }
  io::save_pipeline(o.out, pipeline, fit_info, budget ? &budget_fit.budget : nullptr);
  std::string firmware_note;
  if (firmware) {
    io::save_fixed_point_json(o.firmware + ".json", *firmware);
    io::save_fixed_point_header(o.firmware + ".h", *firmware);
    firmware_note = fmt::format(" (+ {0}.json, {0}.h)", o.firmware);
  }
  fmt::print("{}{}{}", report, pipeline.summary(), budget_fit.report);
  if (fit.summary.chain && !fit.summary.chain->converged) {
    fmt::print(stderr,
               "tofkit fit: warning: the chain's backfitting did not converge after {} "
               "iteration(s): its steps are the last iteration's, not a least-squares optimum; "
               "the model is written (exit status 0): check its residuals (tofkit evaluate) "
               "before use\n",
               fit.summary.chain->backfit_iterations);
  }
  fmt::print(stderr, "tofkit fit: {} rows from {} -> {}{}\n", records.size(), o.in, o.out,
             firmware_note);
}

const bool registered = register_command("fit", [](CLI::App& sub, AppContext& ctx) {
  sub.description(
      "fit a ranging pipeline (chain and/or correction surface, optional confidence) from a raw "
      "CSV with truth");
  auto o = std::make_shared<FitOptions>();
  sub.add_option("--in", o->inputs,
                 "raw CSV with ground truth (calibration data); repeat --in to fit several files' "
                 "rows together")
      ->required()
      ->expected(1)
      ->multi_option_policy(CLI::MultiOptionPolicy::TakeAll);
  sub.add_option("--out", o->out, "model file to write (JSON)")->required();
  sub.add_option("--chain", o->chain,
                 "chain steps to fit: any of offset,grayvalue,temperature (paper Section 5); "
                 "walk instead of grayvalue: a physical walk model (pulse shape through the "
                 "threshold) that extrapolates beyond the calibration's pulse widths");
  sub.add_option("--surface", o->surface,
                 "correction surface: poly:N (thesis Section 4.6) or bspline; after --chain it "
                 "fits the chain's residual");
  CLI::Option* rcond =
      sub.add_option(
             "--rcond", o->rcond,
             "poly: relative cutoff on the scaled design's singular values (the thesis's 1e-2 on "
             "A^T A's spectrum is 0.1 here)")
          ->check(InRange(0.0, 1.0))
          ->capture_default_str();
  sub.add_flag("--temperature", o->surface_temperature, "surface: add a temperature axis");
  sub.add_option("--intensity", o->intensity,
                 "bspline: intensity axis, amplitude (log scale), pulse-width, or auto (the one "
                 "with the lower grouped cross-validated RMS)")
      ->capture_default_str();
  sub.add_flag("--refine-walk", o->refine_walk,
               "chain: refine the grayvalue step by a dense penalized piecewise-linear correction "
               "in pulse width (nodes at quantiles; count and smoothing by grouped 5-fold CV)");
  sub.add_flag("--tdc-periodic", o->tdc_periodic,
               "fit a periodic step modulo the TDC's coarse clock period (1e3 / "
               "tdc.coarse_clock_mhz of the config), at both stops (tof and tof + pulse width): "
               "the interpolator's residual nonlinearity with a clock-synchronous laser; "
               "harmonics by grouped CV");
  sub.add_option("--knots", o->knots,
                 "bspline: knot intervals per axis, RxA[xT], or auto (chosen by generalized "
                 "cross-validation)")
      ->capture_default_str();
  sub.add_option("--smoothing", o->smoothing,
                 "bspline: penalty weight, or auto (chosen by generalized cross-validation)")
      ->capture_default_str();
  CLI::Option* confidence =
      sub.add_option(
             "--confidence", o->confidence,
             "confidence model: calibrated (default: sigma over amplitude and range, fitted "
             "on out-of-fold residuals), noise-systematic (noise from the repeats' scatter plus "
             "the targets' systematic error, each times (1 + h) / (1 - h) for its leverage h "
             "(one refit per target), on the correction's intensity axis), thesis (Section "
             "4.8) or none")
          ->check(CLI::IsMember({"none", "thesis", "calibrated", "noise-systematic"}))
          ->capture_default_str();
  CLI::Option* fraction =
      sub.add_option("--confidence-fraction", o->confidence_fraction,
                     "instead of cross-fitting, hold out every round(1/F)-th truth group for the "
                     "confidence fit (the correction is fitted on the rest)");
  sub.add_option("--confidence-folds", o->confidence_folds,
                 "cross-fitting folds of whole truth groups for the confidence fit (fewer groups: "
                 "one per group)")
      ->check(InRange(2, 50))
      ->capture_default_str();
  CLI::Option* firmware =
      sub.add_option("--firmware", o->firmware,
                     "also export the chain in fixed point: STEM.json and STEM.h (C header)");
  sub.add_flag("--budget", o->budget,
               "fit an uncertainty budget (GUM: type A terms from the protocol's steps, type B "
               "from --spec where a step is missing) into the model: sigma_m is then its "
               "combined standard uncertainty (tofkit correct --since-calibration)");
  sub.add_option("--stability", o->stability,
                 "budget: stability record, a static target's rows in time order (tofkit "
                 "measure --every): drift since calibration from its structure function");
  sub.add_option("--stability-every", o->stability_every_s,
                 "budget: seconds between the stability record's rows")
      ->check(kNotNan);
  sub.add_option("--power-on", o->power_on,
                 "budget: repeats of calibration targets on another power-on (another --seed); "
                 "repeat the option per power-on")
      ->expected(1)
      ->multi_option_policy(CLI::MultiOptionPolicy::TakeAll);
  sub.add_option(
         "--spec", o->spec,
         "budget: a specification for a cause the protocol did not observe, key=value: "
         "tdc_inl_ps, delay_tempco_ps_per_c, walk_tempco_ps_per_c, temperature_half_range_c, "
         "drift_ps, "
         "power_on_ps (repeatable; a default is used, with a warning, otherwise)")
      ->expected(1)
      ->multi_option_policy(CLI::MultiOptionPolicy::TakeAll);
  sub.callback([o, rcond, confidence, fraction, firmware, &ctx] {
    o->firmware_given = firmware->count() > 0;
    o->in.clear();
    for (const std::string& path : o->inputs) o->in += (o->in.empty() ? "" : ", ") + path;
    o->rcond_given = rcond->count() > 0;
    o->confidence_given = confidence->count() > 0;
    o->confidence_fraction_given = fraction->count() > 0;
    run_fit(*o, ctx);
  });
});

}  // namespace
}  // namespace tofkit::app
