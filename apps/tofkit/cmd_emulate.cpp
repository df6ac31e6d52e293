// tofkit emulate: the virtual rangefinder as a device on a serial line. It
// measures the same grid as `tofkit measure` (same order, request i on random
// stream i of --seed, so the values are those of `measure` with the same
// options), paced in real time at --rate, encodes each measurement as a native
// or TFmini frame and writes it to a new pseudo-terminal (its path is printed
// on stdout) or to stdout (--out -). --corrupt P flips one random bit in a
// share P of the bytes after encoding: the measurements never change.

#include <fmt/format.h>
#include <tbb/parallel_for.h>

#include <atomic>
#include <chrono>
#include <csignal>
#include <cstdio>
#include <memory>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include "app.hpp"
#include "tofkit/device/virtual_rangefinder.hpp"
#include "tofkit/io/byte_source.hpp"
#include "tofkit/io/value_list.hpp"
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
  int shots = 0;
  int count = 1;
  std::uint64_t seed = 1;
  std::string mode = "analytic";
  double corrupt = 0;
  std::string out;  // "-": stdout; empty: a new pseudo-terminal
};

std::atomic<bool> g_stop{false};
extern "C" void on_signal(int) {
  g_stop = true;
}

struct GridPoint {
  double distance_m, reflectance, angle_deg, ambient_c;
};

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

void run_emulate(const EmulateOptions& o, const AppContext& ctx) {
  const link::Format format = link::format_from_name(o.format);
  const auto distances = io::parse_value_list(o.distances, "--distance");
  const auto reflectances = io::parse_value_list(o.reflectances, "--reflectance");
  const auto angles = io::parse_value_list(o.angles, "--angle");
  const auto temperatures = io::parse_value_list(o.temperatures, "--temperature");
  const device::DeviceConfig config = ctx.load_config();

  // measure's order: distance outermost, then reflectance, angle, temperature;
  // repeats innermost.
  std::vector<GridPoint> grid;
  for (const double d : distances) {
    for (const double rho : reflectances) {
      for (const double angle : angles) {
        for (const double t : temperatures) grid.push_back({d, rho, angle, t});
      }
    }
  }
  for (const auto& g : grid) {
    if (!(g.distance_m >= 1e-3 && g.distance_m <= 1e5)) {
      throw std::invalid_argument(
          fmt::format("--distance: {} is outside [0.001, 100000]", g.distance_m));
    }
    if (!(g.reflectance >= 0 && g.reflectance <= 1)) {
      throw std::invalid_argument(
          fmt::format("--reflectance: {} is outside [0, 1]", g.reflectance));
    }
    if (!(g.angle_deg >= 0 && g.angle_deg <= 89.9)) {
      throw std::invalid_argument(fmt::format("--angle: {} is outside [0, 89.9]", g.angle_deg));
    }
    if (!(g.ambient_c >= -60 && g.ambient_c <= 150)) {
      throw std::invalid_argument(
          fmt::format("--temperature: {} is outside [-60, 150]", g.ambient_c));
    }
  }
  const std::uint64_t total = grid.size() * static_cast<std::uint64_t>(o.count);

  const auto mode =
      o.mode == "waveform" ? device::SimulationMode::kWaveform : device::SimulationMode::kAnalytic;
  const device::VirtualRangefinder rangefinder(config, mode);

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

  // Blocks of about 20 ms of frames: measured on all cores, then written on
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
    tbb::parallel_for(std::uint64_t{0}, n, [&](std::uint64_t k) {
      const std::uint64_t i = first + k;
      const GridPoint& g = grid[i / static_cast<std::uint64_t>(o.count)];
      device::Conditions conditions;
      conditions.ambient_c = g.ambient_c;
      raw[k] = rangefinder.measure(device::Target::plate(g.distance_m, g.reflectance, g.angle_deg),
                                   conditions, o.seed, i, o.shots);
    });
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
      bytes.clear();
      if (format == link::Format::kNative) {
        const auto f = link::encode_native(
            {static_cast<std::uint32_t>(i),
             static_cast<std::uint32_t>(std::llround(due_s * 1e6) & 0xFFFFFFFF), raw[k]});
        bytes.assign(f.begin(), f.end());
      } else {
        const auto f = link::encode_tfmini(link::tfmini_reading_from(raw[k]));
        bytes.assign(f.begin(), f.end());
      }
      corrupter.apply(bytes);
      io::write_all(fd, bytes, sink, pty ? 30'000 : -1);  // a pty nobody reads: give up
      ++sent;
    }
  }
  std::size_t unread = 0;
  if (pty) unread = pty->wait_drained(g_stop ? 0 : 10'000);
  const double seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  fmt::print(stderr,
             "tofkit emulate: {} {} frames at {:g} Hz in {:.2f} s (at most {:.1f} ms late){}{} "
             "-> {}\n",
             sent, o.format, o.rate_hz, seconds, worst_late_s * 1e3,
             o.corrupt > 0 ? fmt::format(", {:g} of bytes corrupted", o.corrupt) : "",
             unread > 0 ? fmt::format(", {} bytes never read", unread) : "", sink);
}

const bool registered = register_command("emulate", [](CLI::App& sub, AppContext& ctx) {
  sub.description(
      "run the virtual rangefinder in real time and write its frames to a new pseudo-terminal "
      "(path printed) or stdout");
  auto o = std::make_shared<EmulateOptions>();
  sub.add_option("--format", o->format, "frame format")
      ->check(CLI::IsMember({"native", "tfmini"}))
      ->capture_default_str();
  sub.add_option("--rate", o->rate_hz, "frames per second")
      ->check(CLI::Range(1e-3, 1e7))
      ->capture_default_str();
  sub.add_option("--distance", o->distances, "true distances, m: LIST (as tofkit measure)")
      ->required();
  sub.add_option("--reflectance", o->reflectances, "plate reflectances: LIST")->required();
  sub.add_option("--angle", o->angles, "incidence angles, degrees: LIST")->capture_default_str();
  sub.add_option("--temperature", o->temperatures, "ambient temperatures, C: LIST")
      ->capture_default_str();
  sub.add_option("--shots", o->shots, "shots averaged per measurement (default: config's)")
      ->check(CLI::Range(1, 65535));
  sub.add_option("--count", o->count, "repeated measurements per grid point")
      ->check(CLI::Range(1, 100'000'000))
      ->capture_default_str();
  sub.add_option("--seed", o->seed, "random seed (as tofkit measure)")->capture_default_str();
  sub.add_option("--mode", o->mode, "analytic or waveform")
      ->check(CLI::IsMember({"analytic", "waveform"}))
      ->capture_default_str();
  sub.add_option("--corrupt", o->corrupt,
                 "share of bytes with one flipped bit (bytes only; values unchanged)")
      ->check(CLI::Range(0.0, 1.0))
      ->capture_default_str();
  sub.add_option("--out", o->out, "'-' for stdout (default: a new pseudo-terminal)");
  sub.callback([o, &ctx] {
    if (!o->out.empty() && o->out != "-") {
      throw std::invalid_argument(
          "--out: only '-' (stdout); without --out a pseudo-terminal is made");
    }
    run_emulate(*o, ctx);
  });
});

}  // namespace
}  // namespace tofkit::app
