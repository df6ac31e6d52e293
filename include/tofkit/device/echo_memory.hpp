#pragma once
/// \file Device memory: measurements taken as a time-ordered sequence (what a
/// scan produces), where what the receiver saw a moment ago still biases what
/// it reports now (DESIGN.md item 7b; thesis Figs. 3.4-3.5 and 4.28).
///
/// Cause (the `[memory]` section; none on the paper device): an **AC
/// coupling** between the amplifier and the comparator. The coupling
/// capacitor's voltage, the baseline, is a first-order low-pass (time constant
/// `memory.time_constant_ms`) of the echo train the amplifier passes; the
/// comparator sees the echo minus it. On a still target the baseline settles
/// at the train's mean (VirtualRangefinder::coupling_baseline_v, part of every
/// measurement's walk). After a step it is still where the previous targets
/// left it, and relaxes as exp(-t / tau): after a step up the baseline is low,
/// the effective threshold too, the echo crosses early and reads short (a
/// negative spike); after a step down the level is high, a weak echo crosses
/// late, or not at all (missed shots), and reads long. The error is the walk
/// of the shifted level on this echo, not a law of its own: the pulsed core
/// moves every shot's comparator level (analytic mode) or subtracts the
/// baseline from the sampled waveform (waveform mode).
///
/// The loop (oscillator.enabled) has the same coupling inside it: on a still
/// target its baseline settles at oscillator.coupling_duty of the square wave's
/// swing and the comparator fires discriminator.threshold_v above it (walk, in
/// device/oscillator_loop.hpp). In a scan the baseline is a low-pass (the same
/// memory.time_constant_ms) of the swings of the targets just seen: after a
/// stronger return it is high, the level too, and a weak return rises late and
/// falls early (reads long); where the level reaches the swing's top the loop
/// loses lock until the baseline has come down, and the counting window around
/// the stall (device/loop_window.hpp) reads long or not by where its gate falls
/// on it (thesis Fig. 4.28: black after mid grey swings erratically); the
/// intensity output, a peak detector behind the same coupling, reads low by
/// offset / (1 - coupling_duty) meanwhile (device/oscillator_loop.hpp). After a
/// weaker return the level is low: the rise comes earlier and the fall later,
/// so the period, counted over both edges, barely moves on an unsaturated echo
/// (at most 0.05 in short at 19 in), and a saturated echo's slow fall from the
/// clip reads long (white after black: +1.9 in). While the level is within a
/// few noise sigmas of a weak swing's top, the noise adds edges (reads short)
/// and delays rises (reads long): near_top_edges (device/oscillator_loop.hpp),
/// integrated over each locked stretch as the baseline comes down and counted
/// by count_loop_window. With the preset's comparator hysteresis the first
/// outputs after re-lock on black read long (to ~24 in at 19 in); the thesis's
/// short readings (Fig. 4.28, 15.65 in) appear only with less hysteresis.
///  - **Motion**: a beam moving during the averaging window sweeps several
///    targets (`SequenceItem::path`); the shots are shared among them, the window
///    reports the valid-shot average of their times, widths and amplitudes (the
///    time-over-threshold walk does not average linearly: a mixed window is not
///    the window of the mixed target), and the memory evolves within the window.
///    The loop's board counts such a window as one span of periods
///    (device/loop_window.hpp: a time-weighted harmonic mean, stalls included).
///
/// Evaluation: each independent segment of a sequence (split where the time gap
/// exceeds kDecayedTimeConstants time constants, so the memory has decayed to
/// below 1e-13) runs serially, segments run in parallel; item i uses random
/// streams derived from i only, so results do not depend on the thread count.

#include <cstdint>
#include <memory>
#include <span>
#include <vector>

#include "tofkit/device/oscillator_loop.hpp"
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

/// The memory's state over one output (diagnostics and tests).
struct MemoryTrace {
  double strength_neper = 0;      ///< echo charge proxy of the window, ln(V ns)
  double settled_baseline_v = 0;  ///< the coupling's baseline settled on this window's targets
  double baseline_offset_v = 0;   ///< mean unrecovered baseline over the window (0: settled)
  double stall_s = 0;             ///< the loop: time it lost lock in this window
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
  std::shared_ptr<const OscillatorLoop> loop_;  ///< set for a loop device
};

}  // namespace tofkit::device
