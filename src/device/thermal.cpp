#include "tofkit/device/thermal.hpp"

#include <cmath>

namespace tofkit::device {

double internal_temperature_c(const ThermalConfig& thermal, double ambient_c,
                              double minutes_since_power_on) {
  const double settled = 1.0 - std::exp(-minutes_since_power_on / thermal.warmup_time_constant_min);
  return ambient_c + thermal.self_heating_c * settled;
}

double delay_drift_mm(const ThermalConfig& thermal, double internal_c) {
  const double above = internal_c - thermal.knee_c;
  if (above >= 0.0) return thermal.delay_coeff_mm_per_c * above;
  return -thermal.below_knee_coeff_mm_per_c2 * above * above;
}

double warmup_drift_mm(const ThermalConfig& thermal, double ambient_c,
                       double minutes_since_power_on) {
  // The timing electronics lead the sensor: the unseen part is the difference
  // between the settled and the present internal temperature.
  const double lag_c = internal_temperature_c(thermal, ambient_c, 1e9) -
                       internal_temperature_c(thermal, ambient_c, minutes_since_power_on);
  return thermal.warmup_delay_coeff_mm_per_c * lag_c;
}

}  // namespace tofkit::device
