#include "tofkit/device/thermal.hpp"

#include <algorithm>
#include <cmath>

namespace tofkit::device {

double internal_temperature_c(const ThermalConfig& thermal, double ambient_c,
                              double minutes_since_power_on) {
  const double settled = 1.0 - std::exp(-minutes_since_power_on / thermal.warmup_time_constant_min);
  return ambient_c + thermal.self_heating_c * settled;
}

double sensor_temperature_c(const ThermalConfig& thermal, double ambient_c,
                            double minutes_since_power_on) {
  // Step response of two first-order lags in cascade (die tau1, sensor tau2).
  const double t = minutes_since_power_on;
  const double tau1 = thermal.warmup_time_constant_min;
  const double tau2 = thermal.sensor_lag_min;
  double settled = 0;
  if (tau2 <= 0.0) {
    settled = 1.0 - std::exp(-t / tau1);
  } else if (std::abs(tau1 - tau2) < 1e-9 * tau1) {
    settled = 1.0 - (1.0 + t / tau1) * std::exp(-t / tau1);
  } else {
    settled = 1.0 - (tau1 * std::exp(-t / tau1) - tau2 * std::exp(-t / tau2)) / (tau1 - tau2);
  }
  return ambient_c + thermal.self_heating_c * settled;
}

double timing_board_temperature_c(const ThermalConfig& thermal, double internal_c) {
  // A proportional heater: power K (T_set - T_board), never negative, at most
  // what lifts the board heater_max_rise_c above the enclosure. In steady state
  // T_board = T_int + K / (1 + K) (T_set - T_int) while it heats: below the
  // setpoint the board follows the enclosure only by 1 / (1 + K).
  const double k = thermal.heater_loop_gain;
  const double rise = k / (1.0 + k) * (thermal.heater_setpoint_c - internal_c);
  return internal_c + std::clamp(rise, 0.0, thermal.heater_max_rise_c);
}

double warmup_drift_mm(const ThermalConfig& thermal, double ambient_c,
                       double minutes_since_power_on) {
  // The timing electronics lead the board average: the unseen part is the
  // difference between the settled and the present die temperature.
  const double lag_c = internal_temperature_c(thermal, ambient_c, 1e9) -
                       internal_temperature_c(thermal, ambient_c, minutes_since_power_on);
  return thermal.warmup_delay_coeff_mm_per_c * lag_c;
}

}  // namespace tofkit::device
