// Link decoders: throughput of each format's decoder on a clean capture of
// 2^17 frames fed in 64 kB chunks (as a serial read would hand them over),
// and a memcpy of the same bytes as the baseline. Each benchmark reports
// frames/s (items), bytes/s, and `x_memcpy`: its bytes/s divided by a memcpy's
// bytes/s of the same capture measured in the same run. CPU time of this
// thread: per-core figures, unaffected by other processes.
// Target: native >= 20 M frames/s (1 MHz device rate with 20x headroom).

#include <benchmark/benchmark.h>

#include <algorithm>
#include <cstring>
#include <ctime>
#include <random>
#include <vector>

#include "tofkit/link/decoder.hpp"
#include "tofkit/link/lwnx.hpp"
#include "tofkit/link/native_frame.hpp"
#include "tofkit/link/rplidar.hpp"
#include "tofkit/link/tfmini.hpp"

namespace {

using namespace tofkit;
using namespace tofkit::link;

constexpr std::size_t kFrames = 1 << 17;
constexpr std::size_t kChunk = 1 << 16;

double thread_cpu_s() {
  timespec t{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t);
  return static_cast<double>(t.tv_sec) + 1e-9 * static_cast<double>(t.tv_nsec);
}

std::vector<std::uint8_t> capture(Format format) {
  std::mt19937_64 rng(1);
  std::uniform_real_distribution<double> u(0, 1);
  std::vector<std::uint8_t> bytes;
  for (std::size_t i = 0; i < kFrames; ++i) {
    ranging::RawMeasurement m;
    m.tof_ns = 10 + 200 * u(rng);
    m.distance_raw_m = 0.15 * m.tof_ns;
    m.pulse_width_ns = 2 + 10 * u(rng);
    m.amplitude = 0.01 + u(rng);
    m.temperature_c = 20 + 10 * u(rng);
    m.shots_valid = 1000;
    const auto add = [&](const auto& frame) {
      bytes.insert(bytes.end(), frame.begin(), frame.end());
    };
    switch (format) {
      case Format::kNative:
        add(encode_native({static_cast<std::uint32_t>(i), static_cast<std::uint32_t>(i), m}));
        break;
      case Format::kTfmini:
        add(encode_tfmini(tfmini_reading_from(m)));
        break;
      case Format::kLwnx: {
        const std::int16_t d[2] = {static_cast<std::int16_t>(100 * m.distance_raw_m), 50};
        add(encode_lwnx(kLwnxDistanceData, {reinterpret_cast<const std::uint8_t*>(d), 4}));
        break;
      }
      case Format::kRplidar:
        add(encode_rplidar({i % 360 == 0, 40, static_cast<std::uint16_t>((i % 360) * 64),
                            static_cast<std::uint16_t>(4000 * m.distance_raw_m)}));
        break;
    }
  }
  return bytes;
}

// Bytes/s of a memcpy of `bytes` (best of 7).
double memcpy_bytes_per_s(const std::vector<std::uint8_t>& bytes) {
  std::vector<std::uint8_t> dst(bytes.size());
  double best = 1e30;
  for (int rep = 0; rep < 7; ++rep) {
    const double start = thread_cpu_s();
    std::memcpy(dst.data(), bytes.data(), bytes.size());
    benchmark::ClobberMemory();
    best = std::min(best, thread_cpu_s() - start);
  }
  return static_cast<double>(bytes.size()) / best;
}

void run(benchmark::State& state, Format format, bool decode) {
  const std::vector<std::uint8_t> bytes = capture(format);
  const double baseline = memcpy_bytes_per_s(bytes);
  std::vector<std::uint8_t> copy(bytes.size());
  std::vector<Frame> frames;
  frames.reserve(kChunk);
  double seconds = 0;
  std::size_t decoded = 0;
  for (auto _ : state) {
    auto decoder = make_decoder(format);
    const double start = thread_cpu_s();
    for (std::size_t pos = 0; pos < bytes.size(); pos += kChunk) {
      const std::size_t n = std::min(kChunk, bytes.size() - pos);
      if (decode) {
        decoder->feed({bytes.data() + pos, n}, frames);
        decoded += frames.size();
        frames.clear();
      } else {
        std::memcpy(copy.data() + pos, bytes.data() + pos, n);
      }
    }
    benchmark::ClobberMemory();
    seconds += thread_cpu_s() - start;
  }
  if (decode && decoded != kFrames * state.iterations()) state.SkipWithError("frames lost");
  const auto items = static_cast<double>(state.iterations()) * static_cast<double>(kFrames);
  const double total_bytes =
      static_cast<double>(state.iterations()) * static_cast<double>(bytes.size());
  state.SetItemsProcessed(static_cast<std::int64_t>(items));
  state.SetBytesProcessed(static_cast<std::int64_t>(total_bytes));
  state.counters["frames_per_s_cpu"] = items / seconds;
  state.counters["x_memcpy"] = (total_bytes / seconds) / baseline;
}

void BM_LinkMemcpyNativeCapture(benchmark::State& state) {
  run(state, Format::kNative, false);
}
void BM_LinkDecodeNative(benchmark::State& state) {
  run(state, Format::kNative, true);
}
void BM_LinkDecodeTfmini(benchmark::State& state) {
  run(state, Format::kTfmini, true);
}
void BM_LinkDecodeLwnx(benchmark::State& state) {
  run(state, Format::kLwnx, true);
}
void BM_LinkDecodeRplidar(benchmark::State& state) {
  run(state, Format::kRplidar, true);
}
BENCHMARK(BM_LinkMemcpyNativeCapture)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_LinkDecodeNative)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_LinkDecodeTfmini)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_LinkDecodeLwnx)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_LinkDecodeRplidar)->Unit(benchmark::kMillisecond);

}  // namespace
