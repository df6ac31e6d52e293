#pragma once
/// \file Thermal state of the device: where the heat is after power-on, what
/// the temperature sensor sees, and the timing board's heater. No drift law is
/// imposed here; the range drift follows from what each temperature moves
/// (delay tempcos, APD gain through walk, TDC bin width) in the rangefinder.

#include <cmath>

#include "tofkit/device/device_config.hpp"

namespace tofkit::device {

/// Die (timing electronics) temperature before the heater: ambient plus
/// self-heating that builds up after power-on with a first-order time constant
/// (thesis: 25-35 min to settle).
[[nodiscard]] double internal_temperature_c(const ThermalConfig& thermal, double ambient_c,
                                            double minutes_since_power_on);

/// What the enclosure's temperature sensor sees: the die temperature through a
/// further first-order lag (thermal.sensor_lag_min), so it trails during warm-up.
[[nodiscard]] double sensor_temperature_c(const ThermalConfig& thermal, double ambient_c,
                                          double minutes_since_power_on);

/// The sensor's reading of `sensed_c`: its noise (z standard normal), then
/// its resolution (thermal.sensor_resolution_c; 0: a continuous reading).
/// Inline: every measurement reads it.
[[nodiscard]] inline double sensor_reading_c(const ThermalConfig& thermal, double sensed_c,
                                             double z) {
  const double reading = sensed_c + thermal.sensor_noise_c * z;
  const double lsb = thermal.sensor_resolution_c;
  return lsb > 0 ? std::round(reading / lsb) * lsb : reading;
}

/// Timing board temperature: the die temperature lifted by a proportional
/// cold-weather heater below its setpoint (limited to heater_max_rise_c).
[[nodiscard]] double timing_board_temperature_c(const ThermalConfig& thermal, double internal_c);

/// Extra range (mm) during warm-up from gradients across the board (the die's
/// remaining rise times warmup_delay_coeff_mm_per_c).
[[nodiscard]] double warmup_drift_mm(const ThermalConfig& thermal, double ambient_c,
                                     double minutes_since_power_on);

}  // namespace tofkit::device
