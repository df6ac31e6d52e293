#pragma once
/// \file Running a scan: every beam of a pattern is traced through the scene
/// (footprint -> device::Target) and measured by the virtual rangefinder.
/// Beam i uses random stream i, so results do not depend on the thread count.

#include <cstdint>
#include <functional>
#include <vector>

#include "tofkit/device/virtual_rangefinder.hpp"
#include "tofkit/ranging/pipeline.hpp"
#include "tofkit/ranging/raw_measurement.hpp"
#include "tofkit/scan/footprint.hpp"
#include "tofkit/scan/pattern.hpp"

namespace tofkit::scan {

/// One beam's outcome. Origin and direction are in the world frame.
struct BeamResult {
  Beam beam;
  double true_range_m = 0;               ///< first-hit distance of the beam axis; NaN on a miss
  int surfaces = 0;                      ///< surfaces in the footprint (2+: a mixed pixel)
  double reflectance = ranging::kNaN;    ///< of the footprint's largest surface
  double cos_incidence = ranging::kNaN;  ///< cos of the incidence angle on that surface
  ranging::RawMeasurement raw;
  ranging::Range range;  ///< NaN until a model is applied
};

/// `beam` (sensor frame) into `out` in the world frame of `to_world`, field
/// by field (the origin and direction are not copied and then overwritten).
void beam_to_world(const Beam& beam, const RigidTransform& to_world, Beam& out);

/// A beam's footprint into its result: the axis's true range, the number of
/// surfaces, and the reflectance and incidence of the largest (NaN on a miss).
void record_footprint(const Footprint::Result& footprint, BeamResult& b);

struct ScanResult {
  /// The pattern's description (name, size, line columns); its `beams` are
  /// left empty: every beam is in `beams` below, in the world frame.
  BeamPattern pattern;
  Pose sensor;
  std::vector<BeamResult> beams;  ///< in the pattern's (time) order
  bool has_model = false;         ///< ranges filled by a correction model
};

struct ScanOptions {
  std::uint64_t seed = 1;
  int shots = 0;  ///< per beam before the pattern's multiplier (0: measurement.shots)
  device::Conditions conditions;  ///< ambient; warm-up and laser-on clocks at the scan's start
  /// Advance conditions.minutes_since_power_on and ms_since_laser_on with each
  /// beam's time stamp (warm-up drift and the laser's turn-on show in a scan).
  bool clocks_follow_beams = true;
  /// Called from the calling thread after each block of beams (done, total).
  std::function<void(std::size_t, std::size_t)> progress;
};

/// Shots one beam of `pattern` averages: `shots` (0: the device's
/// measurement.shots) times the pattern's multiplier (a raster's samples).
/// Throws std::invalid_argument when that exceeds device::kMaxShots.
[[nodiscard]] int shots_per_beam(const device::DeviceConfig& config, int shots,
                                 const BeamPattern& pattern);

[[nodiscard]] ScanResult run_scan(const RayCaster& caster, const Footprint& footprint,
                                  const device::VirtualRangefinder& device,
                                  const BeamPattern& pattern, const ScanOptions& options);

/// The same into `result`, keeping the storage of its beams: a scanner that
/// produces frame after frame (a spinning lidar in real time) pays for its
/// results' memory once, not the kernel's clearing of fresh pages every frame
/// (a megabeam frame is 176 MB). Every field of `result` is overwritten; the
/// bytes are those of the returning form.
void run_scan(const RayCaster& caster, const Footprint& footprint,
              const device::VirtualRangefinder& device, const BeamPattern& pattern,
              const ScanOptions& options, ScanResult& result);

/// The same with the ray caster, footprint and virtual rangefinder made from
/// `scene` and `config` (what `tofkit scan` and Python's tofkit.scan run).
[[nodiscard]] ScanResult run_scan(const Scene& scene, const device::DeviceConfig& config,
                                  device::SimulationMode mode, const BeamPattern& pattern,
                                  const ScanOptions& options);

/// Corrects every beam's raw measurement with `pipeline` (one batch) into its
/// `range` and sets has_model: the images and points then report corrected
/// distances and sigma.
void apply_pipeline(const ranging::Pipeline& pipeline, ScanResult& result);

/// A row-major float image; NaN marks invalid pixels (no echo: REP-117).
struct Image {
  int rows = 0, columns = 0;
  std::vector<float> values;
  [[nodiscard]] float at(int r, int c) const {
    return values[static_cast<std::size_t>(r) * columns + c];
  }
};

struct ScanImages {
  Image range;      ///< m: corrected distance with a model, else the raw distance
  Image intensity;  ///< echo amplitude, V
  Image sigma;      ///< m: expected error (NaN without a model)
  Image truth;      ///< m: true range of the beam axis
};

/// Images of a scan. Beams sharing a pixel are averaged over those with an
/// echo. For `line`, each line's samples are resampled onto the wanted
/// columns by weighted averaging (thesis Section 4.7): a sample covering
/// [y - e/2, y + e/2] counts in a column by its overlap with the column.
[[nodiscard]] ScanImages make_images(const ScanResult& result);

/// Distance a beam reports: the model's range if present, else the raw one.
[[nodiscard]] double reported_distance_m(const BeamResult& b);

}  // namespace tofkit::scan
