#pragma once
/// \file The device's operating point at given conditions: what the thermal
/// stage (device/thermal.hpp) puts each part at, and what that sets before
/// any echo: the APD's gain at the board's temperature (bias tracking's
/// residual), the laser's power (its tempco), the speed of light in air, the
/// trigger and receive chain's delay (its tempco and the warm-up gradient),
/// the TDC's bin width (its tempco), the temperature sensor's view, and the
/// front end's noise at that gain. Every measurement at the same conditions
/// shares it.

#include "tofkit/device/device_config.hpp"
#include "tofkit/device/front_end.hpp"

namespace tofkit::device {

struct OperatingPoint {
  double internal_c = 0;             ///< die temperature (warm-up after power-on)
  double board_c = 0;                ///< front-end board, behind its heater
  double gain = 0;                   ///< APD multiplication at board_c
  double power_scale = 0;            ///< laser peak power relative to nominal
  double c_m_per_ns = 0;             ///< speed of light in air at the ambient temperature
  double volts_per_watt = 0;         ///< received power to comparator volts, this gain and power
  double fixed_delay_ns = 0;         ///< trigger + receive chain, incl. tempco and warm-up gradient
  double tdc_bin_scale = 1;          ///< fine-bin width relative to nominal
  double temperature_reading_c = 0;  ///< what the temperature sensor sees (before its noise)
  FrontEndNoise noise;               ///< at the comparator, for this gain
};

/// The operating point at `ambient_c`, `minutes_since_power_on` after power-on.
/// `volts_per_watt_unity_gain`: responsivity x transimpedance x the pulse's
/// bandwidth loss; `c_nominal_m_per_ns`: the device's assumed speed of light
/// (the warm-up gradient's range as time).
[[nodiscard]] OperatingPoint operating_point(const DeviceConfig& config, double ambient_c,
                                             double minutes_since_power_on,
                                             double volts_per_watt_unity_gain,
                                             double c_nominal_m_per_ns);

}  // namespace tofkit::device
