// tofkit measure: the virtual rangefinder over a grid of plates and temperatures,
// written as a raw CSV with ground truth.

#include <fmt/format.h>
#include <tbb/global_control.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <iostream>
#include <limits>
#include <memory>
#include <string>
#include <vector>

#include "app.hpp"
#include "plate_grid.hpp"
#include "tofkit/device/config_limits.hpp"
#include "tofkit/device/virtual_rangefinder.hpp"
#include "tofkit/io/input_file.hpp"
#include "tofkit/io/raw_csv.hpp"
#include "tofkit/io/value_list.hpp"

namespace tofkit::app {
namespace {

struct MeasureOptions {
  std::string distances;
  std::string reflectances;
  std::string angles = "0";
  std::string temperatures = fmt::format("{}", device::Conditions{}.ambient_c);
  int shots = 0;  // 0: the config's measurement.shots
  int count = 1;
  std::string count_text = "1";  // --count: a whole number, "1e3" allowed
  std::uint64_t seed = 1;
  std::string mode = "analytic";
  std::string out;
  experiments::RunTiming timing;  // --start-s, --every
};

// --count as a whole number >= 1; "1e8" is 100000000 (then refused by the row
// limit, not by the option parser).
int parse_count(const std::string& text) {
  double v = 0;
  if (const auto why = io::parse_number(text, v)) {
    throw std::invalid_argument("--count " + text + ": " + *why);
  }
  if (!(v >= 1 && v == std::floor(v))) {
    throw std::invalid_argument("--count " + text + ": expected a whole number >= 1");
  }
  const double limit = static_cast<double>(io::resource_limits().max_rows);
  if (v > limit || v > 2147483647.0) {
    throw std::invalid_argument(fmt::format(
        "--count {}: more than the row limit of {:g} (raise it with --max-rows)", text, limit));
  }
  return static_cast<int>(v);
}

void run_measure(const MeasureOptions& o, const AppContext& ctx) {
  experiments::PlateGrid grid =
      parse_plate_grid(o.distances, o.reflectances, o.angles, o.temperatures);
  grid.count = o.count;
  grid.shots = o.shots;
  const device::DeviceConfig config = ctx.load_config();
  if (o.out != "-") require_output_directory(o.out, "--out");

  const double rows = grid.rows();
  const auto max_rows = static_cast<double>(io::resource_limits().max_rows);
  if (rows > max_rows) {
    throw std::invalid_argument(fmt::format(
        "the grid (--distance x --reflectance x --angle x --temperature x --count) has {:g} rows, "
        "more than the limit of {:g} (raise it with --max-rows)",
        rows, max_rows));
  }
  // The echo of every plate, and in waveform mode the record, within the
  // documented limits (device/config_limits.hpp), before any work.
  double widest_spread_ns = 0;
  for (const double d : grid.distances_m) {
    for (const double angle : grid.angles_deg) {
      const std::string problem = device::check_plate_echo(config, d, angle);
      if (!problem.empty()) throw std::invalid_argument("--distance/--angle: " + problem);
      widest_spread_ns = std::max(widest_spread_ns, device::plate_echo_spread_ns(config, d, angle));
    }
  }
  try {
    o.timing.validate(config);
  } catch (const std::invalid_argument& e) {
    const std::string what = e.what();
    throw std::invalid_argument((what.rfind("start_s", 0) == 0 ? "--start-s: " : "--every: ") +
                                what);
  }
  const auto mode = simulation_mode(o.mode, ctx, config);  // refused for the loop
  if (o.mode == "waveform") {
    const auto violations = device::check_waveform_limits(config, widest_spread_ns);
    if (!violations.empty()) {
      const auto& v = violations.front();
      throw std::invalid_argument(
          "--mode waveform: " + origin_of(ctx.load_config_traced(), v.keys.front()) + ": " +
          v.message);
    }
  }

  // The grid's order (experiments/plate_grid.hpp): request i on random stream i
  // (thread-count independent).
  const std::vector<experiments::PlannedMeasurement> plan =
      experiments::plate_grid_plan(grid, max_rows);
  const auto start = std::chrono::steady_clock::now();
  const device::VirtualRangefinder rangefinder(config, mode);
  const std::vector<ranging::Record> records =
      experiments::run(rangefinder, plan, o.seed, o.timing);
  const double seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();

  // A timed run (--start-s, --every) writes each row's time since power-on
  // (time_s): fit takes the calibration's time from it, correct a row's time
  // since calibration.
  std::vector<double> time_s;
  if (o.timing.start_s > 0 || o.timing.every_s > 0) {
    const double step =
        o.timing.every_s > 0 ? o.timing.every_s : experiments::output_period_s(config);
    for (std::size_t k = 0; k < records.size(); ++k)
      time_s.push_back(o.timing.start_s + static_cast<double>(k) * step);
  }
  if (o.out == "-") {
    std::cout.sync_with_stdio(false);
    io::write_raw_csv(std::cout, records, time_s);
    std::cout.flush();
  } else {
    io::write_raw_csv(o.out, records, time_s);
  }
  const int shots = o.shots > 0 ? o.shots : config.measurement.shots;
  const auto threads =
      tbb::global_control::active_value(tbb::global_control::max_allowed_parallelism);
  fmt::print(stderr,
             "tofkit measure: {} rows ({} shots each, {} mode, seed {}) in {:.2f} s on {} "
             "thread(s) -> {}\n",
             records.size(), shots, o.mode, o.seed, seconds, threads,
             o.out == "-" ? "stdout" : o.out);
}

const bool registered = register_command("measure", [](CLI::App& sub, AppContext& ctx) {
  sub.description("simulate measurements of plates over a grid (Cartesian product) into a raw CSV");
  auto o = std::make_shared<MeasureOptions>();
  sub.add_option("--distance", o->distances, "true distances, m: LIST (a,b,c or start:stop:step)")
      ->required();
  sub.add_option("--reflectance", o->reflectances, "plate reflectances: LIST")->required();
  sub.add_option("--angle", o->angles, "incidence angles, degrees: LIST")->capture_default_str();
  sub.add_option("--temperature", o->temperatures, "ambient temperatures, C: LIST")
      ->capture_default_str();
  sub.add_option("--shots", o->shots, "shots averaged per measurement (default: config's)")
      ->check(InRange(1, 10'000'000));
  sub.add_option("--count", o->count_text, "repeated measurements per grid point")
      ->capture_default_str();
  add_seed_option(sub, o->seed, "random seed (the output depends on it only)");
  sub.add_option("--start-s", o->timing.start_s,
                 "start the run S seconds after power-on (the seed is the power-on): the device's "
                 "slow delay offsets (flicker, wander) are those of that time")
      ->check(kNotNan)
      ->capture_default_str();
  sub.add_option("--every", o->timing.every_s,
                 "seconds between the starts of consecutive rows (0: back to back, one output "
                 "period apart): a stability record over time")
      ->check(kNotNan)
      ->capture_default_str();
  sub.add_option("--mode", o->mode, "analytic (fast) or waveform (sampled, reference)")
      ->check(CLI::IsMember({"analytic", "waveform"}))
      ->capture_default_str();
  sub.add_option("--out", o->out, "raw CSV to write (- for stdout); its directory is made")
      ->required();
  sub.callback([o, &ctx] {
    o->count = parse_count(o->count_text);
    run_measure(*o, ctx);
  });
});

}  // namespace
}  // namespace tofkit::app
