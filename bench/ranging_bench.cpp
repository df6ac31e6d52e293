// Ranging hot path: the float pipeline (offset + gray value + temperature),
// the fixed-point chain, and memcpy of the same bytes as the baseline, on 1M
// measurements. Each benchmark reports items/s and bytes/s, and `x_memcpy`:
// its items/s divided by the items/s of a memcpy of its input array measured
// in the same run (target: >= 0.3 for the float pipeline, >= 100 M items/s).

#include <benchmark/benchmark.h>

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <ctime>
#include <random>
#include <vector>

#include "tofkit/ranging/fixed_point_chain.hpp"
#include "tofkit/ranging/pipeline.hpp"

namespace {

using namespace tofkit::ranging;

constexpr std::size_t kRows = 1 << 20;

Pipeline paper_pipeline() {
  Pipeline p;
  p.add_step(make_offset_step(0.050));
  PiecewiseLinear g;
  g.x0 = 6.5;
  g.slope0 = -0.036;
  g.knots = {6.5};
  g.slopes = {0.106};
  p.add_step(make_grayvalue_step(g, {3.0, 12.0}));
  PiecewiseLinear h;
  h.x0 = 20.0;
  h.intercept = 0.0152;
  h.knots = {16.0};
  h.slopes = {-0.0038};
  p.add_step(make_temperature_step(h, {0.0, 40.0}));
  p.set_residual_rms_m(0.003);
  return p;
}

const std::vector<RawMeasurement>& raw_input() {
  static const std::vector<RawMeasurement> data = [] {
    std::mt19937_64 rng(1);
    std::uniform_real_distribution<double> tof(5, 60), pw(3, 12), t(0, 40), a(0.01, 2);
    std::vector<RawMeasurement> v(kRows);
    for (auto& m : v) {
      m.tof_ns = tof(rng);
      m.distance_raw_m = m.tof_ns * 0.15;
      m.pulse_width_ns = pw(rng);
      m.temperature_c = t(rng);
      m.amplitude = a(rng);
      m.shots_valid = 100;
    }
    return v;
  }();
  return data;
}

const FixedPointChain& fixed_chain() {
  static const FixedPointChain chain = FixedPointChain::from_pipeline(paper_pipeline(), {});
  return chain;
}

const std::vector<FixedPointInput>& fixed_input() {
  static const std::vector<FixedPointInput> data = [] {
    std::vector<FixedPointInput> v;
    v.reserve(kRows);
    for (const auto& m : raw_input()) v.push_back(fixed_chain().to_codes(m));
    return v;
  }();
  return data;
}

/// Items/s (CPU time) of a memcpy of kRows items (best of 7), measured once.
/// CPU time of this thread: per-core throughput, unaffected by other processes
/// competing for the cores.
double thread_cpu_s() {
  timespec t{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t);
  return static_cast<double>(t.tv_sec) + 1e-9 * static_cast<double>(t.tv_nsec);
}

template <typename T>
double memcpy_items_per_s() {
  static const double rate = [] {
    std::vector<T> src(kRows), dst(kRows);
    std::memset(static_cast<void*>(src.data()), 1, kRows * sizeof(T));
    double best = 1e30;
    for (int rep = 0; rep < 7; ++rep) {
      const double start = thread_cpu_s();
      std::memcpy(static_cast<void*>(dst.data()), src.data(), kRows * sizeof(T));
      benchmark::ClobberMemory();
      best = std::min(best, thread_cpu_s() - start);
    }
    return static_cast<double>(kRows) / best;
  }();
  return rate;
}

template <typename Body>
void run_timed(benchmark::State& state, double baseline_items_per_s, std::size_t bytes_per_item,
               Body&& body) {
  double seconds = 0;
  for (auto _ : state) {
    const double start = thread_cpu_s();
    body();
    seconds += thread_cpu_s() - start;
  }
  const auto items = static_cast<double>(state.iterations()) * static_cast<double>(kRows);
  state.SetItemsProcessed(static_cast<std::int64_t>(items));
  state.SetBytesProcessed(static_cast<std::int64_t>(items * static_cast<double>(bytes_per_item)));
  state.counters["x_memcpy"] = (items / seconds) / baseline_items_per_s;
}

void BM_MemcpyRawMeasurements(benchmark::State& state) {
  const auto& in = raw_input();
  std::vector<RawMeasurement> out(kRows);
  run_timed(state, memcpy_items_per_s<RawMeasurement>(), sizeof(RawMeasurement), [&] {
    std::memcpy(static_cast<void*>(out.data()), in.data(), kRows * sizeof(RawMeasurement));
    benchmark::ClobberMemory();
  });
}
BENCHMARK(BM_MemcpyRawMeasurements)->Unit(benchmark::kMillisecond);

void BM_FloatPipeline(benchmark::State& state) {
  const Pipeline pipeline = paper_pipeline();
  const auto& in = raw_input();
  std::vector<Range> out(kRows);
  run_timed(state, memcpy_items_per_s<RawMeasurement>(), sizeof(RawMeasurement), [&] {
    pipeline.apply(in, out);
    benchmark::DoNotOptimize(out.data());
    benchmark::ClobberMemory();
  });
}
BENCHMARK(BM_FloatPipeline)->Unit(benchmark::kMillisecond);

/// The same rows inside 80-byte Records (measure()'s layout, a structured
/// NumPy array from Python), read in place through RawColumns: x_memcpy
/// against the same 48-byte memcpy as BM_FloatPipeline.
void BM_FloatPipelineStridedRecords(benchmark::State& state) {
  const Pipeline pipeline = paper_pipeline();
  std::vector<Record> records(kRows);
  for (std::size_t i = 0; i < kRows; ++i) records[i].raw = raw_input()[i];
  std::vector<Range> out(kRows);
  run_timed(state, memcpy_items_per_s<RawMeasurement>(), sizeof(Record), [&] {
    pipeline.apply(RawColumns::of(records), out);
    benchmark::DoNotOptimize(out.data());
    benchmark::ClobberMemory();
  });
}
BENCHMARK(BM_FloatPipelineStridedRecords)->Unit(benchmark::kMillisecond);

/// The same rows as seven separate arrays (a dict of NumPy columns).
void BM_FloatPipelineColumns(benchmark::State& state) {
  const Pipeline pipeline = paper_pipeline();
  const auto& in = raw_input();
  std::vector<double> tof(kRows), raw(kRows), width(kRows), amplitude(kRows), temperature(kRows);
  std::vector<std::uint32_t> shots(kRows), flags(kRows);
  for (std::size_t i = 0; i < kRows; ++i) {
    tof[i] = in[i].tof_ns, raw[i] = in[i].distance_raw_m, width[i] = in[i].pulse_width_ns;
    amplitude[i] = in[i].amplitude, temperature[i] = in[i].temperature_c;
    shots[i] = in[i].shots_valid, flags[i] = in[i].flags;
  }
  const auto column = []<typename T>(const std::vector<T>& v) {
    return StridedColumn<T>{reinterpret_cast<const std::byte*>(v.data()), sizeof(T)};
  };
  const RawColumns columns{kRows,         column(tof),       column(raw),
                           column(width), column(amplitude), column(temperature),
                           column(shots), column(flags)};
  std::vector<Range> out(kRows);
  run_timed(state, memcpy_items_per_s<RawMeasurement>(), sizeof(RawMeasurement), [&] {
    pipeline.apply(columns, out);
    benchmark::DoNotOptimize(out.data());
    benchmark::ClobberMemory();
  });
}
BENCHMARK(BM_FloatPipelineColumns)->Unit(benchmark::kMillisecond);

void BM_MemcpyFixedPointInputs(benchmark::State& state) {
  const auto& in = fixed_input();
  std::vector<FixedPointInput> out(kRows);
  run_timed(state, memcpy_items_per_s<FixedPointInput>(), sizeof(FixedPointInput), [&] {
    std::memcpy(static_cast<void*>(out.data()), in.data(), kRows * sizeof(FixedPointInput));
    benchmark::ClobberMemory();
  });
}
BENCHMARK(BM_MemcpyFixedPointInputs)->Unit(benchmark::kMillisecond);

void BM_FixedPointChain(benchmark::State& state) {
  const FixedPointChain& chain = fixed_chain();
  const auto& in = fixed_input();
  std::vector<FixedPointOutput> out(kRows);
  run_timed(state, memcpy_items_per_s<FixedPointInput>(), sizeof(FixedPointInput), [&] {
    chain.apply(in, out);
    benchmark::DoNotOptimize(out.data());
    benchmark::ClobberMemory();
  });
}
BENCHMARK(BM_FixedPointChain)->Unit(benchmark::kMillisecond);

}  // namespace
