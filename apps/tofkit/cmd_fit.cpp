// tofkit fit: fit a ranging pipeline (the paper's chain, a correction surface,
// or the chain followed by a surface on its residual) and optionally a
// confidence model, from a raw CSV with ground truth; write the model file.

#include <fmt/format.h>

#include <cmath>
#include <cstdio>
#include <map>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <stdexcept>
#include <string>
#include <tuple>
#include <vector>

#include "app.hpp"
#include "tofkit/calib/chain_fit.hpp"
#include "tofkit/calib/confidence_model.hpp"
#include "tofkit/calib/statistics.hpp"
#include "tofkit/calib/surface_fit.hpp"
#include "tofkit/io/firmware_export.hpp"
#include "tofkit/io/model_json.hpp"
#include "tofkit/io/raw_csv.hpp"
#include "tofkit/ranging/fixed_point_chain.hpp"

namespace tofkit::app {
namespace {

struct FitOptions {
  std::string in;
  std::string out;
  std::string chain;    // "offset,grayvalue,temperature" (any subset)
  std::string surface;  // "poly:N" or "bspline"
  double rcond = 1e-2;  // thesis: 1e-2
  bool surface_temperature = false;
  std::string confidence = "calibrated";
  bool confidence_given = false;
  double confidence_fraction = 0.25;
  bool confidence_fraction_given = false;
  int confidence_folds = 5;
  std::string firmware;  // stem: writes STEM.json and STEM.h
  bool rcond_given = false;
  std::string knots = "auto";      // bspline: "auto" (GCV) or RxA[xT] knot intervals
  std::string smoothing = "auto";  // bspline: "auto" (GCV) or a penalty weight
};

/// The conversion the device uses for distance_raw_m (nominal c in air).
ranging::TimeToDistance time_to_distance_of(const device::DeviceConfig& config) {
  ranging::TimeToDistance t;
  t.wavelength_nm = config.link.laser.wavelength_nm;
  t.air.temperature_c = config.measurement.reference_temperature_c;
  t.air.pressure_hpa = config.link.environment.pressure_hpa;
  t.air.relative_humidity_pct = config.link.environment.relative_humidity_pct;
  return t;
}

/// Group of every record: identical truth (distance_true_m, reflectance,
/// angle_deg, ambient_c), numbered in order of first appearance.
std::vector<std::size_t> truth_groups(const std::vector<ranging::Record>& records,
                                      std::size_t& groups) {
  const auto key_of = [](const ranging::GroundTruth& t) {
    const auto v = [](double x) { return std::isnan(x) ? -1e300 : x; };
    return std::make_tuple(v(t.distance_m), v(t.reflectance), v(t.angle_deg), v(t.ambient_c));
  };
  std::map<std::tuple<double, double, double, double>, std::size_t> group_of;
  std::vector<std::size_t> group;
  group.reserve(records.size());
  for (const ranging::Record& r : records) {
    group.push_back(group_of.emplace(key_of(r.truth), group_of.size()).first->second);
  }
  groups = group_of.size();
  return group;
}

/// The time-to-distance conversion of the config, checked before any work; a
/// value the conversion cannot use is reported under the config key that set
/// it (not the conversion's internal field name).
ranging::TimeToDistance checked_time_to_distance(const AppContext& ctx) {
  const io::LoadedDeviceConfig loaded = ctx.load_config_traced();
  const ranging::TimeToDistance t = time_to_distance_of(loaded.config);
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

/// Deterministic hold-out for the confidence fit: rows are grouped by identical
/// truth (distance_true_m, reflectance, angle_deg, ambient_c) in order of first
/// appearance; with k = round(1 / fraction), every k-th group (the k-th, 2k-th,
/// ...) goes to the confidence part, the rest to the correction fit. Whole
/// groups are held out, so the confidence is fitted on targets the correction
/// never saw.
void split_for_confidence(const std::vector<ranging::Record>& records, double fraction,
                          std::vector<ranging::Record>& fit_part,
                          std::vector<ranging::Record>& confidence_part, std::size_t& groups) {
  const auto k = static_cast<std::size_t>(std::lround(1.0 / fraction));
  // NaN keys compare unequal to themselves; map them to a sentinel so they group.
  const auto key_of = [](const ranging::GroundTruth& t) {
    const auto v = [](double x) { return std::isnan(x) ? -1e300 : x; };
    return std::make_tuple(v(t.distance_m), v(t.reflectance), v(t.angle_deg), v(t.ambient_c));
  };
  std::map<std::tuple<double, double, double, double>, std::size_t> group_of;
  for (const ranging::Record& r : records) {
    const auto [it, inserted] = group_of.emplace(key_of(r.truth), group_of.size());
    ((it->second % k) == k - 1 ? confidence_part : fit_part).push_back(r);
  }
  groups = group_of.size();
}

nlohmann::json stats_json(const calib::ErrorStats& s) {
  const auto v = [](double x) { return std::isfinite(x) ? nlohmann::json(x) : nlohmann::json(); };
  return {{"rows", s.rows},
          {"bias_m", v(s.bias_m)},
          {"rms_m", v(s.rms_m)},
          {"max_abs_m", v(s.max_abs_m)}};
}

nlohmann::json hinge_json(const calib::HingeFitResult& h) {
  nlohmann::json bic = nlohmann::json::array();
  for (double b : h.bic) bic.push_back(std::isfinite(b) ? nlohmann::json(b) : nlohmann::json());
  return {{"knots", h.knots},
          {"bic_by_knot_count", bic},
          {"rows_downweighted", h.rows_downweighted},
          {"robust_sigma_m", h.robust_scale}};
}

struct SurfaceSpec {
  bool poly = false;
  int order = 0;
};

SurfaceSpec parse_surface(const std::string& spec) {
  if (spec == "bspline") return {false, 0};
  if (spec.rfind("poly:", 0) == 0) {
    const std::string n = spec.substr(5);
    std::size_t used = 0;
    int order = -1;
    try {
      order = std::stoi(n, &used);
    } catch (const std::exception&) {
      used = 0;
    }
    if (used == n.size() && order >= 1 && order <= 12) return {true, order};
  }
  throw std::invalid_argument("--surface " + spec + ": expected poly:N (N = 1..12) or bspline");
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
    b.smoothing = v;
  }
  b.validate();
  return b;
}

/// A surface over range needs calibration plates at two or more true distances.
void require_two_distances(const std::vector<ranging::Record>& records) {
  double first = ranging::kNaN;
  for (const auto& r : records) {
    if (!std::isfinite(r.truth.distance_m)) continue;
    if (std::isnan(first)) first = r.truth.distance_m;
    if (r.truth.distance_m != first) return;
  }
  throw std::invalid_argument(fmt::format(
      "--surface bspline: range axis undetermined: every row has distance_true_m = {} m (one "
      "distinct distance); measure plates at two or more distances, or fit --chain only",
      first));
}

/// Rows a surface can be fitted on: corrected distance, truth, amplitude (and temperature).
struct SurfaceRows {
  std::vector<double> range, amplitude, temperature, error;
  std::vector<std::uint32_t> group;  ///< truth group (for cross-validation over whole targets)
};

SurfaceRows surface_rows(const ranging::Pipeline& pipeline,
                         const std::vector<ranging::Record>& records, bool use_temperature) {
  std::vector<ranging::RawMeasurement> raw;
  for (const auto& r : records) raw.push_back(r.raw);
  std::vector<ranging::Range> before(raw.size());
  pipeline.apply(raw, before);
  SurfaceRows rows;
  std::size_t groups = 0;
  const std::vector<std::size_t> group = truth_groups(records, groups);
  for (std::size_t i = 0; i < records.size(); ++i) {
    const double d = before[i].distance_m;
    const double truth = records[i].truth.distance_m;
    const double a = records[i].raw.amplitude;
    const double t = records[i].raw.temperature_c;
    if (!std::isfinite(d) || !std::isfinite(truth) || !std::isfinite(a) ||
        (use_temperature && !std::isfinite(t))) {
      continue;
    }
    rows.range.push_back(d);
    rows.amplitude.push_back(a);
    rows.temperature.push_back(t);
    rows.error.push_back(truth - d);  // C = true - measured (thesis Section 4.6)
    rows.group.push_back(static_cast<std::uint32_t>(group[i]));
  }
  return rows;
}

void run_fit(const FitOptions& o, const AppContext& ctx) {
  if (o.chain.empty() && o.surface.empty()) {
    throw std::invalid_argument("give --chain STEPS and/or --surface poly:N|bspline");
  }
  if (o.rcond_given && o.surface.rfind("poly:", 0) != 0) {
    throw std::invalid_argument("--rcond applies to --surface poly:N only");
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
  calib::ChainSteps steps;
  try {
    if (!o.chain.empty()) steps = calib::parse_chain_steps(o.chain);
  } catch (const std::invalid_argument& e) {
    throw std::invalid_argument("--chain " + o.chain + ": " + e.what());
  }
  const SurfaceSpec surface_spec = o.surface.empty() ? SurfaceSpec{} : parse_surface(o.surface);
  const device::DeviceConfig config = ctx.load_config();
  const ranging::TimeToDistance conversion = checked_time_to_distance(ctx);
  require_output_directory(o.out, "--out");
  if (!o.firmware.empty()) require_output_directory(o.firmware + ".json", "--firmware");

  const std::vector<ranging::Record> records = io::read_raw_csv(o.in);
  std::vector<ranging::Record> fit_rows, confidence_rows;
  std::size_t groups = 0;
  // --confidence-fraction: the thesis's hold-out split; otherwise cross-fitting.
  const bool hold_out = o.confidence != "none" && o.confidence_fraction_given;
  if (!hold_out) {
    fit_rows = records;
  } else {
    split_for_confidence(records, o.confidence_fraction, fit_rows, confidence_rows, groups);
    if (confidence_rows.empty() || fit_rows.empty()) {
      throw std::invalid_argument(fmt::format(
          "{}: --confidence {} holds out every {}-th group of identical truth, but the file has "
          "{} group(s): it needs at least {} groups (distances / plates / temperatures)",
          o.in, o.confidence, std::lround(1.0 / o.confidence_fraction), groups,
          std::lround(1.0 / o.confidence_fraction)));
    }
  }

  nlohmann::json fit_info = {
      {"command", "fit"}, {"input", o.in}, {"rows", records.size()}, {"rows_fit", fit_rows.size()}};
  std::string report;

  // The correction (chain, then surface on its residual) fitted on `rows`;
  // the report and fit_info only for the model that is written.
  const auto fit_correction = [&](const std::vector<ranging::Record>& rows, std::string* text,
                                  nlohmann::json* info) {
    ranging::Pipeline pipeline(conversion);
    if (!o.chain.empty()) {
      calib::ChainFitOptions chain_options;
      chain_options.steps = steps;
      chain_options.time_to_distance = conversion;
      const calib::ChainFitResult chain = calib::fit_chain(rows, chain_options);
      pipeline = chain.pipeline;
      if (text) *text += chain.summary();
      if (info) {
        nlohmann::json c = {{"steps", calib::to_string(steps)},
                            {"rows", chain.rows},
                            {"rows_skipped", chain.rows_skipped},
                            {"rows_downweighted", chain.rows_downweighted},
                            {"knot_search_rows", chain.knot_search_rows},
                            {"backfit_iterations", chain.backfit_iterations},
                            {"converged", chain.converged},
                            {"before", stats_json(chain.before)},
                            {"after", stats_json(chain.after)}};
        if (chain.grayvalue) c["grayvalue"] = hinge_json(*chain.grayvalue);
        if (chain.temperature) c["temperature"] = hinge_json(*chain.temperature);
        (*info)["chain"] = c;
      }
    }
    if (!o.surface.empty()) {
      const SurfaceRows surface_input = surface_rows(pipeline, rows, o.surface_temperature);
      calib::SurfaceFitData data{
          {surface_input.range, surface_input.amplitude,
           o.surface_temperature ? std::span<const double>(surface_input.temperature)
                                 : std::span<const double>()},
          surface_input.error,
          surface_input.group};
      calib::SurfaceFitResult surface;
      if (surface_spec.poly) {
        calib::PolynomialFitOptions poly;
        poly.order = surface_spec.order;
        poly.rcond = o.rcond;
        poly.use_temperature = o.surface_temperature;
        surface = calib::fit_polynomial_surface(data, poly);
      } else {
        require_two_distances(rows);
        calib::BSplineFitOptions bspline = bspline_options(o);
        surface = calib::fit_bspline_surface(data, bspline);
      }
      ranging::Step step = ranging::make_surface_step(surface.surface);
      step.fit.rows = surface.rows;
      step.fit.residual_rms_m = surface.residual_rms_m;
      pipeline.add_step(std::move(step));
      pipeline.set_residual_rms_m(surface.residual_rms_m);
      if (text) *text += surface.summary() + "\n";
      if (info) {
        (*info)["surface"] = {
            {"spec", o.surface},
            {"rows", surface.rows},
            {"parameters", surface.parameters},
            {"rank", surface.rank},
            {"knot_intervals",
             std::vector<int>(surface.intervals,
                              surface.intervals + (o.surface_temperature ? 3 : 2))},
            {"smoothing", surface.smoothing},
            {"cv_rms_m", surface.cv_rms_m},
            {"residual_rms_m", surface.residual_rms_m},
            {"error_before", stats_json(calib::error_stats(surface_input.error))}};
      }
    }
    return pipeline;
  };

  /// Residuals of `model` on `rows` (true - corrected), with range and amplitude.
  std::vector<double> range, amplitude, residual;
  const auto add_residuals = [&](const ranging::Pipeline& model,
                                 const std::vector<ranging::Record>& rows) {
    std::vector<ranging::RawMeasurement> raw;
    for (const auto& r : rows) raw.push_back(r.raw);
    std::vector<ranging::Range> corrected(raw.size());
    model.apply(raw, corrected);
    for (std::size_t i = 0; i < raw.size(); ++i) {
      const double e = rows[i].truth.distance_m - corrected[i].distance_m;
      // Out-of-domain rows would teach the in-domain sigma the extrapolation error.
      if (!std::isfinite(e) || !std::isfinite(raw[i].amplitude) ||
          (corrected[i].correction_flags & ranging::kCorrOutOfDomain) != 0) {
        continue;
      }
      range.push_back(corrected[i].distance_m);
      amplitude.push_back(raw[i].amplitude);
      residual.push_back(e);
    }
  };

  ranging::Pipeline pipeline(conversion);
  try {
    pipeline = fit_correction(fit_rows, &report, &fit_info);
    std::string confidence_note;
    bool fit_confidence = o.confidence != "none";
    if (fit_confidence && hold_out) {
      add_residuals(pipeline, confidence_rows);
      confidence_note =
          fmt::format("{} held-out rows (every {}-th of {} truth groups)", residual.size(),
                      std::lround(1.0 / o.confidence_fraction), groups);
    } else if (fit_confidence) {
      // Cross-fitting: every truth group's residual comes from a correction
      // fitted without it (K folds of whole groups), so the confidence learns
      // the error on targets the correction never saw; the model written is
      // fitted on all rows.
      const std::vector<std::size_t> group = truth_groups(records, groups);
      const auto folds = static_cast<std::size_t>(o.confidence_folds);
      try {
        if (groups < folds) {
          throw std::invalid_argument(
              fmt::format("--confidence-folds {} needs at least {} groups of identical truth "
                          "(distances / plates / temperatures), the file has {}",
                          folds, folds, groups));
        }
        for (std::size_t k = 0; k < folds; ++k) {
          std::vector<ranging::Record> train, test;
          for (std::size_t i = 0; i < records.size(); ++i) {
            (group[i] % folds == k ? test : train).push_back(records[i]);
          }
          add_residuals(fit_correction(train, nullptr, nullptr), test);
        }
      } catch (const std::invalid_argument& e) {
        if (o.confidence_given) throw;
        // Default confidence on data too small to cross-fit: sigma stays the residual RMS.
        fit_confidence = false;
        report += std::string("confidence: none (cross-fitting impossible: ") + e.what() + ")\n";
      }
      confidence_note = fmt::format("{} out-of-fold rows ({} folds of {} truth groups)",
                                    residual.size(), folds, groups);
    }
    if (fit_confidence) {
      const calib::ConfidenceFitData data{range, amplitude, residual};
      pipeline.set_confidence(o.confidence == "thesis" ? calib::fit_thesis_confidence(data)
                                                       : calib::fit_calibrated_confidence(data));
      const calib::ErrorStats held_out = calib::error_stats(residual);
      fit_info["confidence"] = {{"kind", o.confidence},
                                {"rows", residual.size()},
                                {"groups", groups},
                                {"held_out_residual", stats_json(held_out)}};
      if (hold_out) {
        fit_info["confidence"]["held_out_every_kth_group"] =
            std::lround(1.0 / o.confidence_fraction);
      } else {
        fit_info["confidence"]["folds"] = o.confidence_folds;
      }
      report += fmt::format("confidence: {} model fitted on {}; held-out RMS {:.3f} mm\n",
                            o.confidence, confidence_note, held_out.rms_m * 1e3);
    }
  } catch (const std::invalid_argument& e) {
    throw std::runtime_error(o.in + ": " + e.what());
  }
  fit_info["residual_rms_m"] = pipeline.residual_rms_m();

  // Quantize before writing anything, so a coefficient that does not fit leaves no files.
  std::optional<ranging::FixedPointChain> firmware;
  if (!o.firmware.empty()) {
    ranging::FixedPointFormat format;
    format.tdc_lsb_ps = config.tdc.lsb_ps;
    format.pulse_width_lsb_ps = config.tdc.lsb_ps;
    format.temperature_lsb_c = config.thermal.sensor_resolution_c;
    firmware = ranging::FixedPointChain::from_pipeline(pipeline, format);
  }
  io::save_pipeline(o.out, pipeline, fit_info);
  std::string firmware_note;
  if (firmware) {
    io::save_fixed_point_json(o.firmware + ".json", *firmware);
    io::save_fixed_point_header(o.firmware + ".h", *firmware);
    firmware_note = fmt::format(" (+ {0}.json, {0}.h)", o.firmware);
  }
  fmt::print("{}{}", report, pipeline.summary());
  fmt::print(stderr, "tofkit fit: {} rows from {} -> {}{}\n", records.size(), o.in, o.out,
             firmware_note);
}

const bool registered = register_command("fit", [](CLI::App& sub, AppContext& ctx) {
  sub.description(
      "fit a ranging pipeline (chain and/or correction surface, optional confidence) from a raw "
      "CSV with truth");
  auto o = std::make_shared<FitOptions>();
  sub.add_option("--in", o->in, "raw CSV with ground truth (calibration data)")->required();
  sub.add_option("--out", o->out, "model file to write (JSON)")->required();
  sub.add_option("--chain", o->chain,
                 "chain steps to fit: any of offset,grayvalue,temperature (paper Section 5)");
  sub.add_option("--surface", o->surface,
                 "correction surface: poly:N (thesis Section 4.6) or bspline; after --chain it "
                 "fits the chain's residual");
  CLI::Option* rcond =
      sub.add_option("--rcond", o->rcond, "poly: relative singular-value cutoff (thesis: 1e-2)")
          ->check(CLI::Range(0.0, 1.0))
          ->capture_default_str();
  sub.add_flag("--temperature", o->surface_temperature, "surface: add a temperature axis");
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
             "on out-of-fold residuals), thesis (Section 4.8) or none")
          ->check(CLI::IsMember({"none", "thesis", "calibrated"}))
          ->capture_default_str();
  CLI::Option* fraction =
      sub.add_option("--confidence-fraction", o->confidence_fraction,
                     "instead of cross-fitting, hold out every round(1/F)-th truth group for the "
                     "confidence fit (the correction is fitted on the rest)");
  sub.add_option("--confidence-folds", o->confidence_folds,
                 "cross-fitting folds of whole truth groups for the confidence fit")
      ->check(CLI::Range(2, 50))
      ->capture_default_str();
  sub.add_option("--firmware", o->firmware,
                 "also export the chain in fixed point: STEM.json and STEM.h (C header)");
  sub.callback([o, rcond, confidence, fraction, &ctx] {
    o->rcond_given = rcond->count() > 0;
    o->confidence_given = confidence->count() > 0;
    o->confidence_fraction_given = fraction->count() > 0;
    run_fit(*o, ctx);
  });
});

}  // namespace
}  // namespace tofkit::app
