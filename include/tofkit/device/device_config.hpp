#pragma once
/// \file The full description of a (virtual) rangefinder, the registry of its
/// configuration keys, and the built-in presets.

#include <string>
#include <string_view>
#include <variant>
#include <vector>

#include "tofkit/physics/link_budget.hpp"
#include "tofkit/ranging/time_to_distance.hpp"

namespace tofkit::device {

/// Fixed-threshold comparator (leading- and trailing-edge timing).
struct DiscriminatorConfig {
  double threshold_v = 0.04;     ///< comparator threshold. Assumption, set so that echoes from
                                 ///< rho = 0.1 fade out past 8 m (paper: 8.08 m achieved) while
                                 ///< staying 19 x above the noise floor (no false alarms).
  double blanking_ns = 0.0;      ///< comparator blanked for this long after emission (echo time,
                                 ///< before the chain's fixed delay): crossings, false alarms and
                                 ///< the peak detector before it are ignored. 0: none.
  double level_wander_mv = 1.0;  ///< rms of a slow 1/f wander of the comparator's effective
                                 ///< level (reference and amplifier offset drift; the 12 levels
                                 ///< of measurement.delay_wander_ps, independent of it). It
                                 ///< turns into time through the echo's slope at the crossing,
                                 ///< so weak echoes wander more: paper Fig. 7's scatter, larger
                                 ///< on the dark plates and far away. Assumption: half the
                                 ///< white noise at the threshold (2.1 mV). 0: off.
};

/// Time-to-digital converter: coarse counter plus fine interpolator.
struct TdcConfig {
  double lsb_ps = 60.0;             ///< fine interpolator LSB (FPGA carry-chain TDC). Assumption.
  double coarse_clock_mhz = 200.0;  ///< coarse counter clock. Assumption.
  double inl_lsb = 0.5;             ///< peak integral nonlinearity of the interpolator, LSB. The
                                    ///< table is code-density style: accumulated random bin-width
                                    ///< errors (DNL), correlated over several bins as in carry
                                    ///< chains, closing over one coarse period. Assumption: 0.5 LSB
                                    ///< (30 ps, 4.5 mm) after the FPGA's code-density calibration.
  int code_density_hits = 0;        ///< firmware code-density calibration of the fine bins:
                                    ///< hits (uniform in time) histogrammed per code once at the
                                    ///< factory; the table then maps each code to its measured
                                    ///< centre, leaving only the counting error
                                    ///< (~ bins sqrt(F (1 - F) / hits) LSB). 0: uncorrected, the
                                    ///< INL above stays
  bool laser_sync = true;           ///< the laser fires on a clock edge (fixed start phase, as the
                                    ///< paper's FPGA: the INL leaves a periodic error every
  ///< c / (2 f_coarse)); false: asynchronous, the INL averages out
  double bin_tempco_ppm_per_c =
      100.0;  ///< fine-bin width change per degree of the timing board
              ///< (carry-chain delays: ~1000 ppm/C bare; the residual
              ///< after per-power-on code-density calibration. Assumption)
};

/// Thermal behaviour: where the heat is, and what each temperature moves.
/// No drift law is imposed here: range drift arises from delay tempcos of the
/// timing board, APD gain drift through walk, and the TDC bin width.
struct ThermalConfig {
  double delay_tempco_ps_per_c = 20.5;  ///< trigger-to-emission plus receive-chain delay drift
                                        ///< per degree of the front-end board (laser driver,
                                        ///< comparator, LVDS, FPGA I/O). Assumption, set so that
                                        ///< with the APD bias loop's walk (receiver.
                                        ///< bias_tracking_error_v_per_c) the paper's 3.8 mm/C
                                        ///< above 16 C at 2.402 m (Section 5.2) arises.
  double heater_setpoint_c = 16.0;  ///< the front-end board's cold-weather heater holds it up to
                                    ///< this temperature. Assumption: reproduces the paper's
                                    ///< "small, non-linear below 16 C" (Fig. 8): below it the
                                    ///< board (delays, APD) hardly follows the enclosure.
  double heater_loop_gain = 10.0;   ///< proportional heater loop gain (W/C of error over W/C of
                                    ///< board-to-enclosure conductance): the board droops by
                                    ///< 1 / (1 + gain) of the enclosure's change below setpoint
  double heater_max_rise_c = 30.0;  ///< most the heater can lift the board above the enclosure
  double self_heating_c = 6.0;      ///< steady-state internal rise above ambient. Assumption.
  double warmup_time_constant_min = 8.0;  ///< timing board (die) temperature time constant after
                                          ///< power-on (settles in ~4 tau: thesis 25-35 min).
  double sensor_lag_min = 3.0;  ///< the enclosure temperature sensor lags the die by this extra
                                ///< time constant (it sits on the case, not the die). Assumption.
  double warmup_delay_coeff_mm_per_c = 0.0;  ///< extra delay drift while the board warms up
                                             ///< (gradients across the board). Assumption.
  double sensor_resolution_c = 0.0625;       ///< temperature sensor LSB (12-bit digital sensor)
  double sensor_noise_c = 0.05;              ///< temperature sensor noise (1 sigma)
};

/// Timing and averaging of one output measurement.
/// Most shots one output may average (measurement.shots, --shots, and a
/// raster's samples times its shots).
inline constexpr int kMaxShots = 10'000'000;

struct MeasurementConfig {
  int shots = 1000;                  ///< shots averaged per output (1 MHz -> 1 kHz)
  double fixed_delay_ns = 2.5;       ///< trigger-to-emission plus receive-chain delay with the
                                     ///< timing board at receiver.nominal_temperature_c
                                     ///< (constant; calibrated out). Assumption.
  double power_on_offset_ps = 10.0;  ///< 1 sigma of a delay offset drawn at each power-on (a run's
                                     ///< seed): comparator offset, PLL/TDC start-up phase. Two runs
                                     ///< on different "days" differ by this. Assumption (1.5 mm).
  double flicker_delay_ps = 5.0;     ///< rms of a slow 1/f delay wander (eight octaves from 1 mHz
                                     ///< to 0.26 Hz), so averaging stops improving. Assumption.
  double delay_wander_ps = 20.0;     ///< rms of a random delay wander over the output's time (12
                                     ///< levels of correlation time 1 ms ... 70 min, equal power
                                     ///< each, drawn per level and time from the seed: a 1/f
                                     ///< spectrum; supply, reference-clock and board-temperature
                                     ///< fluctuations). 0: off. 20 ps (3 mm) reproduces the
                                     ///< scatter of the paper's tests, whose conditions were set
                                     ///< minutes apart: Fig. 7 (4.60 mm std after the correction
                                     ///< at 2.355 m; the twin 3.7-5.3 mm over seeds 1, 2, 3 and
                                     ///< 2022, mean 4.7) and Fig. 9 (4.70 mm over 20
                                     ///< temperatures; the twin 2.7-3.6 mm, short of it).
  double stop_gate_ns = 2.0;         ///< firmware's false-stop rejection: stops farther than this
                              ///< from the median stop are dropped before averaging (0: off).
                              ///< Assumption: +-0.3 m, wider than any walk (< 1 ns).
  double stop_gate_min_share = 0.5;       ///< the gate must keep at least this share of the stops,
                                          ///< else no distance: fewer means false stops (noise
                                          ///< before the echo) outnumber the echo's and the median
                                          ///< is noise's. 0: off. Assumption: a majority.
  double window_ns = 30.0;                ///< waveform-mode record length around the echo
  double sample_period_ps = 100.0;        ///< waveform-mode sampling period (at most: finer
                                          ///< for a fast receiver, device::waveform_step_ns)
  double reference_temperature_c = 20.0;  ///< air temperature the device assumes for c_air
};

/// Scanning: how a beam's footprint is sampled by rays (scan/).
struct ScanConfig {
  int rays_per_beam = 1;  ///< sub-rays sampling the beam footprint (1: the beam axis only)
  /// Sub-ray hits on one primitive of one reflectance are one surface unless
  /// they meet at a crease sharper than this (mesh triangles of a smooth
  /// surface are one surface; a box's faces, a roof edge are two).
  double crease_angle_deg = 30.0;
};

/// Receiver memory in a time-ordered sequence of measurements (a scan), see
/// device/echo_memory.hpp: an AC coupling between the amplifier and the
/// comparator. Its capacitor's voltage (the baseline) is a first-order low-pass
/// of the echo train; the comparator sees the echo minus it, so the effective
/// threshold follows the echoes of the last few time constants. A zero time
/// constant or share: DC coupled, no memory (the paper device: the paper
/// reports none).
struct MemoryConfig {
  double time_constant_ms = 0.0;  ///< AC coupling's time constant (0: DC coupled, no memory)
  double coupling_share = 0.0;    ///< share of the echo train's mean the baseline takes (1: a
                                  ///< plain coupling capacitor; a baseline restorer leaves less;
                                  ///< 0: none, DC coupled). Pulsed core only: the loop's
                                  ///< baseline is its square wave's (coupling_duty of the swing)
};

/// The self-oscillating loop of an AccuRange-like unit (device/oscillator_loop.hpp):
/// the laser stays on until the detector sees the return, then turns off, and on
/// again when the return has gone; an interface board counts the loop's period.
/// `enabled = false` (the paper device): the pulsed time-of-flight core.
struct OscillatorConfig {
  bool enabled = false;              ///< measuring principle: true = self-oscillating loop
  double loop_delay_ns = 8.0;        ///< per edge: laser driver turn-on/off, comparator and logic
  double zero_half_period_ns = 8.0;  ///< the vendor's zero: half period read as range 0
  double count_clock_mhz = 80.0;     ///< interface board's timing clock (thesis: 80 MHz)
  double gate_fraction = 0.5;        ///< share of each output period the counter is gated on
  double coupling_duty = 0.5;        ///< AC-coupled baseline as a share of the swing (duty)
  double overdrive_jitter_ps_per_neper = 0.0;  ///< extra edge jitter per neper of overdrive
  double flicker_delay_ps = 0.0;               ///< rms of the loop delay's slow wander per output
  /// rms of the loop's duty unbalance at a laser switch-on (share), settling over
  /// the laser's turn-on transient: the AC-coupled baseline, at the duty share of
  /// the swing, moves with it, and both edges turn that into time through their
  /// slopes (a weak return's slow rise the most)
  double duty_wander = 0.0;
  /// The laser gated by the board's counting window (on while it counts, off for
  /// the rest of the output period): the laser chip heats in each gate and cools
  /// between with chip_time_constant_us; a cold chip's shorter turn-on delay
  /// reads chip_bias_mm against a hot one (0: no gating effect)
  double chip_bias_mm = 0.0;
  double chip_time_constant_us = 0.0;  ///< the laser chip's thermal time constant
  /// comparator hysteresis: once high, the comparator goes low only below the
  /// level minus this, so noise near a weak swing's top adds fewer edges
  /// (device/oscillator_loop.hpp, near_top_edges)
  double comparator_hysteresis_mv = 0.0;
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
  OscillatorConfig oscillator;
};

/// One configuration key: a dotted name bound to a field, with its valid range.
struct ConfigField {
  std::string key;  ///< "section.name_unit"
  std::variant<double*, int*, bool*> value;
  double min = 0;  ///< smallest valid value (inclusive; physically meaningful, never "> 0")
  double max = 0;  ///< largest valid value (inclusive)
  /// When > 0 (and min is 0, "none"): a nonzero value is at least this.
  double min_nonzero = 0;
  std::string description;  ///< one line, with source or "Assumption"
};

/// Every key of a config, bound to its fields (the one mechanism behind TOML
/// loading, --set overrides, dumping and validation).
[[nodiscard]] std::vector<ConfigField> config_fields(DeviceConfig& config);

/// The key's value as a double (bools as 0/1).
[[nodiscard]] double field_value(const ConfigField& field);

/// The key's valid values: "[0.001, 1e+05]", or "0 or [1e-06, 10]".
[[nodiscard]] std::string range_text(const ConfigField& field);
/// Whether `value` is valid for the key: finite, not subnormal, in its range.
[[nodiscard]] bool in_range(const ConfigField& field, double value);

/// Messages, one per bad key ("receiver.bandwidth_mhz = 0 is out of range [0.001, 1e+05]").
[[nodiscard]] std::vector<std::string> validate(const DeviceConfig& config);

/// The conversion the device reports distance_raw_m with: its wavelength and
/// the nominal speed of light in air at measurement.reference_temperature_c and
/// the environment's pressure and humidity (what a model fitted on its rows
/// assumes unless told otherwise).
[[nodiscard]] ranging::TimeToDistance nominal_time_to_distance(const DeviceConfig& config);
/// The speed of light in air (m/ns) of that conversion.
[[nodiscard]] double nominal_light_speed_m_per_ns(const DeviceConfig& config);

/// Built-in presets: "paper" (the Sensors 2022 rangefinder, Table 1) and
/// "accurange" (an AccuRange-3000-like 780 nm unit, the thesis's device).
[[nodiscard]] DeviceConfig preset(std::string_view name);
[[nodiscard]] std::vector<std::string> preset_names();

}  // namespace tofkit::device
