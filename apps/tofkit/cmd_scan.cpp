// tofkit scan: a scene (TOML) scanned by a pattern through the virtual
// rangefinder, written as images (PNG + JSON sidecar, .npy), point clouds
// (PLY, PCD, LAS), the per-beam table scan.csv and a picture, range_view.png.

#include <fmt/format.h>
#include <tbb/global_control.h>
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <cstring>
#include <future>
#include <memory>
#include <nlohmann/json.hpp>
#include <set>
#include <string>
#include <vector>

#include "app.hpp"
#include "mpi_world.hpp"
#include "scan_shard.hpp"
#include "scene_scan.hpp"
#include "tofkit/device/virtual_rangefinder.hpp"
#include "tofkit/experiments/device_plan.hpp"
#include "tofkit/io/atomic_file.hpp"
#include "tofkit/io/calibration_cache.hpp"
#include "tofkit/io/model_json.hpp"
#include "tofkit/io/scan_output.hpp"
#include "tofkit/io/scan_writer.hpp"
#include "tofkit/io/scene_file.hpp"
#include "tofkit/ranging/uncertainty_budget.hpp"
#include "tofkit/scan/scanner.hpp"

namespace tofkit::app {
namespace {

struct ScanCliOptions {
  SceneScanOptions scan;
  std::string model, mode = "analytic", write = "all", out, shard;
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

/// The factory calibration's seed (`tofkit plan`'s measurements at seed 1).
constexpr std::uint64_t kFactorySeed = 1;

struct MadeCalibration {
  io::FactoryCalibration factory;
  std::string note;  // the cache could not keep it (one line), or ""
};

// The device's factory calibration as the cache holds it: the model (a hit),
// or the key to store a made one under (a miss), or neither (the cache off).
struct FactoryModel {
  std::optional<io::FactoryCalibration> cached;
  std::optional<io::FactoryCalibrationKey> key;
  std::string note;  // an unusable entry, a build without an id (one line), or ""
};

FactoryModel find_factory_model(const device::DeviceConfig& config) {
  FactoryModel found;
  const auto directory = io::calibration_cache_directory();
  if (!directory) return found;
  found.key = io::factory_calibration_key(*directory, config, kFactorySeed, found.note);
  if (found.key) found.cached = io::load_factory_calibration(*found.key, found.note);
  return found;
}

// Rank 0's model and budget (none: raw ranges) on every rank, rank 0's
// too, as their JSON read back.
void share_model(const MpiWorld& world, std::optional<ranging::Pipeline>& pipeline,
                 ranging::UncertaintyBudget& budget) {
  std::string text;
  if (world.rank == 0 && pipeline) {
    nlohmann::json j = {{"model", io::pipeline_to_json(*pipeline)}};
    if (!budget.empty()) j["budget"] = io::budget_to_json(budget);
    text = j.dump();
  }
  mpi_broadcast(text);
  pipeline.reset();
  budget = {};
  if (text.empty()) return;
  const nlohmann::json j = nlohmann::json::parse(text);
  pipeline = io::pipeline_from_json(j.at("model"), "rank 0's model");
  if (j.contains("budget")) budget = io::budget_from_json(j.at("budget"), "rank 0's budget");
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

void run_scan_command(const ScanCliOptions& o, const AppContext& ctx) {
  const auto setup_start = std::chrono::steady_clock::now();
  const auto outputs = parse_write(o.write);
  const device::DeviceConfig config = ctx.load_config();
  const auto mode = simulation_mode(o.mode, ctx, config);  // refused for the loop
  // The device's tables (5-9 ms for the default device) are made on another
  // thread while the scene, the model or the calibration cache are read.
  auto made_rangefinder = std::async(std::launch::async, [&config, mode] {
    return std::make_unique<const device::VirtualRangefinder>(config, mode);
  });
  scan::Scene loaded_scene = io::load_scene(o.scan.scene);
  std::optional<ranging::Pipeline> pipeline;
  ranging::UncertaintyBudget budget;  // sigma_m is its combined uncertainty where there is one
  // Under mpirun every rank measures and corrects its chunks; rank 0 reads
  // the model (sent to the others below) and writes.
  const MpiWorld world = mpi_world();
  if (!o.model.empty() && world.rank == 0) {
    pipeline = io::load_pipeline(o.model);
    budget = io::load_budget(o.model);
  }
  io::create_output_directories(o.out);  // removed again if the scan fails
  const int shots = fitting_shots(o.scan, config, o.shots);
  // Calibrated ranges by default, as a lidar's own output is: the device's
  // factory calibration (the default plan measured at seed 1, chain fitted).
  // In one process the calibration runs on its own thread beside the scan
  // (the beams are measured raw; ranges are corrected as blocks are
  // written), so the scan does not wait for it. Under mpirun rank 0 makes it
  // before the scan and sends it to the others (below).
  // A made calibration is kept in the cache (io/calibration_cache.hpp): the
  // next scan of this device by this build reads it back instead.
  std::future<MadeCalibration> calibration;
  if (world.rank == 0 && !pipeline && !o.raw) {
    const FactoryModel factory = find_factory_model(config);
    if (!factory.note.empty()) fmt::print(stderr, "tofkit scan: {}\n", factory.note);
    if (factory.cached) {
      pipeline = factory.cached->pipeline;
      budget = factory.cached->budget;
    } else {
      calibration =
          std::async(world.size == 1 ? std::launch::async : std::launch::deferred,
                     [&config, key = factory.key] {
                       try {
                         calib::ModelFitResult fit = experiments::factory_calibration(
                             io::calibration_config(config), kFactorySeed);
                         MadeCalibration made;
                         made.factory = {std::move(fit.pipeline), std::move(fit.budget)};
                         if (key) io::store_factory_calibration(*key, made.factory, made.note);
                         return made;
                       } catch (const std::invalid_argument& e) {
                         throw std::runtime_error(
                             std::string("the factory calibration of this device failed (") +
                             e.what() + "): give --model FILE or --raw");
                       }
                     });
    }
    fmt::print(stderr,
               "tofkit scan: ranges corrected by this device's factory calibration (plan's plates "
               "and a distance sweep, seed {}; {}); --model FILE for your own, --raw for none\n",
               kFactorySeed,
               factory.cached ? "from the cache"
               : factory.key  ? "made now and cached"
                              : "made now; cache off");
  } else if (world.rank == 0 && o.raw) {
    fmt::print(stderr, "tofkit scan: raw ranges (--raw: fixed delays and walk included)\n");
  }
  if (world.size > 1) {
    // Every rank corrects the beams it measures (the correction with its
    // budget is about a third of a beam's work: rank 0 alone, correcting
    // every rank's beams, held the others up), with rank 0's model and
    // budget, sent to all as their JSON (which reads back to the same model:
    // numbers in shortest round-trip form, as the cache's entries).
    if (calibration.valid()) {
      MadeCalibration made = calibration.get();
      pipeline = std::move(made.factory.pipeline);
      budget = std::move(made.factory.budget);
      if (!made.note.empty()) fmt::print(stderr, "tofkit scan: {}\n", made.note);
    }
    share_model(world, pipeline, budget);
  }
  const scan::BeamPattern pattern = make_scan_pattern(o.scan, config, shots, /*on_demand=*/true);
  // The set-up (scene file, the scene's BVH, the device's tables, MPI's
  // start) is timed apart from the scan: it does not grow with the beams, and
  // the summary gives both. (The scan's time includes any wait for the
  // factory calibration.)
  const std::unique_ptr<const device::VirtualRangefinder> made_device = made_rangefinder.get();
  const device::VirtualRangefinder& rangefinder = *made_device;
  // (The scene moves into the caster: a 10^6-triangle mesh is held once.)
  const scan::RayCaster caster(std::move(loaded_scene));
  const scan::Scene& scene = caster.scene();
  const scan::Footprint footprint(config);
  scan::ScanOptions options = scene_scan_options(o.scan, shots, o.seed);

  const auto start = std::chrono::steady_clock::now();
  // The scan streams: blocks of beams measured, corrected and written in beam
  // order; every file through the one writer, staged and committed with the
  // others only when the command succeeds (main's OutputTransaction). A
  // shard (--shard K/N) writes its range of beams for `tofkit merge`.
  const Shard shard = o.shard.empty() ? Shard{} : parse_shard(o.shard, "--shard");
  ScanShardHeader header;
  header.shard = shard;
  header.beams = pattern.size();
  std::tie(header.first_beam, header.last_beam) = shard.range(pattern.size());
  header.pattern = scan::describe_scan(pattern, scene).pattern;
  // Each image row's last beam (a pass over every beam): only where rows are
  // finished by it (images asked for; not spherical, whose rows all finish
  // at the end and are made otherwise).
  const bool rows_needed =
      (outputs.count("png") + outputs.count("npy") + outputs.count("view")) != 0 &&
      pattern.name != "spherical";
  header.row_last_beam = rows_needed
                             ? scan::row_last_beams(pattern)
                             : std::vector<std::size_t>(static_cast<std::size_t>(pattern.rows), 0);
  header.has_model = pipeline.has_value() || calibration.valid();
  header.ambient_c = o.scan.ambient_c;
  header.outputs = outputs;
  header.scan_record = {{"scene", o.scan.scene},
                        {"pattern", o.scan.pattern},
                        {"mode", o.mode},
                        {"seed", o.seed},
                        {"shots", o.shots},
                        {"model", o.raw             ? "none (--raw)"
                                  : o.model.empty() ? "factory calibration"
                                                    : o.model},
                        {"beams", pattern.size()}};
  std::optional<io::ScanWriter> writer;
  std::optional<ScanShardWriter> shard_writer;
  if (world.rank == 0 && shard.whole()) {
    scan::ScanResult description = scan::describe_scan(pattern, scene);
    description.has_model = header.has_model;
    writer.emplace(description, header.row_last_beam, scan_writer_settings(o.out, header));
  } else if (world.rank == 0) {
    shard_writer.emplace(o.out, header);
  }
  io::ScanWriter::Summary summary;
  auto take = [&](std::size_t first, std::span<const scan::BeamResult> beams) {
    if (writer) {
      writer->add(first - header.first_beam, beams);
    } else {
      shard_writer->add(beams);
      summary.beams += beams.size();
      io::CloudPoint point{};
      for (const auto& b : beams) {
        summary.points += io::cloud_point(b, point) ? 1 : 0;
        summary.mixed += b.surfaces > 1 ? 1 : 0;
      }
    }
  };
  // Blocks measured while the calibration runs are held (raw, at most
  // kHeldBeams: memory stays bounded, the scan then waits) and corrected and
  // written, in order, once it is done.
  constexpr std::size_t kHeldBeams = 4 * kScanBlockBeams;
  std::vector<scan::BeamResult> held;
  std::size_t held_first = 0;
  // With a budget, sigma_m is its combined uncertainty (scan::apply_pipeline).
  const auto correct = [&](std::span<scan::BeamResult> beams) {
    scan::apply_pipeline(*pipeline, beams, &budget);
  };
  const auto calibrated = [&](bool wait) {
    if (!calibration.valid()) return true;
    if (!wait && calibration.wait_for(std::chrono::seconds(0)) != std::future_status::ready)
      return false;
    MadeCalibration made = calibration.get();
    pipeline = std::move(made.factory.pipeline);
    budget = std::move(made.factory.budget);
    if (!made.note.empty()) fmt::print(stderr, "tofkit scan: {}\n", made.note);
    if (!held.empty()) {
      correct(held);
      take(held_first, held);
      std::vector<scan::BeamResult>().swap(held);
    }
    return true;
  };
  const auto correct_and_take = [&](std::size_t first, std::span<scan::BeamResult> beams) {
    if (!calibrated(held.size() + beams.size() > kHeldBeams)) {
      if (held.empty()) {
        held_first = first;
        held.reserve(kHeldBeams);
      }
      held.insert(held.end(), beams.begin(), beams.end());
      return;
    }
    if (pipeline) correct(beams);
    take(first, beams);
  };
  if (world.size == 1) {
    options.progress = Progress{};
    scan::run_scan_blocks(caster, footprint, rangefinder, pattern, options, header.first_beam,
                          header.last_beam, kScanBlockBeams, correct_and_take);
  } else {
    const std::uint64_t beams = header.last_beam - header.first_beam;
    // Chunks of a quarter block: the last one, made by one rank while the
    // others have nothing left, is short.
    constexpr std::size_t kChunkBeams = kScanBlockBeams / 4;
    const std::size_t chunks = (beams + kChunkBeams - 1) / kChunkBeams;
    std::vector<scan::BeamResult> received;
    mpi_ordered_chunks(
        chunks,
        [&](std::size_t c, std::string& bytes) {
          const std::size_t begin = header.first_beam + c * kChunkBeams;
          const std::size_t end = std::min<std::size_t>(header.last_beam, begin + kChunkBeams);
          // In sub-blocks, the last chunk's send advanced between them.
          bytes.reserve(bytes.size() + (end - begin) * sizeof(scan::BeamResult));
          scan::run_scan_blocks(caster, footprint, rangefinder, pattern, options, begin, end,
                                kChunkBeams / 16, [&](std::size_t, std::span<scan::BeamResult> b) {
                                  if (pipeline) correct(b);
                                  bytes.append(reinterpret_cast<const char*>(b.data()),
                                               b.size_bytes());
                                  mpi_progress();
                                });
        },
        [&](std::size_t c, std::string_view bytes) {
          // The chunk's records where they arrived (corrected where made),
          // without a copy when aligned, as the buffers are (they start
          // after an 8-byte index in memory from operator new).
          const std::size_t first = header.first_beam + c * kChunkBeams;
          const std::size_t n = bytes.size() / sizeof(scan::BeamResult);
          if (reinterpret_cast<std::uintptr_t>(bytes.data()) % alignof(scan::BeamResult) == 0) {
            take(first, {reinterpret_cast<const scan::BeamResult*>(bytes.data()), n});
            return;
          }
          received.resize(n);
          std::memcpy(static_cast<void*>(received.data()), bytes.data(), bytes.size());
          take(first, received);
        });
  }
  calibrated(/*wait=*/true);
  if (writer) summary = writer->finish();
  if (shard_writer) shard_writer->finish();
  mpi_done();
  if (world.rank != 0) return;
  const double seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  const double setup_seconds = std::chrono::duration<double>(start - setup_start).count();

  const auto threads =
      tbb::global_control::active_value(tbb::global_control::max_allowed_parallelism);
  fmt::print(stderr,
             "tofkit scan: {} beams ({} x {} image, {} pattern, {} rays/beam, {} shots, {} mode, "
             "seed {}): "
             "{} points, {} mixed pixels, {} without echo; {:.2f} s on {} thread(s) after "
             "{:.2f} s of set-up (scene, BVH) -> {}{}\n",
             summary.beams, pattern.rows, pattern.columns, o.scan.pattern,
             config.scan.rays_per_beam, scan::shots_per_beam(config, shots, pattern), o.mode,
             o.seed, summary.points, summary.mixed, summary.beams - summary.points, seconds,
             threads, setup_seconds, (std::filesystem::path(o.out) / "").string(),
             shard.whole() ? ""
                           : fmt::format(" (shard {}/{}: beams {}..{})", shard.index, shard.count,
                                         header.first_beam, header.last_beam));
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
  sub.add_option("--shard", o->shard,
                 "K/N: only beams [K n/N, (K+1) n/N) into shard.json + beams.bin, for tofkit "
                 "merge");
  sub.add_option("--out", o->out, "output directory (made if missing)")->required();
  sub.callback([o, &ctx] { run_scan_command(*o, ctx); });
});

}  // namespace
}  // namespace tofkit::app
