#include "demo_thesis.hpp"

#include <fmt/format.h>

#include <cmath>
#include <map>

#include "tofkit/io/atomic_file.hpp"
#include "tofkit/io/plot.hpp"

namespace tofkit::app {

nlohmann::json thesis_summary_json(const experiments::ThesisProtocolResult& r) {
  nlohmann::json rows = nlohmann::json::array();
  for (const auto& row : r.rows)
    rows.push_back({{"model", row.model},
                    {"bias_mm", 1e3 * row.test.bias_m},
                    {"variance_mm2", 1e6 * row.test.variance_m2},
                    {"rms_mm", 1e3 * row.test.rms_m},
                    {"rms_improvement_pct", std::isfinite(row.rms_improvement_pct)
                                                ? nlohmann::json(row.rms_improvement_pct)
                                                : nlohmann::json(nullptr)},
                    {"test_rows_out_of_domain", row.test_rows_out_of_domain}});
  nlohmann::json coverage = nlohmann::json::object();
  for (const auto& c : r.coverage)
    coverage[c.model] = {{"within_1_sigma", c.within_1_sigma.share},
                         {"within_2_sigma", c.within_2_sigma.share},
                         {"within_2_sigma_by_tercile", c.within_2_sigma.tercile_share},
                         {"mean_sigma_mm", 1e3 * c.mean_sigma_m}};
  return {{"rows", rows},
          {"best_polynomial_order", r.best_polynomial_order},
          {"confidence", coverage},
          {"test_rows", r.test.size()},
          {"test_rows_without_echo", r.test_rows_without_echo}};
}

std::vector<Figure> write_thesis_plots(const std::filesystem::path& dir,
                                       const experiments::ThesisProtocolResult& r, bool render) {
  const auto plots = dir / "plots";
  io::create_output_directories(plots);
  std::vector<Figure> figures;
  auto emit = [&](const io::PlotSpec& spec, const std::string& caption) {
    const auto files = io::write_plot(plots, spec, render);
    const auto file = files.png ? *files.png : files.script;
    figures.push_back({"plots/" + file.filename().string(), caption});
  };
  {  // Fig. 4.15: error over (range, intensity) and the fitted B-spline, as cuts at each distance.
    io::PlotSpec s{"thesis_fig4_15_error_surface",
                   "Error surface and B-spline fit (thesis Fig. 4.15)",
                   "amplitude (V)",
                   "true - measured (mm)",
                   "",
                   true,
                   false,
                   false,
                   {}};
    std::map<double, io::PlotSeries> measured;
    for (const auto& rec : r.training) {
      if (!rec.raw.has_echo()) continue;
      auto& series = measured[rec.truth.distance_m];
      series.title = fmt::format("training {:.0f} in", rec.truth.distance_m / 0.0254);
      series.style = "points pt 7 ps 0.3";
      series.x.push_back(rec.raw.amplitude);
      series.y.push_back(1e3 * (rec.truth.distance_m - rec.raw.distance_raw_m));
    }
    for (auto& [d, series] : measured) s.series.push_back(series);
    const auto& g = r.surface_grid;
    for (std::size_t i = 0; i < g.range_m.size();
         i += std::max<std::size_t>(1, g.range_m.size() / 4)) {
      io::PlotSeries fit{
          fmt::format("B-spline at {:.1f} in", g.range_m[i] / 0.0254), {}, {}, "lines lw 2", false};
      for (std::size_t j = 0; j < g.amplitude.size(); ++j) {
        fit.x.push_back(g.amplitude[j]);
        fit.y.push_back(1e3 * g.bspline_m[i * g.amplitude.size() + j]);
      }
      s.series.push_back(fit);
    }
    emit(s,
         "Error (true minus measured) of the grey-chart training scans against intensity, "
         "one cloud per distance, with cuts of the fitted B-spline surface.");
  }
  {  // Fig. 4.19: RMS per grey level before and after.
    io::PlotSpec s{"thesis_fig4_19_rms_per_grey",
                   "RMS per grey level at 19 in (thesis Fig. 4.19)",
                   "grey level",
                   "RMS error (mm)",
                   "",
                   false,
                   true,
                   false,
                   {}};
    io::PlotSeries raw{"uncorrected", {}, {}, "linespoints pt 7", false};
    io::PlotSeries poly{
        fmt::format("poly{}", r.best_polynomial_order), {}, {}, "linespoints pt 5", false};
    io::PlotSeries spline{"B-spline", {}, {}, "linespoints pt 9", false};
    for (const auto& g : r.per_grey) {
      raw.x.push_back(g.grey);
      raw.y.push_back(1e3 * g.raw_rms_m);
      poly.x.push_back(g.grey);
      poly.y.push_back(1e3 * g.best_polynomial_rms_m);
      spline.x.push_back(g.grey);
      spline.y.push_back(1e3 * g.bspline_rms_m);
    }
    s.series = {raw, poly, spline};
    emit(s, "Held-out RMS error per grey level at 19 in, before and after correction.");
  }
  {  // Figs. 4.30-4.31: squared error vs intensity with the confidence fits.
    io::PlotSpec s{"thesis_fig4_30_confidence",
                   "Squared error vs intensity (thesis Figs. 4.30-4.31)",
                   "amplitude (V)",
                   "squared error (mm^2)",
                   "",
                   true,
                   true,
                   false,
                   {}};
    io::PlotSeries e2{"B-spline corrected, 19 in", {}, {}, "points pt 7 ps 0.3", false};
    io::PlotSeries thesis{"thesis metric sigma^2", {}, {}, "points pt 1 ps 0.4", false};
    io::PlotSeries calibrated{"tofkit calibrated sigma^2", {}, {}, "points pt 2 ps 0.4", false};
    for (const auto& t : r.test_rows) {
      const double e = 1e3 * t.bspline_error_m;
      e2.x.push_back(t.amplitude);
      e2.y.push_back(std::max(e * e, 1e-6));
      thesis.x.push_back(t.amplitude);
      thesis.y.push_back(1e6 * t.sigma_thesis_m * t.sigma_thesis_m);
      calibrated.x.push_back(t.amplitude);
      calibrated.y.push_back(1e6 * t.sigma_calibrated_m * t.sigma_calibrated_m);
    }
    s.series = {e2, thesis, calibrated};
    std::string coverage;
    for (const auto& c : r.coverage)
      coverage +=
          fmt::format("{}: {:.1f} % within 2 sigma; ", c.model, 100.0 * c.within_2_sigma.share);
    emit(s,
         "Squared held-out error of B-spline-corrected ranges against intensity, with the "
         "thesis's confidence (cubic in intensity, floored) and tofkit's calibrated one. " +
             coverage);
  }
  return figures;
}

}  // namespace tofkit::app
