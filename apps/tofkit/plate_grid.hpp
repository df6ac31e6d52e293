#pragma once
/// \file The plates `tofkit measure` and `tofkit emulate --distance` measure:
/// the Cartesian product of four LIST options, parsed and range-checked in one
/// place into experiments::PlateGrid, so both commands (and the Python
/// package) see the same plan.

#include <string>

#include "tofkit/experiments/plate_grid.hpp"

namespace tofkit::app {

/// --distance, --reflectance, --angle and --temperature within the ranges of
/// experiments::PlateGrid's lists. Throws std::invalid_argument naming the
/// option and the value. The grid's count and shots are left at 1 and 0.
[[nodiscard]] experiments::PlateGrid parse_plate_grid(const std::string& distances,
                                                      const std::string& reflectances,
                                                      const std::string& angles,
                                                      const std::string& temperatures);

}  // namespace tofkit::app
