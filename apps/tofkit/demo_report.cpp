#include "demo_report.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <sstream>

#include "html.hpp"
#include "tofkit/experiments/paper_reference.hpp"
#include "tofkit/io/atomic_file.hpp"
#include "tofkit/io/plot.hpp"
#include "tofkit/ranging/pipeline.hpp"

namespace tofkit::app {
namespace {

using io::PlotSeries;
using io::PlotSpec;

const ranging::Step* find_step(const ranging::Pipeline& p, ranging::StepKind kind) {
  for (const auto& s : p.steps())
    if (s.kind == kind) return &s;
  return nullptr;
}

double step_value(const ranging::Step* step, double x) {
  return step ? step->function(x) : 0.0;
}

/// The thesis protocol's Fig. 4.18 table and confidence coverage, from
/// summary.json's "thesis" entry, as HTML tables (inches, like the thesis).
std::string thesis_tables_html(const nlohmann::json& summary) {
  if (!summary.contains("thesis")) return {};
  const auto& t = summary["thesis"];
  const auto num = [](const nlohmann::json& v, double scale, int digits) -> std::string {
    return v.is_number() ? fmt::format("{:.{}f}", v.get<double>() * scale, digits) : "";
  };
  const double in = 1.0 / 25.4, in2 = in * in;
  std::string h =
      "<table><tr><th>model</th><th>bias (in)</th><th>variance (in&sup2;)</th><th>RMS "
      "(in)</th><th>RMS impr. (%)</th><th>rows out of domain</th></tr>\n";
  for (const auto& r : t.value("rows", nlohmann::json::array())) {
    h +=
        fmt::format("<tr><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr>\n",
                    html_escape(r.value("model", "")), num(r["bias_mm"], in, 4),
                    num(r["variance_mm2"], in2, 5), num(r["rms_mm"], in, 4),
                    num(r["rms_improvement_pct"], 1, 1), num(r["test_rows_out_of_domain"], 1, 0));
  }
  h += "</table>\n<table><tr><th>confidence model</th><th>within 1 sigma</th><th>within 2 "
       "sigma</th><th>mean sigma (in)</th></tr>\n";
  const auto confidence = t.value("confidence", nlohmann::json::object());
  for (const auto& [name, c] : confidence.items()) {
    h += fmt::format("<tr><td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr>\n", html_escape(name),
                     num(c["within_1_sigma"], 100, 1), num(c["within_2_sigma"], 100, 1),
                     num(c["mean_sigma_mm"], in, 4));
  }
  return h + "</table>\n";
}

}  // namespace

std::vector<Figure> write_demo_plots(const std::filesystem::path& dir,
                                     const experiments::PaperStudyResult& r, bool render) {
  const auto plots = dir / "plots";
  io::create_output_directories(plots);
  std::vector<Figure> figures;
  auto emit = [&](const PlotSpec& spec, const std::string& caption) {
    const auto files = io::write_plot(plots, spec, render);
    const auto file = files.png ? *files.png : files.script;
    figures.push_back({"plots/" + file.filename().string(), caption});
  };
  const auto& pipeline = r.fit.pipeline;
  const auto* gray = find_step(pipeline, ranging::StepKind::kGrayvalue);
  const auto* temp = find_step(pipeline, ranging::StepKind::kTemperature);

  {  // Figure 3: SNR and received power vs distance.
    PlotSpec s{"fig3_link_budget",
               "Link budget, rho = 0.1 (paper Fig. 3)",
               "distance (m)",
               "SNR",
               "received power (W)",
               false,
               true,
               true,
               {}};
    PlotSeries snr{"SNR", {}, {}, "linespoints pt 7 ps 0.5", false};
    PlotSeries pr{"received power", {}, {}, "lines dt 2", true};
    PlotSeries ten{"SNR = 10", {0.5, 15.0}, {10.0, 10.0}, "lines lc rgb 'gray'", false};
    for (const auto& p : r.link_budget) {
      snr.x.push_back(p.distance_m);
      snr.y.push_back(p.snr);
      pr.x.push_back(p.distance_m);
      pr.y.push_back(p.received_power_w);
    }
    s.series = {snr, pr, ten};
    emit(s, fmt::format(
                "SNR and received power vs distance in Table 1's sunlight; SNR = 10 at {:.2f} m "
                "(paper: about 10 m).",
                r.range_at_snr10_m));
  }
  {  // Figure 6: offset vs pulse width with the fitted hinge.
    PlotSpec s{"fig6_offset_vs_pulse_width",
               "Offset vs echo pulse width (paper Fig. 6)",
               "echo pulse width (ns)",
               "true - c t / 2 (mm)",
               "",
               false,
               false,
               false,
               {}};
    PlotSeries pts{"calibration plates", {}, {}, "points pt 7 ps 0.4", false};
    double lo = 1e300, hi = -1e300;
    for (std::size_t i = 0; i < r.calibration.size(); ++i) {
      const auto& rec = r.calibration[i];
      if (!rec.raw.has_echo() || rec.truth.ambient_c != r.calibration.front().truth.ambient_c)
        continue;
      const double e = rec.truth.distance_m - pipeline.start_distance_m(rec.raw) -
                       step_value(temp, rec.raw.temperature_c);
      pts.x.push_back(rec.raw.pulse_width_ns);
      pts.y.push_back(1e3 * e);
      lo = std::min(lo, rec.raw.pulse_width_ns);
      hi = std::max(hi, rec.raw.pulse_width_ns);
    }
    PlotSeries fit{"fitted hinge", {}, {}, "lines lw 2", false};
    for (int k = 0; k <= 400 && gray; ++k) {
      const double x = lo + (hi - lo) * k / 400.0;
      fit.x.push_back(x);
      fit.y.push_back(1e3 * (r.fit.offset_m + gray->function(x)));
    }
    s.series = {pts, fit};
    std::string knots;
    if (r.fit.grayvalue)
      for (double k : r.fit.grayvalue->knots) knots += fmt::format("{:.2f} ", k);
    emit(s, fmt::format("Offset (true minus raw distance) vs echo pulse width for plates of "
                        "2-99 % reflectance, with the fitted continuous hinge; knots found at "
                        "{}ns (paper: one inflection at 6.5 ns, found by inspection).",
                        knots));
  }
  {  // Figure 7: gray-value test through the fixed-point chain.
    PlotSpec s{"fig7_fixed_point",
               "Gray-value correction at 2.355 m, fixed point (paper Fig. 7)",
               "reflectance",
               "error (mm)",
               "",
               true,
               false,
               false,
               {}};
    PlotSeries raw{"uncorrected - mean offset", {}, {}, "points pt 6", false};
    PlotSeries fx{"fixed-point corrected", {}, {}, "linespoints pt 7 ps 0.6", false};
    double mean_raw = 0;
    for (const auto& rec : r.grayvalue_test) mean_raw += pipeline.start_distance_m(rec.raw);
    mean_raw /= static_cast<double>(std::max<std::size_t>(1, r.grayvalue_test.size()));
    for (std::size_t i = 0; i < r.grayvalue_test.size(); ++i) {
      const auto& rec = r.grayvalue_test[i];
      raw.x.push_back(rec.truth.reflectance);
      raw.y.push_back(1e3 * (pipeline.start_distance_m(rec.raw) - mean_raw));
      fx.x.push_back(rec.truth.reflectance);
      fx.y.push_back(1e3 * (r.grayvalue_fixed_point_m[i] - rec.truth.distance_m));
    }
    s.series = {raw, fx};
    emit(s, fmt::format("Distance error of 54 plates at 2.355 m, a run the fit never saw, through "
                        "the integer (FPGA) chain: std {:.2f} mm, within +-{:.2f} mm (paper: "
                        "4.60 mm, +-9 mm); uncorrected spread {:.0f} mm.",
                        r.grayvalue.std_mm, r.grayvalue.accuracy_mm, r.grayvalue.raw_spread_mm));
  }
  {  // Figure 8: offset vs temperature.
    PlotSpec s{"fig8_offset_vs_temperature",
               "Offset vs temperature (paper Fig. 8)",
               "sensor temperature (C)",
               "true - c t / 2 - offset - g(width) (mm)",
               "",
               false,
               false,
               false,
               {}};
    PlotSeries pts{"temperature sweep at 2.402 m", {}, {}, "points pt 7 ps 0.6", false};
    double lo = 1e300, hi = -1e300;
    for (const auto& rec : r.calibration) {
      if (!rec.raw.has_echo() || rec.truth.distance_m != r.temperature.distance_m) continue;
      const double e = rec.truth.distance_m - pipeline.start_distance_m(rec.raw) - r.fit.offset_m -
                       step_value(gray, rec.raw.pulse_width_ns);
      pts.x.push_back(rec.raw.temperature_c);
      pts.y.push_back(1e3 * e);
      lo = std::min(lo, rec.raw.temperature_c);
      hi = std::max(hi, rec.raw.temperature_c);
    }
    PlotSeries fit{"fitted hinge", {}, {}, "lines lw 2", false};
    for (int k = 0; k <= 200 && temp; ++k) {
      const double x = lo + (hi - lo) * k / 200.0;
      fit.x.push_back(x);
      fit.y.push_back(1e3 * temp->function(x));
    }
    s.series = {pts, fit};
    std::string knots;
    if (r.fit.temperature)
      for (double k : r.fit.temperature->knots) knots += fmt::format("{:.1f} ", k);
    emit(s, fmt::format("Temperature part of the offset with the fitted hinge; knots at {}C "
                        "(paper: 0 below 16 C, 3.8 mm/C above).",
                        knots));
  }
  {  // Figure 9: temperature test.
    PlotSpec s{"fig9_temperature_test",
               "Temperature test at 2.402 m (paper Fig. 9)",
               "ambient temperature (C)",
               "error (mm)",
               "",
               false,
               false,
               false,
               {}};
    PlotSeries raw{"gray-value corrected only", {}, {}, "points pt 6", false};
    PlotSeries full{"gray-value + temperature corrected", {}, {}, "linespoints pt 7", false};
    for (std::size_t i = 0; i < r.temperature_test.size(); ++i) {
      const auto& rec = r.temperature_test[i];
      const double corrected = r.temperature_corrected[i].distance_m;
      raw.x.push_back(rec.truth.ambient_c);
      raw.y.push_back(1e3 *
                      (corrected - step_value(temp, rec.raw.temperature_c) - rec.truth.distance_m));
      full.x.push_back(rec.truth.ambient_c);
      full.y.push_back(1e3 * (corrected - rec.truth.distance_m));
    }
    s.series = {raw, full};
    emit(s, fmt::format("20 groups across the knee, a run the fit never saw: std {:.2f} mm, "
                        "within +-{:.2f} mm (paper: 4.70 mm, +-10 mm).",
                        r.temperature.std_mm, r.temperature.accuracy_mm));
  }
  {  // Figure 10: longest distance.
    PlotSpec s{"fig10_longest_distance",
               "Longest achievable distance, rho = 0.1 (paper Fig. 10)",
               "distance (m)",
               "share of shots with an echo",
               "",
               false,
               false,
               false,
               {}};
    PlotSeries share{"echo share", {}, {}, "linespoints pt 7 ps 0.4", false};
    for (const auto& rec : r.max_range_scan) {
      share.x.push_back(rec.truth.distance_m);
      share.y.push_back(rec.raw.shots_valid / 1000.0);
    }
    PlotSeries limit{
        "longest distance", {r.max_range_m, r.max_range_m}, {0.0, 1.0}, "lines lw 2", false};
    s.series = {share, limit};
    emit(s, fmt::format("Share of shots that return an echo from the black foam plate; at least "
                        "90 % up to {:.2f} m (paper: 8.08 m achieved, 10 m simulated).",
                        r.max_range_m));
  }
  {  // Verification and held-out errors.
    PlotSpec s{"verification_and_holdout",
               "Corrected error, verification and held-out grid",
               "true distance (m)",
               "true - corrected (mm)",
               "",
               false,
               false,
               false,
               {}};
    PlotSeries hold{"held out (rho 0.05-0.9, 5-40 C)", {}, {}, "points pt 7 ps 0.3", false};
    for (std::size_t i = 0; i < r.holdout.size(); ++i) {
      if (!r.holdout[i].raw.has_echo()) continue;
      hold.x.push_back(r.holdout[i].truth.distance_m);
      hold.y.push_back(1e3 * (r.holdout[i].truth.distance_m - r.holdout_corrected[i].distance_m));
    }
    PlotSeries ver{"verification (rho 0.1, 20 C)", {}, {}, "linespoints pt 5 ps 0.8", false};
    for (const auto& row : r.verification_rows) {
      ver.x.push_back(row.actual_m);
      ver.y.push_back(row.deviation_mm);
    }
    PlotSeries paper{"paper Table 2", {}, {}, "linespoints pt 4", false};
    for (const auto& row : r.verification_rows) {
      paper.x.push_back(row.actual_m);
      paper.y.push_back(row.paper_deviation_mm);
    }
    s.series = {hold, ver, paper};
    emit(s, fmt::format("Corrected errors of the verification (Table 2) and of the held-out grid: "
                        "max |error| {:.2f} mm, RMS {:.2f} mm over {} rows.",
                        1e3 * r.holdout_stats.max_abs_m, 1e3 * r.holdout_stats.rms_m,
                        r.holdout_stats.rows));
  }
  return figures;
}

std::array<SplitLine, 4> split_lines(const experiments::PaperStudyResult& r) {
  return {{{"gray-value, 2.355 m", &r.grayvalue.split},
           {"temperature, 2.402 m", &r.temperature.split},
           {"Table 2, 1-8 m", &r.verification_split},
           {"held out", &r.holdout_split}}};
}

void write_demo_report(const std::filesystem::path& dir, const experiments::PaperStudyResult& r,
                       const nlohmann::json& summary, const std::vector<Figure>& figures,
                       const std::string& thesis_summary, const std::string& extra_html) {
  namespace paper = experiments::paper;
  std::ostringstream h;
  h << "<!doctype html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
    << "<title>tofkit demo report</title><style>"
    << "body{font-family:sans-serif;max-width:1000px;margin:2em auto;line-height:1.4}"
    << "table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #bbb;padding:.3em .6em;"
    << "text-align:right}th{background:#eee}td:first-child{text-align:left}"
    << "img{max-width:100%;border:1px solid #ddd}figure{margin:2em 0}"
    // Long lines (the fitted chain's knots and slopes) wrap to the page.
    << "pre{white-space:pre-wrap;overflow-wrap:anywhere}</style></head><body>\n"
    << "<h1>tofkit demo: the paper's Section 5 on the virtual rangefinder</h1>\n"
    << "<p>Device: the built-in paper rangefinder (Table 1 plus documented assumptions), "
    << "indoors. Calibration, tests and the held-out grid are separate runs; the fit never "
    << "sees test data. Seed " << summary.value("seed", 0) << ", "
    << fmt::format("{:.1f}", summary.value("seconds", 0.0)) << " s.</p>\n";
  h << "<h2>Paper vs tofkit</h2><table><tr><th>figure</th><th>paper</th><th>tofkit</th></tr>\n";
  auto row = [&](const std::string& name, const std::string& p, double t) {
    h << "<tr><td>" << html_escape(name) << "</td><td>" << p << "</td><td>"
      << fmt::format("{:.2f}", t) << "</td></tr>\n";
  };
  row("range at SNR = 10, rho 0.1, sunlit (m)", "~10", r.range_at_snr10_m);
  row("longest achievable distance (m)", fmt::format("{:.2f}", paper::kLongestDistance_m),
      r.max_range_m);
  row("gray-value std at 2.355 m (mm)", fmt::format("{:.2f}", paper::kGrayvalueStd_mm),
      r.grayvalue.std_mm);
  row("gray-value accuracy +- (mm)", "9", r.grayvalue.accuracy_mm);
  row("temperature std at 2.402 m (mm)", fmt::format("{:.2f}", paper::kTemperatureStd_mm),
      r.temperature.std_mm);
  row("temperature accuracy +- (mm)", "10", r.temperature.accuracy_mm);
  row("held-out max |error| (mm)", "-", 1e3 * r.holdout_stats.max_abs_m);
  row("held-out RMS (mm)", "-", 1e3 * r.holdout_stats.rms_m);
  row("fixed vs float max difference (mm)", "-", r.fixed_vs_float_max_diff_mm);
  h << "</table>\n<h2>Table 2: verification from 1 to 8 m</h2><table><tr><th>actual (m)</th>"
    << "<th>paper measured (m)</th><th>paper deviation (mm)</th><th>tofkit measured (m)</th>"
    << "<th>tofkit deviation (mm)</th><th>tofkit noise, 1 sigma (mm)</th></tr>\n";
  for (const auto& v : r.verification_rows)
    h << fmt::format(
        "<tr><td>{:.3f}</td><td>{:.3f}</td><td>{:.1f}</td><td>{:.4f}</td><td>{:.2f}</td>"
        "<td>{:.2f}</td></tr>\n",
        v.actual_m, v.paper_measured_m, v.paper_deviation_mm, v.measured_m, v.deviation_mm,
        v.noise_mm);
  h << "</table>\n<h2>Noise vs systematic residual</h2><p>Each test condition is measured "
    << (r.verification_rows.empty() ? 0 : r.verification_rows.front().repeats)
    << " times. Noise: the standard deviation of one measurement about its condition's mean "
       "(repeatability). Systematic: the error of that mean (RMS with the mean's own noise "
       "removed, and the worst), what a better correction could still remove.</p><table>"
    << "<tr><th>test set</th><th>conditions</th><th>noise (mm)</th><th>systematic RMS (mm)</th>"
    << "<th>systematic worst (mm)</th><th>noise of a mean (mm)</th></tr>\n";
  for (const auto& [name, s] : split_lines(r)) {
    h << fmt::format(
        "<tr><td>{}</td><td>{}</td><td>{:.2f}</td><td>{:.2f}</td><td>{:.2f}</td><td>{:.2f}</td>"
        "</tr>\n",
        html_escape(std::string(name)), s->groups, 1e3 * s->noise_m, 1e3 * s->systematic_rms_m,
        1e3 * s->systematic_max_abs_m, 1e3 * s->noise_of_mean_m);
  }
  h << "</table>\n<h2>Fitted chain</h2><pre>" << html_escape(r.fit.summary()) << "</pre>\n";
  h << "<h2>The thesis's protocol (AccuRange-like preset)</h2>\n"
    << thesis_tables_html(summary) << "<details><summary>full text</summary><pre>"
    << html_escape(thesis_summary) << "</pre></details>\n";
  h << extra_html;
  h << "<h2>Figures</h2>\n";
  for (const auto& f : figures) {
    if (f.file.ends_with(".png"))
      h << "<figure><img src=\"" << f.file << "\" alt=\"" << html_escape(f.caption)
        << "\"><figcaption>" << html_escape(f.caption) << "</figcaption></figure>\n";
    else
      h << "<figure><p>(gnuplot not installed: run <code>gnuplot " << f.file << "</code>)</p>"
        << "<figcaption>" << html_escape(f.caption) << "</figcaption></figure>\n";
  }
  h << "</body></html>\n";
  io::write_file_atomically(dir / "report.html", h.str());
}

}  // namespace tofkit::app
