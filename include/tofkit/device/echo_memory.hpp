#pragma once
/// \file Device memory: measurements taken as a time-ordered sequence (what a
/// scan produces), where what the receiver saw a moment ago still biases what
/// it reports now (DESIGN.md item 7b; thesis Figs. 3.4-3.5 and 4.28).
///
/// Causes, each a key of the `[memory]` section (all zero on the paper device):
///  - **Strength memory** (`memory.time_constant_ms`, `memory.strength_gain_mm_per_neper`):
///    the receiver's operating point follows the echo strength with a first-order
///    lag: an AC-coupled amplifier's baseline shifts with the charge of the echo
///    train passing its coupling capacitor (and an overdriven amplifier recovers
///    slowly); an AGC settles with its loop time constant. Right after a step up
///    the comparator sees a larger echo than in steady state, so the echo crosses
///    the threshold early and reads short (negative spike); after a step down it
///    reads long (positive spike). The unrecovered part decays as exp(-t / tau).
///    The state variable is the echo's charge proxy ln(clipped peak x time over
///    threshold): a clipped amplifier passes no more than that to the coupling.
///  - **Distance memory** (`memory.distance_gain`): a timing loop that tracks the
///    echo (a self-oscillating or phase-locked loop) lags a range step by a share
///    of it, decaying with the same time constant.
///  - **Motion**: a beam moving during the averaging window sweeps several
///    targets (`SequenceItem::path`); the shots are shared among them, the window
///    reports the valid-shot average of their times, widths and amplitudes (the
///    time-over-threshold walk does not average linearly: a mixed window is not
///    the window of the mixed target), and the memory evolves within the window.
///
/// Evaluation: each independent segment of a sequence (split where the time gap
/// exceeds kDecayedTimeConstants time constants, so the memory has decayed to
/// below 1e-13) runs serially, segments run in parallel; item i uses random
/// streams derived from i only, so results do not depend on the thread count.

#include <cstdint>
#include <span>
#include <vector>

#include "tofkit/device/target.hpp"
#include "tofkit/device/virtual_rangefinder.hpp"
#include "tofkit/ranging/raw_measurement.hpp"

namespace tofkit::device {

/// One output of a sequence: the targets its averaging window sweeps.
struct SequenceItem {
  /// Targets seen during the window, in time order, each for an equal share of
  /// the shots; one target: a still beam. An empty target is a miss.
  std::vector<Target> path;
  Conditions conditions;
  double time_s = 0;  ///< start of the averaging window (non-decreasing along the sequence)
  int shots = 0;      ///< 0: the config's measurement.shots
};

/// What the memory added to one output (diagnostics and tests).
struct MemoryTrace {
  double strength_neper = 0;  ///< echo charge proxy of the window, ln(V ns)
  double lag_neper = 0;       ///< mean unrecovered strength step over the window
  double error_m = 0;         ///< range error the memory added to distance_raw_m
};

/// Gap, in time constants, after which a sequence splits into independent segments.
inline constexpr double kDecayedTimeConstants = 30.0;

/// Measures sequences with the device's memory (see the file comment). Holds a
/// reference to the device, which must outlive it.
class EchoMemory {
 public:
  explicit EchoMemory(const VirtualRangefinder& device);

  /// Measures `items` in order; out[i] and (if not empty) trace[i] for item i.
  /// Throws std::invalid_argument on size mismatches, an item with an empty
  /// path or times that go backwards.
  void measure_sequence(std::span<const SequenceItem> items, std::uint64_t seed,
                        std::span<ranging::RawMeasurement> out,
                        std::span<MemoryTrace> trace = {}) const;

  /// Start indices of the independent segments of a sequence (first is 0).
  [[nodiscard]] std::vector<std::size_t> segments(std::span<const SequenceItem> items) const;

  /// The noise-free echo's charge proxy ln(clipped peak [V] x time over
  /// threshold [ns]); an undetected echo gives the threshold-level floor.
  [[nodiscard]] double echo_strength(const Target& target, const Conditions& conditions) const;

  /// Averaging window of an output of `shots` shots (0: measurement.shots), s.
  [[nodiscard]] double window_s(int shots) const;

 private:
  const VirtualRangefinder* device_;
};

}  // namespace tofkit::device
