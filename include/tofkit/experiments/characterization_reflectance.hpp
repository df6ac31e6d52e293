#pragma once
/// \file Reflectance x distance (thesis Section 4.4): six matte grey levels
/// (0, 51, ..., 255) at 10-30 in. The mean range is linear in the true range
/// (thesis: r = 0.9804 T - 0.6732 in); dark targets read long (their weak
/// echoes cross the threshold late: walk), very bright ones saturate and read
/// short. Thesis RMS at 20 in: 0.2281 in for grey >= 102 (its numbering, 0 =
/// white: the four darker greys, below saturation), 1.0693 in over all. The
/// RMS is about the truth, as the thesis's other RMS figures: Fig. 4.4's rms
/// column is |20 in - mean| (with the variance), Fig. 4.18's raw rms is
/// sqrt(bias^2 + variance).

#include <cstdint>
#include <string>
#include <vector>

#include "tofkit/device/virtual_rangefinder.hpp"
#include "tofkit/experiments/characterization_common.hpp"
#include "tofkit/experiments/thesis_grey_chart.hpp"

namespace tofkit::experiments {

struct ReflectanceOptions {
  std::vector<int> grey_levels{kThesisGreyLevels.begin(), kThesisGreyLevels.end()};
  std::vector<double> distances_m{};  ///< empty: 10, 12, ..., 30 in (thesis: 10-30 in)
  int samples_per_point = 20;
  int shots = 0;  ///< per sample; 0: the device's
  double ambient_c = 20.0;
  double rms_distance_m = inches_to_m(20.0);  ///< where the RMS per grey group is reported
  int unsaturated_grey_min = 102;             ///< thesis: "grey >= 102" (0 = white)
  /// Throws std::invalid_argument naming the bad field.
  void validate() const;
  /// The distances used (the default grid when distances_m is empty).
  [[nodiscard]] std::vector<double> distances() const;
};

struct ReflectancePoint {
  int grey = 0;
  double reflectance = 0;
  double distance_m = 0;
  double mean_error_m = ranging::kNaN;  ///< measured - true (> 0: reads long)
  double sd_m = ranging::kNaN;
  double mean_amplitude = ranging::kNaN;
  double echo_share = 0;       ///< samples with an echo
  double saturated_share = 0;  ///< samples flagged saturated
};

struct ReflectanceResult {
  ReflectanceOptions options;
  std::vector<ranging::Record> records;  ///< grey outermost, then distance, then samples
  std::vector<ReflectancePoint> points;
  LineFit line;  ///< measured vs true range over every sample with an echo (metres)
  double rms_all_m = ranging::kNaN;          ///< at rms_distance_m, about the truth, all greys
  double rms_unsaturated_m = ranging::kNaN;  ///< same, grey >= unsaturated_grey_min
  double darkest_error_m = ranging::kNaN;    ///< mean error of the darkest grey at rms distance
  double brightest_error_m = ranging::kNaN;  ///< of the brightest
  [[nodiscard]] std::vector<Finding> findings() const;
  [[nodiscard]] ResultTable table() const;
  [[nodiscard]] std::string summary() const;
};

[[nodiscard]] ReflectanceResult run_reflectance(const device::VirtualRangefinder& device,
                                                const ReflectanceOptions& options,
                                                std::uint64_t seed);

}  // namespace tofkit::experiments
