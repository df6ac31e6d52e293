// `fit --chain` at scale (issue 8, item 6): fit_chain (offset + grayvalue +
// temperature, knot search, robust joint solve) on 250 k and 1 M synthetic
// calibration rows, CPU time of one thread. The baseline, measured in the same
// run on the same rows, is one Pipeline::apply pass (a linear pass over the
// data); `x_apply` is the fit's time over the baseline's, which stays constant
// when the fit is linear in rows. Target: 1 M rows in under 2 s of CPU.

#include <benchmark/benchmark.h>
#include <tbb/global_control.h>

#include <algorithm>
#include <cmath>
#include <ctime>
#include <random>
#include <vector>

#include "tofkit/calib/chain_fit.hpp"
#include "tofkit/calib/model_fit.hpp"
#include "tofkit/ranging/pipeline.hpp"
#include "tofkit/ranging/time_to_distance.hpp"

namespace {

using namespace tofkit;

double thread_cpu_s() {
  timespec t{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t);
  return static_cast<double>(t.tv_sec) + 1e-9 * static_cast<double>(t.tv_nsec);
}

/// Paper-like chain (knee at 6.5 ns, 16 C) with 2 mm noise and 2 % gross outliers.
std::vector<ranging::Record> calibration_rows(std::size_t n) {
  std::mt19937_64 rng(7);
  std::uniform_real_distribution<double> pw(3.0, 12.0), temp(5.0, 35.0), dist(1.0, 8.0),
      unit(0.0, 1.0);
  std::normal_distribution<double> noise(0.0, 0.002);
  const double k = ranging::metres_per_ns(ranging::TimeToDistance{});
  std::vector<ranging::Record> out(n);
  for (auto& r : out) {
    r.truth.distance_m = dist(rng);
    r.raw.temperature_c = std::round(temp(rng) * 16.0) / 16.0;  // sensor LSB
    r.raw.pulse_width_ns = pw(rng);
    const double g =
        -0.036 * (r.raw.pulse_width_ns - 6.5) + 0.106 * std::max(0.0, r.raw.pulse_width_ns - 6.5);
    const double h = -0.0038 * std::max(0.0, r.raw.temperature_c - 16.0);
    double e = 0.05 + g + h + noise(rng);
    if (unit(rng) < 0.02) e += 0.05 * (unit(rng) - 0.5);
    r.raw.tof_ns = (r.truth.distance_m - e) / k;
    r.raw.distance_raw_m = r.truth.distance_m - e;
    r.raw.amplitude = 0.5;
    r.raw.shots_valid = 100;
  }
  return out;
}

/// CPU seconds of one Pipeline::apply over the rows (best of 3).
double apply_seconds(const std::vector<ranging::Record>& rows, const ranging::Pipeline& p) {
  std::vector<ranging::RawMeasurement> raw;
  raw.reserve(rows.size());
  for (const auto& r : rows) raw.push_back(r.raw);
  std::vector<ranging::Range> out(raw.size());
  double best = 1e30;
  for (int rep = 0; rep < 3; ++rep) {
    const double start = thread_cpu_s();
    p.apply(raw, out);
    benchmark::DoNotOptimize(out.data());
    best = std::min(best, thread_cpu_s() - start);
  }
  return best;
}

void BM_FitChain(benchmark::State& state) {
  tbb::global_control one_core(tbb::global_control::max_allowed_parallelism, 1);
  const auto rows = calibration_rows(static_cast<std::size_t>(state.range(0)));
  double seconds = 0;
  calib::ChainFitResult fit;
  for (auto _ : state) {
    const double start = thread_cpu_s();
    fit = calib::fit_chain(rows);
    seconds += thread_cpu_s() - start;
  }
  const double per_fit = seconds / static_cast<double>(state.iterations());
  state.SetItemsProcessed(static_cast<std::int64_t>(state.iterations()) * state.range(0));
  state.counters["cpu_s"] = per_fit;
  state.counters["x_apply"] = per_fit / apply_seconds(rows, fit.pipeline);
  state.counters["rms_mm"] = fit.after.rms_m * 1e3;
}
BENCHMARK(BM_FitChain)->Arg(250'000)->Arg(1'000'000)->Unit(benchmark::kMillisecond)->Iterations(2);

/// fit --chain ... --refine-walk --confidence none: the chain plus the walk
/// refinement's grouped cross-validation (on at most 50 k rows) and its fit on all.
void BM_FitChainRefineWalk(benchmark::State& state) {
  tbb::global_control one_core(tbb::global_control::max_allowed_parallelism, 1);
  const auto rows = calibration_rows(static_cast<std::size_t>(state.range(0)));
  calib::ModelFitOptions options;
  options.chain = calib::ChainSteps{};
  options.refine_walk = true;
  options.confidence = calib::ConfidenceKind::none;
  double seconds = 0;
  calib::ModelFitResult fit;
  for (auto _ : state) {
    const double start = thread_cpu_s();
    fit = calib::fit_model(rows, options);
    seconds += thread_cpu_s() - start;
  }
  const double per_fit = seconds / static_cast<double>(state.iterations());
  state.SetItemsProcessed(static_cast<std::int64_t>(state.iterations()) * state.range(0));
  state.counters["cpu_s"] = per_fit;
  state.counters["x_apply"] = per_fit / apply_seconds(rows, fit.pipeline);
  state.counters["rms_mm"] = fit.pipeline.residual_rms_m() * 1e3;
}
BENCHMARK(BM_FitChainRefineWalk)
    ->Arg(250'000)
    ->Arg(1'000'000)
    ->Unit(benchmark::kMillisecond)
    ->Iterations(2);

}  // namespace
