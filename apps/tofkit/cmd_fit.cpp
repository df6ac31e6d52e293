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
  std::string confidence = "none";
  double confidence_fraction = 0.25;
  std::string firmware;  // stem: writes STEM.json and STEM.h
  bool rcond_given = false;
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

/// Rows a surface can be fitted on: corrected distance, truth, amplitude (and temperature).
struct SurfaceRows {
  std::vector<double> range, amplitude, temperature, error;
};

SurfaceRows surface_rows(const ranging::Pipeline& pipeline,
                         const std::vector<ranging::Record>& records, bool use_temperature) {
  std::vector<ranging::RawMeasurement> raw;
  for (const auto& r : records) raw.push_back(r.raw);
  std::vector<ranging::Range> before(raw.size());
  pipeline.apply(raw, before);
  SurfaceRows rows;
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
  if (o.confidence == "none") {
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
  ranging::Pipeline pipeline(conversion);
  std::string report;
  try {
    if (!o.chain.empty()) {
      calib::ChainFitOptions chain_options;
      chain_options.steps = steps;
      chain_options.time_to_distance = conversion;
      const calib::ChainFitResult chain = calib::fit_chain(fit_rows, chain_options);
      pipeline = chain.pipeline;
      report += chain.summary();
      nlohmann::json c = {{"steps", calib::to_string(steps)},
                          {"rows", chain.rows},
                          {"rows_skipped", chain.rows_skipped},
                          {"rows_downweighted", chain.rows_downweighted},
                          {"backfit_iterations", chain.backfit_iterations},
                          {"converged", chain.converged},
                          {"before", stats_json(chain.before)},
                          {"after", stats_json(chain.after)}};
      if (chain.grayvalue) c["grayvalue"] = hinge_json(*chain.grayvalue);
      if (chain.temperature) c["temperature"] = hinge_json(*chain.temperature);
      fit_info["chain"] = c;
    }
    if (!o.surface.empty()) {
      const SurfaceRows rows = surface_rows(pipeline, fit_rows, o.surface_temperature);
      calib::SurfaceFitData data{{rows.range, rows.amplitude,
                                  o.surface_temperature ? std::span<const double>(rows.temperature)
                                                        : std::span<const double>()},
                                 rows.error};
      calib::SurfaceFitResult surface;
      if (surface_spec.poly) {
        calib::PolynomialFitOptions poly;
        poly.order = surface_spec.order;
        poly.rcond = o.rcond;
        poly.use_temperature = o.surface_temperature;
        surface = calib::fit_polynomial_surface(data, poly);
      } else {
        calib::BSplineFitOptions bspline;
        bspline.use_temperature = o.surface_temperature;
        surface = calib::fit_bspline_surface(data, bspline);
      }
      ranging::Step step = ranging::make_surface_step(surface.surface);
      step.fit.rows = surface.rows;
      step.fit.residual_rms_m = surface.residual_rms_m;
      pipeline.add_step(std::move(step));
      pipeline.set_residual_rms_m(surface.residual_rms_m);
      report += surface.summary() + "\n";
      fit_info["surface"] = {{"spec", o.surface},
                             {"rows", surface.rows},
                             {"parameters", surface.parameters},
                             {"rank", surface.rank},
                             {"residual_rms_m", surface.residual_rms_m},
                             {"error_before", stats_json(calib::error_stats(rows.error))}};
    }
    if (o.confidence != "none") {
      std::vector<ranging::RawMeasurement> raw;
      for (const auto& r : confidence_rows) raw.push_back(r.raw);
      std::vector<ranging::Range> corrected(raw.size());
      pipeline.apply(raw, corrected);
      std::vector<double> range, amplitude, residual;
      for (std::size_t i = 0; i < raw.size(); ++i) {
        const double e = confidence_rows[i].truth.distance_m - corrected[i].distance_m;
        if (!std::isfinite(e) || !std::isfinite(raw[i].amplitude)) continue;
        range.push_back(corrected[i].distance_m);
        amplitude.push_back(raw[i].amplitude);
        residual.push_back(e);
      }
      const calib::ConfidenceFitData data{range, amplitude, residual};
      pipeline.set_confidence(o.confidence == "thesis" ? calib::fit_thesis_confidence(data)
                                                       : calib::fit_calibrated_confidence(data));
      const calib::ErrorStats held_out = calib::error_stats(residual);
      fit_info["confidence"] = {
          {"kind", o.confidence},
          {"rows", residual.size()},
          {"groups", groups},
          {"held_out_every_kth_group", std::lround(1.0 / o.confidence_fraction)},
          {"held_out_residual", stats_json(held_out)}};
      report += fmt::format(
          "confidence: {} model fitted on {} held-out rows (every {}-th of {} truth groups); "
          "held-out RMS {:.3f} mm\n",
          o.confidence, residual.size(), std::lround(1.0 / o.confidence_fraction), groups,
          held_out.rms_m * 1e3);
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
  sub.add_option("--confidence", o->confidence,
                 "confidence model: none, thesis (Section 4.8) or calibrated")
      ->check(CLI::IsMember({"none", "thesis", "calibrated"}))
      ->capture_default_str();
  sub.add_option("--confidence-fraction", o->confidence_fraction,
                 "share of truth groups held out for the confidence fit (every round(1/F)-th "
                 "group)")
      ->capture_default_str();
  sub.add_option("--firmware", o->firmware,
                 "also export the chain in fixed point: STEM.json and STEM.h (C header)");
  sub.callback([o, rcond, &ctx] {
    o->rcond_given = rcond->count() > 0;
    run_fit(*o, ctx);
  });
});

}  // namespace
}  // namespace tofkit::app
