#pragma once
/// \file The measurement grid of `tofkit measure` (and of the Python
/// package's `measure`): plates over the Cartesian product of distances,
/// reflectances, incidence angles and ambient temperatures, with repeats.
///
/// Order: distance outermost, then reflectance, angle, temperature, repeats
/// innermost. Request i of the plan uses random stream i of
/// VirtualRangefinder::measure_batch, so the same grid and seed give the same
/// numbers whoever builds the plan.

#include <string>
#include <vector>

#include "tofkit/experiments/measurement_grid.hpp"

namespace tofkit::experiments {

/// The physical range each list's values must lie in (tofkit measure's and
/// emulate's options are checked against the same).
struct ValueRange {
  double min, max;
};
inline constexpr ValueRange kDistanceRange_m{1e-3, 1e5};
inline constexpr ValueRange kReflectanceRange{0.0, 1.0};
inline constexpr ValueRange kAngleRange_deg{0.0, 89.9};
inline constexpr ValueRange kTemperatureRange_c{-60.0, 150.0};

struct PlateGrid {
  std::vector<double> distances_m;
  std::vector<double> reflectances;
  std::vector<double> angles_deg = {0.0};
  std::vector<double> ambient_c = {device::Conditions{}.ambient_c};
  int count = 1;  ///< repeated measurements per grid point
  int shots = 0;  ///< shots averaged per measurement (0: the config's measurement.shots)

  /// Rows of the plan (as a double, so a huge product does not overflow).
  [[nodiscard]] double rows() const;
  /// Messages, one per problem, naming the list ("distance_m: 0 is outside
  /// [0.001, 100000]"): empty lists, values outside their physical range,
  /// count < 1, shots < 0, more than `max_rows` rows.
  [[nodiscard]] std::vector<std::string> problems(double max_rows = 1e8) const;
};

/// The plan in grid order (throws std::invalid_argument with problems() joined
/// by newlines when there are any).
[[nodiscard]] std::vector<PlannedMeasurement> plate_grid_plan(const PlateGrid& grid,
                                                              double max_rows = 1e8);

}  // namespace tofkit::experiments
