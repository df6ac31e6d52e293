#pragma once
/// \file The scene-scan options of `tofkit scan`, shared by every command that
/// scans a scene (`scan`, `emulate --scene`): one place registers them with
/// CLI11, builds the pattern and runs the scan, so the same options mean the
/// same beams, and the same seed the same values, in every command.

#include <CLI/CLI.hpp>
#include <cstdint>
#include <functional>
#include <string>

#include "tofkit/device/device_config.hpp"
#include "tofkit/device/virtual_rangefinder.hpp"
#include "tofkit/scan/pattern.hpp"
#include "tofkit/scan/scanner.hpp"

namespace tofkit::app {

/// A scene and a pattern over it; units in the names, defaults as `tofkit scan`.
struct SceneScanOptions {
  std::string scene;    ///< --scene: scene file (TOML)
  std::string pattern;  ///< --pattern: raster | line | mirror | spherical | spinning
  std::string y, z, azimuth, elevation;               ///< LISTs, as the pattern needs them
  scan::PatternSettings settings;                     ///< --samples, --revolutions, --speed, ...
  double ambient_c = device::Conditions{}.ambient_c;  ///< --ambient
};

/// The options as registered, so a command can mark them required or tie
/// them to others (CLI11 needs/excludes).
struct SceneScanOptionHandles {
  CLI::Option* scene = nullptr;
  CLI::Option* pattern = nullptr;
  std::vector<CLI::Option*> others;  ///< every pattern option and --ambient
};

/// Registers --scene, --pattern, --y, --z, --azimuth, --elevation, --samples,
/// --speed, --turnaround, the pattern rate (`rate_option`: `scan` calls it
/// --rate; `emulate`, whose --rate is its frame rate, --scan-rate),
/// --revolutions, --azimuth-step and --ambient, none of them required.
SceneScanOptionHandles add_scene_scan_options(CLI::App& sub, SceneScanOptions& o,
                                              const std::string& rate_option = "--rate");

/// The pattern the options describe for a device averaging `shots` shots per
/// measurement (its output period: shots / laser repetition rate). Throws
/// std::invalid_argument naming the option a pattern lacks, and when the
/// pattern has more beams than --max-rows allows (a beam is a row of scan.csv).
/// With `on_demand`, a mirror, spherical or spinning pattern makes its beams
/// as a streaming scan asks for them (scan::BeamPattern::make_beams).
[[nodiscard]] scan::BeamPattern make_scan_pattern(const SceneScanOptions& o,
                                                  const device::DeviceConfig& config, int shots,
                                                  bool on_demand = false);

/// Shots per beam before the pattern's multiplier: `shots`, or the config's.
[[nodiscard]] int scan_shots(const device::DeviceConfig& config, int shots);

/// Shots per beam: `shots` when given (> 0); else the config's, fewer when a
/// mirror, spherical or spinning pattern's beams come closer in time than
/// that many shots (so a default scan is never refused for its default shots).
[[nodiscard]] int fitting_shots(const SceneScanOptions& o, const device::DeviceConfig& config,
                                int shots);

/// The scan `tofkit scan` makes: `pattern` over `scene` (loaded from the
/// options' file by the caller, io::load_scene) through the virtual
/// rangefinder, beam i on random stream i of `seed`.
[[nodiscard]] scan::ScanResult run_scene_scan(
    const SceneScanOptions& o, const scan::Scene& scene, const scan::BeamPattern& pattern,
    const device::DeviceConfig& config, device::SimulationMode mode, int shots, std::uint64_t seed,
    std::function<void(std::size_t, std::size_t)> progress = {});

/// The scan options run_scene_scan uses (seed, shots, ambient at the start).
[[nodiscard]] scan::ScanOptions scene_scan_options(const SceneScanOptions& o, int shots,
                                                   std::uint64_t seed);

/// Beams a streaming scan measures and writes at a time.
inline constexpr std::size_t kScanBlockBeams = 1 << 15;

}  // namespace tofkit::app
