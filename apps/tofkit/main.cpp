// The `tofkit` command-line tool: global options, then one self-registered
// subcommand (see app.hpp).

#include <fmt/format.h>
#include <tbb/global_control.h>

#include <cstdio>
#include <exception>
#include <memory>
#include <string>

#include "app.hpp"

int main(int argc, char** argv) {
  using tofkit::app::AppContext;

  CLI::App app{"tofkit - pulsed time-of-flight laser rangefinder toolkit", "tofkit"};
  app.require_subcommand(1);
  app.fallthrough();  // global options are accepted after the subcommand too

  AppContext ctx;
  app.add_option("--threads", ctx.threads, "worker threads (default: all cores)")
      ->check(CLI::PositiveNumber);
  app.add_option("--config", ctx.config_file, "device configuration file (TOML)");
  app.add_option("--set", ctx.overrides, "override a configuration key: section.key=value")
      ->expected(1)
      ->multi_option_policy(CLI::MultiOptionPolicy::TakeAll);
  app.add_option("--preset", ctx.preset,
                 "built-in device to start from (paper, accurange; default: the config "
                 "file's, else paper)");

  // Applies --threads before any subcommand callback runs.
  std::unique_ptr<tbb::global_control> thread_limit;
  app.parse_complete_callback([&] {
    if (ctx.threads > 0) {
      thread_limit = std::make_unique<tbb::global_control>(
          tbb::global_control::max_allowed_parallelism, static_cast<std::size_t>(ctx.threads));
    }
  });

  for (const auto& [name, setup] : tofkit::app::registered_commands()) {
    setup(*app.add_subcommand(name), ctx);
  }

  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    const int code = app.exit(e);
    return code == 0 ? 0 : 2;
  } catch (const std::exception& e) {
    std::string command;
    for (const CLI::App* sub : app.get_subcommands()) command = " " + sub->get_name();
    fmt::print(stderr, "tofkit{}: error: {}\n", command, e.what());
    return 1;
  }
  return 0;
}
