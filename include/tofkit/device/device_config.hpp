#pragma once
/// \file The full description of a (virtual) rangefinder, the registry of its
/// configuration keys, and the built-in presets.

#include <string>
#include <string_view>
#include <variant>
#include <vector>

#include "tofkit/physics/link_budget.hpp"

namespace tofkit::device {

/// Fixed-threshold comparator (leading- and trailing-edge timing).
struct DiscriminatorConfig {
  double threshold_v = 0.04;  ///< comparator threshold. Assumption, set so that echoes from
                              ///< rho = 0.1 fade out past 8 m (paper: 8.08 m achieved) while
                              ///< staying 19 x above the noise floor (no false alarms).
};

/// Time-to-digital converter: coarse counter plus fine interpolator.
struct TdcConfig {
  double lsb_ps = 60.0;            ///< fine interpolator LSB (FPGA carry-chain TDC). Assumption.
  double coarse_clock_mhz = 200.0;  ///< coarse counter clock. Assumption.
  double inl_lsb = 0.5;            ///< peak integral nonlinearity of the interpolator, LSB,
                                   ///< sinusoidal over one coarse period. Assumption.
};

/// Thermal behaviour of delays, sensor and warm-up.
struct ThermalConfig {
  double knee_c = 16.0;                  ///< paper Section 5.2: linear drift above 16 C
  double delay_coeff_mm_per_c = 3.8;     ///< paper Section 5.2: 3.8 mm/C above the knee
  double below_knee_coeff_mm_per_c2 = 0.02;  ///< small non-linear (quadratic) drift below the
                                             ///< knee, mm/C^2 (paper: "small, non-linear")
  double self_heating_c = 6.0;           ///< steady-state internal rise above ambient. Assumption.
  double warmup_time_constant_min = 8.0;  ///< internal temperature time constant after power-on
                                          ///< (settles in ~4 tau: thesis 25-35 min). Assumption.
  double warmup_delay_coeff_mm_per_c = 0.0;  ///< extra delay drift while the board warms up,
                                             ///< beyond what the sensor sees. Assumption.
  double sensor_resolution_c = 0.0625;   ///< temperature sensor LSB (12-bit digital sensor)
  double sensor_noise_c = 0.05;          ///< temperature sensor noise (1 sigma)
};

/// Timing and averaging of one output measurement.
struct MeasurementConfig {
  int shots = 1000;                  ///< shots averaged per output (1 MHz -> 1 kHz)
  double fixed_delay_ns = 2.5;       ///< trigger-to-emission plus receive-chain delay at the
                                     ///< knee temperature (constant; calibrated out). Assumption.
  double window_ns = 30.0;           ///< waveform-mode record length around the echo
  double sample_period_ps = 100.0;   ///< waveform-mode sampling period
  double reference_temperature_c = 20.0;  ///< air temperature the device assumes for c_air
};

/// Scanning: how a beam's footprint is sampled by rays (scan/).
struct ScanConfig {
  int rays_per_beam = 1;  ///< sub-rays sampling the beam footprint (1: the beam axis only)
};

/// Receiver memory in a time-ordered sequence of measurements (a scan), see
/// device/echo_memory.hpp. All zero: no memory (the paper device).
struct MemoryConfig {
  double time_constant_ms = 0.0;  ///< recovery of the receiver's operating point (0: none)
  double strength_gain_mm_per_neper = 0.0;  ///< range error per neper of unrecovered
                                            ///< echo-strength step (+: a rise reads short)
  double distance_gain = 0.0;  ///< share of an unrecovered distance step the timing lags by
};

/// A complete device.
struct DeviceConfig {
  std::string name = "paper";  ///< preset this config started from
  physics::LinkConfig link;
  DiscriminatorConfig discriminator;
  TdcConfig tdc;
  ThermalConfig thermal;
  MeasurementConfig measurement;
  ScanConfig scan;
  MemoryConfig memory;
};

/// One configuration key: a dotted name bound to a field, with its valid range.
struct ConfigField {
  std::string key;  ///< "section.name_unit"
  std::variant<double*, int*, bool*> value;
  double min = 0;           ///< smallest valid value (inclusive unless min_exclusive)
  double max = 0;           ///< largest valid value (inclusive)
  bool min_exclusive = false;
  std::string description;  ///< one line, with source or "Assumption"
};

/// Every key of a config, bound to its fields (the one mechanism behind TOML
/// loading, --set overrides, dumping and validation).
[[nodiscard]] std::vector<ConfigField> config_fields(DeviceConfig& config);

/// The key's value as a double (bools as 0/1).
[[nodiscard]] double field_value(const ConfigField& field);

/// Messages, one per bad key ("receiver.bandwidth_mhz = 0 is out of range (0, 1e5]").
[[nodiscard]] std::vector<std::string> validate(const DeviceConfig& config);

/// Built-in presets: "paper" (the Sensors 2022 rangefinder, Table 1) and
/// "accurange" (an AccuRange-3000-like 780 nm unit, the thesis's device).
[[nodiscard]] DeviceConfig preset(std::string_view name);
[[nodiscard]] std::vector<std::string> preset_names();

}  // namespace tofkit::device
