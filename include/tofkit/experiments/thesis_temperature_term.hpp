#pragma once
/// \file The thesis protocol's temperature term (tofkit beyond the thesis, its
/// future work "include temperature in the model"): corrected ranges move by
/// slope x (the unit's sensor reading - a reference reading), and the slope's
/// standard uncertainty times that departure is the term's. The slope is the
/// device's own, measured in a temperature run (type A, as a calibration lab
/// would), or the thesis's stated drift, 0.25-0.60 in per 10 C (Section 4.4,
/// type B: a rectangular distribution over the range).

#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "tofkit/device/virtual_rangefinder.hpp"
#include "tofkit/experiments/characterization_common.hpp"

namespace tofkit::experiments {

enum class TemperatureTermSource {
  run,     ///< the slope of a temperature run on the device (type A)
  stated,  ///< the thesis's stated drift range (type B)
  none,    ///< no temperature term
};

/// "run", "stated" or "none".
[[nodiscard]] const char* to_string(TemperatureTermSource source);

struct TemperatureTermOptions {
  /// Not an aggregate: as one, GCC 12 warns (-Wmaybe-uninitialized, a false
  /// positive) on the vectors of a temporary ThesisProtocolOptions{}.
  TemperatureTermOptions() = default;
  TemperatureTermSource source = TemperatureTermSource::run;
  /// source run: a separate session (its own power-on and random stream) of
  /// run_temperature (characterization_temperature.hpp) at the protocol's
  /// training distances, once per grey here, the chamber stepped through these
  /// ambients. Assumption: the laboratory's range, bracketing the training's
  /// 20 C and the warmer test session's 28 C; a few greys, because the test chart
  /// mixes greys and a drift through the walk would differ between them.
  std::vector<int> run_grey_levels{0, 102, 255};
  std::vector<double> run_ambient_c{15, 20, 25, 30, 35};
  int run_samples_per_point = 50;  ///< N-shot samples per distance and ambient
  /// source stated: thesis Section 4.4, the range falls 0.25-0.60 in per 10 C.
  double stated_drift_min_in_per_10c = 0.25;
  double stated_drift_max_in_per_10c = 0.60;
  /// Throws std::invalid_argument naming the bad field.
  void validate() const;
};

/// One line of the temperature run: range error against the sensor's reading.
struct TemperatureTermLine {
  int grey = 0;
  double distance_m = 0;
  double slope_m_per_c = ranging::kNaN;  ///< d(true - measured) / d(reading)
  double slope_se_m_per_c = ranging::kNaN;
};

struct TemperatureTerm {
  TemperatureTermSource source = TemperatureTermSource::none;
  /// d(true - measured) / d(sensor reading): the range falls as the unit warms
  /// (delay tempcos of the timing board), so the correction rises.
  double slope_m_per_c = 0;
  /// Standard uncertainty of the slope where the term is applied. run: the
  /// mean slope's standard error and the slopes' spread (sample sd) over
  /// distances and greys in quadrature; stated: half the range / sqrt(3).
  double u_slope_m_per_c = 0;
  double slope_se_m_per_c = ranging::kNaN;      ///< run: of the mean over the lines
  double slope_spread_m_per_c = ranging::kNaN;  ///< run: sd over the lines
  double reference_c = 0;                       ///< the training's mean reading
  std::vector<TemperatureTermLine> lines;       ///< run: one per grey and distance

  [[nodiscard]] bool active() const { return source != TemperatureTermSource::none; }
  /// true - measured added by a reading of t_c (0 for a missing reading).
  [[nodiscard]] double correction_m(double t_c) const;
  /// Its standard uncertainty (a missing reading: no correction, none).
  [[nodiscard]] double u_m(double t_c) const;
  /// One line: the source, the slope and its uncertainty in mm per C and in per 10 C.
  [[nodiscard]] std::string summary() const;
};

/// The term for `options.source`, counted from the mean of the finite
/// `training_readings_c`. source run measures it on `device` at `distances_m`
/// with streams derived from `seed`. Throws std::invalid_argument on bad
/// options and std::runtime_error if the run leaves a line without a slope.
[[nodiscard]] TemperatureTerm make_temperature_term(const device::VirtualRangefinder& device,
                                                    const TemperatureTermOptions& options,
                                                    const std::vector<double>& distances_m,
                                                    std::span<const double> training_readings_c,
                                                    std::uint64_t seed);

}  // namespace tofkit::experiments
