#include "tofkit/io/surface_json.hpp"

#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>
#include <vector>

#include "tofkit/calib/bspline_surface.hpp"
#include "tofkit/calib/polynomial_surface.hpp"
#include "tofkit/io/json_fields.hpp"

namespace tofkit::io {

namespace {

using json_fields::fail;
using json_fields::field;
using json_fields::number;
using nlohmann::json;

constexpr int kVersion = 1;

/// Numbers that may be infinite (a condition number) are written as null.
json finite_or_null(double v) {
  return std::isfinite(v) ? json(v) : json(nullptr);
}
double number_or_infinity(const json& j, const char* key, const std::string& where) {
  const auto it = j.find(key);
  if (it == j.end() || it->is_null()) return std::numeric_limits<double>::infinity();
  return number(*it, where + "." + key);
}

std::size_t count(const json& j, const char* key, const std::string& where) {
  const json& v = field(j, key, where);
  if (!v.is_number_integer() && !v.is_number_unsigned())
    fail(where + "." + key, "expected an integer");
  const auto value = v.get<long long>();
  if (value < 0) fail(where + "." + key, "must not be negative");
  return static_cast<std::size_t>(value);
}

int integer(const json& j, const std::string& where) {
  if (!j.is_number_integer() && !j.is_number_unsigned()) fail(where, "expected an integer");
  const auto value = j.get<long long>();
  if (value < -1000000 || value > 1000000) fail(where, "integer out of range");
  return static_cast<int>(value);
}

bool boolean(const json& j, const char* key, const std::string& where) {
  const json& v = field(j, key, where);
  if (!v.is_boolean()) fail(where + "." + key, "expected true or false");
  return v.get<bool>();
}

std::vector<double> numbers(const json& j, const char* key, const std::string& where) {
  const json& v = field(j, key, where);
  const std::string here = where + "." + key;
  if (!v.is_array()) fail(here, "expected an array of numbers");
  std::vector<double> out;
  out.reserve(v.size());
  for (std::size_t k = 0; k < v.size(); ++k)
    out.push_back(number(v[k], here + "[" + std::to_string(k) + "]"));
  return out;
}

void check_kind(const json& j, const char* kind, const std::string& where) {
  const json& k = field(j, "kind", where);
  if (!k.is_string() || k.get<std::string>() != kind)
    fail(where + ".kind", std::string("expected \"") + kind + "\"");
  const json& v = field(j, "version", where);
  if (!v.is_number_integer() || v.get<int>() != kVersion) {
    fail(where + ".version",
         "unsupported version (this build reads version " + std::to_string(kVersion) + ")");
  }
}

json interval(double lo, double hi) {
  return json::array({lo, hi});
}
void read_interval(const json& j, const char* key, const std::string& where, double& lo,
                   double& hi) {
  const json& v = field(j, key, where);
  const std::string here = where + "." + key;
  if (!v.is_array() || v.size() != 2) fail(here, "expected [min, max]");
  lo = number(v[0], here + "[0]");
  hi = number(v[1], here + "[1]");
}

json scaling_json(const calib::AxisScaling& s) {
  return {{"center", s.center}, {"half_width", s.half_width}};
}
calib::AxisScaling read_scaling(const json& j, const char* key, const std::string& where) {
  const json& v = field(j, key, where);
  const std::string here = where + "." + key;
  return {number(v, "center", here), number(v, "half_width", here)};
}

json domain_json(const calib::SurfaceDomain& d, bool with_temperature) {
  json out = {{"range_m", interval(d.range_min_m, d.range_max_m)},
              {"amplitude", interval(d.amplitude_min, d.amplitude_max)}};
  if (with_temperature) out["temperature_c"] = interval(d.temperature_min_c, d.temperature_max_c);
  return out;
}
calib::SurfaceDomain read_domain(const json& j, bool with_temperature, const std::string& where) {
  const json& v = field(j, "domain", where);
  const std::string here = where + ".domain";
  calib::SurfaceDomain d;
  read_interval(v, "range_m", here, d.range_min_m, d.range_max_m);
  read_interval(v, "amplitude", here, d.amplitude_min, d.amplitude_max);
  if (with_temperature)
    read_interval(v, "temperature_c", here, d.temperature_min_c, d.temperature_max_c);
  return d;
}

json fit_json(const calib::SurfaceFitStats& s, bool bspline) {
  json out = {{"rows", s.rows},
              {"parameters", s.parameters},
              {"rank", s.rank},
              {"residual_rms_m", s.residual_rms_m},
              {"condition_number", finite_or_null(s.condition_number)},
              {"effective_parameters", s.effective_parameters}};
  if (bspline) {
    out["smoothing"] = s.smoothing;
    if (s.cv_rms_m > 0) out["cv_rms_m"] = s.cv_rms_m;
  } else {
    out["rcond"] = s.rcond;
  }
  return out;
}
calib::SurfaceFitStats read_fit(const json& j, bool bspline, const std::string& where) {
  const json& v = field(j, "fit", where);
  const std::string here = where + ".fit";
  calib::SurfaceFitStats s;
  s.rows = count(v, "rows", here);
  s.parameters = count(v, "parameters", here);
  s.rank = count(v, "rank", here);
  s.residual_rms_m = number(v, "residual_rms_m", here);
  s.condition_number = number_or_infinity(v, "condition_number", here);
  s.effective_parameters = number(v, "effective_parameters", here);
  if (bspline) {
    s.smoothing = number(v, "smoothing", here);
    if (v.contains("cv_rms_m")) s.cv_rms_m = number(v, "cv_rms_m", here);  // optional
  } else {
    s.rcond = number(v, "rcond", here);
  }
  return s;
}

/// An axis: its breakpoints ("knots", in the axis coordinate: the log of the
/// input on a "log" scale), with intervals, lo and hi beside them for a reader's
/// eye (and for files written before knots were stored, which held only
/// those: their knots are uniform).
json axis_json(const calib::BSplineAxis& a) {
  return {{"intervals", a.intervals()},
          {"scale", a.log_scale ? "log" : "linear"},
          {"lo", a.lo()},
          {"hi", a.hi()},
          {"knots", a.breakpoints}};
}
calib::BSplineAxis read_axis(const json& j, const char* key, const std::string& where) {
  const json& v = field(j, key, where);
  const std::string here = where + "." + key;
  calib::BSplineAxis a;
  const json& scale = field(v, "scale", here);
  if (!scale.is_string() || (scale != "log" && scale != "linear"))
    fail(here + ".scale", "expected \"linear\" or \"log\"");
  a.log_scale = scale == "log";
  if (!v.contains("knots")) {
    // Uniform knots from intervals, lo and hi (files without "knots").
    const int intervals = integer(field(v, "intervals", here), here + ".intervals");
    if (intervals < 1 || intervals > 1000) fail(here + ".intervals", "must be in [1, 1000]");
    const double lo = number(v, "lo", here);
    const double hi = number(v, "hi", here);
    if (!std::isfinite(lo)) fail(here + ".lo", "must be finite");
    if (!std::isfinite(hi) || !(hi > lo)) fail(here + ".hi", "must be finite and above lo");
    return calib::BSplineAxis::uniform(lo, hi, intervals, a.log_scale);
  }
  const std::string kw = here + ".knots";
  a.breakpoints = numbers(v, "knots", here);
  const std::size_t n = a.breakpoints.size();
  if (n < 2 || n > 1001) {
    fail(kw, "has " + std::to_string(n) +
                 " breakpoints; a cubic axis needs 2 .. 1001 (1 .. 1000 knot intervals)");
  }
  for (std::size_t k = 0; k < n; ++k) {
    const std::string at = kw + "[" + std::to_string(k) + "]";
    if (!std::isfinite(a.breakpoints[k])) fail(at, "must be finite");
    if (k > 0 && !(a.breakpoints[k] > a.breakpoints[k - 1])) {
      fail(at, "must be above knots[" + std::to_string(k - 1) + "] (knots strictly increasing)");
    }
  }
  // The summary fields beside the knots must agree with them when present.
  if (v.contains("intervals")) {
    const int intervals = integer(v["intervals"], here + ".intervals");
    if (intervals != a.intervals()) {
      fail(here + ".intervals", "is " + std::to_string(intervals) + " but knots has " +
                                    std::to_string(n) + " breakpoints (" +
                                    std::to_string(a.intervals()) + " intervals)");
    }
  }
  if (v.contains("lo") && number(v, "lo", here) != a.lo()) {
    fail(here + ".lo", "differs from knots[0]");
  }
  if (v.contains("hi") && number(v, "hi", here) != a.hi()) {
    fail(here + ".hi", "differs from the last of knots");
  }
  return a;
}

/// Runs a model constructor, turning its validation error into one naming the context.
template <class Make>
auto construct(const std::string& where, Make make) {
  try {
    return make();
  } catch (const std::invalid_argument& e) {
    fail(where, e.what());
  }
}

// ---------------------------------------------------------------- surfaces

json poly_json(const calib::PolynomialSurface& s) {
  const auto& p = s.params();
  json exps = json::array();
  for (const auto& e : p.exponents) {
    exps.push_back(p.use_temperature ? json::array({e[0], e[1], e[2]}) : json::array({e[0], e[1]}));
  }
  json scaling = {{"range_m", scaling_json(p.range_scaling)},
                  {"amplitude", scaling_json(p.amplitude_scaling)}};
  if (p.use_temperature) scaling["temperature_c"] = scaling_json(p.temperature_scaling);
  return {{"kind", "poly"},
          {"version", kVersion},
          {"order", p.order},
          {"use_temperature", p.use_temperature},
          {"exponents", exps},
          {"coefficients", p.coefficients},
          {"scaling", scaling},
          {"domain", domain_json(p.domain, p.use_temperature)},
          {"fit", fit_json(p.fit, false)}};
}

std::shared_ptr<const calib::CorrectionSurface> poly_from_json(const json& j,
                                                               const std::string& where) {
  calib::PolynomialSurfaceParams p;
  p.order = integer(field(j, "order", where), where + ".order");
  p.use_temperature = boolean(j, "use_temperature", where);
  const json& exps = field(j, "exponents", where);
  if (!exps.is_array()) fail(where + ".exponents", "expected an array");
  const std::size_t dims = p.use_temperature ? 3 : 2;
  for (std::size_t k = 0; k < exps.size(); ++k) {
    const std::string here = where + ".exponents[" + std::to_string(k) + "]";
    if (!exps[k].is_array() || exps[k].size() != dims) {
      fail(here, "expected " + std::to_string(dims) + " powers");
    }
    calib::MonomialExponents e{0, 0, 0};
    for (std::size_t d = 0; d < dims; ++d) e[d] = integer(exps[k][d], here);
    p.exponents.push_back(e);
  }
  p.coefficients = numbers(j, "coefficients", where);
  const json& scaling = field(j, "scaling", where);
  p.range_scaling = read_scaling(scaling, "range_m", where + ".scaling");
  p.amplitude_scaling = read_scaling(scaling, "amplitude", where + ".scaling");
  if (p.use_temperature)
    p.temperature_scaling = read_scaling(scaling, "temperature_c", where + ".scaling");
  p.domain = read_domain(j, p.use_temperature, where);
  p.fit = read_fit(j, false, where);
  return construct(where,
                   [&] { return std::make_shared<const calib::PolynomialSurface>(std::move(p)); });
}

json bspline_json(const calib::BSplineSurface& s) {
  const auto& p = s.params();
  json axes = {{"range_m", axis_json(p.range)}, {"amplitude", axis_json(p.amplitude)}};
  json shape = json::array({p.range.basis_count(), p.amplitude.basis_count()});
  if (p.use_temperature) {
    axes["temperature_c"] = axis_json(p.temperature);
    shape.push_back(p.temperature.basis_count());
  }
  json j = {{"kind", "bspline"},
            {"version", kVersion},
            {"degree", 3},
            {"use_temperature", p.use_temperature},
            {"axes", axes},
            {"shape", shape},
            {"coefficients", p.coefficients},
            {"domain", domain_json(p.domain, p.use_temperature)},
            {"fit", fit_json(p.fit, true)}};
  // Absent: amplitude (files written before the pulse-width axis read the same).
  if (p.intensity == ranging::IntensityInput::pulse_width) j["intensity"] = "pulse_width_ns";
  return j;
}

std::shared_ptr<const calib::CorrectionSurface> bspline_from_json(const json& j,
                                                                  const std::string& where) {
  calib::BSplineSurfaceParams p;
  if (integer(field(j, "degree", where), where + ".degree") != 3)
    fail(where + ".degree", "only cubic (3) is supported");
  p.use_temperature = boolean(j, "use_temperature", where);
  if (j.contains("intensity")) {
    const json& v = j["intensity"];
    if (v == "pulse_width_ns") {
      p.intensity = ranging::IntensityInput::pulse_width;
    } else if (v != "amplitude") {
      fail(where + ".intensity", "expected \"amplitude\" or \"pulse_width_ns\"");
    }
  }
  const json& axes = field(j, "axes", where);
  p.range = read_axis(axes, "range_m", where + ".axes");
  p.amplitude = read_axis(axes, "amplitude", where + ".axes");
  if (p.use_temperature) p.temperature = read_axis(axes, "temperature_c", where + ".axes");
  const json& shape = field(j, "shape", where);
  const std::size_t dims = p.use_temperature ? 3 : 2;
  const int want[3] = {p.range.basis_count(), p.amplitude.basis_count(),
                       p.temperature.basis_count()};
  if (!shape.is_array() || shape.size() != dims)
    fail(where + ".shape", "expected " + std::to_string(dims) + " extents");
  for (std::size_t d = 0; d < dims; ++d) {
    if (integer(shape[d], where + ".shape") != want[d]) {
      fail(where + ".shape[" + std::to_string(d) + "]",
           "must be the axis's knot intervals + 3 = " + std::to_string(want[d]) +
               " (the coefficient grid does not match the knots)");
    }
  }
  p.coefficients = numbers(j, "coefficients", where);
  p.domain = read_domain(j, p.use_temperature, where);
  p.fit = read_fit(j, true, where);
  return construct(where,
                   [&] { return std::make_shared<const calib::BSplineSurface>(std::move(p)); });
}

// -------------------------------------------------------------- confidence

json thesis_json(const calib::ThesisConfidence& m) {
  const auto& p = m.params();
  return {{"kind", "thesis"},
          {"version", kVersion},
          {"coefficients", p.coefficients},
          {"scaling", {{"amplitude", scaling_json(p.amplitude_scaling)}}},
          {"domain", {{"amplitude", interval(p.amplitude_min, p.amplitude_max)}}},
          {"floor_m2", p.floor_m2},
          {"floor_above_amplitude", p.floor_above_amplitude},
          {"fit", {{"rows", p.rows}}}};
}

std::shared_ptr<const calib::ConfidenceModel> thesis_from_json(const json& j,
                                                               const std::string& where) {
  calib::ThesisConfidenceParams p;
  p.coefficients = numbers(j, "coefficients", where);
  p.amplitude_scaling = read_scaling(field(j, "scaling", where), "amplitude", where + ".scaling");
  read_interval(field(j, "domain", where), "amplitude", where + ".domain", p.amplitude_min,
                p.amplitude_max);
  p.floor_m2 = number(j, "floor_m2", where);
  if (j.contains("floor_above_amplitude"))  // optional: files written before it floor everywhere
    p.floor_above_amplitude = number(j, "floor_above_amplitude", where);
  p.rows = count(field(j, "fit", where), "rows", where + ".fit");
  return construct(where,
                   [&] { return std::make_shared<const calib::ThesisConfidence>(std::move(p)); });
}

json calibrated_json(const calib::CalibratedConfidence& m) {
  const auto& p = m.params();
  json exps = json::array();
  for (const auto& e : p.exponents) exps.push_back(json::array({e[0], e[1]}));
  json out = {{"kind", "calibrated"},
              {"version", kVersion},
              {"log_amplitude", p.log_amplitude},
              {"exponents", exps},
              {"coefficients", p.coefficients},
              {"scaling",
               {{"amplitude", scaling_json(p.amplitude_scaling)},
                {"range_m", scaling_json(p.range_scaling)}}},
              {"domain", domain_json(p.domain, false)},
              {"bands", {{"coordinate", p.band_coordinate}, {"scale", p.band_scale}}},
              {"target_coverage_2sigma", p.target_coverage_2sigma},
              {"fit", {{"rows", p.rows}, {"coverage_2sigma", p.fit_coverage_2sigma}}}};
  // Written only when used, so files of the amplitude-only form stay as they were.
  if (p.intensity == ranging::IntensityInput::pulse_width) out["intensity"] = "pulse_width_ns";
  if (!p.systematic_coefficients.empty()) {
    json sys_exps = json::array();
    for (const auto& e : p.systematic_exponents) sys_exps.push_back(json::array({e[0], e[1]}));
    out["systematic"] = {{"exponents", sys_exps}, {"coefficients", p.systematic_coefficients}};
  }
  return out;
}

std::shared_ptr<const calib::ConfidenceModel> calibrated_from_json(const json& j,
                                                                   const std::string& where) {
  calib::CalibratedConfidenceParams p;
  p.log_amplitude = boolean(j, "log_amplitude", where);
  const auto read_exponents = [](const json& parent, const std::string& at) {
    const json& exps = field(parent, "exponents", at);
    if (!exps.is_array()) fail(at + ".exponents", "expected an array");
    std::vector<std::array<int, 2>> out;
    for (std::size_t k = 0; k < exps.size(); ++k) {
      const std::string here = at + ".exponents[" + std::to_string(k) + "]";
      if (!exps[k].is_array() || exps[k].size() != 2) fail(here, "expected 2 powers");
      out.push_back({integer(exps[k][0], here), integer(exps[k][1], here)});
    }
    return out;
  };
  p.exponents = read_exponents(j, where);
  p.coefficients = numbers(j, "coefficients", where);
  if (j.contains("systematic")) {
    const json& sys = j["systematic"];
    if (!sys.is_object()) fail(where + ".systematic", "expected an object");
    p.systematic_exponents = read_exponents(sys, where + ".systematic");
    p.systematic_coefficients = numbers(sys, "coefficients", where + ".systematic");
  }
  if (j.contains("intensity")) {
    const json& v = j["intensity"];
    if (v == "pulse_width_ns")
      p.intensity = ranging::IntensityInput::pulse_width;
    else if (v != "amplitude")
      fail(where + ".intensity", "expected \"amplitude\" or \"pulse_width_ns\"");
  }
  const json& scaling = field(j, "scaling", where);
  p.amplitude_scaling = read_scaling(scaling, "amplitude", where + ".scaling");
  p.range_scaling = read_scaling(scaling, "range_m", where + ".scaling");
  p.domain = read_domain(j, false, where);
  const json& bands = field(j, "bands", where);
  p.band_coordinate = numbers(bands, "coordinate", where + ".bands");
  p.band_scale = numbers(bands, "scale", where + ".bands");
  p.target_coverage_2sigma = number(j, "target_coverage_2sigma", where);
  const json& fit = field(j, "fit", where);
  p.rows = count(fit, "rows", where + ".fit");
  p.fit_coverage_2sigma = number(fit, "coverage_2sigma", where + ".fit");
  return construct(
      where, [&] { return std::make_shared<const calib::CalibratedConfidence>(std::move(p)); });
}

std::string kind_of(const json& j, const std::string& where) {
  const json& k = field(j, "kind", where);
  if (!k.is_string()) fail(where + ".kind", "expected a string");
  return k.get<std::string>();
}

}  // namespace

nlohmann::json surface_to_json(const calib::CorrectionSurface& surface) {
  if (const auto* poly = dynamic_cast<const calib::PolynomialSurface*>(&surface))
    return poly_json(*poly);
  if (const auto* spline = dynamic_cast<const calib::BSplineSurface*>(&surface))
    return bspline_json(*spline);
  throw std::invalid_argument("surface_to_json: no JSON form for a surface of kind \"" +
                              surface.kind() + "\"");
}

std::shared_ptr<const calib::CorrectionSurface> surface_from_json(const nlohmann::json& j,
                                                                  const std::string& context) {
  const std::string kind = kind_of(j, context);
  if (kind == "poly") {
    check_kind(j, "poly", context);
    return poly_from_json(j, context);
  }
  if (kind == "bspline") {
    check_kind(j, "bspline", context);
    return bspline_from_json(j, context);
  }
  fail(context + ".kind",
       "unknown surface kind \"" + kind + "\" (expected \"poly\" or \"bspline\")");
}

nlohmann::json confidence_to_json(const calib::ConfidenceModel& model) {
  if (const auto* thesis = dynamic_cast<const calib::ThesisConfidence*>(&model))
    return thesis_json(*thesis);
  if (const auto* cal = dynamic_cast<const calib::CalibratedConfidence*>(&model))
    return calibrated_json(*cal);
  throw std::invalid_argument("confidence_to_json: no JSON form for a confidence model of kind \"" +
                              model.kind() + "\"");
}

std::shared_ptr<const calib::ConfidenceModel> confidence_from_json(const nlohmann::json& j,
                                                                   const std::string& context) {
  const std::string kind = kind_of(j, context);
  if (kind == "thesis") {
    check_kind(j, "thesis", context);
    return thesis_from_json(j, context);
  }
  if (kind == "calibrated") {
    check_kind(j, "calibrated", context);
    return calibrated_from_json(j, context);
  }
  fail(context + ".kind",
       "unknown confidence kind \"" + kind + "\" (expected \"thesis\" or \"calibrated\")");
}

}  // namespace tofkit::io
