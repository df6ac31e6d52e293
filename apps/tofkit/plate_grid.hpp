#pragma once
/// \file The plates `tofkit measure` and `tofkit emulate --distance` measure:
/// the Cartesian product of four LIST options, parsed and range-checked in one
/// place, in one order, so both commands see the same requests.

#include <string>
#include <vector>

namespace tofkit::app {

/// One plate and the ambient temperature it is measured at.
struct PlatePoint {
  double distance_m, reflectance, angle_deg, ambient_c;
};

struct PlateGrid {
  std::vector<double> distances_m, reflectances, angles_deg, ambients_c;

  /// Number of points, as a double (the product may not fit an integer).
  [[nodiscard]] double size() const;
  /// Distance outermost, then reflectance, angle, temperature.
  [[nodiscard]] std::vector<PlatePoint> points() const;
};

/// --distance in [0.001, 100000] m, --reflectance in [0, 1], --angle in
/// [0, 89.9] degrees, --temperature in [-60, 150] C. Throws
/// std::invalid_argument naming the option and the value.
[[nodiscard]] PlateGrid parse_plate_grid(const std::string& distances,
                                         const std::string& reflectances, const std::string& angles,
                                         const std::string& temperatures);

}  // namespace tofkit::app
