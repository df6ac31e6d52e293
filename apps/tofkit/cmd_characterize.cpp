// tofkit characterize: the thesis's characterization protocols on the virtual
// rangefinder (reference/characterization_thesis.md, Chapter 4). Writes
// <name>.csv (the raw records with ground truth) and <name>.json (findings,
// tables, summary) atomically into --out, and prints the summary.

#include <fmt/format.h>

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <functional>
#include <map>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "app.hpp"
#include "characterize_registry.hpp"
#include "tofkit/device/accurange_preset.hpp"
#include "tofkit/device/virtual_rangefinder.hpp"
#include "tofkit/experiments/characterization.hpp"
#include "tofkit/experiments/thesis_protocol.hpp"
#include "tofkit/io/atomic_file.hpp"
#include "tofkit/io/raw_csv.hpp"

namespace tofkit::app {
namespace {

struct CharacterizeOptions {
  std::string name;
  std::string out = ".";
  std::uint64_t seed = 1;
  bool json = false;
};

using Outcome = CharacterizeOutcome;  // what every protocol hands back

template <typename Result>
Outcome outcome_of(Result&& r) {
  Outcome o{{}, r.findings(), {r.table()}, r.summary()};  // before the records move out
  o.records = std::move(r.records);
  return o;
}

using Runner = std::function<Outcome(const device::VirtualRangefinder&, std::uint64_t)>;

const std::map<std::string, Runner>& runners() {
  using namespace experiments;
  static const std::map<std::string, Runner> map{
      {"warmup", [](const auto& d, auto s) { return outcome_of(run_warmup(d, {}, s)); }},
      {"turnon", [](const auto& d, auto s) { return outcome_of(run_turn_on(d, {}, s)); }},
      {"sampling", [](const auto& d, auto s) { return outcome_of(run_sampling(d, {}, s)); }},
      {"temperature", [](const auto& d, auto s) { return outcome_of(run_temperature(d, {}, s)); }},
      {"mixed-pixel", [](const auto& d, auto s) { return outcome_of(run_mixed_pixel(d, {}, s)); }},
      {"reflectance", [](const auto& d, auto s) { return outcome_of(run_reflectance(d, {}, s)); }},
      {"angle", [](const auto& d, auto s) { return outcome_of(run_angle(d, {}, s)); }},
      {"thesis",
       [](const auto& d, auto s) {
         auto r = run_thesis_protocol(d, {}, s);
         return Outcome{r.all_records(), r.findings(), r.tables(), r.summary()};
       }},
  };
  return map;
}

/// The built-in protocols and those registered from other files.
const std::map<std::string, Runner>& all_runners() {
  static const std::map<std::string, Runner> map = [] {
    auto m = runners();
    m.insert(registered_characterizations().begin(), registered_characterizations().end());
    return m;
  }();
  return map;
}

/// The device: the user's (--preset / --config), else the accurange preset
/// (the thesis's unit) with any --set overrides applied.
device::DeviceConfig device_config(const AppContext& ctx) {
  if (!ctx.preset.empty() || ctx.config_file) return ctx.load_config();
  if (ctx.overrides.empty()) return device::accurange_preset();
  AppContext accurange = ctx;
  accurange.preset = "accurange";
  return accurange.load_config();
}

nlohmann::json findings_json(const Outcome& o) {
  nlohmann::json findings = nlohmann::json::object();
  nlohmann::json units = nlohmann::json::object();
  for (const auto& f : o.findings) {
    findings[f.name] = f.value;  // NaN is written as null
    units[f.name] = f.unit;
  }
  return {{"findings", findings}, {"units", units}};
}

void run_characterize(const CharacterizeOptions& o, const AppContext& ctx) {
  const auto& table = all_runners();
  const auto it = table.find(o.name);
  if (it == table.end()) throw std::invalid_argument("unknown experiment '" + o.name + "'");
  const std::filesystem::path dir(o.out);
  try {
    io::create_output_directories(dir);  // removed again if the command fails
  } catch (const std::exception& e) {
    throw std::runtime_error("--out " + o.out + ": " + e.what());
  }
  const device::DeviceConfig config = device_config(ctx);
  const device::VirtualRangefinder rangefinder(config);

  const auto start = std::chrono::steady_clock::now();
  const Outcome outcome = it->second(rangefinder, o.seed);
  const double seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();

  nlohmann::json j = findings_json(outcome);
  j["experiment"] = o.name;
  j["device"] = config.name;
  j["seed"] = o.seed;
  j["records"] = outcome.records.size();
  nlohmann::json tables = nlohmann::json::object();
  for (const auto& t : outcome.tables) tables[t.name] = {{"columns", t.columns}, {"rows", t.rows}};
  j["tables"] = tables;
  j["summary"] = outcome.summary;

  const auto csv_path = dir / (o.name + ".csv");
  const auto json_path = dir / (o.name + ".json");
  io::write_raw_csv(csv_path, outcome.records);
  io::write_file_atomically(json_path, j.dump(2) + "\n");

  if (o.json) {
    nlohmann::json brief = findings_json(outcome);
    brief["experiment"] = o.name;
    brief["device"] = config.name;
    brief["seed"] = o.seed;
    fmt::print("{}\n", brief.dump(2));
  } else {
    fmt::print("{}", outcome.summary);
    fmt::print("findings:\n{}", experiments::findings_text(outcome.findings));
  }
  fmt::print(stderr,
             "tofkit characterize {}: device {}, seed {}, {} records in {:.2f} s -> {}, {}\n",
             o.name, config.name, o.seed, outcome.records.size(), seconds, csv_path.string(),
             json_path.string());
}

const bool registered = register_command("characterize", [](CLI::App& sub, AppContext& ctx) {
  sub.description(
      "run one of the thesis's characterization protocols on the virtual rangefinder "
      "(default device: accurange) and write <name>.csv and <name>.json");
  auto o = std::make_shared<CharacterizeOptions>();
  std::vector<std::string> names;
  for (const auto& [name, runner] : all_runners()) names.push_back(name);
  sub.add_option("name", o->name, "experiment: " + fmt::format("{}", fmt::join(names, ", ")))
      ->required()
      ->check(CLI::IsMember(names));
  sub.add_option("--out", o->out, "output directory")->capture_default_str();
  add_seed_option(sub, o->seed, "random seed (the output depends on it only)");
  sub.add_flag("--json", o->json, "print the findings as JSON instead of the summary");
  sub.callback([o, &ctx] { run_characterize(*o, ctx); });
});

}  // namespace

const std::map<std::string, CharacterizeRunner>& characterize_experiments() {
  return all_runners();
}

}  // namespace tofkit::app
