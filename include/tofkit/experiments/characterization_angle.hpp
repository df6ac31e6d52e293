#pragma once
/// \file Incidence angle (thesis Section 4.4): the grey chart tilted against the
/// beam. The echo weakens as cos(angle) (Lambertian) and spreads over the
/// footprint's depth, so the error grows with angle, roughly linearly below
/// about 60 deg for the lighter greys (thesis numbering: 0 = white ... 255 =
/// black); the thesis names greys 0 and 51 unusable at large angles.

#include <cstdint>
#include <string>
#include <vector>

#include "tofkit/device/virtual_rangefinder.hpp"
#include "tofkit/experiments/characterization_common.hpp"
#include "tofkit/experiments/thesis_grey_chart.hpp"

namespace tofkit::experiments {

struct AngleOptions {
  std::vector<int> grey_levels{kThesisGreyLevels.begin(), kThesisGreyLevels.end()};
  std::vector<double> angles_deg{0, 10, 20, 30, 40, 50, 60, 70, 80};
  double distance_m = inches_to_m(19.0);  ///< Assumption: the test distance
  int samples_per_point = 20;
  int shots = 0;  ///< per sample; 0: the device's
  double ambient_c = 20.0;
  double reference_angle_deg = 60.0;  ///< error growth is reported up to here
  /// Throws std::invalid_argument naming the bad field.
  void validate() const;
};

struct AnglePoint {
  int grey = 0;
  double angle_deg = 0;
  double mean_error_m = ranging::kNaN;  ///< measured - true (along the beam axis)
  double sd_m = ranging::kNaN;
  double mean_amplitude = ranging::kNaN;
  double echo_share = 0;
};

/// Per grey level: how the error grows with angle.
struct AngleGrowth {
  int grey = 0;
  double growth_at_reference_m = ranging::kNaN;  ///< error(reference angle) - error(0)
  double slope_mm_per_deg = ranging::kNaN;       ///< line fit of the error, 0..reference angle
  double max_usable_angle_deg = ranging::kNaN;   ///< largest angle with echoes on all samples
};

struct AngleResult {
  AngleOptions options;
  std::vector<ranging::Record> records;  ///< grey outermost, then angle, then samples
  std::vector<AnglePoint> points;
  std::vector<AngleGrowth> growth;  ///< one per grey level, in option order
  [[nodiscard]] std::vector<Finding> findings() const;
  [[nodiscard]] ResultTable table() const;
  [[nodiscard]] std::string summary() const;
};

[[nodiscard]] AngleResult run_angle(const device::VirtualRangefinder& device,
                                    const AngleOptions& options, std::uint64_t seed);

}  // namespace tofkit::experiments
