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
#include "tofkit/experiments/device_plan.hpp"
#include "tofkit/io/atomic_file.hpp"
#include "tofkit/io/model_json.hpp"
#include "tofkit/io/scan_output.hpp"
#include "tofkit/io/scene_file.hpp"
#include "tofkit/scan/scanner.hpp"

namespace tofkit::app {
namespace {

struct ScanCliOptions {
  SceneScanOptions scan;
  std::string model, mode = "analytic", write = "all", out;
  int shots = 0;
  std::uint64_t seed = 1;
  bool raw = false;  // --raw: no correction (the default is the factory calibration)
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

nlohmann::json sidecar(const std::string& file, const char* quantity, const char* units,
                       const io::Png16& png, const scan::ScanResult& r, const ScanCliOptions& o) {
  nlohmann::json j;
  j["file"] = file;
  j["quantity"] = quantity;
  j["units"] = units;
  j["value"] = "offset + scale * pixel";
  j["scale"] = png.scale;
  j["offset"] = png.offset;
  j["invalid_value"] = 0;
  j["rows"] = r.pattern.rows;
  j["columns"] = r.pattern.columns;
  j["frame"] = "REP-103: sensor looks along +x, z up; row 0 top, column 0 left";
  j["scan"] = {{"scene", o.scan.scene},
               {"pattern", o.scan.pattern},
               {"mode", o.mode},
               {"seed", o.seed},
               {"shots", o.shots},
               {"model", o.raw             ? "none (--raw)"
                         : o.model.empty() ? "factory calibration"
                                           : o.model},
               {"beams", r.beams.size()}};
  return j;
}

void run_scan_command(const ScanCliOptions& o, const AppContext& ctx) {
  const auto outputs = parse_write(o.write);
  const device::DeviceConfig config = ctx.load_config();
  const scan::Scene scene = io::load_scene(o.scan.scene);
  std::optional<ranging::Pipeline> pipeline;
  if (!o.model.empty()) pipeline = io::load_pipeline(o.model);
  io::create_output_directories(o.out);  // removed again if the scan fails
  const int shots = fitting_shots(o.scan, config, o.shots);
  const scan::BeamPattern pattern = make_scan_pattern(o.scan, config, shots);
  // Calibrated ranges by default, as a lidar's own output is: the device's
  // factory calibration (the default plan measured at seed 1, chain fitted).
  if (!pipeline && !o.raw) {
    try {
      pipeline = experiments::factory_calibration(config).pipeline;
    } catch (const std::invalid_argument& e) {
      throw std::runtime_error(std::string("the factory calibration of this device failed (") +
                               e.what() + "): give --model FILE or --raw");
    }
    fmt::print(stderr,
               "tofkit scan: ranges corrected by this device's factory calibration (plan's plates "
               "and a distance sweep, seed 1); --model FILE for your own, --raw for none\n");
  } else if (o.raw) {
    fmt::print(stderr, "tofkit scan: raw ranges (--raw: fixed delays and walk included)\n");
  }

  const auto start = std::chrono::steady_clock::now();
  const auto mode = simulation_mode(o.mode);
  scan::ScanResult result =
      run_scene_scan(o.scan, scene, pattern, config, mode, shots, o.seed, Progress{});
  if (pipeline) scan::apply_pipeline(*pipeline, result);
  const double seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();

  // Every file through the one writer: staged, and committed with the
  // others only when the command succeeds (main's OutputTransaction); a
  // target that is an input, a link, a FIFO or a directory is refused.
  const scan::ScanImages images = scan::make_images(result);
  const std::filesystem::path dir(o.out);
  auto write = [&](const std::string& name, const std::string& bytes) {
    io::write_file_atomically(dir / name, bytes);
  };
  if (outputs.count("csv") != 0) write("scan.csv", io::encode_scan_csv(result, o.scan.ambient_c));
  const struct {
    const char* name;
    const char* quantity;
    const char* units;
    const scan::Image* image;
  } planes[] = {{"range", "range", "m", &images.range},
                {"intensity", "echo amplitude", "V", &images.intensity},
                {"sigma", "expected range error (1 sigma)", "m", &images.sigma}};
  for (const auto& p : planes) {
    if (p.image == &images.sigma && !result.has_model) continue;
    if (outputs.count("png") != 0) {
      const io::Png16 png = io::encode_png16(*p.image);
      const std::string name = std::string(p.name) + ".png";
      write(name, png.png);
      write(std::string(p.name) + ".json",
            sidecar(name, p.quantity, p.units, png, result, o).dump(2) + "\n");
    }
    if (outputs.count("npy") != 0) write(std::string(p.name) + ".npy", io::encode_npy(*p.image));
  }
  const auto points = io::cloud_points(result);
  if (outputs.count("ply") != 0) write("points.ply", io::encode_ply(points));
  if (outputs.count("pcd") != 0) write("points.pcd", io::encode_pcd(points));
  if (outputs.count("las") != 0) write("points.las", io::encode_las(points));
  if (outputs.count("view") != 0) write("range_view.png", io::encode_range_view(images));

  std::size_t mixed = 0;
  for (const auto& b : result.beams) mixed += b.surfaces > 1 ? 1 : 0;
  const auto threads =
      tbb::global_control::active_value(tbb::global_control::max_allowed_parallelism);
  fmt::print(stderr,
             "tofkit scan: {} beams ({} x {} image, {} pattern, {} rays/beam, {} shots, {} mode, "
             "seed {}): "
             "{} points, {} mixed pixels, {} without echo; {:.2f} s on {} thread(s) -> {}\n",
             result.beams.size(), pattern.rows, pattern.columns, o.scan.pattern,
             config.scan.rays_per_beam, scan::shots_per_beam(config, shots, pattern), o.mode,
             o.seed, points.size(), mixed, result.beams.size() - points.size(), seconds, threads,
             (std::filesystem::path(o.out) / "").string());
}

const bool registered = register_command("scan", [](CLI::App& sub, AppContext& ctx) {
  sub.description("scan a scene (TOML) with a pattern: range/intensity images and point clouds");
  auto o = std::make_shared<ScanCliOptions>();
  const SceneScanOptionHandles h = add_scene_scan_options(sub, o->scan);
  h.scene->required();
  h.pattern->required();
  CLI::Option* model = sub.add_option(
      "--model", o->model,
      "correction model (JSON, from tofkit fit; default: the device's factory calibration)");
  sub.add_flag("--raw", o->raw, "write raw ranges (no correction; fixed delays included)")
      ->excludes(model);
  sub.add_option("--mode", o->mode, "analytic (fast) or waveform (sampled, reference)")
      ->check(CLI::IsMember({"analytic", "waveform"}))
      ->capture_default_str();
  sub.add_option("--shots", o->shots, "shots averaged per beam (default: config's)")
      ->check(InRange(1, 10'000'000));
  add_seed_option(sub, o->seed, "random seed (the output depends on it only)");
  sub.add_option("--write", o->write, "outputs: all or LIST of csv, png, npy, ply, pcd, las, view")
      ->capture_default_str();
  sub.add_option("--out", o->out, "output directory (made if missing)")->required();
  sub.callback([o, &ctx] { run_scan_command(*o, ctx); });
});

}  // namespace
}  // namespace tofkit::app
