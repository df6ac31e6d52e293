#pragma once
/// \file Environmental temperature (thesis Section 4.4): the range decreases as
/// the temperature rises, 0.25-0.60 in per 10 C in the mean. Swept at several
/// distances, the drift is a delay of the electronics, so its slope (mm/C) is
/// the same at every distance.

#include <cstdint>
#include <string>
#include <vector>

#include "tofkit/device/virtual_rangefinder.hpp"
#include "tofkit/experiments/characterization_common.hpp"
#include "tofkit/experiments/thesis_grey_chart.hpp"

namespace tofkit::experiments {

struct TemperatureOptions {
  std::vector<double> distances_m{inches_to_m(15), inches_to_m(17), inches_to_m(20),
                                  inches_to_m(22)};           ///< the thesis's training distances
  std::vector<double> ambient_c{10, 15, 20, 25, 30, 35, 40};  ///< Assumption: climate chamber
  double reflectance = grey_reflectance(102);                 ///< Assumption: a mid-grey target
  int samples_per_point = 50;
  int shots = 0;  ///< per sample; 0: the device's
  /// Throws std::invalid_argument naming the bad field.
  void validate() const;
};

struct TemperaturePoint {
  double distance_m = 0;
  double ambient_c = 0;
  double mean_range_m = ranging::kNaN;
  double sd_range_m = ranging::kNaN;
  double mean_sensor_c = ranging::kNaN;  ///< the unit's own temperature reading
  std::size_t samples = 0;
};

struct TemperatureSlope {
  double distance_m = 0;
  double slope_mm_per_c = ranging::kNaN;  ///< d(range)/d(ambient), least squares over all samples
  double slope_se_mm_per_c = ranging::kNaN;
  [[nodiscard]] double inches_per_10c() const { return slope_mm_per_c * 10.0 / 25.4; }
};

struct TemperatureResult {
  TemperatureOptions options;
  std::vector<ranging::Record> records;  ///< distance outermost, then temperature, then samples
  std::vector<TemperaturePoint> points;
  std::vector<TemperatureSlope> slopes;  ///< one per distance
  double mean_slope_mm_per_c = ranging::kNaN;
  double slope_spread_mm_per_c = ranging::kNaN;  ///< max - min over distances
  double slope_spread_se = ranging::kNaN;        ///< the spread in standard errors of a difference
  [[nodiscard]] std::vector<Finding> findings() const;
  [[nodiscard]] ResultTable table() const;
  [[nodiscard]] std::string summary() const;
};

/// Warmed-up device, laser settled; each point at its ambient temperature.
[[nodiscard]] TemperatureResult run_temperature(const device::VirtualRangefinder& device,
                                                const TemperatureOptions& options,
                                                std::uint64_t seed);

}  // namespace tofkit::experiments
