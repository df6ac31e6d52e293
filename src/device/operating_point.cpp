#include "tofkit/device/operating_point.hpp"

#include <algorithm>

#include "tofkit/device/thermal.hpp"
#include "tofkit/physics/air.hpp"
#include "tofkit/physics/link_budget.hpp"

namespace tofkit::device {

OperatingPoint operating_point(const DeviceConfig& config, double ambient_c,
                               double minutes_since_power_on, double volts_per_watt_unity_gain,
                               double c_nominal_m_per_ns) {
  const auto& th = config.thermal;
  const auto& rx = config.link.receiver;
  const auto& link = config.link;
  OperatingPoint c;
  c.internal_c = internal_temperature_c(th, ambient_c, minutes_since_power_on);
  // The front-end board (laser driver, APD, amplifier, comparator, TDC) sits
  // behind its heater; the APD's gain follows the board's temperature through
  // the bias loop's residual.
  c.board_c = timing_board_temperature_c(th, c.internal_c);
  c.gain = physics::apd_gain_at(rx, c.board_c);
  c.power_scale = std::max(
      0.0, 1.0 + link.laser.power_temp_coeff_per_c * (c.internal_c - rx.nominal_temperature_c));
  physics::AirConditions air{ambient_c, link.environment.pressure_hpa,
                             link.environment.relative_humidity_pct};
  c.c_m_per_ns = physics::speed_of_light_in_air_m_per_s(link.laser.wavelength_nm, air) * 1e-9;
  c.volts_per_watt = volts_per_watt_unity_gain * c.gain * c.power_scale;
  // Delays: fixed chain delay plus the timing board's delay tempco and the
  // unseen warm-up gradient, as extra round-trip time.
  const double board_dt = c.board_c - rx.nominal_temperature_c;
  const double warmup_mm = warmup_drift_mm(th, ambient_c, minutes_since_power_on);
  c.fixed_delay_ns = config.measurement.fixed_delay_ns +
                     th.delay_tempco_ps_per_c * 1e-3 * board_dt +
                     2.0 * warmup_mm * 1e-3 / c_nominal_m_per_ns;
  c.tdc_bin_scale = 1.0 + config.tdc.bin_tempco_ppm_per_c * 1e-6 * board_dt;
  c.temperature_reading_c = sensor_temperature_c(th, ambient_c, minutes_since_power_on);
  c.noise = front_end_noise(rx, c.gain);
  return c;
}

}  // namespace tofkit::device
