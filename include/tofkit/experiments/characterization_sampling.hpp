#pragma once
/// \file Sampling rate versus resolution (thesis Fig. 4.4,
/// reference/fig4_4_sampling.csv): the unit averages 2^N shots per output, so
/// the sampling rate is 312,500 / 2^N samples/s; on a pulsed device the spread of
/// the outputs falls with averaging, as 1 / sqrt(2^N) for independent shots; on the
/// self-oscillating loop (oscillator.enabled) the count's resolution halves with
/// each halving of the rate until a slow wander of the loop delay is the floor.

#include <cstdint>
#include <string>
#include <vector>

#include "tofkit/device/virtual_rangefinder.hpp"
#include "tofkit/experiments/characterization_common.hpp"
#include "tofkit/experiments/thesis_grey_chart.hpp"

namespace tofkit::experiments {

struct SamplingOptions {
  double distance_m = inches_to_m(20.0);      ///< thesis Fig. 4.4: 20 in
  double reflectance = grey_reflectance(51);  ///< Assumption: a light grey target (0 = white)
  double ambient_c = 20.0;
  int min_exponent = 3;   ///< 2^3 = 8 shots: 39,062.5 samples/s (first row of Fig. 4.4)
  int max_exponent = 11;  ///< 2^11 = 2048 shots: 152.6 samples/s (last row)
  int samples_per_setting = 200;
  /// Throws std::invalid_argument naming the bad field.
  void validate() const;
};

struct SamplingRow {
  int exponent = 0;  ///< N: 2^N shots per output
  int shots = 0;
  double sampling_rate_hz = 0;  ///< repetition rate / 2^N
  double mean_range_m = ranging::kNaN;
  double sd_range_m = ranging::kNaN;             ///< spread of the outputs (resolution)
  double rms_error_m = ranging::kNaN;            ///< about the true distance
  double sd_times_sqrt_shots_m = ranging::kNaN;  ///< constant if sd ~ 1/sqrt(2^N)
  /// Range step of one count of the interface board's clock (thesis Fig. 4.4's
  /// resolution column); NaN on a pulsed device (its TDC LSB does not depend on N).
  double resolution_m = ranging::kNaN;
};

struct SamplingResult {
  SamplingOptions options;
  std::vector<ranging::Record> records;  ///< grouped by setting, ascending N
  std::vector<SamplingRow> rows;
  double log_slope = ranging::kNaN;  ///< d ln(sd) / d ln(shots); -0.5 for independent shots
  double max_scaling_deviation = ranging::kNaN;  ///< max |sd sqrt(n) / median - 1| over settings
  [[nodiscard]] std::vector<Finding> findings() const;
  [[nodiscard]] ResultTable table() const;
  [[nodiscard]] std::string summary() const;
};

[[nodiscard]] SamplingResult run_sampling(const device::VirtualRangefinder& device,
                                          const SamplingOptions& options, std::uint64_t seed);

}  // namespace tofkit::experiments
