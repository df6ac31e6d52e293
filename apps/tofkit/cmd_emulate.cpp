// tofkit emulate: the virtual rangefinder as a device on a serial line. With
// --distance/--reflectance it measures the same grid as `tofkit measure` (same
// order, request i on random stream i of --seed, so the values are those of
// `measure` with the same options); with --scene it scans the scene as
// `tofkit scan` does (the same pattern options, beam i on stream i of --seed:
// the values of scan.csv) and sends one frame per beam in the pattern's time
// order. Frames are paced in real time at --rate, encoded as native or TFmini
// frames and written to a new pseudo-terminal (its path is printed on stdout)
// or to stdout (--out -). --corrupt P flips one random bit in a share P of
// the bytes after encoding: the measurements never change.

#include <fmt/format.h>
#include <tbb/parallel_for.h>

#include <atomic>
#include <chrono>
#include <csignal>
#include <cstdio>
#include <functional>
#include <memory>
#include <random>
#include <span>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include "app.hpp"
#include "plate_grid.hpp"
#include "scene_scan.hpp"
#include "tofkit/device/virtual_rangefinder.hpp"
#include "tofkit/io/byte_source.hpp"
#include "tofkit/io/scene_file.hpp"
#include "tofkit/link/decoder.hpp"
#include "tofkit/link/native_frame.hpp"
#include "tofkit/link/tfmini.hpp"

namespace tofkit::app {
namespace {

struct EmulateOptions {
  std::string format = "native";
  double rate_hz = 100;
  std::string distances;
  std::string reflectances;
  std::string angles = "0";
  std::string temperatures = fmt::format("{}", device::Conditions{}.ambient_c);
  SceneScanOptions scan;  // --scene and the pattern options of `tofkit scan`
  int shots = 0;
  int count = 1;
  std::uint64_t seed = 1;
  std::string mode = "analytic";
  double corrupt = 0;
  std::string out;   // "-": stdout; empty: a new pseudo-terminal
  bool wait = true;  // pty: send nothing until a reader has opened it
};

std::atomic<bool> g_stop{false};
extern "C" void on_signal(int) {
  g_stop = true;
}

// Flips one random bit in a share p of the bytes; its own random stream, so
// the measurements (drawn from --seed's Philox streams) cannot depend on it.
class Corrupter {
 public:
  Corrupter(double p, std::uint64_t seed) : p_(p), rng_(seed ^ 0x636F72727570746CULL) {}
  void apply(std::vector<std::uint8_t>& bytes) {
    if (p_ <= 0) return;
    std::bernoulli_distribution hit(p_);
    std::uniform_int_distribution<int> bit(0, 7);
    for (auto& b : bytes) {
      if (hit(rng_)) b ^= static_cast<std::uint8_t>(1u << bit(rng_));
    }
  }

