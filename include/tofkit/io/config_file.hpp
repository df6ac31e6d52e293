#pragma once
/// \file Device configuration files (TOML) and `--set section.key=value`
/// overrides: loading with errors that name file, line and key, and dumping
/// the full effective configuration (which loads back to the same config).
///
/// A file looks like
///
///     preset = "accurange"        # optional; the built-in config to start from
///     [receiver]
///     bandwidth_mhz = 120         # integers are accepted for real-valued keys
///
/// Keys are those of device::config_fields(); sections are laser, receiver,
/// environment, discriminator, tdc, thermal, measurement.

#include <filesystem>
#include <optional>
#include <span>
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

#include "tofkit/device/device_config.hpp"

namespace tofkit::io {

/// Bad configuration: unknown key or section, wrong type, TOML syntax error,
/// value out of range, unknown preset. The message names the file and line
/// ("dev.toml:7: ...") or "--set", and the key; several problems are reported
/// at once, one per line.
class ConfigError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// Where one key's value came from.
struct ConfigSource {
  std::string key;     ///< "receiver.bandwidth_mhz"
  std::string value;   ///< the value as written
  std::string origin;  ///< "dev.toml:7" or "--set"
};

/// A loaded configuration and the provenance of everything that differs from
/// the preset.
struct LoadedDeviceConfig {
  device::DeviceConfig config;
  std::string preset_origin;          ///< "--preset", "dev.toml:1" or "default"
  std::vector<ConfigSource> sources;  ///< in the order applied (later ones win)
};

/// Start from the preset (`preset` empty: the file's `preset = ...`, else
/// "paper"; a file naming a different preset than a non-empty `preset` is an
/// error), apply the file's keys, then the overrides ("section.key=value"),
/// then validate. Throws ConfigError.
[[nodiscard]] LoadedDeviceConfig load_device_config_traced(
    std::string_view preset, const std::optional<std::filesystem::path>& file,
    std::span<const std::string> overrides);

/// load_device_config_traced(...).config.
[[nodiscard]] device::DeviceConfig load_device_config(
    std::string_view preset, const std::optional<std::filesystem::path>& file,
    std::span<const std::string> overrides);

/// Refuses a config text before the TOML parser sees it (ConfigError naming
/// name:line:column) when it is larger than 1 MB, nests brackets or braces
/// deeper than 16 levels or has more than 64 dots on one line outside strings
/// and comments: such files are never configs and could exhaust the parser's
/// stack.
void check_toml_shape(std::string_view text, const std::string& name);

/// A TOML document with `preset = "<name>"` and every key, each preceded by its
/// description and valid range as a comment. Numbers are written in shortest
/// round-trip form, so loading it back gives an identical config.
[[nodiscard]] std::string dump_device_config(const device::DeviceConfig& config);

}  // namespace tofkit::io
