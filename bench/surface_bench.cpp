// Correction-surface throughput: batch evaluation of poly4 and B-spline surfaces
// on 1M rows beside a memcpy of the same input bytes (the floor any pass over
// the data pays), and fit time for 1M training points.

#include <benchmark/benchmark.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <random>
#include <vector>

#include "tofkit/calib/surface_fit.hpp"

namespace {

using namespace tofkit::calib;

constexpr std::size_t kRows = 1'000'000;

struct Data {
  std::vector<double> range_m, amplitude, temperature_c, error_m;
  Data() {
    std::mt19937_64 rng(42);
    std::uniform_real_distribution<double> unit(0.0, 1.0);
    std::normal_distribution<double> gauss(0.0, 0.002);
    for (std::size_t k = 0; k < kRows; ++k) {
      const double r = 1.0 + 29.0 * unit(rng);
      const double a = 20.0 * std::pow(200.0, unit(rng));
      const double t = 50.0 * unit(rng);
      range_m.push_back(r);
      amplitude.push_back(a);
      temperature_c.push_back(t);
      // Range walk, range slope and thermal drift (thesis Section 4.5, paper 3.8 mm/C).
      error_m.push_back(0.06 * std::exp(-a / 300.0) + 1e-3 * r - 3.8e-3 * (t - 25.0) + gauss(rng));
    }
  }
  [[nodiscard]] SurfaceFitData fit_data(bool temperature) const {
    return {{range_m, amplitude,
             temperature ? std::span<const double>(temperature_c) : std::span<const double>()},
            error_m};
  }
};

const Data& data() {
  static const Data d;
  return d;
}

const CorrectionSurface& surface(int which) {
  static const auto poly4 = [] {
    PolynomialFitOptions o;
    o.order = 4;
    return fit_polynomial_surface(data().fit_data(false), o).surface;
  }();
  static const auto bspline =
      fit_bspline_surface(data().fit_data(false), BSplineFitOptions{}).surface;
  static const auto bspline_t = [] {
    BSplineFitOptions o;
    o.use_temperature = true;
    return fit_bspline_surface(data().fit_data(true), o).surface;
  }();
  return which == 0 ? *poly4 : which == 1 ? *bspline : *bspline_t;
}

/// Seconds per memcpy of `bytes`, best of a few, measured in this run as the baseline.
double memcpy_seconds(std::size_t bytes) {
  std::vector<char> from(bytes, 1), to(bytes);
  double best = 1e9;
  for (int k = 0; k < 10; ++k) {
    const auto t0 = std::chrono::steady_clock::now();
    std::memcpy(to.data(), from.data(), bytes);
    benchmark::DoNotOptimize(to.data());
    benchmark::ClobberMemory();
    best = std::min(best,
                    std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
  }
  return best;
}

void BM_MemcpyInputs(benchmark::State& state) {
  const std::size_t columns = static_cast<std::size_t>(state.range(0));
  const std::size_t bytes = kRows * columns * sizeof(double);
  std::vector<char> from(bytes, 1), to(bytes);
  for (auto _ : state) {
    std::memcpy(to.data(), from.data(), bytes);
    benchmark::DoNotOptimize(to.data());
    benchmark::ClobberMemory();
  }
  state.SetItemsProcessed(static_cast<std::int64_t>(state.iterations() * kRows));
  state.SetBytesProcessed(static_cast<std::int64_t>(state.iterations() * bytes));
}
BENCHMARK(BM_MemcpyInputs)->Arg(2)->Arg(3)->Unit(benchmark::kMillisecond);

void BM_Evaluate(benchmark::State& state) {
  const int which = static_cast<int>(state.range(0));
  const CorrectionSurface& s = surface(which);
  const Data& d = data();
  const SurfaceInputs in{
      d.range_m, d.amplitude,
      s.uses_temperature() ? std::span<const double>(d.temperature_c) : std::span<const double>()};
  std::vector<double> out(kRows);
  std::vector<std::uint8_t> flags(kRows);
  const std::size_t columns = s.uses_temperature() ? 3 : 2;
  const std::size_t bytes = kRows * columns * sizeof(double);
  const double baseline = memcpy_seconds(bytes);
  const auto t0 = std::chrono::steady_clock::now();
  for (auto _ : state) {
    s.evaluate(in, out, flags);
    benchmark::DoNotOptimize(out.data());
    benchmark::ClobberMemory();
  }
  const double seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  state.SetLabel(which == 0   ? "poly4"
                 : which == 1 ? "bspline 9x11"
                              : "bspline 9x11x6 (temperature)");
  state.SetItemsProcessed(static_cast<std::int64_t>(state.iterations() * kRows));
  state.SetBytesProcessed(static_cast<std::int64_t>(state.iterations() * bytes));
  // Time of one evaluation pass over the time of copying its input bytes.
  state.counters["x_memcpy"] =
      benchmark::Counter(baseline * static_cast<double>(state.iterations()),
                         benchmark::Counter::kIsRate | benchmark::Counter::kInvert);
}
BENCHMARK(BM_Evaluate)->Arg(0)->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond);

void BM_FitPoly4(benchmark::State& state) {
  PolynomialFitOptions o;
  o.order = 4;
  o.use_temperature = state.range(0) != 0;
  for (auto _ : state)
    benchmark::DoNotOptimize(fit_polynomial_surface(data().fit_data(o.use_temperature), o));
  state.SetLabel(o.use_temperature ? "order 4, temperature (35 terms)" : "order 4 (15 terms)");
  state.SetItemsProcessed(static_cast<std::int64_t>(state.iterations() * kRows));
}
BENCHMARK(BM_FitPoly4)->Arg(0)->Arg(1)->Unit(benchmark::kMillisecond)->Iterations(3);

void BM_FitBSpline(benchmark::State& state) {
  BSplineFitOptions o;
  o.use_temperature = state.range(0) != 0;
  for (auto _ : state)
    benchmark::DoNotOptimize(fit_bspline_surface(data().fit_data(o.use_temperature), o));
  state.SetLabel(o.use_temperature ? "9x11x6, temperature" : "9x11");
  state.SetItemsProcessed(static_cast<std::int64_t>(state.iterations() * kRows));
}
BENCHMARK(BM_FitBSpline)->Arg(0)->Arg(1)->Unit(benchmark::kMillisecond)->Iterations(3);

}  // namespace
