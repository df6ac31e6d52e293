#pragma once
/// \file Pieces shared by the characterization protocols (thesis Chapter 4):
/// running a batch of requests into records with ground truth, sample
/// statistics, straight-line fits, and the named numbers and tables a protocol
/// returns for summaries, JSON and plots.

#include <cstddef>
#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "tofkit/device/virtual_rangefinder.hpp"
#include "tofkit/experiments/measurement_grid.hpp"
#include "tofkit/ranging/raw_measurement.hpp"

namespace tofkit::experiments {

/// One number a protocol finds (what the thesis reports), with its unit.
struct Finding {
  std::string name;  ///< snake_case, e.g. "settle_time_min"
  double value = ranging::kNaN;
  std::string unit;  ///< "min", "mm", "mm/C", "" (ratio), ...
};

/// A protocol's table (one row per step, setting, group ...), for plots and JSON.
struct ResultTable {
  std::string name;
  std::vector<std::string> columns;
  std::vector<std::vector<double>> rows;  ///< each as long as `columns`
};

/// Mean and standard deviation (n - 1) of the finite values.
struct SampleStats {
  std::size_t count = 0;
  double mean = ranging::kNaN;
  double sd = ranging::kNaN;  ///< NaN with fewer than two values
  [[nodiscard]] double standard_error() const;
};
[[nodiscard]] SampleStats sample_stats(std::span<const double> values);

/// Ordinary least-squares line y = slope x + intercept over the finite pairs.
struct LineFit {
  std::size_t rows = 0;
  double slope = ranging::kNaN;
  double intercept = ranging::kNaN;
  double slope_se = ranging::kNaN;  ///< standard error of the slope
  double residual_sd = ranging::kNaN;
};
/// Throws std::invalid_argument when x and y differ in length.
[[nodiscard]] LineFit fit_line(std::span<const double> x, std::span<const double> y);

/// First-order settling of a drift towards its final value: ln|offset| falls
/// linearly in time with slope -1/tau. Fitted over the points still well above
/// the tolerance (more than twice it), where the noise does not bend the line.
struct ExponentialSettling {
  double time_constant = ranging::kNaN;      ///< tau, in the unit of `time`
  double time_to_tolerance = ranging::kNaN;  ///< where the fitted offset falls to the tolerance
};
[[nodiscard]] ExponentialSettling fit_exponential_settling(std::span<const double> time,
                                                           std::span<const double> offset_mm,
                                                           double tolerance_mm);

/// Shots per output: `shots`, or the device's measurement.shots when 0.
[[nodiscard]] int resolve_shots(const device::VirtualRangefinder& device, int shots);

/// Output rate of N-shot averaging: repetition rate / N (thesis: 312,500 / 2^N).
[[nodiscard]] double output_rate_hz(const device::VirtualRangefinder& device, int shots);

/// An independent seed for a sub-scan (SplitMix64 of seed and salt), so that
/// scans of one protocol never share random streams.
[[nodiscard]] std::uint64_t derive_seed(std::uint64_t seed, std::uint64_t salt);

/// distance_raw_m - truth.distance_m of each record (NaN without an echo).
[[nodiscard]] std::vector<double> range_errors_m(std::span<const ranging::Record> records);

/// "name = value unit" lines.
[[nodiscard]] std::string findings_text(std::span<const Finding> findings);

}  // namespace tofkit::experiments
