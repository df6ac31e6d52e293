// Shots per second of the virtual rangefinder, both modes, one thread and all
// threads, beside a baseline measured in the same run: drawing the per-shot
// random numbers alone (one Philox4x32-10 block and a Box-Muller pair).
#include <Random123/philox.h>
#include <benchmark/benchmark.h>
#include <tbb/global_control.h>
#include <tbb/info.h>

#include <cmath>
#include <vector>

#include "tofkit/device/virtual_rangefinder.hpp"

using namespace tofkit::device;

namespace {

std::vector<MeasureRequest> grid(int count, int shots) {
  std::vector<MeasureRequest> requests;
  for (int i = 0; i < count; ++i)
    requests.push_back(
        {Target::plate(1.0 + 7.0 * i / count, 0.05 + 0.9 * ((i * 7) % count) / count), {}, shots});
  return requests;
}

void run(benchmark::State& state, SimulationMode mode, int shots) {
  const auto threads = static_cast<std::size_t>(state.range(0));
  tbb::global_control limit(tbb::global_control::max_allowed_parallelism, threads);
  const VirtualRangefinder dev(preset("paper"), mode);
  const auto requests = grid(64, shots);
  std::vector<tofkit::ranging::RawMeasurement> out(requests.size());
  std::uint64_t seed = 1;
  for (auto _ : state) {
    dev.measure_batch(requests, seed++, out);
    benchmark::DoNotOptimize(out.data());
  }
  state.SetItemsProcessed(state.iterations() * static_cast<std::int64_t>(requests.size()) * shots);
  state.counters["threads"] = static_cast<double>(threads);
}

void BM_AnalyticShots(benchmark::State& state) {
  run(state, SimulationMode::kAnalytic, 2000);
}
void BM_WaveformShots(benchmark::State& state) {
  run(state, SimulationMode::kWaveform, 100);
}

/// One shot per measurement over varied one-surface targets (a scan's device
/// side without the ray casting): measurements per second.
void BM_AnalyticOneShotMeasurements(benchmark::State& state) {
  const auto threads = static_cast<std::size_t>(state.range(0));
  tbb::global_control limit(tbb::global_control::max_allowed_parallelism, threads);
  const VirtualRangefinder dev(preset("paper"), SimulationMode::kAnalytic);
  std::vector<MeasureRequest> requests;
  constexpr int kCount = 1 << 16;
  for (int i = 0; i < kCount; ++i) {
    const double f = static_cast<double>((static_cast<std::int64_t>(i) * 40503) % kCount) / kCount;
    requests.push_back(
        {Target::plate(0.5 + 20.0 * i / kCount, 0.05 + 0.9 * f, 80.0 * (1.0 - f)), {}, 1});
  }
  std::vector<tofkit::ranging::RawMeasurement> out(requests.size());
  std::uint64_t seed = 1;
  for (auto _ : state) {
    dev.measure_batch(requests, seed++, out);
    benchmark::DoNotOptimize(out.data());
  }
  state.SetItemsProcessed(state.iterations() * static_cast<std::int64_t>(requests.size()));
  state.counters["threads"] = static_cast<double>(threads);
}

/// Baseline: the random numbers a shot needs, and nothing else.
void BM_BaselinePhiloxNormalPair(benchmark::State& state) {
  const r123::Philox4x32::key_type key{{1, 2}};
  std::uint32_t i = 0;
  double acc = 0;
  for (auto _ : state) {
    const auto r = r123::Philox4x32{}({{i++, 0, 0, 0}}, key);
    const double u1 = (static_cast<double>(r[0] >> 8) + 0.5) / 16777216.0;
    const double u2 = (static_cast<double>(r[1] >> 8) + 0.5) / 16777216.0;
    const double rad = std::sqrt(-2.0 * std::log(u1));
    acc += rad * std::cos(6.283185307179586 * u2) + rad * std::sin(6.283185307179586 * u2);
  }
  benchmark::DoNotOptimize(acc);
  state.SetItemsProcessed(state.iterations());
}

int all_threads() {
  return tbb::info::default_concurrency();
}

}  // namespace

BENCHMARK(BM_BaselinePhiloxNormalPair);
BENCHMARK(BM_AnalyticShots)
    ->Arg(1)
    ->Arg(all_threads())
    ->UseRealTime()
    ->Unit(benchmark::kMillisecond);
BENCHMARK(BM_AnalyticOneShotMeasurements)
    ->Arg(1)
    ->Arg(all_threads())
    ->UseRealTime()
    ->Unit(benchmark::kMillisecond);
BENCHMARK(BM_WaveformShots)
    ->Arg(1)
    ->Arg(all_threads())
    ->UseRealTime()
    ->Unit(benchmark::kMillisecond);
