#pragma once
/// \file The "accurange" preset: an AccuRange-3000-like pulsed ToF rangefinder,
/// the device of the characterization thesis (reference/characterization_thesis.md:
/// 780 nm, 20 mW peak, 2.5 in collecting lens, working range 0.3-0.6 m).
///
/// Its values are tuned so that the thesis's findings arise from the physics of
/// the virtual rangefinder rather than being imposed:
///  - walk of a fixed-threshold discriminator on a fast, bandwidth-limited echo
///    gives raw errors of about an inch over grey levels 0-255 at 15-22 in, dark
///    targets reading long (near the threshold the rising edge crosses late) and
///    very bright ones saturating and reading short (thesis Section 4.4, reflectance);
///  - a negative delay coefficient makes the range fall 0.25-0.60 in per 10 C;
///  - warm-up drift of the timing electronics settles in 25-35 min;
///  - the laser's first shots after switch-on are biased (turn-on transient);
///  - the ~3 mm beam footprint makes mixed pixels at step edges.

#include "tofkit/device/device_config.hpp"

namespace tofkit::device {

/// The AccuRange-3000-like device (name "accurange"). Every value is documented
/// in the .cpp with its source (thesis, datasheet class) or "Assumption" and why.
[[nodiscard]] DeviceConfig accurange_preset();

}  // namespace tofkit::device
