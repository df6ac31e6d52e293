#pragma once
/// \file Running a scan: every beam of a pattern is traced through the scene
/// (footprint -> device::Target) and measured by the virtual rangefinder.
/// Beam i uses random stream i, so results do not depend on the thread count.

#include <cstdint>
#include <functional>
#include <memory>
#include <span>
#include <vector>

#include "tofkit/device/virtual_rangefinder.hpp"
#include "tofkit/ranging/pipeline.hpp"
#include "tofkit/ranging/raw_measurement.hpp"
#include "tofkit/ranging/uncertainty_budget.hpp"
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

/// Blocks of beams as a streaming scan hands them out: the index of the
/// block's first beam in the pattern and its results (mutable: a sink may
/// correct them in place, apply_pipeline's batch on a block).
using BeamBlockSink = std::function<void(std::size_t first_beam, std::span<BeamResult> beams)>;

/// The streaming scan: beams [first, last) of `pattern`, made and measured in
/// blocks of at most `block_beams`, each handed to `sink` in beam order from
/// the calling thread while the next block is measured. Memory: two blocks
/// (a block's results are reused). The beams' values are those run_scan gives
/// them (beam i on random stream i): any range, any block size, any threads.
void run_scan_blocks(const RayCaster& caster, const Footprint& footprint,
                     const device::VirtualRangefinder& device, const BeamPattern& pattern,
                     const ScanOptions& options, std::size_t first, std::size_t last,
                     std::size_t block_beams, const BeamBlockSink& sink);

/// A ScanResult without beams: the pattern's description and the sensor pose
/// (what a streaming scan's writers need before the first block).
[[nodiscard]] ScanResult describe_scan(const BeamPattern& pattern, const Scene& scene);

/// Corrects the raw measurements of `beams` with `pipeline` into their `range`
/// (one batch). With a non-empty `budget`, sigma_m is its combined standard
/// uncertainty for a row on another power-on than the calibration's
/// (ranging::apply_budget, time since calibration unknown): a scan is a run of
/// its own power-on (its seed).
void apply_pipeline(const ranging::Pipeline& pipeline, std::span<BeamResult> beams,
                    const ranging::UncertaintyBudget* budget = nullptr);

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

/// Images built row by row as a streaming scan's blocks arrive (what
/// make_images computes, the same values): add() takes blocks in beam order;
/// a row is finished once the last beam that falls in it has been added, and
/// take_finished_rows() hands out the finished rows in row order. Held: the
/// rows begun and not finished (for a row-major pattern a row or two; for
/// `spherical`, whose beams go down columns, every row until the end).
class ImageBuilder {
 public:
  /// One finished row: its index and its values per plane (NaN: no echo).
  struct Row {
    int row = 0;
    std::span<const float> range, intensity, sigma, truth;
  };
  /// `description`: the pattern's name, size and line columns (its beams may
  /// be empty); `row_last_beam`: per row, the index of the last beam in it
  /// (row_last_beams gives them).
  ImageBuilder(const BeamPattern& description, std::vector<std::size_t> row_last_beam);
  ~ImageBuilder();
  ImageBuilder(const ImageBuilder&) = delete;
  ImageBuilder& operator=(const ImageBuilder&) = delete;

  /// Adds beams `first_beam` .. `first_beam + beams.size()` (in order, no gap).
  void add(std::size_t first_beam, std::span<const BeamResult> beams);
  /// Calls `take` for every finished row not yet handed out, in row order.
  void take_finished_rows(const std::function<void(const Row&)>& take);
  /// Beams added so far plus the first one (where the next block starts).
  [[nodiscard]] std::size_t next_beam() const { return next_beam_; }

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
  std::size_t next_beam_ = 0;
};

/// Per image row, the index of the pattern's last beam in it (a row without
/// beams: 0, finished from the start).
[[nodiscard]] std::vector<std::size_t> row_last_beams(const BeamPattern& pattern);

/// Distance a beam reports: the model's range if present, else the raw one.
[[nodiscard]] double reported_distance_m(const BeamResult& b);

}  // namespace tofkit::scan
