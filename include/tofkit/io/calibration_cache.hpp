#pragma once
/// \file The factory calibration kept between runs, as a real unit keeps its
/// calibration in flash: `tofkit scan` without --model corrects with the
/// device's factory calibration (experiments::factory_calibration, about a
/// second of CPU), made once per device, seed and build and then read back.
///
/// An entry is the model JSON (io::pipeline_to_json) and its uncertainty
/// budget (io::budget_to_json) of one key:
/// - the device config in its canonical form (io::dump_device_config) with
///   what the calibration never reads (the [scan] section) at its defaults;
///   the calibration is made with that same config (calibration_config), so
///   the key holds everything the entry depends on;
/// - the seed;
/// - the code: the GNU build-id of the object (executable or shared library)
///   that holds the calibration code, so a rebuilt binary never reads a model
///   an older build made.
/// The entry's file name is a hash of the key, and the file holds the key
/// itself: an entry is used only when its key is the one asked for.
///
/// Where: `$TOFKIT_CACHE_DIR`, else `$XDG_CACHE_HOME/tofkit`, else
/// `$HOME/.cache/tofkit`. `TOFKIT_CACHE_DIR=off` (or an empty value) turns
/// the cache off. Entries are written atomically (a temporary beside them,
/// renamed over), never through a command's output transaction: they are not
/// outputs. An entry that cannot be read (corrupt, truncated, another key) is
/// ignored and made again; a cache that cannot be written (read-only, full)
/// only costs the next run its calibration again. Neither fails a command.

#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>

#include "tofkit/device/device_config.hpp"
#include "tofkit/ranging/pipeline.hpp"
#include "tofkit/ranging/uncertainty_budget.hpp"

namespace tofkit::io {

/// The cache's directory as the environment sets it (see above); nullopt
/// when it is off (TOFKIT_CACHE_DIR=off or empty, or none of the variables
/// set).
[[nodiscard]] std::optional<std::filesystem::path> calibration_cache_directory();

/// The GNU build-id (lower-case hex) of the loaded object that holds the
/// calibration code (experiments::factory_calibration); "" when it has none
/// (linked with --build-id=none: then nothing is cached).
[[nodiscard]] std::string calibration_code_build_id();

/// `config` with what the factory calibration never reads (the [scan]
/// section: rays per beam, crease angle) at its defaults: the config a cached
/// calibration is made with and keyed by.
[[nodiscard]] device::DeviceConfig calibration_config(const device::DeviceConfig& config);

/// One cache entry's key.
struct FactoryCalibrationKey {
  std::filesystem::path directory;
  std::string build_id;
  std::uint64_t seed = 1;
  std::string config_text;  ///< dump_device_config(calibration_config(config))

  /// `directory/factory-<hash of the key>.json`.
  [[nodiscard]] std::filesystem::path entry() const;
};

/// The key of (config, seed) for this build in `directory`; nullopt (and
/// `note` says why) when this build has no build-id.
[[nodiscard]] std::optional<FactoryCalibrationKey> factory_calibration_key(
    const std::filesystem::path& directory, const device::DeviceConfig& config, std::uint64_t seed,
    std::string& note);

/// A factory calibration as an entry holds it: the model and its uncertainty
/// budget (a scan's sigma_m is the budget's combined uncertainty).
struct FactoryCalibration {
  ranging::Pipeline pipeline;
  ranging::UncertaintyBudget budget;
};

/// The entry's model and budget, or nullopt: absent (note stays ""), or unusable (not
/// JSON, truncated, another key, a bad model: `note` says which and why).
/// Never throws.
[[nodiscard]] std::optional<FactoryCalibration> load_factory_calibration(
    const FactoryCalibrationKey& key, std::string& note);

/// Writes the entry atomically (the directory made if missing). False, with
/// `note`, when it cannot (a read-only or full cache; a model or budget whose
/// JSON does not read back to the same JSON). Never throws.
bool store_factory_calibration(const FactoryCalibrationKey& key,
                               const FactoryCalibration& calibration, std::string& note);

}  // namespace tofkit::io
