#pragma once
/// \file Scan patterns: the beams a scanner fires, in time order, each with
/// its image row and column, time stamp, origin and direction in the sensor
/// frame (REP-103: +x forward, +y left, z up). Image row 0 is the top (largest
/// z or elevation), column 0 the left (largest y or azimuth). Time stamps
/// follow from the stage speed, the device's output period and mirror rates.

#include <cstddef>
#include <functional>
#include <span>
#include <string>
#include <vector>

#include "tofkit/scan/scene.hpp"

namespace tofkit::scan {

struct Beam {
  int row = 0;
  int column = 0;           ///< image column; for `line`, the sample index within its line
  double time_s = 0;        ///< time of the measurement's start since the scan's start
  double position_m = 0;    ///< `line`: stage position along the line (y); else 0
  Vec3 origin_m{0, 0, 0};   ///< sensor frame
  Vec3 direction{1, 0, 0};  ///< unit, sensor frame
};

struct BeamPattern {
  std::string name;  ///< raster, line, mirror, spherical, spinning
  int rows = 0;
  int columns = 0;           ///< image columns (`line`: the resampled width)
  int shots_multiplier = 1;  ///< raster: samples averaged per point
  std::vector<Beam> beams;   ///< in time order, per line
  /// `line`: image column centres along y (column 0 first) and the stretch of
  /// the line one measurement integrates (stage speed x output period).
  std::vector<double> column_positions_m;
  double sample_extent_m = 0;
  /// A pattern made on demand (mirror, spherical, spinning from make_pattern
  /// with on_demand): `beams` stays empty and make_beams(first, out) makes
  /// beams first .. first + out.size() (the same values as the stored form),
  /// so a scan of 10^8 beams does not hold them; `beam_count` counts them.
  std::function<void(std::size_t first, std::span<Beam> out)> make_beams;
  std::size_t beam_count = 0;

  /// Number of beams, stored or on demand.
  [[nodiscard]] std::size_t size() const { return make_beams ? beam_count : beams.size(); }
  /// Beams first .. first + out.size() into `out` (copied or made).
  void get(std::size_t first, std::span<Beam> out) const;
};

/// Every builder refuses a pattern of more than `max_beams` beams before it
/// allocates them (std::length_error naming the count): a typed step of
/// 0.0001 degrees asks for tens of gigabytes.
inline constexpr std::size_t kMaxPatternBeams = 100'000'000;

/// XY stage, point by point: the sensor at every (y, z) looks along +x;
/// serpentine rows; `samples` measurements averaged per point. The stage
/// moves between points at `stage_speed_m_per_s`.
struct RasterOptions {
  std::vector<double> y_m, z_m;
  int samples = 1;
  double stage_speed_m_per_s = 0.05;
};
[[nodiscard]] BeamPattern raster_pattern(const RasterOptions& o, double measurement_period_s,
                                         std::size_t max_beams = kMaxPatternBeams);

/// XY stage moving along y at constant speed while the device measures at its
/// own rate (thesis Section 4.7): the number of samples per line varies with
/// the phase of the device's clock at the line start; `y_m` gives the wanted
/// image columns, `z_m` the lines; serpentine; `turnaround_s` between lines.
struct LineOptions {
  std::vector<double> y_m, z_m;
  double stage_speed_m_per_s = 0.05;
  double turnaround_s = 0.5;
};
[[nodiscard]] BeamPattern line_pattern(const LineOptions& o, double measurement_period_s,
                                       std::size_t max_beams = kMaxPatternBeams);

/// A rotating 45-degree mirror: one vertical profile (x-z plane, the listed
/// elevations) per revolution; the mirror may ride a stage along y.
struct MirrorOptions {
  std::vector<double> elevation_deg;
  int revolutions = 1;
  double revolutions_per_s = 10;
  double stage_speed_m_per_s = 0;
};
[[nodiscard]] BeamPattern mirror_pattern(const MirrorOptions& o,
                                         std::size_t max_beams = kMaxPatternBeams);

/// The mirror on a rotary table: one elevation profile per revolution, the
/// table stepping through the azimuths (rows: elevation, columns: azimuth).
struct SphericalOptions {
  std::vector<double> azimuth_deg, elevation_deg;
  double revolutions_per_s = 10;
};
[[nodiscard]] BeamPattern spherical_pattern(const SphericalOptions& o,
                                            std::size_t max_beams = kMaxPatternBeams);

/// A multi-beam spinning lidar (Velodyne/Ouster-like): the listed elevations
/// fire together every `azimuth_step_deg` while the head spins at `rotation_hz`.
struct SpinningOptions {
  std::vector<double> elevation_deg;
  double azimuth_step_deg = 0.2;
  double rotation_hz = 10;
  int revolutions = 1;
};
[[nodiscard]] BeamPattern spinning_pattern(const SpinningOptions& o,
                                           std::size_t max_beams = kMaxPatternBeams);

/// A pattern's scalar settings by `tofkit scan`'s names, with its defaults;
/// each pattern reads the ones it has.
struct PatternSettings {
  int samples = 1;                ///< raster: measurements averaged per point
  int revolutions = 1;            ///< mirror, spinning
  double speed_m_per_s = 0.05;    ///< raster, line, mirror: stage speed
  double turnaround_s = 0.5;      ///< line: time between lines
  double rate_hz = 10;            ///< mirror, spherical: revolutions per s; spinning: rotation
  double azimuth_step_deg = 0.2;  ///< spinning: azimuth between firings
};

/// The lists a pattern may need, in this order (a caller can index its own
/// four fields by them), and their names: "y", "z", "azimuth", "elevation".
enum class PatternListName { y, z, azimuth, elevation };
[[nodiscard]] const char* pattern_list_name(PatternListName list);

/// The list a pattern needs: the caller parses its own option (and names it
/// in its errors).
using PatternList = std::function<std::vector<double>(PatternListName list)>;

/// The pattern called `name` (raster | line | mirror | spherical | spinning),
/// asking `list` for the lists it needs, for a device with output period
/// `measurement_period_s`. The one dispatch `tofkit scan`, `emulate --scene` and
/// Python's tofkit.scan share; throws std::invalid_argument for another name.
/// With `on_demand`, mirror, spherical and spinning patterns make their
/// beams when asked (BeamPattern::make_beams); raster and line are stored.
[[nodiscard]] BeamPattern make_pattern(const std::string& name, const PatternSettings& settings,
                                       const PatternList& list, double measurement_period_s,
                                       std::size_t max_beams = kMaxPatternBeams,
                                       bool on_demand = false);

/// Direction of azimuth a (about z, from +x towards +y) and elevation e.
[[nodiscard]] Vec3 direction_from_angles(double azimuth_deg, double elevation_deg);

}  // namespace tofkit::scan
