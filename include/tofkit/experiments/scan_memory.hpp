#pragma once
/// \file The thesis's uncorrected scanning errors and their correction
/// (reference/characterization_thesis.md; thesis Figs. 3.4-3.5 and 4.28):
///  - mirror edges: a profile swept by the rotating 45-degree mirror across
///    blocks in front of a wall: a spike at every edge, decaying exponentially
///    (on the loop device both ways read long: its period is shortest with the
///    coupling's baseline settled, device/echo_memory.hpp; after a large step
///    down the loop first loses lock, no echo, and the spike is where it re-locks);
///  - colour transition (Fig. 4.28, in the thesis's line-scan section): a chart
///    of a mid-grey area beside a black one scanned line by line as Figs.
///    4.23-4.27 (the stage moving while the device samples): on black after mid
///    grey the range swings (thesis: erratically, 15.65-23.91 in over half the
///    black area); the same transition on the mirror as a profile too;
///  - beyond the thesis, the memory correction: a causal filter
///    (ranging/memory_correction.hpp) whose time constant and gain are fitted
///    on a separate step-edge scan (one block), then applied to both profiles;
///    spike amplitude and RMS near edges before and after.
/// Profiles are averaged over revolutions (the mirror sweeps the same profile
/// each turn), so the spikes stand out of the noise; one revolution is kept too.

#include <cstdint>
#include <string>
#include <vector>

#include "tofkit/calib/memory_fit.hpp"
#include "tofkit/calib/statistics.hpp"
#include "tofkit/device/virtual_rangefinder.hpp"
#include "tofkit/experiments/characterization_common.hpp"
#include "tofkit/ranging/memory_correction.hpp"

namespace tofkit::experiments {

struct MemoryScanOptions {
  double wall_distance_m = 0.60;    ///< background wall
  double wall_reflectance = 0.15;   ///< Assumption: a darker wall
  double block_front_m = 0.45;      ///< blocks' front faces
  double block_reflectance = 0.60;  ///< Assumption: light-grey blocks
  /// Vertical extents of the blocks of the mirror-edge scene (z, m).
  std::vector<double> block_bottom_m{-0.15, 0.03}, block_top_m{-0.06, 0.13};
  /// The step-edge calibration scene: one block from this height up.
  double calibration_edge_m = -0.02;
  double transition_distance_m = 0.4826;  ///< 19 in
  int transition_from_grey = 128;         ///< mid grey (below; thesis numbering, 0 = white)
  int transition_to_grey = 255;           ///< black (above the horizon)
  /// Fig. 4.28's line scan: each area this wide (Assumption: 2 in), sampled at
  /// line_shots per output while the stage moves at stage_speed_m_per_s (the
  /// line-scan set-up of experiments/thesis_line_scan.hpp).
  double transition_area_m = 0.0508;
  int line_shots = 256;
  double stage_speed_m_per_s = 0.15;
  double elevation_min_deg = -20, elevation_max_deg = 20, elevation_step_deg = 0.25;
  double revolutions_per_s = 5;  ///< 139 us per 0.25 deg column
  int revolutions = 40;
  int shots = 0;  ///< per output (0: measurement.shots)
  double ambient_c = 20.0;
  /// A step between neighbouring outputs of more than this many nepers of echo
  /// strength is an edge.
  double edge_step_neper = 0.3;
  int spike_columns = 3;  ///< columns after an edge searched for the spike's extreme
  calib::MemoryFitOptions fit{};
  void validate() const;
};

/// One edge of a profile.
struct EdgeSpike {
  double elevation_deg = 0;
  bool rising = false;  ///< echo strength steps up (onto a block / a lighter grey)
  double spike_before_m = ranging::kNaN;  ///< signed extreme of error - settled error
  double spike_after_m = ranging::kNaN;   ///< the same after the memory correction
};

/// A profile: per column (elevation), mean over revolutions; error = true - measured.
struct Profile {
  std::string name;
  std::vector<double> elevation_deg, truth_m;
  std::vector<double> error_before_m, error_after_m;    ///< mean over revolutions
  std::vector<double> single_before_m, single_after_m;  ///< first revolution
  std::vector<EdgeSpike> edges;
  double spike_before_m = ranging::kNaN;  ///< mean |spike| over edges
  double spike_after_m = ranging::kNaN;
  double rms_near_edges_before_m = ranging::kNaN;  ///< of error - settled, within 5 tau after edges
  double rms_near_edges_after_m = ranging::kNaN;
};

/// Fig. 4.28 as a line scan: every output along one line, in time order.
struct TransitionLine {
  std::vector<double> position_m;        ///< along the line from the mid-grey side's start
  std::vector<double> truth_m, range_m;  ///< range_m NaN: no echo
  double black_start_m = ranging::kNaN;  ///< where the black area begins
  /// max - min of the range over the first half of the black area (NaN: no reading there)
  double swing_m = ranging::kNaN;
  std::size_t outputs_first_half = 0, no_echo_first_half = 0;
};

struct MemoryScanResult {
  MemoryScanOptions options;
  calib::MemoryFitResult fit;  ///< from the step-edge calibration scan
  Profile mirror_edges, color_transition;
  TransitionLine transition_line;  ///< Fig. 4.28
  /// Every output of the mirror-edge scan, then of the colour-transition scan,
  /// with the true range of its beam axis (raw, before the memory correction).
  std::vector<ranging::Record> mirror_records, transition_records;
  [[nodiscard]] std::vector<Finding> findings() const;
  /// "edges", "mirror_profile", "transition_profile".
  [[nodiscard]] std::vector<ResultTable> tables() const;
  [[nodiscard]] std::string summary() const;
};

/// Runs the calibration scan, the fit, and both profiles. Throws
/// std::invalid_argument on bad options.
[[nodiscard]] MemoryScanResult run_memory_scans(const device::VirtualRangefinder& device,
                                                const MemoryScanOptions& options,
                                                std::uint64_t seed);

}  // namespace tofkit::experiments
