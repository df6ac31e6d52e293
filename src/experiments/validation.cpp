#include "tofkit/experiments/validation.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <set>

#include "validation_quantities.hpp"

namespace tofkit::experiments {
namespace {

using validation_detail::quantities;

std::string trim(std::string_view s) {
  const auto b = s.find_first_not_of(" \t\r\n");
  if (b == std::string_view::npos) return {};
  const auto e = s.find_last_not_of(" \t\r\n");
  return std::string(s.substr(b, e - b + 1));
}

double share(std::size_t part, std::size_t whole) {
  return whole == 0 ? ranging::kNaN : static_cast<double>(part) / static_cast<double>(whole);
}

std::string format_value(double v) {
  if (!std::isfinite(v)) return "-";
  char buf[32];
  const double a = std::abs(v);
  if (a != 0 && (a < 1e-3 || a >= 1e5))
    std::snprintf(buf, sizeof buf, "%.3e", v);
  else if (a < 0.1)
    std::snprintf(buf, sizeof buf, "%.5f", v);
  else
    std::snprintf(buf, sizeof buf, "%.4g", v);
  return buf;
}

}  // namespace

std::string_view to_string(ValidationRole role) {
  return role == ValidationRole::kCalibration ? "calibration" : "held_out";
}

std::string_view to_string(ValidationMethod method) {
  return method == ValidationMethod::kDocument ? "document" : "tofkit";
}

double ValidationRow::band_width() const {
  return band_relative ? band / 100.0 * std::abs(value) : band;
}

std::map<std::string, std::string> parse_conditions(std::string_view text) {
  std::map<std::string, std::string> out;
  std::size_t start = 0;
  while (start <= text.size()) {
    const auto end = std::min(text.find(';', start), text.size());
    const std::string part = trim(text.substr(start, end - start));
    start = end + 1;
    if (part.empty()) {
      if (end >= text.size()) break;
      continue;
    }
    const auto eq = part.find('=');
    if (eq == std::string::npos) throw std::invalid_argument("'" + part + "' is not key=value");
    const std::string key = trim(std::string_view(part).substr(0, eq));
    const std::string value = trim(std::string_view(part).substr(eq + 1));
    if (key.empty() || value.empty())
      throw std::invalid_argument("'" + part + "' needs a key and a value");
    if (!out.emplace(key, value).second)
      throw std::invalid_argument("key '" + key + "' is given twice");
  }
  return out;
}

const std::vector<QuantityInfo>& validation_quantities() {
  static const std::vector<QuantityInfo> list = [] {
    std::vector<QuantityInfo> v;
    for (const auto& [id, q] : quantities()) v.push_back(q.info);
    return v;
  }();
  return list;
}

void check_validation_rows(std::span<const ValidationRow> rows) {
  std::set<std::string> ids;
  for (const auto& row : rows) {
    auto fail = [&](const std::string& column, const std::string& why) {
      throw ValidationMatrixError(row.line, column, "row " + row.id + ": " + why);
    };
    if (row.id.empty()) fail("id", "empty id");
    if (!ids.insert(row.id).second) fail("id", "id '" + row.id + "' appears twice");
    const auto it = quantities().find(row.quantity);
    if (it == quantities().end())
      fail("quantity", "unknown quantity '" + row.quantity +
                           "' (see docs/validation.md or "
                           "`tofkit validate --list`)");
    const auto& info = it->second.info;
    for (const auto& [key, value] : row.parameters) {
      if (const auto f = info.fixed.find(key); f != info.fixed.end()) {
        char* end = nullptr;
        const double v = std::strtod(value.c_str(), &end);
        if (!(end && *end == '\0' &&
              std::abs(v - f->second) <= 1e-3 * std::abs(f->second) + 1e-9)) {
          char buf[64];
          std::snprintf(buf, sizeof buf, "%g", f->second);
          fail("conditions", "quantity " + row.quantity + " runs its protocol at " + key + "=" +
                                 buf + ", not " + value);
        }
        continue;
      }
      if (std::find(info.parameters.begin(), info.parameters.end(), key) == info.parameters.end()) {
        std::string keys;
        for (const auto& k : info.parameters) keys += (keys.empty() ? "" : ", ") + k;
        fail("conditions", "quantity " + row.quantity + " takes no condition '" + key +
                               "' (it takes: " + (keys.empty() ? "none" : keys) + ")");
      }
    }
    for (const auto& key : info.required)
      if (!row.parameters.contains(key))
        fail("conditions", "quantity " + row.quantity + " needs the condition '" + key + "'");
    if (row.method == ValidationMethod::kTofkit && !info.tofkit_method)
      fail("method", "quantity " + row.quantity + " has no tofkit method (method = document)");
    if (!std::isfinite(row.value)) fail("value", "the document's value must be a finite number");
    if (!(row.band > 0) || !std::isfinite(row.band)) fail("band", "the band must be > 0");
    if (row.preset.empty()) fail("preset", "empty preset");
    if (it->second.check) it->second.check(row);
  }
}

double plot_abscissa(const ValidationRow& row, std::string* name) {
  const auto it = quantities().find(row.quantity);
  if (it == quantities().end()) return ranging::kNaN;
  for (const auto& key : it->second.info.parameters) {
    const auto p = row.parameters.find(key);
    if (p == row.parameters.end()) continue;
    char* end = nullptr;
    const double v = std::strtod(p->second.c_str(), &end);
    if (end && *end == '\0' && std::isfinite(v)) {
      if (name) *name = key;
      return v;
    }
  }
  return ranging::kNaN;
}

ValidationResult run_validation(std::span<const ValidationRow> rows,
                                const DeviceForPreset& device_for_preset,
                                const ValidationOptions& options) {
  check_validation_rows(rows);
  ValidationResult result;
  // One context (device + cached experiment runs) per preset, in matrix order.
  std::vector<std::string> presets;
  std::map<std::string, std::optional<device::DeviceConfig>> devices;
  std::size_t selected = 0;
  for (const auto& row : rows) {
    if (!row.id.starts_with(options.only)) continue;
    ++selected;
    if (devices.contains(row.preset)) continue;
    devices[row.preset] = device_for_preset(row.preset);
    presets.push_back(row.preset);
  }
  std::map<std::string, std::unique_ptr<validation_detail::QuantityContext>> contexts;
  for (const auto& p : presets) {
    if (!devices[p]) continue;
    result.devices.push_back(devices[p]->name);
    contexts[p] = std::make_unique<validation_detail::QuantityContext>(*devices[p], options.seed);
  }
  std::size_t done = 0;
  for (const auto& row : rows) {
    ValidationOutcome o;
    o.row = row;
    const auto ctx = contexts.find(row.preset);
    if (row.id.starts_with(options.only) && ctx != contexts.end()) {
      o.run = true;
      if (options.progress) options.progress(row.id, share(done, selected));
      ++done;
      try {
        o.twin = quantities().at(row.quantity).compute(*ctx->second, row.parameters, row.method);
      } catch (const std::exception& e) {
        o.error = e.what();
      }
      const double deviation = std::abs(o.twin - row.value);
      o.in_band = std::isfinite(o.twin) && deviation <= row.band_width();
      o.outside_twice = !(std::isfinite(o.twin) && deviation <= 2 * row.band_width());
      if (o.error.empty() && !std::isfinite(o.twin)) o.error = "the twin gives no value";
    }
    result.rows.push_back(std::move(o));
  }
  result.summary = summarize_validation(result.rows);
  if (options.progress) options.progress("done", 1.0);
  return result;
}

ValidationSummary summarize_validation(std::span<const ValidationOutcome> outcomes,
                                       std::string_view preset) {
  ValidationSummary s;
  for (const auto& o : outcomes) {
    if (!preset.empty() && o.row.preset != preset) continue;
    if (!o.run) {
      ++s.not_run;
    } else if (o.row.method == ValidationMethod::kTofkit) {
      ++s.tofkit_rows;
      s.tofkit_in_band += o.in_band;
    } else {
      ++s.rows;
      s.in_band += o.in_band;
      s.outside_twice += o.outside_twice;
      if (o.row.role == ValidationRole::kHeldOut) {
        ++s.held_out;
        s.held_out_in_band += o.in_band;
      } else {
        ++s.calibration;
        s.calibration_in_band += o.in_band;
      }
    }
  }
  return s;
}

double ValidationSummary::in_band_share() const {
  return share(in_band, rows);
}
double ValidationSummary::held_out_in_band_share() const {
  return share(held_out_in_band, held_out);
}
double ValidationSummary::calibration_in_band_share() const {
  return share(calibration_in_band, calibration);
}

std::string ValidationResult::table() const {
  std::string out;
  char line[512];
  std::snprintf(line, sizeof line, "%-38s %-18s %-9s %11s %11s %11s  %-8s %s\n", "id", "figure",
                "role", "document", "twin", "band +-", "in band", "method");
  out += line;
  for (const auto& o : rows) {
    if (!o.run) continue;
    const std::string verdict = o.in_band ? "yes" : (o.outside_twice ? "NO (>2x)" : "no");
    std::snprintf(line, sizeof line, "%-38s %-18s %-9s %11s %11s %11s  %-8s %s\n", o.row.id.c_str(),
                  o.row.figure.substr(0, 18).c_str(),
                  o.row.role == ValidationRole::kHeldOut ? "held out" : "calib.",
                  format_value(o.row.value).c_str(), format_value(o.twin).c_str(),
                  format_value(o.row.band_width()).c_str(), verdict.c_str(),
                  std::string(to_string(o.row.method)).c_str());
    out += line;
    if (!o.error.empty()) out += "    (" + o.error + ")\n";
  }
  return out;
}

std::string ValidationResult::summary_text() const {
  const auto& s = summary;
  auto pct = [](double v) {
    char b[16];
    std::snprintf(b, sizeof b, "%.1f %%", 100 * v);
    return std::isfinite(v) ? std::string(b) : std::string("-");
  };
  char line[512];
  std::string out;
  std::snprintf(line, sizeof line,
                "rows (document's methods): %zu; in band %zu (%s); outside twice the band %zu\n",
                s.rows, s.in_band, pct(s.in_band_share()).c_str(), s.outside_twice);
  out += line;
  std::snprintf(line, sizeof line, "held-out rows in band: %zu of %zu (%s)\n", s.held_out_in_band,
                s.held_out, pct(s.held_out_in_band_share()).c_str());
  out += line;
  std::snprintf(line, sizeof line, "calibration rows in band: %zu of %zu (%s)\n",
                s.calibration_in_band, s.calibration, pct(s.calibration_in_band_share()).c_str());
  out += line;
  if (s.tofkit_rows > 0) {
    std::snprintf(line, sizeof line,
                  "tofkit's own methods (beside them, not counted): %zu rows, %zu in the "
                  "document's band\n",
                  s.tofkit_rows, s.tofkit_in_band);
    out += line;
  }
  if (s.not_run > 0) {
    std::snprintf(line, sizeof line, "rows not run (other preset or --only): %zu\n", s.not_run);
    out += line;
  }
  return out;
}

}  // namespace tofkit::experiments
