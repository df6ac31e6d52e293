#include "app.hpp"

#include <charconv>
#include <stdexcept>
#include <utility>

#include "tofkit/io/atomic_file.hpp"

namespace tofkit::app {
namespace {

// Function-local static: safe whatever order the commands' static initializers run in.
std::map<std::string, CommandSetup>& registry() {
  static std::map<std::string, CommandSetup> commands;
  return commands;
}

}  // namespace

device::DeviceConfig AppContext::load_config() const {
  return load_config_traced().config;
}

io::LoadedDeviceConfig AppContext::load_config_traced() const {
  return io::load_device_config_traced(preset, config_file, overrides);
}

bool register_command(std::string name, CommandSetup setup) {
  auto [it, inserted] = registry().emplace(std::move(name), std::move(setup));
  if (!inserted) throw std::logic_error("tofkit command registered twice: " + it->first);
  return true;
}

const std::map<std::string, CommandSetup>& registered_commands() {
  return registry();
}

device::SimulationMode simulation_mode(const std::string& mode) {
  return mode == "waveform" ? device::SimulationMode::kWaveform : device::SimulationMode::kAnalytic;
}

device::SimulationMode simulation_mode(const std::string& mode, const AppContext& ctx,
                                       const device::DeviceConfig& config) {
  const auto m = simulation_mode(mode);
  if (m == device::SimulationMode::kWaveform && config.oscillator.enabled) {
    throw std::invalid_argument(
        "--mode waveform: " + origin_of(ctx.load_config_traced(), "oscillator.enabled") +
        " measures by the self-oscillating loop (oscillator.enabled = true), which has no "
        "sampled-waveform evaluation; use --mode analytic");
  }
  return m;
}

void require_output_directory(const std::filesystem::path& path, const std::string& option) {
  const std::filesystem::path directory = path.parent_path();
  if (directory.empty()) return;
  try {
    io::create_output_directories(directory);  // removed again if the command fails
  } catch (const std::exception& e) {
    throw std::runtime_error(option + " " + path.string() + ": " + e.what());
  }
}

std::string origin_of(const io::LoadedDeviceConfig& loaded, const std::string& key) {
  std::string origin = "preset '" + loaded.config.name + "'";
  for (const auto& s : loaded.sources) {
    if (s.key != key) continue;  // the last assignment wins
    origin = s.origin == "--set" ? "--set " + key + "=" + s.value : s.origin + " (" + key + ")";
  }
  return origin;
}

std::uint64_t parse_seed(const std::string& text, const std::string& option) {
  std::uint64_t seed = 0;
  const auto [ptr, ec] = std::from_chars(text.data(), text.data() + text.size(), seed);
  if (text.empty() || ec != std::errc() || ptr != text.data() + text.size()) {
    throw std::invalid_argument(option + " " + text +
                                ": a seed is a whole number from 0 to 18446744073709551615");
  }
  return seed;
}

CLI::Option* add_seed_option(CLI::App& sub, std::uint64_t& seed, const std::string& help) {
  return sub
      .add_option_function<std::string>(
          "--seed", [&seed](const std::string& text) { seed = parse_seed(text, "--seed"); }, help)
      ->default_str(std::to_string(seed));
}

}  // namespace tofkit::app
