#pragma once
/// \file The self-oscillating loop's counting window over a return that changes
/// within it (a scan: the stage or the mirror moves while the board counts;
/// thesis Section 4.7's line-by-line scans, Figs. 4.23, 4.27 and 4.28).
///
/// The interface board counts its clock from the first loop edge in its gate to
/// the last and divides by the whole periods between them (reciprocal counting,
/// device/oscillator_loop.hpp). Over a changing return the window is a sequence
/// of stretches, each on one target:
///  - a locked stretch contributes its duration and duration / period periods,
///    so the reported mean period is the span over the count: the periods
///    average weighted by the time the loop spent on each target, not by the
///    shots a sampling device would have taken there;
///  - a stretch whose return the loop cannot follow (lock lost: the swing does
///    not reach the comparator's level, e.g. while the AC coupling's baseline
///    still sits where a stronger return left it, or the beam is on a target too
///    weak to oscillate on) has no edges. If the loop re-locks inside the gate,
///    the stall lies between the first and the last edge: the span grows, the
///    count does not, and the output reads long by stall / count periods. A
///    stall before the first edge or after the last only costs periods. The
///    same stall thus reads long or not by where the window's gate falls on it:
///    erratic, not a smooth offset;
///  - a stretch locked with the swing's top within a few noise sigmas of the
///    level (the baseline still recovering) counts count_factor edges per clean
///    period over the same span: extra edges read short, missed rises long.
/// The reported intensity is the peak detector's mean over the locked time.

#include <cstdint>
#include <span>

#include "tofkit/device/oscillator_loop.hpp"
#include "tofkit/device/target.hpp"
#include "tofkit/ranging/raw_measurement.hpp"

namespace tofkit::device {

/// One stretch of a counting window on one target.
struct LoopStretch {
  Target target;
  Conditions conditions;  ///< baseline_offset_v: the coupling's mean offset while locked
  double duration_ns = 0;
  double stall_ns = 0;  ///< lock lost at the stretch's start (<= duration_ns)
  /// Edges the board counts per clean loop period over the locked time: 1 on a
  /// clean swing; near the swing's top (near_top_edges) chatter adds edges (> 1,
  /// reads short) and missed rises lengthen periods (< 1, reads long).
  double count_factor = 1.0;
};

/// One output of the loop over `stretches` (in time order, durations summing to
/// the output period shots / laser.repetition_hz, shots > 0). Stretch k's loop
/// noise comes from stream (stream, k) as OscillatorLoop::measure draws it.
/// No echo when no locked time falls in the gate or fewer than one period fits.
[[nodiscard]] ranging::RawMeasurement count_loop_window(const OscillatorLoop& loop,
                                                        std::span<const LoopStretch> stretches,
                                                        std::uint64_t seed, std::uint64_t stream,
                                                        int shots);

}  // namespace tofkit::device
