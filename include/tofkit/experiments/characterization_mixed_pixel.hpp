#pragma once
/// \file Mixed pixels (thesis Section 4.4): the ~3 mm beam footprint stepped
/// across a step edge in 0.5 mm steps, 500 samples per step. Where the footprint
/// straddles the edge both surfaces return echoes that add in the receiver, and
/// the range passes through values between the two surfaces.

#include <cstdint>
#include <string>
#include <vector>

#include "tofkit/device/virtual_rangefinder.hpp"
#include "tofkit/experiments/characterization_common.hpp"
#include "tofkit/experiments/thesis_grey_chart.hpp"

namespace tofkit::experiments {

/// Share of a uniform disk footprint of diameter D, centred at signed offset x
/// from a straight edge, that lies on the edge's negative side (x < 0: the
/// centre is on that side): circular segment area / (pi D^2 / 4), 1 at x <= -D/2,
/// 1/2 at x = 0, 0 at x >= D/2.
[[nodiscard]] double disk_fraction_beyond_edge(double centre_offset_m, double footprint_diameter_m);

struct MixedPixelOptions {
  double near_distance_m = inches_to_m(19.0);       ///< the step's top surface
  double step_height_m = inches_to_m(1.0);          ///< far surface = near + step. Assumption
  double near_reflectance = grey_reflectance(102);  ///< Assumption: same mid-grey finish
  double far_reflectance = grey_reflectance(102);
  double scan_half_width_mm = 4.0;  ///< beam centre from -4 mm (on near) to +4 mm (on far)
  double step_mm = 0.5;             ///< thesis: 0.5 mm steps
  int samples_per_step = 500;       ///< thesis: 500 samples per step
  int shots = 0;                    ///< per sample; 0: the device's
  double ambient_c = 20.0;
  /// Throws std::invalid_argument naming the bad field.
  void validate() const;
};

struct MixedPixelStep {
  double beam_offset_mm = 0;  ///< beam centre from the edge; < 0 on the near surface
  double near_fraction = 0;   ///< share of the footprint on the near surface
  double mean_range_m = ranging::kNaN;
  double sd_range_m = ranging::kNaN;
  double mean_amplitude = ranging::kNaN;
  std::size_t samples = 0;
};

struct MixedPixelResult {
  MixedPixelOptions options;
  double footprint_diameter_m = 0;       ///< at the near surface
  std::vector<ranging::Record> records;  ///< truth: the near surface's distance and finish
  std::vector<MixedPixelStep> steps;
  double near_range_m = ranging::kNaN;  ///< mean at the first step (fully on near)
  double far_range_m = ranging::kNaN;   ///< mean at the last step (fully on far)
  int intermediate_steps = 0;  ///< steps whose mean lies between, 5 sd of a mean from each end
  double monotonicity_violation_mm = 0;  ///< largest rise of the mean against the expected trend
  double transition_width_mm = ranging::kNaN;  ///< beam travel from 10 % to 90 % of the jump
  [[nodiscard]] std::vector<Finding> findings() const;
  [[nodiscard]] ResultTable table() const;
  [[nodiscard]] std::string summary() const;
};

[[nodiscard]] MixedPixelResult run_mixed_pixel(const device::VirtualRangefinder& device,
                                               const MixedPixelOptions& options,
                                               std::uint64_t seed);

}  // namespace tofkit::experiments
