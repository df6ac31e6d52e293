#pragma once
/// \file Laser turn-on transient (thesis Section 4.4): the first samples after
/// the laser diode is switched on are wrong, then the range reaches a plateau;
/// the transient is to be discarded. Consecutive N-shot samples from switch-on
/// (Conditions::ms_since_laser_on), grouped into blocks of a few milliseconds.

#include <cstdint>
#include <string>
#include <vector>

#include "tofkit/device/virtual_rangefinder.hpp"
#include "tofkit/experiments/characterization_common.hpp"
#include "tofkit/experiments/thesis_grey_chart.hpp"

namespace tofkit::experiments {

struct TurnOnOptions {
  double distance_m = inches_to_m(19.0);      ///< as the warm-up run
  double reflectance = grey_reflectance(51);  ///< Assumption: a light grey target (0 = white)
  double ambient_c = 20.0;
  double duration_ms = 500.0;     ///< record length after switch-on
  int shots = 0;                  ///< per sample; 0: the device's
  double block_ms = 5.0;          ///< samples are averaged in blocks of this length
  int first_samples = 10;         ///< "the first samples": their mean bias is reported
  double plateau_fraction = 0.4;  ///< the plateau is the mean of the last 40 % of the record
  double tolerance_mm = 0.25;     ///< on the plateau once every later block stays this close
  /// Throws std::invalid_argument naming the bad field.
  void validate() const;
};

struct TurnOnBlock {
  double start_ms = 0;  ///< since switch-on
  double mean_range_m = ranging::kNaN;
  double sd_range_m = ranging::kNaN;
  std::size_t samples = 0;
};

struct TurnOnResult {
  TurnOnOptions options;
  double sample_period_ms = 0;           ///< N shots / repetition rate
  std::vector<ranging::Record> records;  ///< consecutive samples from switch-on
  std::vector<TurnOnBlock> blocks;
  double plateau_range_m = ranging::kNaN;
  double first_samples_bias_mm = ranging::kNaN;   ///< mean of the first samples minus plateau
  double time_to_plateau_ms = ranging::kNaN;      ///< end of the last block off the plateau
  double time_to_plateau_fit_ms = ranging::kNaN;  ///< where the fitted exponential meets the
                                                  ///< tolerance (less noisy)
  double time_constant_ms = ranging::kNaN;        ///< exponential fit of the block offsets
  [[nodiscard]] std::vector<Finding> findings() const;
  [[nodiscard]] ResultTable table() const;
  [[nodiscard]] std::string summary() const;
};

/// The device is warmed up (the laser alone is switched on at t = 0).
[[nodiscard]] TurnOnResult run_turn_on(const device::VirtualRangefinder& device,
                                       const TurnOnOptions& options, std::uint64_t seed);

}  // namespace tofkit::experiments