 private:
  double p_;
  std::mt19937_64 rng_;
};

// Frame i's bytes: its sequence number and due time (device clock, us) and
// its measurement. Throws std::out_of_range naming a field that does not fit.
void encode_frame(link::Format format, std::uint64_t i, double due_s,
                  const ranging::RawMeasurement& raw, std::vector<std::uint8_t>& bytes) {
  bytes.clear();
  if (format == link::Format::kNative) {
    const auto f = link::encode_native(
        {static_cast<std::uint32_t>(i),
         static_cast<std::uint32_t>(std::llround(due_s * 1e6) & 0xFFFFFFFF), raw});
    bytes.assign(f.begin(), f.end());
  } else {
    const auto f = link::encode_tfmini(link::tfmini_reading_from(raw));
    bytes.assign(f.begin(), f.end());
  }
}

// The measurements of frames [first, first + out.size()).
using FrameSource = std::function<void(std::uint64_t first, std::span<ranging::RawMeasurement>)>;

// Writes `total` frames from `source` paced at o.rate_hz to a new pty or
// stdout; `what` describes them in the closing summary.
void send_frames(const EmulateOptions& o, std::uint64_t total, const FrameSource& source,
                 const std::string& what) {
  const link::Format format = link::format_from_name(o.format);
  std::unique_ptr<io::PseudoTerminal> pty;
  int fd = 1;
  std::string sink = "stdout";
  if (o.out != "-") {
    pty = std::make_unique<io::PseudoTerminal>();
    fd = pty->master_fd();
    sink = pty->slave_path();
    fmt::print("{}\n", sink);
    std::fflush(stdout);
  }
  std::signal(SIGINT, on_signal);
  std::signal(SIGTERM, on_signal);
  std::signal(SIGPIPE, SIG_IGN);
  if (pty && o.wait && !pty->wait_for_reader(g_stop, 250)) {
    fmt::print(stderr, "tofkit emulate: stopped before a reader opened {}\n", sink);
    return;
  }

  // Blocks of about 20 ms of frames: measured (on all cores), then written on
  // schedule (frame i is due at start + i / rate; being late does not drift).
  const auto block = static_cast<std::uint64_t>(std::max(1.0, o.rate_hz * 0.02));
  Corrupter corrupter(o.corrupt, o.seed);
  std::vector<ranging::RawMeasurement> raw;
  std::vector<std::uint8_t> bytes;
  const auto start = std::chrono::steady_clock::now();
  double worst_late_s = 0;
  std::uint64_t sent = 0;
  for (std::uint64_t first = 0; first < total && !g_stop; first += block) {
    const std::uint64_t n = std::min(block, total - first);
    raw.resize(n);
    source(first, raw);
    for (std::uint64_t k = 0; k < n && !g_stop; ++k) {
      const std::uint64_t i = first + k;
      const double due_s = static_cast<double>(i) / o.rate_hz;
      const auto due = start + std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                                   std::chrono::duration<double>(due_s));
      const auto now = std::chrono::steady_clock::now();
      if (due > now) {
        std::this_thread::sleep_until(due);
      } else {
        worst_late_s = std::max(worst_late_s, std::chrono::duration<double>(now - due).count());
      }
      encode_frame(format, i, due_s, raw[k], bytes);
      corrupter.apply(bytes);
      io::write_all(fd, bytes, sink, pty ? 30'000 : -1);  // a pty nobody reads: give up
      ++sent;
    }
  }
  std::size_t unread = 0;
  if (pty) unread = pty->wait_drained(g_stop ? 0 : 10'000);
  const double sent_s =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  if (pty && o.wait) pty->linger(g_stop, 1'000);
  const double seconds = sent_s;
  fmt::print(stderr,
             "tofkit emulate: {} {} frames{} at {:g} Hz in {:.2f} s (at most {:.1f} ms late){}{} "
             "-> {}\n",
             sent, o.format, what, o.rate_hz, seconds, worst_late_s * 1e3,
             o.corrupt > 0 ? fmt::format(", {:g} of bytes corrupted", o.corrupt) : "",
             unread > 0 ? fmt::format(", {} bytes never read", unread) : "", sink);
}

// The plate grid of `tofkit measure`: frame i is request i of measure's order
// (repeats innermost), on random stream i.
void emulate_plates(const EmulateOptions& o, const AppContext& ctx) {
  // The grid's points (count 1); frame i measures point i / count.
  const std::vector<experiments::PlannedMeasurement> points = experiments::plate_grid_plan(
      parse_plate_grid(o.distances, o.reflectances, o.angles, o.temperatures));
  const device::DeviceConfig config = ctx.load_config();
  const std::uint64_t total = points.size() * static_cast<std::uint64_t>(o.count);
  const device::VirtualRangefinder rangefinder(config, simulation_mode(o.mode, ctx, config));
  const auto source = [&](std::uint64_t first, std::span<ranging::RawMeasurement> out) {
    tbb::parallel_for(std::size_t{0}, out.size(), [&](std::size_t k) {
      const std::uint64_t i = first + k;
      const device::MeasureRequest& r = points[i / static_cast<std::uint64_t>(o.count)].request;
      out[k] = rangefinder.measure(r.target, r.conditions, o.seed, i, o.shots);
    });
  };
  send_frames(o, total, source, "");
}

// A scan of --scene as `tofkit scan` makes it, measured before the first frame
// is sent (beam i on random stream i, as in scan.csv), then one frame per beam
// in the pattern's time order. Every frame is encoded once beforehand, so a
// value a frame cannot carry stops the command before any output.
void emulate_scene(const EmulateOptions& o, const AppContext& ctx) {
  const device::DeviceConfig config = ctx.load_config();
  const auto mode = simulation_mode(o.mode, ctx, config);  // refused for the loop
  const scan::Scene scene = io::load_scene(o.scan.scene);
  const int shots = fitting_shots(o.scan, config, o.shots);
  const scan::BeamPattern pattern = make_scan_pattern(o.scan, config, shots);
  const auto start = std::chrono::steady_clock::now();
  const scan::ScanResult result =
      run_scene_scan(o.scan, scene, pattern, config, mode, shots, o.seed);
  const double scan_s =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();

  const link::Format format = link::format_from_name(o.format);
  std::vector<std::uint8_t> bytes;
  for (std::size_t i = 0; i < result.beams.size(); ++i) {
    try {
      encode_frame(format, i, static_cast<double>(i) / o.rate_hz, result.beams[i].raw, bytes);
    } catch (const std::out_of_range& e) {
      throw std::invalid_argument(fmt::format("--scene {}: beam {} does not fit a {} frame: {}",
                                              o.scan.scene, i, o.format, e.what()));
    }
  }
  const auto source = [&](std::uint64_t first, std::span<ranging::RawMeasurement> out) {
    for (std::size_t k = 0; k < out.size(); ++k) out[k] = result.beams[first + k].raw;
  };
  send_frames(o, result.beams.size(), source,
              fmt::format(" ({} pattern over {}: {} beams scanned in {:.2f} s)", o.scan.pattern,
                          o.scan.scene, result.beams.size(), scan_s));
}

const bool registered = register_command("emulate", [](CLI::App& sub, AppContext& ctx) {
  sub.description(
      "run the virtual rangefinder in real time (a plate grid, or a scan of a scene) and write "
      "its frames to a new pseudo-terminal (path printed) or stdout");
  auto o = std::make_shared<EmulateOptions>();
  sub.add_option("--format", o->format, "frame format")
      ->check(CLI::IsMember({"native", "tfmini"}))
      ->capture_default_str();
  sub.add_option("--rate", o->rate_hz, "frames per second")
      ->check(InRange(1e-3, 1e7))
      ->capture_default_str();
  const std::vector<CLI::Option*> plate_options = {
      sub.add_option("--distance", o->distances, "true distances, m: LIST (as tofkit measure)"),
      sub.add_option("--reflectance", o->reflectances, "plate reflectances: LIST"),
      sub.add_option("--angle", o->angles, "incidence angles, degrees: LIST")
          ->capture_default_str(),
      sub.add_option("--temperature", o->temperatures, "ambient temperatures, C: LIST")
          ->capture_default_str(),
      sub.add_option("--count", o->count, "repeated measurements per grid point")
          ->check(InRange(1, 100'000'000))
          ->capture_default_str(),
  };
  // --scene and the pattern options as `tofkit scan` takes them; its --rate
  // (the mirror's or the head's) is --scan-rate here.
  const SceneScanOptionHandles scene_options = add_scene_scan_options(sub, o->scan, "--scan-rate");
  sub.add_option("--shots", o->shots, "shots averaged per measurement (default: config's)")
      ->check(InRange(1, 65535));
  add_seed_option(sub, o->seed, "random seed (as tofkit measure and tofkit scan)");
  sub.add_option("--mode", o->mode, "analytic or waveform")
      ->check(CLI::IsMember({"analytic", "waveform"}))
      ->capture_default_str();
  sub.add_option("--corrupt", o->corrupt,
                 "share of bytes with one flipped bit (bytes only; values unchanged)")
      ->check(InRange(0.0, 1.0))
      ->capture_default_str();
  CLI::Option* out =
      sub.add_option("--out", o->out, "'-' for stdout (default: a new pseudo-terminal)");
  sub.add_flag("--wait,!--no-wait", o->wait,
               "pty: send the first frame only once a reader has opened the pty (and 0.25 s "
               "for it to set the line up); on by default")
      ->capture_default_str();
  sub.callback([o, &ctx, plate_options, scene_options, out] {
    if (out->count() > 0 && o->out != "-") {  // '' too: not a silent pseudo-terminal
      throw std::invalid_argument(
          "--out: only '-' (stdout); without --out a pseudo-terminal is made");
    }
    if (scene_options.scene->count() > 0) {
      for (const CLI::Option* opt : plate_options) {
        if (opt->count() > 0) {
          throw std::invalid_argument(opt->get_name() +
                                      ": a plate-grid option; --scene takes the pattern options "
                                      "of tofkit scan instead");
        }
      }
      if (o->scan.pattern.empty()) throw std::invalid_argument("--scene needs --pattern");
      emulate_scene(*o, ctx);
      return;
    }
    std::vector<const CLI::Option*> scan_only = {scene_options.pattern};
    scan_only.insert(scan_only.end(), scene_options.others.begin(), scene_options.others.end());
    for (const CLI::Option* opt : scan_only) {
      if (opt->count() > 0) throw std::invalid_argument(opt->get_name() + " needs --scene");
    }
    if (o->distances.empty() || o->reflectances.empty()) {
      throw std::invalid_argument("give --distance and --reflectance, or --scene and --pattern");
    }
    emulate_plates(*o, ctx);
  });
});

}  // namespace
}  // namespace tofkit::app
