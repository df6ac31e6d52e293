#pragma once
/// \file Plots as gnuplot scripts plus their data, rendered to PNG when
/// gnuplot is installed (scripts/setup installs gnuplot-nox).

#include <filesystem>
#include <optional>
#include <string>
#include <vector>

namespace tofkit::io {

struct PlotSeries {
  std::string title;
  std::vector<double> x, y;
  std::string style = "points pt 7 ps 0.6";  ///< gnuplot "with" clause
  bool second_axis = false;                  ///< plot against the right-hand y axis
};

struct PlotSpec {
  std::string name;  ///< file stem: <name>.gp, <name>.dat, <name>.png
  std::string title, x_label, y_label, y2_label;
  bool log_x = false, log_y = false, log_y2 = false;
  std::vector<PlotSeries> series;
};

struct PlotFiles {
  std::filesystem::path script, data;
  std::optional<std::filesystem::path> png;  ///< set when gnuplot rendered it
};

/// Is a gnuplot with the pngcairo terminal on the PATH?
[[nodiscard]] bool gnuplot_available();

/// Writes <dir>/<name>.gp and .dat; renders <name>.png if `render` and gnuplot is available.
PlotFiles write_plot(const std::filesystem::path& dir, const PlotSpec& spec, bool render);

}  // namespace tofkit::io
