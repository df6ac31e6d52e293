#include "plate_grid.hpp"

#include <fmt/format.h>

#include <stdexcept>
#include <vector>

#include "tofkit/io/value_list.hpp"

namespace tofkit::app {
namespace {

std::vector<double> checked_list(const std::string& text, const char* option,
                                 experiments::ValueRange range) {
  std::vector<double> values = io::parse_value_list(text, option);
  for (const double v : values) {
    if (!(v >= range.min && v <= range.max)) {
      throw std::invalid_argument(
          fmt::format("{}: {} is outside [{}, {}]", option, v, range.min, range.max));
    }
  }
  return values;
}

}  // namespace

experiments::PlateGrid parse_plate_grid(const std::string& distances,
                                        const std::string& reflectances, const std::string& angles,
                                        const std::string& temperatures) {
  experiments::PlateGrid g;
  g.distances_m = checked_list(distances, "--distance", experiments::kDistanceRange_m);
  g.reflectances = checked_list(reflectances, "--reflectance", experiments::kReflectanceRange);
  g.angles_deg = checked_list(angles, "--angle", experiments::kAngleRange_deg);
  g.ambient_c = checked_list(temperatures, "--temperature", experiments::kTemperatureRange_c);
  return g;
}

}  // namespace tofkit::app
