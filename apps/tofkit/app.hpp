#pragma once
/// \file The `tofkit` command-line tool's shared context and its registry of
/// subcommands. Each subcommand lives in its own file and registers itself:
///
///     namespace {
///     const bool registered = tofkit::app::register_command(
///         "fit", [](CLI::App& sub, tofkit::app::AppContext& ctx) {
///           sub.description("fit a correction model");
///           auto opts = std::make_shared<FitOptions>();
///           sub.add_option("--in", opts->in)->required();
///           sub.callback([opts, &ctx] { run_fit(*opts, ctx); });
///         });
///     }
///
/// Callbacks report failure by throwing; main prints
/// "tofkit <command>: error: <message>" and exits with status 1.

#include <CLI/CLI.hpp>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "tofkit/device/device_config.hpp"
#include "tofkit/device/virtual_rangefinder.hpp"
#include "tofkit/io/config_file.hpp"

namespace tofkit::app {

/// Global options, shared by every subcommand.
struct AppContext {
  int threads = 0;  ///< --threads: worker threads for TBB (0: all cores)
  std::optional<std::filesystem::path> config_file;  ///< --config FILE
  std::vector<std::string> overrides;                ///< --set section.key=value, in order
  std::string preset;  ///< --preset NAME (empty: the config file's, else "paper")
  /// Exit status once the command has succeeded and its outputs are committed
  /// (0; `validate --require-in-band` sets 3 when rows are outside their band).
  int exit_status = 0;

  /// The device configuration from --preset, --config and --set (throws
  /// io::ConfigError naming file, line and key).
  [[nodiscard]] device::DeviceConfig load_config() const;
  /// The same with the origin of every value.
  [[nodiscard]] io::LoadedDeviceConfig load_config_traced() const;
};

using CommandSetup = std::function<void(CLI::App& sub, AppContext& ctx)>;

/// Register a subcommand; call from a namespace-scope static initializer.
/// Returns true (so it can initialize a `static const bool`). Throws
/// std::logic_error on a duplicate name.
bool register_command(std::string name, CommandSetup setup);

/// All registered subcommands, by name.
[[nodiscard]] const std::map<std::string, CommandSetup>& registered_commands();

/// A validator's message for NaN ("" otherwise): CLI11's validators let it
/// through (every comparison with NaN is false).
inline std::string nan_refused(const std::string& input) {
  double value = 0;
  if (CLI::detail::lexical_cast(input, value) && std::isnan(value))
    return "Value " + input + " is not a number";
  return "";
}

/// CLI::Range that also refuses NaN. Every bounded option uses it.
class InRange : public CLI::Range {
 public:
  template <typename T>
  InRange(T min_value, T max_value) : CLI::Range(min_value, max_value) {
    func_ = [bounds = func_](std::string& input) {
      std::string refused = nan_refused(input);
      return refused.empty() ? bounds(input) : refused;
    };
  }
};

/// A number option without bounds of its own (its command checks them) but
/// not NaN.
inline const CLI::Validator kNotNan([](std::string& input) { return nan_refused(input); },
                                    "NUMBER");

/// Makes `path`'s directory and its parents (every command makes its output
/// directory; a failed command removes what it made). Throws
/// std::runtime_error naming `option` when a parent is not a directory or
/// cannot be made. Call before a long computation.
void require_output_directory(const std::filesystem::path& path, const std::string& option);

/// The --mode option's value (CLI11 checks it is analytic or waveform).
[[nodiscard]] device::SimulationMode simulation_mode(const std::string& mode);

/// The --mode option's value for `config`: throws std::invalid_argument naming
/// --mode and where oscillator.enabled came from (e.g. "preset 'accurange'") when
/// waveform is asked of the self-oscillating loop, which has no sampled-waveform
/// evaluation (it would repeat the analytic one and check nothing).
[[nodiscard]] device::SimulationMode simulation_mode(const std::string& mode, const AppContext& ctx,
                                                     const device::DeviceConfig& config);

/// Where a config key's value came from, for messages: "--set key=value",
/// "dev.toml:7 (key)" or "preset 'paper'".
[[nodiscard]] std::string origin_of(const io::LoadedDeviceConfig& loaded, const std::string& key);

/// A random seed given on the command line: decimal digits in [0, 2^64 - 1].
/// Throws std::invalid_argument naming `option` for anything else (-1,
/// 18446744073709551616, 1e3): a seed is never clamped or wrapped.
[[nodiscard]] std::uint64_t parse_seed(const std::string& text, const std::string& option);

/// `--seed` of a command, read by parse_seed into `seed` (whose value is the
/// default shown in --help); a bad seed fails the command (exit 1).
CLI::Option* add_seed_option(CLI::App& sub, std::uint64_t& seed, const std::string& help);

}  // namespace tofkit::app
