#pragma once
/// \file A scan measured as a time-ordered sequence: every beam of a pattern is
/// traced through the scene at several points of its averaging window (the
/// beam moves while the device averages) and the whole scan goes through the
/// device's memory (device/echo_memory.hpp), so edges swept by the beam leave
/// their spikes and the stage's motion its line-by-line bias. The result is a
/// scan::ScanResult like scan::run_scan's, so scan::make_images resamples it.

#include <cstdint>
#include <vector>

#include "tofkit/device/echo_memory.hpp"
#include "tofkit/scan/scanner.hpp"

namespace tofkit::experiments {

struct SequenceScanOptions {
  std::uint64_t seed = 1;
  int shots = 0;  ///< per beam (0: measurement.shots)
  device::Conditions conditions;
  /// Points of the averaging window at which the beam's footprint is traced
  /// (1: a still beam). The beam moves towards the next beam of its row.
  int window_points = 4;
  void validate() const;
};

struct SequenceScan {
  scan::ScanResult result;                  ///< per beam, in time order
  std::vector<device::MemoryTrace> memory;  ///< what the memory added, per beam
};

/// Traces and measures every beam (footprints in parallel, then the sequence).
[[nodiscard]] SequenceScan run_sequence_scan(const scan::RayCaster& caster,
                                             const scan::Footprint& footprint,
                                             const device::VirtualRangefinder& device,
                                             const scan::BeamPattern& pattern,
                                             const SequenceScanOptions& options);

}  // namespace tofkit::experiments
