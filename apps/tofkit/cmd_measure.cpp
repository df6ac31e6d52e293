// tofkit measure: the virtual rangefinder over a grid of plates and temperatures,
// written as a raw CSV with ground truth.

#include <fmt/format.h>
#include <tbb/global_control.h>

#include <chrono>
#include <cstdio>
#include <limits>
#include <memory>
#include <string>
#include <vector>

#include "app.hpp"
#include "tofkit/device/virtual_rangefinder.hpp"
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
  std::uint64_t seed = 1;
  std::string mode = "analytic";
  std::string out;
};

constexpr double kMaxRows = 1e8;

void check_all(const std::vector<double>& values, const char* option, double min, double max) {
  for (const double v : values) {
    if (!(v >= min && v <= max)) {
      throw std::invalid_argument(fmt::format("{}: {} is outside [{}, {}]", option, v, min, max));
    }
  }
}

void run_measure(const MeasureOptions& o, const AppContext& ctx) {
  const auto distances = io::parse_value_list(o.distances, "--distance");
  const auto reflectances = io::parse_value_list(o.reflectances, "--reflectance");
  const auto angles = io::parse_value_list(o.angles, "--angle");
  const auto temperatures = io::parse_value_list(o.temperatures, "--temperature");
  check_all(distances, "--distance", 1e-3, 1e5);
  check_all(reflectances, "--reflectance", 0.0, 1.0);
  check_all(angles, "--angle", 0.0, 89.9);
  check_all(temperatures, "--temperature", -60.0, 150.0);

  const device::DeviceConfig config = ctx.load_config();
  require_output_directory(o.out, "--out");

  double rows = static_cast<double>(o.count);
  for (const auto* list : {&distances, &reflectances, &angles, &temperatures}) {
    rows *= static_cast<double>(list->size());
  }
  if (rows > kMaxRows) {
    throw std::invalid_argument(
        fmt::format("the grid has {:g} rows, more than {:g}", rows, kMaxRows));
  }

  // Cartesian product: distance outermost, then reflectance, angle, temperature,
  // repeats innermost. Request i uses random stream i (thread-count independent).
  std::vector<device::MeasureRequest> requests;
  std::vector<ranging::Record> records;
  requests.reserve(static_cast<std::size_t>(rows));
  records.reserve(static_cast<std::size_t>(rows));
  for (const double d : distances) {
    for (const double rho : reflectances) {
      for (const double angle : angles) {
        for (const double t : temperatures) {
          device::Conditions conditions;
          conditions.ambient_c = t;
          for (int k = 0; k < o.count; ++k) {
            requests.push_back(
                device::MeasureRequest{device::Target::plate(d, rho, angle), conditions, o.shots});
            ranging::Record record;
            record.truth = ranging::GroundTruth{d, rho, angle, t};
            records.push_back(record);
          }
        }
      }
    }
  }

  const auto mode =
      o.mode == "waveform" ? device::SimulationMode::kWaveform : device::SimulationMode::kAnalytic;
  const auto start = std::chrono::steady_clock::now();
  const device::VirtualRangefinder rangefinder(config, mode);
  std::vector<ranging::RawMeasurement> raw(requests.size());
  rangefinder.measure_batch(requests, o.seed, raw);
  for (std::size_t i = 0; i < raw.size(); ++i) records[i].raw = raw[i];
  const double seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();

  io::write_raw_csv(o.out, records);
  const int shots = o.shots > 0 ? o.shots : config.measurement.shots;
  const auto threads =
      tbb::global_control::active_value(tbb::global_control::max_allowed_parallelism);
  fmt::print(stderr,
             "tofkit measure: {} rows ({} shots each, {} mode, seed {}) in {:.2f} s on {} "
             "thread(s) -> {}\n",
             records.size(), shots, o.mode, o.seed, seconds, threads, o.out);
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
      ->check(CLI::Range(1, 10'000'000));
  sub.add_option("--count", o->count, "repeated measurements per grid point")
      ->check(CLI::Range(1, 100'000'000))
      ->capture_default_str();
  sub.add_option("--seed", o->seed, "random seed (the output depends on it only)")
      ->capture_default_str();
  sub.add_option("--mode", o->mode, "analytic (fast) or waveform (sampled, reference)")
      ->check(CLI::IsMember({"analytic", "waveform"}))
      ->capture_default_str();
  sub.add_option("--out", o->out, "raw CSV to write")->required();
  sub.callback([o, &ctx] { run_measure(*o, ctx); });
});

}  // namespace
}  // namespace tofkit::app
