// tofkit scan: a scene (TOML) scanned by a pattern through the virtual
// rangefinder, written as images (PNG + JSON sidecar, .npy), point clouds
// (PLY, PCD, LAS), the per-beam table scan.csv and a picture, range_view.png.

#include <fmt/format.h>
#include <tbb/global_control.h>
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <memory>
#include <nlohmann/json.hpp>
#include <set>
#include <string>
#include <vector>

#include "app.hpp"
#include "scene_scan.hpp"
#include "tofkit/device/virtual_rangefinder.hpp"
#include "tofkit/io/atomic_file.hpp"
#include "tofkit/io/model_json.hpp"
#include "tofkit/io/scan_output.hpp"
#include "tofkit/io/scan_writer.hpp"
#include "tofkit/io/scene_file.hpp"
#include "tofkit/scan/scanner.hpp"

namespace tofkit::app {
namespace {

struct ScanCliOptions {
  SceneScanOptions scan;
  std::string model, mode = "analytic", write = "all", out;
  int shots = 0;
  std::uint64_t seed = 1;
};

const std::vector<std::string>& all_outputs() {
  static const std::vector<std::string> names = {"csv", "png", "npy", "ply", "pcd", "las", "view"};
  return names;
}

std::set<std::string> parse_write(const std::string& text) {
  std::set<std::string> picked;
  // Every item between commas, the empty ones too ("csv," names an empty output).
  for (std::size_t start = 0, comma = 0; comma != std::string::npos; start = comma + 1) {
    comma = text.find(',', start);
    const std::string item = text.substr(start, comma == std::string::npos ? comma : comma - start);
    if (item == "all") {
      picked.insert(all_outputs().begin(), all_outputs().end());
      continue;
    }
    if (std::find(all_outputs().begin(), all_outputs().end(), item) == all_outputs().end()) {
      throw std::invalid_argument("--write: unknown output '" + item +
                                  "' (known: all, csv, png, npy, ply, pcd, las, view)");
    }
    picked.insert(item);
  }
  if (picked.empty()) throw std::invalid_argument("--write: nothing to write");
  return picked;
}

// A one-line progress indicator on a terminal; silent when stderr is a file.
struct Progress {
  bool tty = ::isatty(STDERR_FILENO) != 0;
  void operator()(std::size_t done, std::size_t total) const {
    if (!tty || total < (1u << 17)) return;
    fmt::print(stderr, "\rtofkit scan: {:5.1f} % of {} beams",
               100.0 * static_cast<double>(done) / static_cast<double>(total), total);
    if (done == total) fmt::print(stderr, "\r\033[K");
  }
};

std::string sidecar(const std::string& file, const char* quantity, const char* units, double scale,
                    double offset, const scan::BeamPattern& pattern, const ScanCliOptions& o) {
  nlohmann::json j;
  j["file"] = file;
  j["quantity"] = quantity;
  j["units"] = units;
  j["value"] = "offset + scale * pixel";
  j["scale"] = scale;
  j["offset"] = offset;
  j["invalid_value"] = 0;
  j["rows"] = pattern.rows;
  j["columns"] = pattern.columns;
  j["frame"] = "REP-103: sensor looks along +x, z up; row 0 top, column 0 left";
  j["scan"] = {{"scene", o.scan.scene},  {"pattern", o.scan.pattern}, {"mode", o.mode},
               {"seed", o.seed},         {"shots", o.shots},          {"model", o.model},
               {"beams", pattern.size()}};
  return j.dump(2) + "\n";
}

void run_scan_command(const ScanCliOptions& o, const AppContext& ctx) {
  const auto outputs = parse_write(o.write);
  const device::DeviceConfig config = ctx.load_config();
  const scan::Scene scene = io::load_scene(o.scan.scene);
  std::optional<ranging::Pipeline> pipeline;
  if (!o.model.empty()) pipeline = io::load_pipeline(o.model);
  std::error_code ec;
  if (!std::filesystem::is_directory(o.out, ec)) {
    throw std::runtime_error("--out: '" + o.out + "' " +
                             (std::filesystem::exists(o.out, ec) ? "is not a directory"
                                                                 : "(a directory) does not exist"));
  }
  const int shots = scan_shots(config, o.shots);
  const scan::BeamPattern pattern = make_scan_pattern(o.scan, config, shots, /*on_demand=*/true);

  const auto start = std::chrono::steady_clock::now();
  const auto mode = simulation_mode(o.mode);
  // The scan streams: blocks of beams measured, corrected and written in beam
  // order; every file through the one writer, staged and committed with the
  // others only when the command succeeds (main's OutputTransaction).
  scan::ScanResult description = scan::describe_scan(pattern, scene);
  description.has_model = pipeline.has_value();
  io::ScanWriterSettings settings;
  settings.directory = o.out;
  settings.outputs = outputs;
  settings.ambient_c = o.scan.ambient_c;
  settings.sidecar = [&](const std::string& file, const char* quantity, const char* units,
                         double scale, double offset) {
    return sidecar(file, quantity, units, scale, offset, pattern, o);
  };
  io::ScanWriter writer(description, scan::row_last_beams(pattern), std::move(settings));
  run_scene_scan_blocks(
      o.scan, scene, pattern, config, mode, shots, o.seed, 0, pattern.size(),
      [&](std::size_t first, std::span<scan::BeamResult> beams) {
        if (pipeline) scan::apply_pipeline(*pipeline, beams);
        writer.add(first, beams);
      },
      Progress{});
  const io::ScanWriter::Summary summary = writer.finish();
  const double seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();

  const auto threads =
      tbb::global_control::active_value(tbb::global_control::max_allowed_parallelism);
  fmt::print(stderr,
             "tofkit scan: {} beams ({} x {} image, {} pattern, {} rays/beam, {} shots, {} mode, "
             "seed {}): "
             "{} points, {} mixed pixels, {} without echo; {:.2f} s on {} thread(s) -> {}/\n",
             summary.beams, pattern.rows, pattern.columns, o.scan.pattern,
             config.scan.rays_per_beam, scan::shots_per_beam(config, o.shots, pattern), o.mode,
             o.seed, summary.points, summary.mixed, summary.beams - summary.points, seconds,
             threads, o.out);
}

const bool registered = register_command("scan", [](CLI::App& sub, AppContext& ctx) {
  sub.description("scan a scene (TOML) with a pattern: range/intensity images and point clouds");
  auto o = std::make_shared<ScanCliOptions>();
  const SceneScanOptionHandles h = add_scene_scan_options(sub, o->scan);
  h.scene->required();
  h.pattern->required();
  sub.add_option("--model", o->model,
                 "correction model (JSON, from tofkit fit): adds range, sigma");
  sub.add_option("--mode", o->mode, "analytic (fast) or waveform (sampled, reference)")
      ->check(CLI::IsMember({"analytic", "waveform"}))
      ->capture_default_str();
  sub.add_option("--shots", o->shots, "shots averaged per beam (default: config's)")
      ->check(InRange(1, 10'000'000));
  add_seed_option(sub, o->seed, "random seed (the output depends on it only)");
  sub.add_option("--write", o->write, "outputs: all or LIST of csv, png, npy, ply, pcd, las, view")
      ->capture_default_str();
  sub.add_option("--out", o->out, "output directory (must exist)")->required();
  sub.callback([o, &ctx] { run_scan_command(*o, ctx); });
});

}  // namespace
}  // namespace tofkit::app
