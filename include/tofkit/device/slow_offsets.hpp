#pragma once
/// \file The timing stage's slow drift: a delay offset that every shot of one
/// output shares, so averaging shots has a floor (DESIGN, "Measurement").
/// Three causes, drawn from the run's seed (a run is a power-on):
///  - the power-on offset (measurement.power_on_offset_ps): one normal draw
///    per power-on, the trigger and receive chain settling a little
///    differently each time;
///  - 1/f flicker (measurement.flicker_delay_ps): equal power per octave over
///    kFlickerOctaves octaves from kFlickerLowestHz, one sinusoid per octave
///    of random phase; the even and the odd octaves each a chain of x4
///    steps from a base frequency drawn log-uniformly within its octave per
///    power-on (two periods that differ: the sum does not repeat);
///  - a random wander (measurement.delay_wander_ps): kWanderLevels processes
///    of equal power whose correlation times grow by kWanderLevelRatio (two
///    octaves) from kWanderShortestS, each passing from one independent knot
///    to the next as cos(pi w / 2) g_j + sin(pi w / 2) g_j+1 (unit variance at
///    every w): a 1/f spectrum from 1 / s_max to 1 / s_0.
/// The comparator's effective level wanders as a second, independent process
/// on the same levels and knot times (discriminator.level_wander_mv: the
/// reference's and the amplifier's offset drift).
/// An output's offset depends on the seed and its time only: stream i starts
/// i output periods (shots / repetition rate) after power-on, plus its
/// conditions' session_time_s. No thread count or grouping shows in it.

#include <array>
#include <cstddef>
#include <cstdint>

#include "tofkit/device/device_config.hpp"
#include "tofkit/device/target.hpp"

namespace tofkit::device {

class SlowOffsets {
 public:
  static constexpr std::size_t kMaxOutputs = 64;  ///< outputs per offsets_ns call
  static constexpr int kFlickerOctaves = 8;       ///< 1/f flicker: octaves from kFlickerLowestHz
  static constexpr double kFlickerLowestHz = 1e-3;
  static constexpr int kWanderLevels = 12;  ///< 1 ms ... 4^11 ms (70 min)
  static constexpr double kWanderShortestS = 1e-3;
  static constexpr double kWanderLevelRatio = 4.0;
  /// Random streams of the run's draws (the per-shot draws use the low ones).
  static constexpr std::uint64_t kPowerOnStream = ~std::uint64_t{0};
  static constexpr std::uint64_t kWanderStream = ~std::uint64_t{0} - 1;  ///< level k: minus k

  /// `device_id` tags the per-thread caches of the run's draws.
  SlowOffsets(const DeviceConfig& config, std::uint64_t device_id);

  /// The run's draws (power-on offset, the phases of the flicker's octaves):
  /// they depend on the seed only, so they are worked out once per thread
  /// and seed (the reference stays valid until the thread asks for another).
  struct RunDraws {
    std::uint64_t device = 0, seed = 0;
    double offset_ns = 0;  ///< the power-on offset
    std::array<double, kFlickerOctaves> cos_phase{}, sin_phase{};
    /// The flicker's two chains of octaves (even, odd): octave 2 j + chain
    /// oscillates at chain_hz[chain] 4^j, chain_hz[chain] in [f_0 2^chain, f_0 2^(chain + 1)).
    std::array<double, 2> chain_hz{};
  };
  [[nodiscard]] const RunDraws& run_draws(std::uint64_t seed) const;

  /// The delay offsets (ns) of n <= kMaxOutputs consecutive streams from
  /// stream0 (power-on offset + flicker + wander) into offsets, and the
  /// comparator level's wander (V; 0 without wander) into level_offsets;
  /// conds[i] gives output i's session time.
  void offsets_ns(std::uint64_t seed, const RunDraws& run, std::uint64_t stream0, std::size_t n,
                  const Conditions* conds, double* offsets, double* level_offsets) const;

  /// Whether the delay or the comparator level wanders at all.
  [[nodiscard]] bool wandering() const { return wandering_; }

 private:
  void flicker_offsets_ns(const RunDraws& run, std::uint64_t stream0, std::size_t n,
                          double* offsets) const;
  void add_wander_ns(std::uint64_t seed, std::uint64_t stream0, std::size_t n,
                     const Conditions* conds, double* offsets, double* level_offsets) const;

  MeasurementConfig measurement_;
  double repetition_hz_ = 0;
  double level_wander_mv_ = 0;
  std::uint64_t device_id_ = 0;
  bool wandering_ = false;
};

}  // namespace tofkit::device
