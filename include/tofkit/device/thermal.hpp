#pragma once
/// \file Thermal behaviour: internal temperature after power-on and the drift
/// of the fixed delays with it (paper Section 5.2; thesis cold-start warm-up).

#include "tofkit/device/device_config.hpp"

namespace tofkit::device {

/// Internal (board) temperature: ambient plus self-heating that builds up after
/// power-on with a first-order time constant (thesis: 25-35 min to settle).
[[nodiscard]] double internal_temperature_c(const ThermalConfig& thermal, double ambient_c,
                                            double minutes_since_power_on);

/// Extra range (mm) caused by the temperature drift of the trigger and receive
/// delays: linear above the knee (paper: 3.8 mm/C above 16 C), small and
/// quadratic below it.
[[nodiscard]] double delay_drift_mm(const ThermalConfig& thermal, double internal_c);

/// Extra range (mm) during warm-up not seen by the temperature sensor
/// (gradients between the sensor and the timing electronics).
[[nodiscard]] double warmup_drift_mm(const ThermalConfig& thermal, double ambient_c,
                                     double minutes_since_power_on);

}  // namespace tofkit::device
