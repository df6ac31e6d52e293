#include "tofkit/io/model_json.hpp"

#include <fmt/format.h>

#include <cmath>
#include <fstream>
#include <initializer_list>
#include <limits>
#include <memory>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

#include "tofkit/calib/model_fit.hpp"
#include "tofkit/io/atomic_file.hpp"
#include "tofkit/io/json_fields.hpp"
#include "tofkit/io/surface_json.hpp"

namespace tofkit::io {
namespace {

using json_fields::fail;
using json_fields::field;
using json_fields::number;
using nlohmann::json;

constexpr const char* kKind = "tofkit.pipeline";
constexpr int kVersion = 1;

/// null (or absent) -> `missing`.
double number_or(const json& j, const char* key, const std::string& where, double missing) {
  if (!j.is_object()) fail(where, "expected an object");
  const auto it = j.find(key);
  if (it == j.end() || it->is_null()) return missing;
  return number(*it, where + "." + key);
}

json finite_or_null(double v) {
  return std::isfinite(v) ? json(v) : json(nullptr);
}

std::vector<double> numbers(const json& j, const char* key, const std::string& where) {
  const json& v = field(j, key, where);
  const std::string here = where + "." + key;
  if (!v.is_array()) fail(here, "expected an array of numbers");
  std::vector<double> out;
  for (std::size_t k = 0; k < v.size(); ++k) {
    out.push_back(number(v[k], here + "[" + std::to_string(k) + "]"));
  }
  return out;
}

std::string text(const json& j, const char* key, const std::string& where) {
  const json& v = field(j, key, where);
  if (!v.is_string()) fail(where + "." + key, "expected a string");
  return v.get<std::string>();
}

/// A walk step's objects are read strictly: a key this reader does not know is
/// an error naming it (a misspelt parameter must not silently fall back).
void refuse_unknown_keys(const json& j, const std::string& where,
                         std::initializer_list<const char*> known) {
  if (!j.is_object()) fail(where, "expected an object");
  for (const auto& [key, value] : j.items()) {
    bool ok = false;
    for (const char* k : known) ok = ok || key == k;
    if (!ok) fail(where + "." + key, "unknown key");
  }
}

json walk_shape_to_json(const ranging::WalkShape& shape) {
  return {{"pulse_sigma_ns", shape.pulse_sigma_ns},
          {"pole_time_constant_ns", shape.pole_time_constant_ns},
          {"saturation_log_overdrive", finite_or_null(shape.saturation_log_overdrive)},
          {"recovery_ns_per_neper", shape.recovery_ns_per_neper}};
}

ranging::WalkShape walk_shape_from_json(const json& sj, const std::string& sw) {
  if (!sj.is_object()) fail(sw, "must be an object");
  refuse_unknown_keys(sj, sw,
                      {"pulse_sigma_ns", "pole_time_constant_ns", "saturation_log_overdrive",
                       "recovery_ns_per_neper"});
  ranging::WalkShape shape;
  shape.pulse_sigma_ns = number(sj, "pulse_sigma_ns", sw);
  shape.pole_time_constant_ns = number(sj, "pole_time_constant_ns", sw);
  shape.saturation_log_overdrive =
      number_or(sj, "saturation_log_overdrive", sw, std::numeric_limits<double>::infinity());
  shape.recovery_ns_per_neper = number(sj, "recovery_ns_per_neper", sw);
  try {
    shape.validate();
  } catch (const std::invalid_argument& e) {
    fail(sw, e.what());
  }
  return shape;
}

json fit_to_json(const ranging::StepFitInfo& fit) {
  return {{"rows", fit.rows}, {"residual_rms_m", finite_or_null(fit.residual_rms_m)}};
}

ranging::StepFitInfo fit_from_json(const json& step, const std::string& where) {
  ranging::StepFitInfo fit;
  const auto it = step.find("fit");
  if (it == step.end() || it->is_null()) return fit;
  const std::string here = where + ".fit";
  if (!it->is_object()) fail(here, "expected an object");
  const auto rows = it->find("rows");
  if (rows != it->end()) {
    if (!rows->is_number_unsigned() &&
        !(rows->is_number_integer() && rows->get<long long>() >= 0)) {
      fail(here + ".rows", "expected a non-negative integer");
    }
    fit.rows = rows->get<std::size_t>();
  }
  fit.residual_rms_m = number_or(*it, "residual_rms_m", here, ranging::kNaN);
  return fit;
}

json step_to_json(const ranging::Step& step) {
  json j;
  j["kind"] = std::string(ranging::step_kind_name(step.kind));
  switch (step.kind) {
    case ranging::StepKind::kOffset:
      j["offset_m"] = step.offset_m;
      break;
    case ranging::StepKind::kGrayvalue:
    case ranging::StepKind::kTemperature:
      j["input"] = step.kind == ranging::StepKind::kGrayvalue ? "pulse_width_ns" : "temperature_c";
      j["function"] = {{"x0", step.function.x0},
                       {"intercept", step.function.intercept},
                       {"slope0", step.function.slope0},
                       {"knots", step.function.knots},
                       {"slopes", step.function.slopes}};
      j["domain"] = {{"min", finite_or_null(step.domain.min)},
                     {"max", finite_or_null(step.domain.max)}};
      break;
    case ranging::StepKind::kSurface:
      j["surface"] = surface_to_json(*step.surface);
      break;
    case ranging::StepKind::kWalk: {
      j["input"] = "pulse_width_ns";
      j["shape"] = walk_shape_to_json(step.walk->shape());
      j["reference_pulse_width_ns"] = step.walk->reference_pulse_width_ns();
      if (step.walk->has_replicates()) {
        json replicates = json::array();
        for (const auto& r : step.walk->replicates()) replicates.push_back(walk_shape_to_json(r));
        j["shape_replicates"] = std::move(replicates);
      }
      j["domain"] = {{"min", finite_or_null(step.domain.min)},
                     {"max", finite_or_null(step.domain.max)}};
      break;
    }
    case ranging::StepKind::kPeriodic:
      j["input"] = "tof_ns";
      j["period_ns"] = step.period_ns;
      j["harmonics_m"] = step.harmonics_m;
      if (!step.harmonics_per_c_m.empty()) {
        j["harmonics_per_c_m"] = step.harmonics_per_c_m;
        j["reference_temperature_c"] = step.reference_temperature_c;
      }
      // Models before it had none: the rising edge's stop only.
      if (step.both_stops) j["stops"] = "rise_and_fall";
      break;
  }
  j["fit"] = fit_to_json(step.fit);
  return j;
}

ranging::Step step_from_json(const json& j, const std::string& where) {
  ranging::StepKind kind;
  try {
    kind = ranging::step_kind_from_name(text(j, "kind", where));
  } catch (const std::invalid_argument& e) {
    fail(where + ".kind", e.what());
  }
  ranging::Step step;
  step.kind = kind;
  switch (kind) {
    case ranging::StepKind::kOffset:
      step.offset_m = number(j, "offset_m", where);
      break;
    case ranging::StepKind::kGrayvalue:
    case ranging::StepKind::kTemperature: {
      const char* input =
          kind == ranging::StepKind::kGrayvalue ? "pulse_width_ns" : "temperature_c";
      if (j.contains("input") && text(j, "input", where) != input) {
        fail(where + ".input",
             fmt::format("a {} step's input is \"{}\"", ranging::step_kind_name(kind), input));
      }
      const std::string fw = where + ".function";
      const json& f = field(j, "function", where);
      step.function.x0 = number(f, "x0", fw);
      step.function.intercept = number(f, "intercept", fw);
      step.function.slope0 = number(f, "slope0", fw);
      step.function.knots = numbers(f, "knots", fw);
      step.function.slopes = numbers(f, "slopes", fw);
      const json& d = field(j, "domain", where);
      step.domain.min =
          number_or(d, "min", where + ".domain", -std::numeric_limits<double>::infinity());
      step.domain.max =
          number_or(d, "max", where + ".domain", std::numeric_limits<double>::infinity());
      break;
    }
    case ranging::StepKind::kSurface:
      step.surface = surface_from_json(field(j, "surface", where), where + ".surface");
      break;
    case ranging::StepKind::kWalk: {
      refuse_unknown_keys(j, where,
                          {"kind", "input", "shape", "reference_pulse_width_ns", "shape_replicates",
                           "shape_covariance", "domain", "fit"});
      if (text(j, "input", where) != "pulse_width_ns") {
        fail(where + ".input", "a walk step's input is \"pulse_width_ns\"");
      }
      const ranging::WalkShape shape =
          walk_shape_from_json(field(j, "shape", where), where + ".shape");
      std::vector<ranging::WalkShape> replicates;
      if (j.contains("shape_replicates")) {
        const std::string rw = where + ".shape_replicates";
        const json& rj = j["shape_replicates"];
        if (!rj.is_array()) fail(rw, "must be an array of shapes");
        for (std::size_t r = 0; r < rj.size(); ++r) {
          replicates.push_back(walk_shape_from_json(rj[r], rw + "[" + std::to_string(r) + "]"));
        }
      }
      if (j.contains("shape_covariance")) {
        // Older files: a covariance over ranging::walk_parameters(shape), row-major.
        if (j.contains("shape_replicates")) {
          fail(where + ".shape_covariance", "give shape_replicates or shape_covariance, not both");
        }
        try {
          replicates = ranging::walk_sigma_points(shape, numbers(j, "shape_covariance", where));
        } catch (const std::invalid_argument& e) {
          fail(where + ".shape_covariance", e.what());
        }
      }
      try {
        step.walk = std::make_shared<const ranging::WalkModel>(
            shape, number(j, "reference_pulse_width_ns", where), std::move(replicates));
      } catch (const std::invalid_argument& e) {
        fail(where, e.what());
      }
      const json& d = field(j, "domain", where);
      refuse_unknown_keys(d, where + ".domain", {"min", "max"});
      step.domain.min =
          number_or(d, "min", where + ".domain", -std::numeric_limits<double>::infinity());
      step.domain.max =
          number_or(d, "max", where + ".domain", std::numeric_limits<double>::infinity());
      break;
    }
    case ranging::StepKind::kPeriodic:
      step.period_ns = number(j, "period_ns", where);
      step.harmonics_m = numbers(j, "harmonics_m", where);
      if (j.contains("harmonics_per_c_m")) {
        step.harmonics_per_c_m = numbers(j, "harmonics_per_c_m", where);
        step.reference_temperature_c = number(j, "reference_temperature_c", where);
      }
      if (j.contains("stops")) {
        const std::string stops = text(j, "stops", where);
        if (stops != "rise" && stops != "rise_and_fall")
          fail(where + ".stops", "expected \"rise\" or \"rise_and_fall\"");
        step.both_stops = stops == "rise_and_fall";
      }
      break;
  }
  step.fit = fit_from_json(j, where);
  try {
    step.validate();
  } catch (const std::invalid_argument& e) {
    fail(where, e.what());
  }
  return step;
}

}  // namespace

json pipeline_to_json(const ranging::Pipeline& pipeline, const json& fit) {
  const ranging::TimeToDistance& t = pipeline.time_to_distance();
  json j;
  j["kind"] = kKind;
  j["version"] = kVersion;
  j["time_to_distance"] = {{"wavelength_nm", t.wavelength_nm},
                           {"air",
                            {{"temperature_c", t.air.temperature_c},
                             {"pressure_hpa", t.air.pressure_hpa},
                             {"relative_humidity_pct", t.air.relative_humidity_pct}}},
                           {"metres_per_ns", ranging::metres_per_ns(t)}};
  json steps = json::array();
  for (const ranging::Step& step : pipeline.steps()) steps.push_back(step_to_json(step));
  j["steps"] = std::move(steps);
  if (pipeline.confidence()) j["confidence"] = confidence_to_json(*pipeline.confidence());
  j["residual_rms_m"] = finite_or_null(pipeline.residual_rms_m());
  if (!fit.is_null()) j["fit"] = fit;
  return j;
}

ranging::Pipeline pipeline_from_json(const json& j, const std::string& context) {
  if (!j.is_object()) fail(context, "expected a JSON object");
  const std::string kind = text(j, "kind", context);
  if (kind != kKind) fail(context + ".kind", "is \"" + kind + "\", expected \"" + kKind + "\"");
  const json& version = field(j, "version", context);
  if (!version.is_number_integer() || version.get<long long>() != kVersion) {
    fail(context + ".version", "unsupported version " + version.dump() + " (this tofkit reads " +
                                   std::to_string(kVersion) + ")");
  }
  const std::string tw = context + ".time_to_distance";
  const json& tj = field(j, "time_to_distance", context);
  ranging::TimeToDistance t;
  t.wavelength_nm = number(tj, "wavelength_nm", tw);
  const json& air = field(tj, "air", tw);
  t.air.temperature_c = number(air, "temperature_c", tw + ".air");
  t.air.pressure_hpa = number(air, "pressure_hpa", tw + ".air");
  t.air.relative_humidity_pct = number(air, "relative_humidity_pct", tw + ".air");
  ranging::Pipeline pipeline;
  try {
    pipeline = ranging::Pipeline(t);
  } catch (const std::invalid_argument& e) {
    fail(tw, e.what());
  }
  // metres_per_ns is written for people: it follows from the wavelength and
  // the air, and a file whose value disagrees has been edited or corrupted.
  if (tj.contains("metres_per_ns")) {
    const double given = number(tj, "metres_per_ns", tw);
    const double derived = ranging::metres_per_ns(t);
    if (!(std::abs(given - derived) <= 1e-12 * derived)) {
      fail(tw + ".metres_per_ns",
           fmt::format("{} disagrees with {} from the wavelength and the air (it is derived "
                       "from them, not read)",
                       given, derived));
    }
  }
  const json& steps = field(j, "steps", context);
  if (!steps.is_array()) fail(context + ".steps", "expected an array");
  for (std::size_t s = 0; s < steps.size(); ++s) {
    pipeline.add_step(step_from_json(steps[s], context + ".steps[" + std::to_string(s) + "]"));
  }
  const auto confidence = j.find("confidence");
  if (confidence != j.end() && !confidence->is_null()) {
    pipeline.set_confidence(confidence_from_json(*confidence, context + ".confidence"));
  }
  const double rms = number_or(j, "residual_rms_m", context, ranging::kNaN);
  if (rms < 0) fail(context + ".residual_rms_m", "must not be negative");
  pipeline.set_residual_rms_m(rms);
  return pipeline;
}

void save_pipeline(const std::filesystem::path& path, const ranging::Pipeline& pipeline,
                   const json& fit, const ranging::UncertaintyBudget* budget) {
  json j = pipeline_to_json(pipeline, fit);
  if (budget != nullptr && !budget->empty()) j["uncertainty_budget"] = budget_to_json(*budget);
  write_file_atomically(path, j.dump(2) + "\n");
}

ranging::Pipeline load_pipeline(const std::filesystem::path& path) {
  const json j = json_fields::parse_file(path, "model file");
  return pipeline_from_json(j, path.string());
}

namespace {

const char* scope_name(ranging::BudgetScope s) {
  switch (s) {
    case ranging::BudgetScope::same_power_on:
      return "same_power_on";
    case ranging::BudgetScope::other_power_on:
      return "other_power_on";
    case ranging::BudgetScope::always:
      break;
  }
  return "always";
}

const char* axis_name(ranging::BudgetComponent::Axis a) {
  switch (a) {
    case ranging::BudgetComponent::Axis::log_amplitude:
      return "log_amplitude";
    case ranging::BudgetComponent::Axis::time_since_calibration_s:
      return "time_since_calibration_s";
    case ranging::BudgetComponent::Axis::temperature_c:
      return "temperature_c";
    case ranging::BudgetComponent::Axis::lost_shot_share:
      return "lost_shot_share";
    case ranging::BudgetComponent::Axis::false_stop_rate_per_m:
      return "false_stop_rate_per_m";
    case ranging::BudgetComponent::Axis::none:
      break;
  }
  return "none";
}

std::string text_field(const json& j, const char* key, const std::string& where) {
  const json& v = field(j, key, where);
  if (!v.is_string()) fail(where + "." + key, "expected a string");
  return v.get<std::string>();
}

bool bool_field(const json& j, const char* key, const std::string& where) {
  const json& v = field(j, key, where);
  if (!v.is_boolean()) fail(where + "." + key, "expected true or false");
  return v.get<bool>();
}

}  // namespace

json budget_to_json(const ranging::UncertaintyBudget& budget) {
  json components = json::array();
  for (const auto& c : budget.components) {
    components.push_back({{"name", c.name},
                          {"step", c.step},
                          {"type", c.type_b ? "B" : "A"},
                          {"default_specification", c.default_specification},
                          {"scope", scope_name(c.scope)},
                          {"axis", axis_name(c.axis)},
                          {"node", c.node},
                          {"variance_m2", c.variance_m2}});
  }
  json j = {{"components", components}, {"unobserved", budget.unobserved}};
  if (std::isfinite(budget.calibration_time_s)) j["calibration_time_s"] = budget.calibration_time_s;
  if (std::isfinite(budget.shots)) j["shots"] = budget.shots;
  return j;
}

ranging::UncertaintyBudget budget_from_json(const json& j, const std::string& context) {
  if (!j.is_object()) fail(context, "expected an object");
  ranging::UncertaintyBudget budget;
  const json& components = field(j, "components", context);
  if (!components.is_array()) fail(context + ".components", "expected an array");
  for (std::size_t k = 0; k < components.size(); ++k) {
    const std::string where = context + ".components[" + std::to_string(k) + "]";
    const json& cj = components[k];
    ranging::BudgetComponent c;
    c.name = text_field(cj, "name", where);
    c.step = text_field(cj, "step", where);
    const std::string type = text_field(cj, "type", where);
    if (type != "A" && type != "B") fail(where + ".type", "expected \"A\" or \"B\"");
    c.type_b = type == "B";
    c.default_specification = bool_field(cj, "default_specification", where);
    const std::string scope = text_field(cj, "scope", where);
    if (scope == "always") {
      c.scope = ranging::BudgetScope::always;
    } else if (scope == "same_power_on") {
      c.scope = ranging::BudgetScope::same_power_on;
    } else if (scope == "other_power_on") {
      c.scope = ranging::BudgetScope::other_power_on;
    } else {
      fail(where + ".scope", "expected always, same_power_on or other_power_on");
    }
    const std::string axis = text_field(cj, "axis", where);
    if (axis == "none") {
      c.axis = ranging::BudgetComponent::Axis::none;
    } else if (axis == "log_amplitude") {
      c.axis = ranging::BudgetComponent::Axis::log_amplitude;
    } else if (axis == "time_since_calibration_s") {
      c.axis = ranging::BudgetComponent::Axis::time_since_calibration_s;
    } else if (axis == "temperature_c") {
      c.axis = ranging::BudgetComponent::Axis::temperature_c;
    } else if (axis == "lost_shot_share") {
      c.axis = ranging::BudgetComponent::Axis::lost_shot_share;
    } else if (axis == "false_stop_rate_per_m") {
      c.axis = ranging::BudgetComponent::Axis::false_stop_rate_per_m;
    } else {
      fail(where + ".axis",
           "expected none, log_amplitude, time_since_calibration_s, temperature_c, "
           "lost_shot_share or false_stop_rate_per_m");
    }
    c.node = numbers(cj, "node", where);
    c.variance_m2 = numbers(cj, "variance_m2", where);
    budget.components.push_back(std::move(c));
  }
  if (j.contains("unobserved")) {
    const json& u = j["unobserved"];
    if (!u.is_array()) fail(context + ".unobserved", "expected an array of strings");
    for (std::size_t k = 0; k < u.size(); ++k) {
      if (!u[k].is_string())
        fail(context + ".unobserved[" + std::to_string(k) + "]", "expected a string");
      budget.unobserved.push_back(u[k].get<std::string>());
    }
  }
  if (j.contains("calibration_time_s")) {
    budget.calibration_time_s = number(j["calibration_time_s"], context + ".calibration_time_s");
    if (!(budget.calibration_time_s >= 0))
      fail(context + ".calibration_time_s", "expected a time since power-on >= 0 s");
  }
  if (j.contains("shots")) {
    budget.shots = number(j["shots"], context + ".shots");
    if (!(budget.shots >= 1)) fail(context + ".shots", "expected shots per measurement >= 1");
  }
  try {
    budget.validate();
  } catch (const std::invalid_argument& e) {
    fail(context, e.what());
  }
  return budget;
}

ranging::UncertaintyBudget load_budget(const std::filesystem::path& path) {
  const json j = json_fields::parse_file(path, "model file");
  const auto it = j.is_object() ? j.find("uncertainty_budget") : j.end();
  if (it == j.end() || it->is_null()) return {};  // a model from before the budget: none
  return budget_from_json(*it, path.string() + ".uncertainty_budget");
}

namespace {

json stats_json(const calib::ErrorStats& s) {
  return {{"rows", s.rows},
          {"bias_m", finite_or_null(s.bias_m)},
          {"rms_m", finite_or_null(s.rms_m)},
          {"max_abs_m", finite_or_null(s.max_abs_m)}};
}

json hinge_json(const calib::HingeFitResult& h) {
  json bic = json::array();
  for (double b : h.bic) bic.push_back(finite_or_null(b));
  return {{"knots", h.knots},
          {"bic_by_knot_count", bic},
          {"rows_downweighted", h.rows_downweighted},
          {"robust_sigma_m", h.robust_scale}};
}

}  // namespace

json fit_summary_json(const calib::ModelFitSummary& s, const std::string& input) {
  json j = {{"command", "fit"}, {"input", input}, {"rows", s.rows}, {"rows_fit", s.rows_fit}};
  if (s.chain) {
    const calib::ChainFitResult& chain = *s.chain;
    json c = {{"steps", s.chain_steps},
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
    if (chain.walk) {
      const calib::WalkFitResult& w = *chain.walk;
      c["walk"] = {{"pulse_sigma_ns", w.shape.pulse_sigma_ns},
                   {"pole_time_constant_ns", w.shape.pole_time_constant_ns},
                   {"saturation_log_overdrive", finite_or_null(w.shape.saturation_log_overdrive)},
                   {"recovery_ns_per_neper", w.shape.recovery_ns_per_neper},
                   {"rows_clipped", w.saturated_rows},
                   {"rms_m", w.rms_m},
                   {"iterations", w.iterations},
                   {"converged", w.converged}};
    }
    j["chain"] = c;
  }
  if (s.walk) {
    j["walk_refinement"] = {{"nodes", s.walk->nodes},
                            {"smoothing", s.walk->smoothing},
                            {"cv_rms_m", s.walk->cv_rms_m},
                            {"cv_rms_without_m", s.walk->cv_rms_without_m},
                            {"effective_parameters", s.walk->effective_parameters}};
  }
  if (s.periodic) {
    j["periodic"] = {{"harmonics", s.periodic->harmonics},
                     {"temperature_slope", s.periodic->temperature_slope},
                     {"cv_rms_m", s.periodic->cv_rms_m},
                     {"cv_rms_without_m", s.periodic->cv_rms_without_m}};
  }
  if (s.surface) {
    const calib::SurfaceFitResult& surface = *s.surface;
    j["surface"] = {
        {"spec", s.surface_spec},
        {"rows", surface.rows},
        {"parameters", surface.parameters},
        {"rank", surface.rank},
        {"knot_intervals",
         std::vector<int>(surface.intervals, surface.intervals + (s.surface_temperature ? 3 : 2))},
        {"smoothing", surface.smoothing},
        {"cv_rms_m", surface.cv_rms_m},
        {"intensity", s.surface_intensity},
        {"residual_rms_m", surface.residual_rms_m},
        {"error_before", stats_json(s.surface_error_before)}};
    if (!surface.knots[0].empty()) {
      // B-spline: the breakpoints per axis in input units, how they were
      // placed, and each axis's penalty weight relative to the smoothing.
      json knots = json::array(), placement = json::array();
      for (int k = 0; k < (s.surface_temperature ? 3 : 2); ++k) {
        knots.push_back(surface.knots[k]);
        placement.push_back(calib::to_string(surface.placement[k]));
      }
      j["surface"]["knots"] = knots;
      j["surface"]["knot_placement"] = placement;
      j["surface"]["axis_weights"] = std::vector<double>(
          surface.axis_weight, surface.axis_weight + (s.surface_temperature ? 3 : 2));
    }
    if (s.surface_cv_rms_other_m > 0) {
      j["surface"]["cv_rms_other_intensity_m"] = s.surface_cv_rms_other_m;
    }
  }
  if (s.confidence) {
    const auto& c = *s.confidence;
    j["confidence"] = {{"kind", calib::to_string(c.kind)},
                       {"rows", c.rows},
                       {"groups", c.groups},
                       {"held_out_residual", stats_json(c.held_out)}};
    if (c.kind == calib::ConfidenceKind::noise_systematic) {
      j["confidence"]["effective_parameters"] = c.effective_parameters;
      j["confidence"]["leverage_sum"] = c.leverage_sum;
      j["confidence"]["optimism_mean"] = c.optimism;
      j["confidence"]["optimism_max"] = c.optimism_max;
    } else if (c.every_kth_group > 0) {
      j["confidence"]["held_out_every_kth_group"] = c.every_kth_group;
    } else {
      j["confidence"]["folds"] = c.folds;
    }
  }
  j["residual_rms_m"] = s.residual_rms_m;
  return j;
}

}  // namespace tofkit::io
