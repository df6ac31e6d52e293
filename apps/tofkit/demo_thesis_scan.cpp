#include "demo_thesis_scan.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <tuple>
#include <vector>

#include "html.hpp"
#include "tofkit/device/accurange_preset.hpp"
#include "tofkit/io/atomic_file.hpp"
#include "tofkit/io/plot.hpp"
#include "tofkit/io/scan_output.hpp"

namespace tofkit::app {
namespace {

using experiments::kMetersPerInch;

/// The thesis's tables (reference/fig4_23_line_fit.csv, fig4_27_checker_fit.csv), inches.
struct ThesisRow {
  const char* model;
  double bias_in, variance_in2, rms_in, rms_improvement_pct;
};
constexpr ThesisRow kFig423[] = {{"raw", 0.1264, 0.88461, 0.94899, NAN},
                                 {"poly4", 0.0553, 0.09607, 0.31485, 66.82},
                                 {"poly5", 0.0681, 0.08919, 0.30631, 67.72},
                                 {"poly6", 0.4917, 0.33859, 0.76185, 19.71}};
constexpr ThesisRow kFig427[] = {{"raw", 0.42263, 1.88368, 1.43607, NAN},
                                 {"poly4", 0.39736, 1.73512, 1.37587, 4.19},
                                 {"poly5", 0.14863, 0.31219, 0.57817, 59.74},
                                 {"poly6", 0.08793, 5.39887, 2.32521, -61.91}};

nlohmann::json number(double v) {
  return std::isfinite(v) ? nlohmann::json(v) : nlohmann::json(nullptr);
}

nlohmann::json table_json(const experiments::LineTable& t, const ThesisRow (&ref)[4],
                          const std::string& source) {
  nlohmann::json rows = nlohmann::json::array();
  for (const auto& r : t.rows) {
    rows.push_back({{"model", r.model},
                    {"bias_mm", 1e3 * r.test.bias_m},
                    {"variance_mm2", 1e6 * r.test.variance_m2},
                    {"rms_mm", 1e3 * r.test.rms_m},
                    {"rms_improvement_pct", number(r.rms_improvement_pct)},
                    {"excess_over_noise_pct", number(r.excess_over_noise_pct)},
                    {"rows_out_of_domain", r.out_of_domain}});
  }
  const double mm = kMetersPerInch * 1e3;
  nlohmann::json thesis = nlohmann::json::array();
  for (const auto& r : ref) {
    thesis.push_back({{"model", r.model},
                      {"bias_mm", r.bias_in * mm},
                      {"variance_mm2", r.variance_in2 * mm * mm},
                      {"rms_mm", r.rms_in * mm},
                      {"rms_improvement_pct", number(r.rms_improvement_pct)}});
  }
  return {{"rows", rows},
          {"raw_reference", thesis[0]},
          {"thesis_rows", thesis},
          {"source", source},
          {"best_model", t.best().model},
          {"noise_limit_mm", 1e3 * t.noise_limit_m}};
}

nlohmann::json coverage_json(const experiments::ChartImages& im) {
  return {{"within_1_sigma", im.within_1_sigma.share},
          {"within_2_sigma", im.within_2_sigma.share},
          {"sigma_min_mm", 1e3 * im.sigma_min_m},
          {"sigma_max_mm", 1e3 * im.sigma_max_m}};
}

// ------------------------------------------------------------ pictures

struct Rgb {
  unsigned char r, g, b;
};

/// Blue - white - red for signed errors, t in [-1, 1].
Rgb diverging(double t) {
  t = std::clamp(t, -1.0, 1.0);
  const auto c = [](double v) { return static_cast<unsigned char>(std::lround(255 * v)); };
  return t < 0 ? Rgb{c(1 + t), c(1 + t), 255} : Rgb{255, c(1 - t), c(1 - t)};
}

/// Dark blue - green - yellow for magnitudes, t in [0, 1] (viridis-like stops).
Rgb sequential(double t) {
  static constexpr double stops[5][3] = {
      {68, 1, 84}, {59, 82, 139}, {33, 145, 140}, {94, 201, 98}, {253, 231, 37}};
  t = std::clamp(t, 0.0, 1.0) * 4;
  const int i = std::min(3, static_cast<int>(t));
  const double f = t - i;
  const auto mix = [&](int k) {
    return static_cast<unsigned char>(
        std::lround(stops[i][k] + f * (stops[i + 1][k] - stops[i][k])));
  };
  return {mix(0), mix(1), mix(2)};
}

/// An image of per-pixel values, each pixel a block, with a colour bar below.
void write_picture(const std::filesystem::path& file, int rows, int columns,
                   const std::vector<double>& values, double lo, double hi, bool signed_map) {
  const int px = std::max(2, 480 / columns), py = std::max(px, 96 / rows);
  const int width = columns * px, bar = 14, gap = 4, height = rows * py + gap + bar;
  std::vector<unsigned char> rgb(static_cast<std::size_t>(width * height * 3), 255);
  auto put = [&](int y, int x, Rgb c) {
    const auto k = static_cast<std::size_t>((y * width + x) * 3);
    rgb[k] = c.r;
    rgb[k + 1] = c.g;
    rgb[k + 2] = c.b;
  };
  auto colour = [&](double v) {
    if (!std::isfinite(v)) return Rgb{150, 150, 150};
    const double t = (v - lo) / (hi - lo);
    return signed_map ? diverging(2 * t - 1) : sequential(t);
  };
  for (int r = 0; r < rows; ++r)
    for (int c = 0; c < columns; ++c)
      for (int y = 0; y < py; ++y)
        for (int x = 0; x < px; ++x)
          put(r * py + y, c * px + x, colour(values[static_cast<std::size_t>(r * columns + c)]));
  for (int x = 0; x < width; ++x)
    for (int y = 0; y < bar; ++y)
      put(rows * py + gap + y, x, colour(lo + (hi - lo) * x / std::max(1, width - 1)));
  io::write_file_atomically(file, io::encode_png_rgb(height, width, rgb));
}

std::string cell(double v, int digits) {
  return std::isfinite(v) ? fmt::format("{:.{}f}", v, digits) : "";
}

/// Fig. 4.23 / 4.27 as an HTML table, tofkit beside the thesis, in inches.
std::string model_table(const experiments::LineTable& t, const ThesisRow (&ref)[4]) {
  const double in2 = kMetersPerInch * kMetersPerInch;
  std::string h =
      "<table><tr><th>model</th><th>bias (in)</th><th>variance (in&sup2;)</th><th>RMS (in)</th>"
      "<th>RMS impr. (%)</th><th>excess over noise (%)</th><th>thesis bias</th>"
      "<th>thesis variance</th><th>thesis RMS</th><th>thesis impr. (%)</th></tr>\n";
  for (const auto& r : t.rows) {
    h += fmt::format("<tr><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td>",
                     r.model, cell(r.test.bias_m / kMetersPerInch, 4),
                     cell(r.test.variance_m2 / in2, 5), cell(r.test.rms_m / kMetersPerInch, 4),
                     cell(r.rms_improvement_pct, 1), cell(r.excess_over_noise_pct, 1));
    const ThesisRow* match = nullptr;
    for (const auto& x : ref)
      if (r.model == x.model) match = &x;
    if (match) {
      h += fmt::format("<td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr>\n",
                       cell(match->bias_in, 4), cell(match->variance_in2, 5),
                       cell(match->rms_in, 4), cell(match->rms_improvement_pct, 1));
    } else {
      h += "<td colspan=\"4\">(thesis: future work)</td></tr>\n";
    }
  }
  h += fmt::format(
      "<tr><td>noise limit</td><td></td><td></td><td>{}</td><td colspan=\"6\">RMS a perfect "
      "systematic correction would leave (from a repeated scan)</td></tr></table>\n",
      cell(t.noise_limit_m / kMetersPerInch, 4));
  return h;
}

std::string figure(const std::string& file, const std::string& caption) {
  return "<figure><img src=\"" + file + "\" alt=\"" + html_escape(caption) + "\"><figcaption>" +
         html_escape(caption) + "</figcaption></figure>\n";
}

/// Raw error, corrected error and sigma pictures of one chart.
std::string chart_pictures(const std::filesystem::path& plots, const std::string& stem,
                           const std::string& name, const experiments::ChartImages& im) {
  const int rows = im.raw.rows, cols = im.raw.columns;
  std::vector<double> raw, corrected, sigma;
  for (std::size_t i = 0; i < im.raw.values.size(); ++i) {
    const double t = im.truth.values[i];
    raw.push_back((t - im.raw.values[i]) / kMetersPerInch);
    corrected.push_back((t - im.corrected.values[i]) / kMetersPerInch);
    sigma.push_back(im.sigma.values[i] / kMetersPerInch);
  }
  std::vector<double> mag;
  for (const double v : raw)
    if (std::isfinite(v)) mag.push_back(std::abs(v));
  std::sort(mag.begin(), mag.end());
  const double limit = mag.empty() ? 1.0 : std::max(1e-3, mag[mag.size() * 98 / 100]);
  const double s_lo = im.sigma_min_m / kMetersPerInch, s_hi = im.sigma_max_m / kMetersPerInch;
  write_picture(plots / (stem + "_raw.png"), rows, cols, raw, -limit, limit, true);
  write_picture(plots / (stem + "_corrected.png"), rows, cols, corrected, -limit, limit, true);
  write_picture(plots / (stem + "_sigma.png"), rows, cols, sigma, s_lo,
                std::max(s_hi, s_lo * 1.0001), false);
  std::string h;
  h += figure("plots/" + stem + "_raw.png",
              fmt::format("{}: raw error true - measured, colour bar blue {:.3f} in to red "
                          "+{:.3f} in (white: none; grey: no echo)",
                          name, -limit, limit));
  h += figure("plots/" + stem + "_corrected.png",
              fmt::format("{}: after the line model, same colour bar ({:.3f} to +{:.3f} in)", name,
                          -limit, limit));
  h += figure(
      "plots/" + stem + "_sigma.png",
      fmt::format("{}: confidence image, expected error (1 sigma) from {:.3f} in (dark "
                  "blue) to {:.3f} in (yellow); {:.1f} % of pixels within 1 sigma, "
                  "{:.1f} % within 2 sigma",
                  name, s_lo, s_hi, 100 * im.within_1_sigma.share, 100 * im.within_2_sigma.share));
  return h;
}

}  // namespace

ThesisScanDemo run_thesis_scan_demo(std::uint64_t seed) {
  const device::VirtualRangefinder accurange(device::accurange_preset());
  return {experiments::run_line_scan(accurange, {}, seed),
          experiments::run_memory_scans(accurange, {}, seed)};
}

void add_thesis_scan_summary(nlohmann::json& summary, const ThesisScanDemo& d) {
  summary["thesis_line"] = table_json(d.line.line, kFig423, "thesis Fig. 4.23");
  summary["thesis_line"]["confidence"] = coverage_json(d.line.stripe_images);
  nlohmann::json grey = nlohmann::json::array();
  for (const auto& g : d.line.per_grey)
    grey.push_back(
        {{"grey", g.grey}, {"raw_rms_mm", 1e3 * g.raw_rms_m}, {"best_rms_mm", 1e3 * g.best_rms_m}});
  summary["thesis_line"]["per_grey"] = grey;
  summary["thesis_checker"] = table_json(d.line.checker, kFig427, "thesis Fig. 4.27");
  summary["thesis_checker"]["confidence"] = coverage_json(d.line.checker_images);
  const auto& m = d.memory;
  summary["memory_correction"] = {
      {"spike_mm_before", 1e3 * m.mirror_edges.spike_before_m},
      {"spike_mm_after", 1e3 * m.mirror_edges.spike_after_m},
      {"rms_near_edges_mm_before", 1e3 * m.mirror_edges.rms_near_edges_before_m},
      {"rms_near_edges_mm_after", 1e3 * m.mirror_edges.rms_near_edges_after_m},
      {"time_constant_ms", 1e3 * m.fit.correction.time_constant_s},
      {"gain_mm_per_neper", 1e3 * m.fit.correction.gain_m_per_neper},
      {"color_transition_spike_mm_before", 1e3 * m.color_transition.spike_before_m},
      {"color_transition_spike_mm_after", 1e3 * m.color_transition.spike_after_m}};
}

std::string write_thesis_scan_section(const std::filesystem::path& dir, const ThesisScanDemo& d,
                                      bool render) {
  const auto plots = dir / "plots";
  std::filesystem::create_directories(plots);
  const auto& line = d.line;
  std::string h = "<h2>The thesis's scanning results (AccuRange-like preset)</h2>\n";
  int lo = 1 << 30, hi = 0;
  for (const int s : line.samples_per_line) {
    lo = std::min(lo, s);
    hi = std::max(hi, s);
  }
  h += fmt::format(
      "<p>Stripe chart scanned line by line (stage at {:.2f} m/s, {} shots per sample; {}-{} "
      "samples per line resampled by weighted averaging), training at 15, 17, 20, 22 in, test "
      "at 19 in. Error = true - corrected. Best model: {}.</p>\n",
      line.options.stage_speed_m_per_s, line.options.shots_per_sample, lo, hi, line.best_model);
  h +=
      "<h3>Line-by-line model at 19 in (thesis Fig. 4.23)</h3>\n" + model_table(line.line, kFig423);
  h += "<h3>Random-grey checkerboard at 18 in, line model (thesis Fig. 4.27)</h3>\n" +
       model_table(line.checker, kFig427);
  h += "<h3>RMS per grey at 19 in (thesis Fig. 4.24)</h3><table><tr><th>grey</th><th>raw RMS "
       "(in)</th><th>" +
       line.best_model + " RMS (in)</th></tr>\n";
  for (const auto& g : line.per_grey)
    h += fmt::format("<tr><td>{}</td><td>{}</td><td>{}</td></tr>\n", g.grey,
                     cell(g.raw_rms_m / kMetersPerInch, 4), cell(g.best_rms_m / kMetersPerInch, 4));
  h += "</table>\n";
  h += "<h3>Confidence images (thesis Figs. 4.32-4.33)</h3><table><tr><th>chart</th><th>sigma "
       "(in)</th><th>thesis sigma (in)</th><th>within 1 sigma</th><th>within 2 sigma</th></tr>\n";
  for (const auto& [name, im, thesis] :
       {std::tuple{"stripe chart, 19 in", &line.stripe_images, "0.076-0.401"},
        std::tuple{"checkerboard, 18 in", &line.checker_images, "0.005-0.513"}}) {
    h += fmt::format(
        "<tr><td>{}</td><td>{}-{}</td><td>{}</td><td>{:.1f} %</td><td>{:.1f} %</td></tr>\n", name,
        cell(im->sigma_min_m / kMetersPerInch, 3), cell(im->sigma_max_m / kMetersPerInch, 3),
        thesis, 100 * im->within_1_sigma.share, 100 * im->within_2_sigma.share);
  }
  h += "</table>\n";
  const auto& best_line = line.line.best();
  const auto& best_checker = line.checker.best();
  h += fmt::format(
      "<p>Closing note: the best model ({}) improves RMS by {:.1f} % on the stripe chart (thesis "
      "best polynomial: 67.7 %) and {:.1f} % on the checkerboard (thesis: 59.7 %). The noise "
      "limit - the RMS a perfect systematic correction would leave - is {:.4f} in and {:.4f} "
      "in; the best model leaves {:.1f} % and {:.1f} % of the raw RMS above it.</p>\n",
      best_line.model, best_line.rms_improvement_pct, best_checker.rms_improvement_pct,
      line.line.noise_limit_m / kMetersPerInch, line.checker.noise_limit_m / kMetersPerInch,
      best_line.excess_over_noise_pct, best_checker.excess_over_noise_pct);
  h += chart_pictures(plots, "thesis_scan_stripes", "Stripe chart at 19 in", line.stripe_images);
  h += chart_pictures(plots, "thesis_scan_checker", "Checkerboard at 18 in", line.checker_images);

  const auto& m = d.memory;
  h += "<h3>Edge spikes and the memory correction (thesis Figs. 3.4-3.5, 4.28)</h3>\n";
  h += fmt::format(
      "<p>Memory correction fitted on a separate step-edge mirror scan: time constant {:.3f} "
      "ms, gain {:.2f} mm per neper of echo-strength step. Error = true - measured, so a "
      "positive spike is a range that reads short.</p>\n",
      1e3 * m.fit.correction.time_constant_s, 1e3 * m.fit.correction.gain_m_per_neper);
  h += "<table><tr><th>profile</th><th>edge (deg)</th><th>echo strength</th><th>spike before "
       "(mm)</th><th>spike after (mm)</th></tr>\n";
  for (const auto* p : {&m.mirror_edges, &m.color_transition}) {
    for (const auto& e : p->edges) {
      h += fmt::format(
          "<tr><td>{}</td><td>{:.2f}</td><td>{}</td><td>{:+.2f}</td><td>{:+.2f}</td>"
          "</tr>\n",
          p->name, e.elevation_deg, e.rising ? "steps up" : "steps down", 1e3 * e.spike_before_m,
          1e3 * e.spike_after_m);
    }
    h += fmt::format(
        "<tr><td>{}</td><td colspan=\"2\">mean |spike|; RMS near edges</td><td>{:.2f}; "
        "{:.2f}</td><td>{:.2f}; {:.2f}</td></tr>\n",
        p->name, 1e3 * p->spike_before_m, 1e3 * p->rms_near_edges_before_m, 1e3 * p->spike_after_m,
        1e3 * p->rms_near_edges_after_m);
  }
  h += "</table>\n";
  for (const auto* p : {&m.mirror_edges, &m.color_transition}) {
    io::PlotSpec s;
    s.name = "thesis_scan_" + p->name;
    s.title = p->name == "mirror_edges" ? "Mirror profile across blocks (thesis Figs. 3.4-3.5)"
                                        : "Mid grey into black (thesis Fig. 4.28)";
    s.x_label = "elevation (deg)";
    s.y_label = "true - measured (mm)";
    io::PlotSeries one{"one revolution, raw", p->elevation_deg, {}, "lines lw 1 lc rgb '#bbbbbb'"};
    io::PlotSeries before{"mean of revolutions, raw", p->elevation_deg, {}, "lines lw 2"};
    io::PlotSeries after{"mean, memory-corrected", p->elevation_deg, {}, "lines lw 2"};
    for (std::size_t k = 0; k < p->elevation_deg.size(); ++k) {
      one.y.push_back(1e3 * p->single_before_m[k]);
      before.y.push_back(1e3 * p->error_before_m[k]);
      after.y.push_back(1e3 * p->error_after_m[k]);
    }
    s.series = {one, before, after};
    const auto files = io::write_plot(plots, s, render);
    const auto file = files.png ? *files.png : files.script;
    h += figure("plots/" + file.filename().string(),
                s.title + ": edge profile before and after the memory correction");
  }
  return h;
}

}  // namespace tofkit::app
