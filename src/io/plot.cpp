#include "tofkit/io/plot.hpp"

#include <fmt/format.h>
#include <unistd.h>

#include <cstdlib>
#include <fstream>
#include <sstream>

#include "tofkit/io/atomic_file.hpp"

namespace tofkit::io {
namespace {

std::string quoted(const std::string& text) {
  std::string out = "'";
  for (char c : text) out += c == '\'' ? std::string("''") : std::string(1, c);
  return out + "'";
}

std::string shell_quoted(const std::string& text) {
  std::string out = "'";
  for (char c : text) out += c == '\'' ? std::string("'\\''") : std::string(1, c);
  return out + "'";
}

std::string plot_script(const PlotSpec& spec, const std::string& data_file,
                        const std::string& png_file) {
  std::ostringstream gp;
  gp << "set terminal pngcairo size 960,600 font 'Sans,11'\n"
     << "set output " << quoted(png_file) << "\n"
     << "set title " << quoted(spec.title) << "\n"
     << "set xlabel " << quoted(spec.x_label) << "\n"
     << "set ylabel " << quoted(spec.y_label) << "\n"
     << "set grid\nset key outside right top\n";
  if (spec.log_x) gp << "set logscale x\n";
  if (spec.log_y) gp << "set logscale y\n";
  bool uses_y2 = false;
  for (const auto& s : spec.series) uses_y2 = uses_y2 || s.second_axis;
  if (uses_y2) {
    gp << "set y2label " << quoted(spec.y2_label) << "\nset y2tics\nset ytics nomirror\n";
    if (spec.log_y2) gp << "set logscale y2\n";
  }
  gp << "plot ";
  for (std::size_t i = 0; i < spec.series.size(); ++i) {
    const auto& s = spec.series[i];
    gp << (i ? ", \\\n     " : "") << quoted(data_file) << " index " << i << " using 1:2"
       << (s.second_axis ? " axes x1y2" : "") << " with " << s.style << " title "
       << quoted(s.title);
  }
  gp << "\n";
  return gp.str();
}

}  // namespace

bool gnuplot_available() {
  static const bool available =
      std::system("gnuplot -e \"set terminal pngcairo\" >/dev/null 2>&1") == 0;
  return available;
}

PlotFiles write_plot(const std::filesystem::path& dir, const PlotSpec& spec, bool render) {
  PlotFiles files;
  files.data = dir / (spec.name + ".dat");
  files.script = dir / (spec.name + ".gp");
  std::ostringstream data;
  for (const auto& s : spec.series) {
    data << "# " << s.title << "\n";
    for (std::size_t i = 0; i < s.x.size() && i < s.y.size(); ++i)
      data << fmt::format("{} {}\n", s.x[i], s.y[i]);
    data << "\n\n";  // gnuplot index separator
  }
  write_file_atomically(files.data, data.str());

  const std::string script = plot_script(spec, spec.name + ".dat", spec.name + ".png");
  write_file_atomically(files.script, script);

  if (render && gnuplot_available()) {
    // Render from the data as written so far (staged until the command
    // commits), into a temporary PNG handed to the output mechanism.
    const std::string suffix = ".tmp." + std::to_string(::getpid());
    const std::string png_temporary = "." + spec.name + ".png" + suffix;
    const std::string render_script = "." + spec.name + ".gp" + suffix;
    const std::string staged_data = staged_path(files.data).filename().string();
    {
      // A scratch file, not an output: written directly and removed below.
      std::ofstream scratch(dir / render_script, std::ios::binary | std::ios::trunc);
      scratch << plot_script(spec, staged_data, png_temporary);
    }
    const auto command = fmt::format("cd {} && gnuplot {} >/dev/null 2>&1",
                                     shell_quoted(dir.string()), shell_quoted(render_script));
    const bool ok = std::system(command.c_str()) == 0;
    std::error_code ignored;
    std::filesystem::remove(dir / render_script, ignored);
    if (ok && std::filesystem::exists(dir / png_temporary)) {
      files.png = dir / (spec.name + ".png");
      adopt_written_file(dir / png_temporary, *files.png);
    } else {
      std::filesystem::remove(dir / png_temporary, ignored);
    }
  }
  return files;
}

}  // namespace tofkit::io
