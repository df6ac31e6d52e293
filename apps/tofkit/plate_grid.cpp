#include "plate_grid.hpp"

#include <fmt/format.h>

#include <stdexcept>

#include "tofkit/io/value_list.hpp"

namespace tofkit::app {
namespace {

std::vector<double> checked_list(const std::string& text, const char* option, double min,
                                 double max) {
  std::vector<double> values = io::parse_value_list(text, option);
  for (const double v : values) {
    if (!(v >= min && v <= max)) {
      throw std::invalid_argument(fmt::format("{}: {} is outside [{}, {}]", option, v, min, max));
    }
  }
  return values;
}

}  // namespace

double PlateGrid::size() const {
  double n = 1;
  for (const auto* list : {&distances_m, &reflectances, &angles_deg, &ambients_c}) {
    n *= static_cast<double>(list->size());
  }
  return n;
}

std::vector<PlatePoint> PlateGrid::points() const {
  std::vector<PlatePoint> out;
  out.reserve(static_cast<std::size_t>(size()));
  for (const double d : distances_m) {
    for (const double rho : reflectances) {
      for (const double angle : angles_deg) {
        for (const double t : ambients_c) out.push_back({d, rho, angle, t});
      }
    }
  }
  return out;
}

PlateGrid parse_plate_grid(const std::string& distances, const std::string& reflectances,
                           const std::string& angles, const std::string& temperatures) {
  PlateGrid g;
  g.distances_m = checked_list(distances, "--distance", 1e-3, 1e5);
  g.reflectances = checked_list(reflectances, "--reflectance", 0.0, 1.0);
  g.angles_deg = checked_list(angles, "--angle", 0.0, 89.9);
  g.ambients_c = checked_list(temperatures, "--temperature", -60.0, 150.0);
  return g;
}

}  // namespace tofkit::app
