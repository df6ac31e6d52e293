// tofkit config [--dump]: the effective device configuration and where it came from.

#include <fmt/format.h>

#include <cstdio>
#include <memory>

#include "app.hpp"
#include "tofkit/io/config_file.hpp"

namespace tofkit::app {
namespace {

struct ConfigOptions {
  bool dump = false;
};

void run_config(const ConfigOptions& options, const AppContext& ctx) {
  const io::LoadedDeviceConfig loaded = ctx.load_config_traced();
  if (options.dump) {
    fmt::print("{}", io::dump_device_config(loaded.config));
    return;
  }
  fmt::print("preset: {} ({})\n", loaded.config.name, loaded.preset_origin);
  if (ctx.config_file) fmt::print("config file: {}\n", ctx.config_file->string());
  if (loaded.sources.empty()) {
    fmt::print("no overrides: the built-in preset as is (--dump prints every key)\n");
    return;
  }
  std::size_t width = 0;
  for (const auto& s : loaded.sources) width = std::max(width, s.key.size() + s.value.size() + 3);
  fmt::print("overrides (later ones win):\n");
  for (const auto& s : loaded.sources) {
    fmt::print("  {:<{}}  from {}\n", s.key + " = " + s.value, width, s.origin);
  }
}

const bool registered = register_command("config", [](CLI::App& sub, AppContext& ctx) {
  sub.description("show the effective device configuration (--dump: as a complete TOML file)");
  auto options = std::make_shared<ConfigOptions>();
  sub.add_flag("--dump", options->dump, "print every key with its value and description (TOML)");
  sub.callback([options, &ctx] { run_config(*options, ctx); });
});

}  // namespace
}  // namespace tofkit::app
