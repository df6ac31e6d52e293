#pragma once
/// \file A sweep plan (TOML): parameter axes (any device key, applied as
/// `--set key=value`, and the conditions distance_m, reflectance, angle_deg,
/// ambient_c, seed) and the measurements to take at each point of their
/// Cartesian product (last axis fastest); the row of the sweep table for a
/// point. `tofkit sweep` and Python's tofkit.sweep share it, so their tables
/// are the same bytes.
///
///     [axes]
///     "laser.pulse_width_ns" = [1.0, 2.0, 4.0]
///     distance_m = [1.0, 4.0]
///     reflectance = [0.1, 0.9]
///     [measure]                  # count measurements of `shots` shots; a condition
///     shots = 1000               # that is not an axis may be given here
///     count = 3
///     mode = "analytic"
///     [budget]                   # optional: received_power_w, snr, range_at_snr10_m
///     [characterize]             # optional: a `tofkit characterize` experiment's
///     experiment = "reflectance" # findings at every point (the command line's)

#include <cstdint>
#include <filesystem>
#include <functional>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "tofkit/device/device_config.hpp"

namespace tofkit::io {

/// A `tofkit characterize` experiment's findings (name, value) on a device
/// at a seed. The experiments live with the command line (apps/), which
/// supplies this; without it a plan's [characterize] is refused.
using SweepCharacterize = std::function<std::vector<std::pair<std::string, double>>(
    const std::string& experiment, const device::DeviceConfig& config, std::uint64_t seed)>;

/// The device configuration every point starts from (the CLI's --preset,
/// --config and --set), and the characterize experiments at hand.
struct SweepBase {
  std::string preset;
  std::optional<std::filesystem::path> config_file;
  std::vector<std::string> overrides;
  SweepCharacterize characterize;        ///< runs an experiment (empty: none available)
  std::vector<std::string> experiments;  ///< their names
};

struct SweepAxis {
  std::string key;                  ///< device key or condition
  bool device_key = false;          ///< applied as --set key=value
  std::vector<std::string> values;  ///< as written in the table (and in --set)
  std::vector<double> numbers;      ///< the values as numbers (NaN for a non-number)
};

struct SweepPlan {
  std::vector<SweepAxis> axes;  ///< in the file's order
  int shots = 0, count = 1;
  std::string mode = "analytic";
  bool measure = true, budget = false;
  std::string characterize;                        ///< [characterize] experiment ("": none)
  std::vector<std::string> characterize_findings;  ///< its findings' names (the columns)
  double distance_m = 0, reflectance = 0, angle_deg = 0, ambient_c = 0;  ///< when not an axis
  std::uint64_t seed = 1;
  std::uint64_t fingerprint = 0;  ///< of the plan and the base configuration
  [[nodiscard]] std::uint64_t points() const;
};

/// Reads and checks a plan; throws std::invalid_argument naming the file,
/// line and key of the first problem (an unknown key, a bad value, a device
/// key the configuration refuses, more points than --max-rows).
[[nodiscard]] SweepPlan load_sweep_plan(const std::filesystem::path& file, const SweepBase& base);

/// The table's header (no newline): the axes, then the figures.
[[nodiscard]] std::string sweep_header(const SweepPlan& plan);

/// Row `index` of the table (no newline). Throws std::invalid_argument naming
/// the point when its echo cannot be simulated.
[[nodiscard]] std::string sweep_row(const SweepPlan& plan, const SweepBase& base,
                                    std::uint64_t index);

}  // namespace tofkit::io
