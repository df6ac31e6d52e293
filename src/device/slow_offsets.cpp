#include "tofkit/device/slow_offsets.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>

#include "random_draws.hpp"

namespace tofkit::device {
namespace {

using detail::CounterRng;
using detail::normal_pair;
using detail::sincos_of_phase;
using detail::unit_open;
using physics::kPi;
constexpr std::size_t kMaxOutputs = SlowOffsets::kMaxOutputs;
constexpr int kFlickerOctaves = SlowOffsets::kFlickerOctaves;
constexpr int kWanderLevels = SlowOffsets::kWanderLevels;

/// Knot j of wander level k: a unit-variance draw of the run (seed), level and
/// knot only, so any output reads the same knots on any thread or grouping.
/// The last two knots of each level are kept per thread (consecutive outputs
/// share them).
/// Each knot is a pair of independent draws: [0] for the delay's wander,
/// [1] for the comparator level's.
using KnotPair = std::array<double, 2>;
/// (Inlined into the wander's lanes: most calls only check the cache.)
[[gnu::always_inline]] inline const std::array<KnotPair, 2>& wander_knots(const CounterRng& rng,
                                                                          std::uint64_t device,
                                                                          int level,
                                                                          std::uint64_t j) {
  struct Knots {
    std::uint64_t device = 0, seed = 0, j = ~std::uint64_t{0};
    std::array<KnotPair, 2> g{};
  };
  thread_local std::array<Knots, kWanderLevels> cache;
  auto& c = cache[static_cast<std::size_t>(level)];
  if (c.device != device || c.seed != rng.seed() || c.j != j) {
    auto knot = [&](std::uint64_t index) {
      const auto r =
          rng.draw(SlowOffsets::kWanderStream - static_cast<std::uint64_t>(level),
                   static_cast<std::uint32_t>(index), static_cast<std::uint32_t>(index >> 32));
      // Two uniforms each (triangular, unit variance): one draw, no
      // logarithm; an output sums 24 knots, normal by the central limit.
      constexpr double kUnitTriangle = 2.449489742783178;  // sqrt(6)
      return KnotPair{kUnitTriangle * (unit_open(r[0]) + unit_open(r[1]) - 1.0),
                      kUnitTriangle * (unit_open(r[2]) + unit_open(r[3]) - 1.0)};
    };
    // A step of one knot reuses the shared one.
    c.g = c.device == device && c.seed == rng.seed() && c.j + 1 == j
              ? std::array<KnotPair, 2>{c.g[1], knot(j + 1)}
              : std::array<KnotPair, 2>{knot(j), knot(j + 1)};
    c.device = device;
    c.seed = rng.seed();
    c.j = j;
  }
  return c.g;
}

/// cos(pi w / 2) for w in [0, 1] (Taylor to w^10: within 5e-7).
inline double cos_quarter_turn(double w) {
  constexpr double h = kPi / 2;
  const double x = h * h * w * w;
  return 1.0 + x * (-1.0 / 2 +
                    x * (1.0 / 24 + x * (-1.0 / 720 + x * (1.0 / 40320 + x * (-1.0 / 3628800)))));
}

}  // namespace

SlowOffsets::SlowOffsets(const DeviceConfig& config, std::uint64_t device_id)
    : measurement_(config.measurement),
      repetition_hz_(config.link.laser.repetition_hz),
      level_wander_mv_(config.discriminator.level_wander_mv),
      device_id_(device_id),
      wandering_(config.measurement.delay_wander_ps > 0.0 ||
                 config.discriminator.level_wander_mv > 0.0) {}

const SlowOffsets::RunDraws& SlowOffsets::run_draws(std::uint64_t seed) const {
  const CounterRng rng(seed);
  const auto& mc = measurement_;
  thread_local RunDraws run;
  if (run.device != device_id_ || run.seed != rng.seed()) {
    const auto power_on = rng.draw(kPowerOnStream, 0, 0);
    run.offset_ns = mc.power_on_offset_ps * 1e-3 * normal_pair(power_on[0], power_on[1])[0];
    for (int k = 0; k < kFlickerOctaves; k += 4) {
      const auto r = rng.draw(kPowerOnStream, 1, static_cast<std::uint32_t>(k));
      for (int j = 0; j < 4 && k + j < kFlickerOctaves; ++j) {
        const auto o = static_cast<std::size_t>(k + j);
        ::sincos(2.0 * kPi * unit_open(r[static_cast<std::size_t>(j)]), &run.sin_phase[o],
                 &run.cos_phase[o]);
      }
    }
    const auto f = rng.draw(kPowerOnStream, 2, 0);
    for (std::size_t chain = 0; chain < 2; ++chain)
      run.chain_hz[chain] =
          kFlickerLowestHz * std::exp2(static_cast<double>(chain) + unit_open(f[chain]));
    run.device = device_id_;
    run.seed = rng.seed();
  }
  return run;
}

/// The power-on offset plus the 1/f flicker (measurement.flicker_delay_ps)
/// of n <= kMaxOutputs consecutive streams from stream0 (in stages over the
/// streams: the octaves' sum vectorizes).
/// Also compiled for AVX2, as add_wander_ns.
__attribute__((target_clones("avx2", "default"))) void SlowOffsets::flicker_offsets_ns(
    const RunDraws& run, std::uint64_t stream0, std::size_t n, double* offsets) const {
  const auto& mc = measurement_;
  if (mc.flicker_delay_ps <= 0.0) {
    std::fill(offsets, offsets + n, run.offset_ns);
    return;
  }
  // 1/f noise has equal power per octave: one sinusoid of random phase per
  // octave, each with rms flicker / sqrt(octaves), i.e. amplitude sqrt(2) times that.
  // The even octaves oscillate at chain_hz[0] 4^j, the odd ones at chain_hz[1]
  // 4^j, each chain's base drawn within its octave at power-on: a chain's angle
  // is its base's doubled twice per octave, and the two chains' periods differ,
  // so the sum does not repeat (octaves at exact doublings of f_0 would sum to
  // a signal of period 1 / f_0, 1000 s, whose change over 1000 s is nil and
  // over 1200 s 1.12x its mean).
  const double amplitude = mc.flicker_delay_ps * 1e-3 * std::sqrt(2.0 / kFlickerOctaves);
  std::array<std::array<double, kMaxOutputs>, 2> sin_a, cos_a;
  for (std::size_t i = 0; i < n; ++i) {
    const double t_s = static_cast<double>(stream0 + i) * mc.shots / repetition_hz_;
    for (std::size_t chain = 0; chain < 2; ++chain) {
      // The chain's base phase in cycles, to 2^-32 of a cycle (table sincos).
      const double cycles = run.chain_hz[chain] * t_s;
      const auto phase = static_cast<std::uint32_t>(
          static_cast<std::int64_t>((cycles - std::floor(cycles)) * 0x1p32) & 0xFFFFFFFF);
      sincos_of_phase(phase, sin_a[chain][i], cos_a[chain][i]);
    }
  }
  for (std::size_t i = 0; i < n; ++i) {
    double wander = 0;
    for (std::size_t chain = 0; chain < 2; ++chain) {
      double s = sin_a[chain][i], c = cos_a[chain][i];
      for (std::size_t k = chain; k < kFlickerOctaves; k += 2) {
        wander += s * run.cos_phase[k] + c * run.sin_phase[k];  // sin(a + phase)
        for (int twice = 0; twice < 2; ++twice) {
          const double s2 = 2.0 * s * c;
          c = (c - s) * (c + s);
          s = s2;
        }
      }
    }
    offsets[i] = run.offset_ns + amplitude * wander;
  }
}

/// Adds the random delay wander (measurement.delay_wander_ps) of n <=
/// kMaxOutputs consecutive streams from stream0 to offsets, and writes the
/// comparator level's (discriminator.level_wander_mv, V) to level_offsets.
/// Each output's value depends on its time and the seed only; its time is its
/// place in the run (stream x output period) plus its conditions' session
/// time (a protocol that waits between points, e.g. for a plate swap or a
/// climate chamber, says so there).
/// Also compiled for AVX2, as the pulsed core's single-shot lanes (the
/// interpolation vectorizes; AVX2 brings no FMA, so both give the same bytes).
__attribute__((target_clones("avx2", "default"))) void SlowOffsets::add_wander_ns(
    std::uint64_t seed, std::uint64_t stream0, std::size_t n, const Conditions* conds,
    double* offsets, double* level_offsets) const {
  const CounterRng rng(seed);
  const auto& mc = measurement_;
  const double norm = 1.0 / std::sqrt(static_cast<double>(kWanderLevels));
  const double amplitude = mc.delay_wander_ps * 1e-3 * norm;
  const double level_amplitude = level_wander_mv_ * 1e-3 * norm;
  const double period_s = static_cast<double>(mc.shots) / repetition_hz_;
  std::array<double, kMaxOutputs> t_s, wander, level_wander;
  for (std::size_t i = 0; i < n; ++i) {
    t_s[i] = static_cast<double>(stream0 + i) * period_s + conds[i].session_time_s;
    wander[i] = 0.0;
    level_wander[i] = 0.0;
  }
  // Per level: the knots in a scalar pass (a lookup only where the knot
  // index changes from the previous lane), then the interpolation over the
  // lanes in a pass that vectorizes.
  std::array<double, kMaxOutputs> w, g0, g1, h0, h1;
  double inv_scale = 1.0 / kWanderShortestS;
  for (int level = 0; level < kWanderLevels; ++level) {
    std::uint64_t j_prev = ~std::uint64_t{0};
    const std::array<KnotPair, 2>* g = nullptr;
    for (std::size_t i = 0; i < n; ++i) {
      const double u = t_s[i] * inv_scale;
      const double floor_u = std::floor(u);
      w[i] = u - floor_u;
      const auto j = static_cast<std::uint64_t>(floor_u);
      if (g == nullptr || j != j_prev) {
        g = &wander_knots(rng, device_id_, level, j);
        j_prev = j;
      }
      g0[i] = (*g)[0][0];
      g1[i] = (*g)[1][0];
      h0[i] = (*g)[0][1];
      h1[i] = (*g)[1][1];
    }
    for (std::size_t i = 0; i < n; ++i) {
      const double c0 = cos_quarter_turn(w[i]), c1 = cos_quarter_turn(1.0 - w[i]);
      wander[i] += c0 * g0[i] + c1 * g1[i];
      level_wander[i] += c0 * h0[i] + c1 * h1[i];
    }
    inv_scale /= kWanderLevelRatio;
  }
  for (std::size_t i = 0; i < n; ++i) {
    offsets[i] += amplitude * wander[i];
    level_offsets[i] = level_amplitude * level_wander[i];
  }
}

void SlowOffsets::offsets_ns(std::uint64_t seed, const RunDraws& run, std::uint64_t stream0,
                             std::size_t n, const Conditions* conds, double* offsets,
                             double* level_offsets) const {
  if (n > kMaxOutputs)
    throw std::invalid_argument("SlowOffsets::offsets_ns: more than kMaxOutputs (64) outputs");
  flicker_offsets_ns(run, stream0, n, offsets);
  if (wandering_)
    add_wander_ns(seed, stream0, n, conds, offsets, level_offsets);
  else
    std::fill(level_offsets, level_offsets + n, 0.0);
}

}  // namespace tofkit::device
