// The `tofkit` command-line tool: global options, then one self-registered
// subcommand (see app.hpp).

#include <fmt/format.h>
#include <tbb/global_control.h>

#include <algorithm>
#include <cstdio>
#include <exception>
#include <memory>
#include <new>
#include <string>
#include <vector>

#include "app.hpp"
#include "tofkit/io/atomic_file.hpp"
#include "tofkit/io/edit_distance.hpp"
#include "tofkit/io/input_file.hpp"

namespace {

/// ", did you mean 'X'?" for the nearest of `known` within a third of the
/// word's length (at least 2 edits), else "".
std::string suggestion(const std::string& word, const std::vector<std::string>& known) {
  std::string best;
  std::size_t best_distance = std::max<std::size_t>(2, word.size() / 3) + 1;
  for (const std::string& name : known) {
    const std::size_t d = tofkit::io::edit_distance(word, name);
    if (d < best_distance) {
      best = name;
      best_distance = d;
    }
  }
  return best.empty() ? "" : "; did you mean '" + best + "'?";
}

std::vector<std::string> long_option_names(const CLI::App& app) {
  std::vector<std::string> names;
  for (const CLI::Option* option : app.get_options()) {
    for (const std::string& name : option->get_lnames()) names.push_back("--" + name);
  }
  return names;
}

/// Typo help before CLI11 parses (which would say only "A subcommand is
/// required" or "--distance is required"): an unknown command, or an
/// unknown --option of the command or of the globals, is named with the
/// nearest known one. Returns the message, "" when every word is known.
std::string unknown_word(const CLI::App& app, int argc, char** argv) {
  static const std::vector<std::string> kGlobalsWithValue = {
      "--threads", "--config", "--set", "--preset", "--max-rows", "--max-input-mb"};
  const CLI::App* command = nullptr;
  std::vector<std::string> commands;
  std::vector<const CLI::App*> subs;
  for (const CLI::App* sub : app.get_subcommands({})) {
    commands.push_back(sub->get_name());
    subs.push_back(sub);
  }
  for (int i = 1; i < argc; ++i) {
    const std::string word = argv[i];
    if (word == "--") break;
    if (word.rfind("--", 0) == 0) {
      const std::string name = word.substr(0, word.find('='));
      const bool known = app.get_option_no_throw(name) != nullptr ||
                         (command != nullptr && command->get_option_no_throw(name) != nullptr);
      if (!known) {
        std::vector<std::string> names = long_option_names(app);
        if (command != nullptr) {
          const auto own = long_option_names(*command);
          names.insert(names.end(), own.begin(), own.end());
        }
        return fmt::format("tofkit{}: unknown option '{}'{}",
                           command != nullptr ? " " + command->get_name() : "", name,
                           suggestion(name, names));
      }
      // A global option's value is the next word (unless given as --x=v).
      if (command == nullptr && word.find('=') == std::string::npos &&
          std::find(kGlobalsWithValue.begin(), kGlobalsWithValue.end(), name) !=
              kGlobalsWithValue.end())
        ++i;
      continue;
    }
    if (command != nullptr || word.rfind('-', 0) == 0) continue;
    if (std::find(commands.begin(), commands.end(), word) == commands.end()) {
      return fmt::format("tofkit: unknown command '{}'{} (tofkit --help lists them)", word,
                         suggestion(word, commands));
    }
    command = subs[static_cast<std::size_t>(std::find(commands.begin(), commands.end(), word) -
                                            commands.begin())];
  }
  return "";
}

}  // namespace

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

  auto& limits = tofkit::io::resource_limits();
  app.add_option("--max-rows", limits.max_rows,
                 "largest number of rows a command reads or simulates, and of values in a LIST")
      ->check(CLI::PositiveNumber)
      ->capture_default_str();
  double max_input_mb = static_cast<double>(limits.max_input_bytes) / 1048576.0;
  app.add_option("--max-input-mb", max_input_mb, "largest input file read, MB")
      ->check(tofkit::app::InRange(1e-3, 1e6))
      ->capture_default_str();

  // Applies --threads and the input limit before any subcommand callback runs.
  std::unique_ptr<tbb::global_control> thread_limit;
  app.parse_complete_callback([&] {
    limits.max_input_bytes = static_cast<std::uint64_t>(max_input_mb * 1048576.0);
    if (ctx.threads > 0) {
      thread_limit = std::make_unique<tbb::global_control>(
          tbb::global_control::max_allowed_parallelism, static_cast<std::size_t>(ctx.threads));
    }
  });

  for (const auto& [name, setup] : tofkit::app::registered_commands()) {
    setup(*app.add_subcommand(name), ctx);
  }

  // Every file a command writes is staged and renamed into place only once
  // the command has succeeded; on an error the destructor removes them all.
  tofkit::io::OutputTransaction outputs;
  auto fail = [&](const std::string& message) {
    std::string command;
    for (const CLI::App* sub : app.get_subcommands()) command = " " + sub->get_name();
    fmt::print(stderr, "tofkit{}: error: {}\n", command, message);
    return 1;
  };
  if (const std::string unknown = unknown_word(app, argc, argv); !unknown.empty()) {
    fmt::print(stderr, "{}\n", unknown);
    return 2;
  }
  try {
    app.parse(argc, argv);
    outputs.commit();
  } catch (const CLI::ValidationError& e) {
    // A value outside its option's range or set (NaN included) is bad input,
    // as every other: status 1 naming the option, like a bad config key.
    return fail(e.what());
  } catch (const CLI::ConversionError& e) {
    return fail(e.what());
  } catch (const CLI::ParseError& e) {
    const int code = app.exit(e);
    return code == 0 ? 0 : 2;
  } catch (const std::bad_alloc&) {
    return fail(
        "out of memory: the inputs or options ask for more memory than this machine has "
        "(see --max-rows, --max-input-mb and the limits in README 'Errors, limits and fuzzing')");
  } catch (const std::exception& e) {
    return fail(e.what());
  }
  return ctx.exit_status;
}
