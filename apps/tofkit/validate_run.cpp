#include "validate_run.hpp"

#include <fmt/format.h>
#include <unistd.h>

#include <algorithm>
#include <climits>
#include <cmath>
#include <map>
#include <sstream>

#include "html.hpp"
#include "tofkit/io/atomic_file.hpp"
#include "tofkit/io/config_file.hpp"
#include "tofkit/io/plot.hpp"

#ifndef TOFKIT_SOURCE_REFERENCE_DIR
#define TOFKIT_SOURCE_REFERENCE_DIR ""
#endif

namespace tofkit::app {
namespace {

namespace fs = std::filesystem;
using experiments::ValidationMethod;
using experiments::ValidationOutcome;
using experiments::ValidationResult;
using experiments::ValidationRole;

nlohmann::json number(double v) {
  return std::isfinite(v) ? nlohmann::json(v) : nlohmann::json(nullptr);
}

std::string csv_field(const std::string& s) {
  if (s.find_first_of(",\"\n\r") == std::string::npos) return s;
  std::string out = "\"";
  for (const char c : s) out += c == '"' ? std::string("\"\"") : std::string(1, c);
  return out + "\"";
}

std::string fmt_number(double v) {
  return std::isfinite(v) ? fmt::format("{:.6g}", v) : std::string();
}

/// A file-name-safe stem from a figure and a quantity.
std::string stem_of(const std::string& s) {
  std::string out;
  for (const char c : s) out += std::isalnum(static_cast<unsigned char>(c)) ? c : '_';
  return out;
}

}  // namespace

fs::path default_validation_matrix() {
  std::vector<fs::path> tried;
  std::error_code ec;
  char buf[PATH_MAX];
  const ssize_t n = ::readlink("/proc/self/exe", buf, sizeof buf - 1);
  if (n > 0) {
    const fs::path exe_dir = fs::path(std::string(buf, static_cast<std::size_t>(n))).parent_path();
    for (const fs::path& p : {exe_dir / ".." / "reference", exe_dir / "reference",
                              exe_dir / ".." / "share" / "tofkit" / "reference"})
      tried.push_back(p / "validation_matrix.csv");
  }
  if (std::string(TOFKIT_SOURCE_REFERENCE_DIR).size() > 0)
    tried.push_back(fs::path(TOFKIT_SOURCE_REFERENCE_DIR) / "validation_matrix.csv");
  for (const auto& p : tried)
    if (fs::is_regular_file(p, ec)) return p.lexically_normal();
  std::string where;
  for (const auto& p : tried) where += (where.empty() ? "" : ", ") + p.lexically_normal().string();
  throw std::runtime_error("no reference/validation_matrix.csv found (looked at " + where +
                           "); give one with --matrix FILE");
}

experiments::DeviceForPreset device_selection(const AppContext& ctx) {
  if (ctx.preset.empty() && !ctx.config_file) {
    return [overrides = ctx.overrides](const std::string& preset) {
      return std::optional<device::DeviceConfig>(
          io::load_device_config(preset, std::nullopt, overrides));
    };
  }
  const device::DeviceConfig config = ctx.load_config();
  return [config](const std::string& preset) {
    return preset == config.name ? std::optional<device::DeviceConfig>(config) : std::nullopt;
  };
}

nlohmann::json validation_summary_json(const experiments::ValidationSummary& s) {
  return {{"rows", s.rows},
          {"in_band", s.in_band},
          {"in_band_share", number(s.in_band_share())},
          {"outside_twice_band", s.outside_twice},
          {"held_out_rows", s.held_out},
          {"held_out_in_band", s.held_out_in_band},
          {"held_out_in_band_share", number(s.held_out_in_band_share())},
          {"calibration_rows", s.calibration},
          {"calibration_in_band", s.calibration_in_band},
          {"calibration_in_band_share", number(s.calibration_in_band_share())},
          {"tofkit_rows", s.tofkit_rows},
          {"tofkit_in_band", s.tofkit_in_band},
          {"rows_not_run", s.not_run}};
}

nlohmann::json validation_json(const ValidationResult& result, const std::string& matrix,
                               std::uint64_t seed) {
  nlohmann::json rows = nlohmann::json::array();
  for (const auto& o : result.rows) {
    rows.push_back({{"id", o.row.id},
                    {"document", o.row.document},
                    {"figure", o.row.figure},
                    {"quantity", o.row.quantity},
                    {"conditions", o.row.conditions},
                    {"value", o.row.value},
                    {"band", o.row.band_width()},
                    {"band_reason", o.row.band_reason},
                    {"unit", o.row.unit},
                    {"preset", o.row.preset},
                    {"role", std::string(to_string(o.row.role))},
                    {"method", std::string(to_string(o.row.method))},
                    {"run", o.run},
                    {"twin", number(o.twin)},
                    {"in_band", o.in_band},
                    {"outside_twice_band", o.run && o.outside_twice},
                    {"error", o.error}});
  }
  return {{"matrix", matrix},
          {"seed", seed},
          {"devices", result.devices},
          {"summary", validation_summary_json(result.summary)},
          {"rows", rows}};
}

nlohmann::json validation_demo_json(const ValidationResult& result, const std::string& matrix) {
  nlohmann::json by_preset = nlohmann::json::object();
  for (const auto& o : result.rows)
    if (!by_preset.contains(o.row.preset))
      by_preset[o.row.preset] =
          validation_summary_json(experiments::summarize_validation(result.rows, o.row.preset));
  return {{"matrix", matrix},
          {"summary", validation_summary_json(result.summary)},
          {"by_preset", by_preset}};
}

std::string validation_section_html(const ValidationResult& result, const std::string& matrix) {
  auto pct = [](double v) { return std::isfinite(v) ? fmt::format("{:.1f} %", 100 * v) : "-"; };
  std::vector<std::string> presets;
  for (const auto& o : result.rows)
    if (std::find(presets.begin(), presets.end(), o.row.preset) == presets.end())
      presets.push_back(o.row.preset);
  std::string h =
      "<h2>Validation matrix (<code>tofkit validate</code>)</h2>\n<p>Every row of <code>" +
      html_escape(matrix) +
      "</code> run on the twin: a figure of a document, the twin's value and the band. "
      "Held-out rows were never used to choose a twin parameter. <code>tofkit validate --out "
      "DIR</code> writes the full table and a plot per figure.</p>\n<table><tr><th>preset</th>"
      "<th>rows</th><th>in band</th><th>outside twice the band</th><th>held out in band</th>"
      "<th>calibration in band</th></tr>\n";
  auto line = [&](const std::string& name, const experiments::ValidationSummary& s) {
    h += fmt::format(
        "<tr><td>{}</td><td>{}</td><td>{} ({})</td><td>{}</td><td>{} of {} ({})</td><td>{} of {} "
        "({})</td></tr>\n",
        html_escape(name), s.rows, s.in_band, pct(s.in_band_share()), s.outside_twice,
        s.held_out_in_band, s.held_out, pct(s.held_out_in_band_share()), s.calibration_in_band,
        s.calibration, pct(s.calibration_in_band_share()));
  };
  for (const auto& p : presets) line(p, experiments::summarize_validation(result.rows, p));
  line("all", result.summary);
  return h + "</table>\n";
}

void write_validation_outputs(const fs::path& dir, const ValidationResult& result,
                              const std::string& matrix, std::uint64_t seed, bool render) {
  io::create_output_directories(dir);
  io::write_file_atomically(dir / "validation.json",
                            validation_json(result, matrix, seed).dump(2) + "\n");

  std::string csv =
      "id,document,figure,quantity,conditions,unit,preset,role,method,value,band,twin,in_band,"
      "outside_twice_band,error\n";
  for (const auto& o : result.rows) {
    if (!o.run) continue;
    csv +=
        fmt::format("{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}\n", csv_field(o.row.id),
                    csv_field(o.row.document), csv_field(o.row.figure), csv_field(o.row.quantity),
                    csv_field(o.row.conditions), csv_field(o.row.unit), csv_field(o.row.preset),
                    to_string(o.row.role), to_string(o.row.method), fmt_number(o.row.value),
                    fmt_number(o.row.band_width()), fmt_number(o.twin), o.in_band ? 1 : 0,
                    o.outside_twice ? 1 : 0, csv_field(o.error));
  }
  io::write_file_atomically(dir / "validation.csv", csv);

  // One plot per (figure, quantity): the document's points and band, the twin's.
  std::vector<std::pair<std::string, std::string>> groups;
  std::map<std::pair<std::string, std::string>, std::vector<const ValidationOutcome*>> members;
  for (const auto& o : result.rows) {
    if (!o.run) continue;
    const auto key = std::pair{o.row.figure, o.row.quantity};
    if (!members.contains(key)) groups.push_back(key);
    members[key].push_back(&o);
  }
  const fs::path plots = dir / "plots";
  io::create_output_directories(plots);
  std::ostringstream body;
  const auto& s = result.summary;
  auto pct = [](double v) { return std::isfinite(v) ? fmt::format("{:.1f} %", 100 * v) : "-"; };
  for (const auto& key : groups) {
    const auto& list = members[key];
    std::string x_name;
    bool numeric = true;
    for (const auto* o : list) {
      std::string name;
      if (!std::isfinite(experiments::plot_abscissa(o->row, &name))) numeric = false;
      if (x_name.empty()) x_name = name;
    }
    io::PlotSpec spec;
    spec.name = "validation_" + stem_of(key.first + "_" + key.second);
    spec.title = key.first + ": " + key.second;
    std::replace(spec.title.begin(), spec.title.end(), '_', ' ');  // gnuplot's enhanced text
    spec.x_label = numeric ? x_name : "row (see the table)";
    std::replace(spec.x_label.begin(), spec.x_label.end(), '_', ' ');
    spec.y_label = list.front()->row.unit.empty() ? "value" : list.front()->row.unit;
    io::PlotSeries doc{"document", {}, {}, "points pt 7 ps 1.2 lc rgb 'black'", false};
    io::PlotSeries lo{"document - band", {}, {}, "points pt 2 ps 0.8 lc rgb 'gray'", false};
    io::PlotSeries hi{"document + band", {}, {}, "points pt 2 ps 0.8 lc rgb 'gray'", false};
    io::PlotSeries twin{"twin (document's method)", {}, {}, "points pt 5 ps 1 lc rgb 'red'", false};
    io::PlotSeries own{"twin (tofkit's method)", {}, {}, "points pt 9 ps 1 lc rgb 'blue'", false};
    body << "<h3>" << html_escape(key.first) << " &mdash; <code>" << html_escape(key.second)
         << "</code></h3>\n<table><tr><th>id</th><th>conditions</th><th>role</th><th>method</th>"
            "<th>document</th><th>band &plusmn;</th><th>twin</th><th>in band</th><th>band "
            "reason</th></tr>\n";
    for (std::size_t k = 0; k < list.size(); ++k) {
      const auto& o = *list[k];
      const double x = numeric ? experiments::plot_abscissa(o.row) : static_cast<double>(k + 1);
      const double b = o.row.band_width();
      if (o.row.method == ValidationMethod::kDocument) {
        doc.x.push_back(x);
        doc.y.push_back(o.row.value);
        lo.x.push_back(x);
        lo.y.push_back(o.row.value - b);
        hi.x.push_back(x);
        hi.y.push_back(o.row.value + b);
      }
      if (std::isfinite(o.twin)) {
        auto& series = o.row.method == ValidationMethod::kDocument ? twin : own;
        series.x.push_back(x);
        series.y.push_back(o.twin);
      }
      const std::string verdict = o.in_band ? "yes" : (o.outside_twice ? "NO (&gt; 2x)" : "no");
      body << fmt::format(
          "<tr><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td>"
          "<td class=\"{}\">{}</td><td>{}</td></tr>\n",
          html_escape(o.row.id), html_escape(o.row.conditions), to_string(o.row.role),
          to_string(o.row.method), fmt_number(o.row.value), fmt_number(b),
          std::isfinite(o.twin) ? fmt_number(o.twin) : html_escape("- (" + o.error + ")"),
          o.in_band ? "ok" : "out", verdict, html_escape(o.row.band_reason));
    }
    body << "</table>\n";
    spec.series = {doc, lo, hi};
    if (!twin.x.empty()) spec.series.push_back(twin);
    if (!own.x.empty()) spec.series.push_back(own);
    const auto files = io::write_plot(plots, spec, render);
    const auto file = "plots/" + (files.png ? *files.png : files.script).filename().string();
    if (file.ends_with(".png"))
      body << "<figure><img src=\"" << file << "\" alt=\"" << html_escape(spec.title)
           << "\"></figure>\n";
    else
      body << "<p>(gnuplot not installed: run <code>gnuplot " << file << "</code>)</p>\n";
  }

  std::ostringstream h;
  h << "<!doctype html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
    << "<title>tofkit validate</title><style>"
    << "body{font-family:sans-serif;max-width:1100px;margin:2em auto;line-height:1.4}"
    << "table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #bbb;padding:.3em .6em;"
    << "text-align:right}th{background:#eee}td:first-child{text-align:left}"
    << "td:last-child{text-align:left;font-size:85%}td.out{background:#fdd}td.ok{background:#dfd}"
    << "img{max-width:100%;border:1px solid #ddd}figure{margin:1em 0 2.5em}</style></head><body>\n"
    << "<h1>tofkit validate: the twin against the documents</h1>\n"
    << "<p>Matrix <code>" << html_escape(matrix) << "</code>, seed " << seed
    << ", devices: " << html_escape(fmt::format("{}", fmt::join(result.devices, ", "))) << ".</p>\n"
    << "<table><tr><th>rows (document's methods)</th><th>in band</th><th>outside twice the "
       "band</th><th>held out in band</th><th>calibration in band</th><th>tofkit's methods "
       "(not counted)</th></tr>\n"
    << fmt::format(
           "<tr><td>{}</td><td>{} ({})</td><td>{}</td><td>{} of {} ({})</td><td>{} of {} ({})"
           "</td><td>{} rows, {} in band</td></tr></table>\n",
           s.rows, s.in_band, pct(s.in_band_share()), s.outside_twice, s.held_out_in_band,
           s.held_out, pct(s.held_out_in_band_share()), s.calibration_in_band, s.calibration,
           pct(s.calibration_in_band_share()), s.tofkit_rows, s.tofkit_in_band)
    << "<p>A row is in band when |twin - document| &le; band. Calibration rows were used to "
       "choose a twin parameter; held-out rows never were. Rows of tofkit's own methods are "
       "shown beside the document's (blue) and not counted.</p>\n"
    << body.str() << "</body></html>\n";
  io::write_file_atomically(dir / "validation.html", h.str());
}

}  // namespace tofkit::app
