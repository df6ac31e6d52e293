#pragma once
/// \file Cold-start warm-up (thesis Section 4.4, "cold start"): from power-on,
/// 500 samples each minute for 2 h at a fixed distance (19 in). The mean range
/// per minute drifts while the electronics warm, then settles; the thesis saw
/// 25-35 min before the range was stable.

#include <cstdint>
#include <string>
#include <vector>

#include "tofkit/device/virtual_rangefinder.hpp"
#include "tofkit/experiments/characterization_common.hpp"
#include "tofkit/experiments/thesis_grey_chart.hpp"

namespace tofkit::experiments {

struct WarmupOptions {
  double distance_m = inches_to_m(19.0);      ///< thesis: 19 in
  double reflectance = grey_reflectance(51);  ///< Assumption: a light grey target (0 = white)
  double ambient_c = 20.0;                    ///< laboratory
  int duration_min = 120;                     ///< thesis: 2 h
  int samples_per_minute = 500;               ///< thesis: 500 samples each minute
  int shots = 0;                              ///< per sample; 0: the device's
  int final_window_min = 30;   ///< the settled value is the mean of the last 30 minutes
  double tolerance_mm = 0.25;  ///< settled once every later minute mean stays this close
                               ///< (0.01 in, the thesis's reporting resolution)
  int smoothing_min = 5;       ///< the minute means are judged through a centred running mean of
                          ///< this many minutes (the thesis read the drift off a plotted curve)
  /// Throws std::invalid_argument naming the bad field.
  void validate() const;
};

/// One minute's samples.
struct WarmupMinute {
  int minute = 0;  ///< since power-on (samples spread over the minute)
  double mean_range_m = ranging::kNaN;
  double sd_range_m = ranging::kNaN;          ///< spread of single samples
  double mean_temperature_c = ranging::kNaN;  ///< the unit's sensor
  std::size_t samples = 0;                    ///< with an echo
};

struct WarmupResult {
  WarmupOptions options;
  std::vector<ranging::Record> records;  ///< every sample, in time order
  std::vector<WarmupMinute> minutes;
  double final_range_m = ranging::kNaN;        ///< mean over the final window
  double total_drift_mm = ranging::kNaN;       ///< final minus first minute (> 0: range inflates)
  double settle_time_min = ranging::kNaN;      ///< end of the last minute outside the tolerance
  double settle_time_fit_min = ranging::kNaN;  ///< where the fitted exponential meets the
                                               ///< tolerance (less noisy than settle_time_min)
  double time_constant_min = ranging::kNaN;    ///< exponential fit of |mean - final|
  [[nodiscard]] std::vector<Finding> findings() const;
  [[nodiscard]] ResultTable table() const;
  [[nodiscard]] std::string summary() const;
};

/// Samples are spread evenly over each minute; the laser is switched on at
/// power-on and stays on (Conditions: minutes_since_power_on, ms_since_laser_on).
[[nodiscard]] WarmupResult run_warmup(const device::VirtualRangefinder& device,
                                      const WarmupOptions& options, std::uint64_t seed);

}  // namespace tofkit::experiments
