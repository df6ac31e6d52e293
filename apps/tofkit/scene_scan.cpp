#include "scene_scan.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include "app.hpp"
#include "tofkit/io/input_file.hpp"
#include "tofkit/io/value_list.hpp"

namespace tofkit::app {
namespace {

std::vector<double> list(const std::string& text, const char* option, const std::string& pattern) {
  if (text.empty())
    throw std::invalid_argument(fmt::format("--pattern {} needs {}", pattern, option));
  return io::parse_value_list(text, option);
}

}  // namespace

SceneScanOptionHandles add_scene_scan_options(CLI::App& sub, SceneScanOptions& o,
                                              const std::string& rate_option) {
  SceneScanOptionHandles h;
  h.scene = sub.add_option("--scene", o.scene, "scene file (TOML)");
  h.pattern =
      sub.add_option("--pattern", o.pattern, "raster | line | mirror | spherical | spinning")
          ->check(CLI::IsMember({"raster", "line", "mirror", "spherical", "spinning"}));
  h.others = {
      sub.add_option("--y", o.y, "raster/line: stage positions along y, m: LIST"),
      sub.add_option("--z", o.z, "raster/line: stage positions along z (lines), m: LIST"),
      sub.add_option("--azimuth", o.azimuth, "spherical: azimuths, degrees: LIST"),
      sub.add_option("--elevation", o.elevation,
                     "mirror/spherical/spinning: elevations, degrees: LIST"),
      sub.add_option("--samples", o.settings.samples, "raster: measurements averaged per point")
          ->check(InRange(1, 100000))
          ->capture_default_str(),
      sub.add_option("--speed", o.settings.speed_m_per_s, "raster/line/mirror: stage speed, m/s")
          ->check(InRange(0.0, 100.0))
          ->capture_default_str(),
      sub.add_option("--turnaround", o.settings.turnaround_s, "line: time between lines, s")
          ->check(InRange(0.0, 1e4))
          ->capture_default_str(),
      sub.add_option(rate_option, o.settings.rate_hz,
                     "mirror/spherical: mirror revolutions per s; spinning: rotation Hz")
          ->check(InRange(1e-6, 1e5))
          ->capture_default_str(),
      sub.add_option("--revolutions", o.settings.revolutions, "mirror/spinning: revolutions")
          ->check(InRange(1, 1000000))
          ->capture_default_str(),
      sub.add_option("--azimuth-step", o.settings.azimuth_step_deg,
                     "spinning: azimuth between firings, degrees")
          ->check(InRange(1e-4, 360.0))
          ->capture_default_str(),
      sub.add_option("--ambient", o.ambient_c, "ambient temperature, C")
          ->check(InRange(-60.0, 150.0))
          ->capture_default_str(),
  };
  return h;
}

scan::BeamPattern make_scan_pattern(const SceneScanOptions& o, const device::DeviceConfig& config,
                                    int shots, bool on_demand) {
  const double period_s = shots / config.link.laser.repetition_hz;
  const std::string* texts[] = {&o.y, &o.z, &o.azimuth, &o.elevation};  // PatternListName order
  const auto lists = [&](scan::PatternListName l) {
    return list(*texts[static_cast<std::size_t>(l)],
                (std::string("--") + scan::pattern_list_name(l)).c_str(), o.pattern);
  };
  try {
    return scan::make_pattern(o.pattern, o.settings, lists, period_s,
                              io::resource_limits().max_rows, on_demand);
  } catch (const std::length_error& e) {
    // A beam is a row of scan.csv: the rows' limit applies.
    throw std::invalid_argument(std::string(e.what()) + " (raise it with --max-rows)");
  }
}

int scan_shots(const device::DeviceConfig& config, int shots) {
  return shots > 0 ? shots : config.measurement.shots;
}

int fitting_shots(const SceneScanOptions& o, const device::DeviceConfig& config, int shots) {
  if (shots > 0 || o.pattern == "raster" || o.pattern == "line") return scan_shots(config, shots);
  // The beams' times do not depend on the shots for these patterns: the
  // closest pair sets how many shots one beam's measurement can average.
  const scan::BeamPattern timing = make_scan_pattern(o, config, 1);
  double gap_s = 0;
  for (std::size_t i = 1; i < timing.beams.size(); ++i) {
    const double gap = timing.beams[i].time_s - timing.beams[i - 1].time_s;
    if (gap > 0 && (gap_s == 0 || gap < gap_s)) gap_s = gap;
  }
  const int configured = config.measurement.shots;
  if (gap_s == 0) return configured;
  const double fit = std::floor(gap_s * config.link.laser.repetition_hz * (1 + 1e-9));
  return std::max(1, static_cast<int>(std::min<double>(configured, fit)));
}

scan::ScanResult run_scene_scan(const SceneScanOptions& o, const scan::Scene& scene,
                                const scan::BeamPattern& pattern,
                                const device::DeviceConfig& config, device::SimulationMode mode,
                                int shots, std::uint64_t seed,
                                std::function<void(std::size_t, std::size_t)> progress) {
  scan::ScanOptions options = scene_scan_options(o, shots, seed);
  options.progress = std::move(progress);
  return scan::run_scan(scene, config, mode, pattern, options);
}

scan::ScanOptions scene_scan_options(const SceneScanOptions& o, int shots, std::uint64_t seed) {
  scan::ScanOptions options;
  options.seed = seed;
  options.shots = shots;
  options.conditions.ambient_c = o.ambient_c;
  return options;
}

}  // namespace tofkit::app
