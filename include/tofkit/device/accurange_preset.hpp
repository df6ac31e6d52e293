#pragma once
/// \file The "accurange" preset: an AccuRange-3000-like pulsed ToF rangefinder,
/// the device of the characterization thesis (reference/characterization_thesis.md:
/// 780 nm, 20 mW peak, 2.5 in collecting lens, working range 0.3-0.6 m).
///
/// It measures by the AccuRange's own principle, a self-oscillating loop
/// (device/oscillator_loop.hpp; thesis Section 3.1), and its values are tuned so
/// that the thesis's findings arise from the physics rather than being imposed:
///  - the receiver's step response crossing a fixed threshold above its AC-coupled
///    baseline makes the walk: dark targets read long, saturating bright ones
///    short; with the vendor zero of the thesis's reflectance fit the unit reads
///    about an inch short over the grey chart (Fig. 4.18's raw row);
///  - the 80 MHz count over a gate set by the sampling rate gives Fig. 4.4's
///    resolution; a slow wander of the loop delay its variance floor;
///  - a negative delay coefficient makes the range fall 0.25-0.60 in per 10 C;
///  - warm-up drift of the timing electronics settles in 25-35 min;
///  - the laser's first moments after switch-on are biased (turn-on transient);
///  - the ~3 mm beam footprint makes mixed pixels at step edges;
///  - receiver memory makes the mirror-edge spikes and colour-transition swings.

#include "tofkit/device/device_config.hpp"

namespace tofkit::device {

/// The AccuRange-3000-like device (name "accurange"). Every value is documented
/// in the .cpp with its source (thesis, datasheet class) or "Assumption" and why.
[[nodiscard]] DeviceConfig accurange_preset();

}  // namespace tofkit::device
