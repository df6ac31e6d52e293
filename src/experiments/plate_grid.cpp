#include "tofkit/experiments/plate_grid.hpp"

#include <sstream>
#include <stdexcept>

namespace tofkit::experiments {
namespace {

std::string number(double v, int precision = 15) {
  std::ostringstream out;
  out.precision(precision);
  out << v;
  return out.str();
}

void check_all(const std::vector<double>& values, const char* name, ValueRange range,
               std::vector<std::string>& problems) {
  if (values.empty()) problems.push_back(std::string(name) + ": no values");
  for (const double v : values) {
    if (!(v >= range.min && v <= range.max)) {
      problems.push_back(std::string(name) + ": " + number(v) + " is outside [" +
                         number(range.min) + ", " + number(range.max) + "]");
      return;  // one message per list
    }
  }
}

}  // namespace

double PlateGrid::rows() const {
  double n = static_cast<double>(count);
  for (const auto* list : {&distances_m, &reflectances, &angles_deg, &ambient_c}) {
    n *= static_cast<double>(list->size());
  }
  return n;
}

std::vector<std::string> PlateGrid::problems(double max_rows) const {
  std::vector<std::string> out;
  // Physical ranges: the same as tofkit measure's options.
  check_all(distances_m, "distance_m", kDistanceRange_m, out);
  check_all(reflectances, "reflectance", kReflectanceRange, out);
  check_all(angles_deg, "angle_deg", kAngleRange_deg, out);
  check_all(ambient_c, "temperature_c", kTemperatureRange_c, out);
  if (count < 1) out.push_back("count: " + std::to_string(count) + " is below 1");
  if (shots < 0) out.push_back("shots: " + std::to_string(shots) + " is below 0");
  if (out.empty() && rows() > max_rows) {
    out.push_back("the grid has " + number(rows(), 6) + " rows, more than " + number(max_rows, 6));
  }
  return out;
}

std::vector<PlannedMeasurement> plate_grid_plan(const PlateGrid& grid, double max_rows) {
  const auto problems = grid.problems(max_rows);
  if (!problems.empty()) {
    std::string message;
    for (const auto& p : problems) message += (message.empty() ? "" : "\n") + p;
    throw std::invalid_argument(message);
  }
  std::vector<PlannedMeasurement> plan;
  plan.reserve(static_cast<std::size_t>(grid.rows()));
  for (const double d : grid.distances_m) {
    for (const double rho : grid.reflectances) {
      for (const double angle : grid.angles_deg) {
        for (const double t : grid.ambient_c) {
          for (int k = 0; k < grid.count; ++k) plan.push_back(plate(d, rho, t, angle, grid.shots));
        }
      }
    }
  }
  return plan;
}

}  // namespace tofkit::experiments
