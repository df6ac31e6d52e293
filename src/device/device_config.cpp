#include "tofkit/device/device_config.hpp"

#include <charconv>
#include <cmath>
#include <stdexcept>
#include <string>
#include <type_traits>
#include <utility>

#include "tofkit/device/accurange_preset.hpp"
#include "tofkit/physics/air.hpp"

namespace tofkit::device {
namespace {

constexpr double kHalfPiRad = 1.5707963267948966;

// Shortest round-trip text of a number, for messages ("1e+05", "0.012").
std::string number_text(double value) {
  char buffer[64];
  const auto result = std::to_chars(buffer, buffer + sizeof buffer, value);
  return std::string(buffer, result.ptr);
}

// Helpers that bind one struct member to a dotted key with its valid range
// [min, max]. A positive physical quantity has a physically meaningful
// smallest value, never "> 0": a subnormal pulse width or sensor step passes
// "> 0" and then overflows the physics (a 1e-300 ns pulse crashed the setup).
ConfigField field(std::string key, double* value, double min, double max, std::string description) {
  return ConfigField{std::move(key), value, min, max, 0.0, std::move(description)};
}
ConfigField field(std::string key, int* value, double min, double max, std::string description) {
  return ConfigField{std::move(key), value, min, max, 0.0, std::move(description)};
}
ConfigField field(std::string key, bool* value, std::string description) {
  return ConfigField{std::move(key), value, 0.0, 1.0, 0.0, std::move(description)};
}
// A quantity where 0 means "none" (a continuous sensor, no noise floor): 0 or
// [min_nonzero, max].
ConfigField field_or_off(std::string key, double* value, double min_nonzero, double max,
                         std::string description) {
  return ConfigField{std::move(key), value, 0.0, max, min_nonzero, std::move(description)};
}

}  // namespace

std::string range_text(const ConfigField& f) {
  std::string text = f.min_nonzero > 0 ? number_text(f.min) + " or [" : "[";
  text += number_text(f.min_nonzero > 0 ? f.min_nonzero : f.min);
  text += ", ";
  text += number_text(f.max);
  text += ']';
  return text;
}

bool in_range(const ConfigField& f, double v) {
  if (!std::isfinite(v)) return false;
  // No key takes a subnormal: it is no measurable quantity, and its reciprocal
  // overflows.
  if (v != 0 && std::fpclassify(v) == FP_SUBNORMAL) return false;
  if (!(v >= f.min) || !(v <= f.max)) return false;
  return v == 0 || !(std::abs(v) < f.min_nonzero);
}

namespace {}  // namespace

std::vector<ConfigField> config_fields(DeviceConfig& config) {
  auto& laser = config.link.laser;
  auto& rx = config.link.receiver;
  auto& env = config.link.environment;
  auto& disc = config.discriminator;
  auto& tdc = config.tdc;
  auto& th = config.thermal;
  auto& m = config.measurement;
  return {
      // laser: the pulsed emitter, paper Table 1
      field("laser.wavelength_nm", &laser.wavelength_nm, 200, 2000, "emitted wavelength, Table 1"),
      field("laser.peak_power_w", &laser.peak_power_w, 1e-6, 1e4,
            "transmitted peak power Pt, Table 1"),
      field("laser.pulse_width_ns", &laser.pulse_width_ns, 0.01, 1000,
            "emitted pulse FWHM: Table 1's 0.1 % duty cycle at 1 MHz"),
      field("laser.repetition_hz", &laser.repetition_hz, 1, 1e9,
            "pulse repetition frequency, Table 1"),
      field("laser.transmit_efficiency", &laser.transmit_efficiency, 1e-6, 1,
            "transmitting optics efficiency Tt, Table 1"),
      field("laser.beam_divergence_mrad", &laser.beam_divergence_mrad, 1e-3, 1000,
            "full-angle divergence after collimation. Assumption"),
      field("laser.exit_beam_diameter_mm", &laser.exit_beam_diameter_mm, 1e-3, 1000,
            "collimated beam diameter at the exit. Assumption"),
      field("laser.power_temp_coeff_per_c", &laser.power_temp_coeff_per_c, -0.1, 0.1,
            "relative change of Pt per degree (driver-regulated diode). Assumption"),
      field("laser.turn_on_bias_mm", &laser.turn_on_bias_mm, -1000, 1000,
            "range bias of the first shot after laser switch-on (thermal chirp). Assumption"),
      field("laser.turn_on_time_constant_ms", &laser.turn_on_time_constant_ms, 1e-6, 1e7,
            "decay time of the turn-on bias. Assumption"),

      field_or_off("laser.lasing_onset_ns", &laser.lasing_onset_ns, 1e-3, 100,
                   "emission starts this long before the pulse's peak (the drive current "
                   "crosses the lasing threshold; bounds walk under strong echoes). 0: a whole "
                   "Gaussian"),

      // receiver: optics, APD, transimpedance amplifier
      field("receiver.aperture_diameter_mm", &rx.aperture_diameter_mm, 1e-3, 1000,
            "receiving aperture diameter, Table 1"),
      field("receiver.optics_efficiency", &rx.optics_efficiency, 1e-6, 1,
            "receiving optics efficiency Tr, Table 1"),
      field("receiver.field_of_view_rad", &rx.field_of_view_rad, 1e-6, kHalfPiRad,
            "receiving field angle theta_r, Table 1"),
      field("receiver.filter_bandwidth_nm", &rx.filter_bandwidth_nm, 1e-3, 1000,
            "optical filter bandwidth, Table 1"),
      field("receiver.bandwidth_mhz", &rx.bandwidth_mhz, 1e-3, 1e5,
            "electrical -3 dB bandwidth B, Table 1"),
      field("receiver.responsivity_a_per_w", &rx.responsivity_a_per_w, 1e-6, 2,
            "unity-gain responsivity; Table 1's 58 A/W read as 0.58 A/W x gain 100"),
      field("receiver.apd_gain", &rx.apd_gain, 1, 1e4,
            "APD multiplication M at the nominal temperature"),
      field("receiver.excess_noise_factor", &rx.excess_noise_factor, 1, 100,
            "APD excess noise factor F; Table 1's noise figure 3"),
      field_or_off("receiver.nep_w_per_sqrt_hz", &rx.nep_w_per_sqrt_hz, 1e-20, 1e-6,
                   "noise-equivalent power, Table 1 (2e-14 W/sqrt(Hz))"),
      field("receiver.dark_current_na", &rx.dark_current_na, 0, 1e6,
            "primary (unmultiplied) dark current. Assumption: typical Si APD"),
      field("receiver.transimpedance_kohm", &rx.transimpedance_kohm, 1e-6, 1e6,
            "gain converting APD current to volts at the comparator (TIA + post-amp). Assumption"),
      field("receiver.saturation_v", &rx.saturation_v, 1e-6, 100,
            "amplifier output clip level. Assumption: saturation starts at the 6.5 ns echo width"),
      field("receiver.recovery_ns_per_neper", &rx.recovery_ns_per_neper, 0, 1000,
            "extra clipped time per e-fold of overdrive (charge storage). Assumption"),
      field_or_off("receiver.space_charge_v", &rx.space_charge_v, 1e-6, 1e4,
                   "APD space charge: the linear echo amplitude at which the gain has halved, "
                   "A / (1 + A / this); bounds overdrive. 0: none"),
      field("receiver.amplitude_noise_rel", &rx.amplitude_noise_rel, 0, 1,
            "relative noise of the amplitude (peak) reading"),
      field("receiver.nominal_temperature_c", &rx.nominal_temperature_c, -60, 150,
            "temperature at which apd_gain holds"),
      field("receiver.breakdown_temp_coeff_v_per_c", &rx.breakdown_temp_coeff_v_per_c, 0, 10,
            "Si APD breakdown voltage drift (about 0.65 V/C)"),
      field("receiver.bias_margin_v", &rx.bias_margin_v, 1e-3, 1000,
            "V_br - V_bias at the nominal temperature (sets dM/dT at fixed bias)"),
      field("receiver.bias_temperature_compensated", &rx.bias_temperature_compensated,
            "APD bias tracks the breakdown voltage, holding M nearly constant (paper's design)"),
      field("receiver.bias_tracking_error_v_per_c", &rx.bias_tracking_error_v_per_c, -10, 10,
            "residual of the APD bias loop: margin changes by -error per C. Assumption"),
      field("receiver.amplitude_clip_v", &rx.amplitude_clip_v, 1e-6, 1000,
            "ceiling of the amplitude (peak) reading, where its stage clips. Assumption"),
      field("receiver.crosstalk_v", &rx.crosstalk_v, 0, 1000,
            "emitter-receiver optical crosstalk: its peak at the comparator (a pulse at zero "
            "range; follows laser power and APD gain). 0: none"),
      field("receiver.axis_offset_mm", &rx.axis_offset_mm, 0, 1000,
            "emitter-receiver axis offset (biaxial optics; sets the near blind zone). Assumption"),
      field_or_off("receiver.focus_distance_m", &rx.focus_distance_m, 1e-3, 1e6,
                   "the receiver's field stop sits in the image of a target at this distance; "
                   "nearer targets are defocused and pass only part of their light. 0: "
                   "far field (every returned ray passes)"),

      // environment: sunlight, atmosphere, air
      field("environment.solar_irradiance_w_per_m2_um", &env.solar_irradiance_w_per_m2_um, 0, 3000,
            "solar spectral irradiance H: 0 indoors; Table 1: 748.5 at 905 nm"),
      field("environment.sun_angle_deg", &env.sun_angle_deg, 0, 90,
            "angle between sun and target normal theta, Table 1"),
      field("environment.sky_radiance_w_per_m2_sr_um", &env.sky_radiance_w_per_m2_sr_um, 0, 1e4,
            "sky spectral radiance N (Eq. 9); the paper's case has none"),
      field("environment.atmospheric_transmission", &env.atmospheric_transmission, 1e-6, 1,
            "one-way atmospheric transmission Ta, Table 1"),
      field("environment.pressure_hpa", &env.pressure_hpa, 100, 1200,
            "air pressure, for the group index of air"),
      field("environment.relative_humidity_pct", &env.relative_humidity_pct, 0, 100,
            "relative humidity, for the group index of air"),
      field("environment.eq9_as_printed", &env.eq9_as_printed,
            "background by Eq. 9 as printed (rho twice; reproduces the paper's Fig. 3)"),

      // discriminator, TDC
      field("discriminator.threshold_v", &disc.threshold_v, 1e-9, 100,
            "comparator threshold. Assumption: rho = 0.1 echoes fade out past 8 m (paper: 8.08 m)"),
      field("discriminator.blanking_ns", &disc.blanking_ns, 0, 1e5,
            "comparator blanked this long after emission: earlier crossings ignored. 0: none"),
      field("discriminator.level_wander_mv", &disc.level_wander_mv, 0, 1e4,
            "rms of a slow 1/f wander of the comparator's effective level (reference and "
            "offset drift); through the echo's slope weak echoes wander more. Assumption: the "
            "paper's Fig. 7 scatter"),
      field("tdc.lsb_ps", &tdc.lsb_ps, 1e-3, 1e6,
            "fine interpolator LSB (FPGA carry-chain TDC). Assumption"),
      field("tdc.coarse_clock_mhz", &tdc.coarse_clock_mhz, 1e-3, 1e5,
            "coarse counter clock. Assumption"),
      field("tdc.inl_lsb", &tdc.inl_lsb, 0, 1000,
            "peak integral nonlinearity of the interpolator (code-density style table), LSB. "
            "Assumption"),
      field("tdc.code_density_hits", &tdc.code_density_hits, 0, 1e8,
            "firmware code-density calibration: hits histogrammed per fine code (factory); the "
            "table leaves only their counting error. 0: uncorrected (tdc.inl_lsb stays)"),
      field("tdc.laser_sync", &tdc.laser_sync,
            "laser fires on a TDC clock edge (fixed phase: INL stays); false: asynchronous"),
      field("tdc.bin_tempco_ppm_per_c", &tdc.bin_tempco_ppm_per_c, -1e5, 1e5,
            "fine-bin width change per C of the timing board. Assumption"),

      // thermal: delay drift, sensor, warm-up
      field("thermal.delay_tempco_ps_per_c", &th.delay_tempco_ps_per_c, -1e4, 1e4,
            "trigger + receive-chain delay drift per C of the timing board. Assumption"),
      field("thermal.heater_setpoint_c", &th.heater_setpoint_c, -100, 200,
            "timing-board heater setpoint (paper Fig. 8: flat below 16 C). Assumption"),
      field("thermal.heater_loop_gain", &th.heater_loop_gain, 0, 1e6,
            "proportional heater loop gain (board follows 1/(1+gain) below setpoint)"),
      field("thermal.heater_max_rise_c", &th.heater_max_rise_c, 0, 200,
            "most the heater lifts the timing board above the enclosure"),
      field("thermal.self_heating_c", &th.self_heating_c, 0, 100,
            "steady-state internal rise above ambient. Assumption"),
      field("thermal.warmup_time_constant_min", &th.warmup_time_constant_min, 1e-6, 1e4,
            "internal temperature time constant after power-on (thesis: 25-35 min). Assumption"),
      field("thermal.warmup_delay_coeff_mm_per_c", &th.warmup_delay_coeff_mm_per_c, -1000, 1000,
            "extra delay drift while the board warms up. Assumption"),
      field("thermal.sensor_lag_min", &th.sensor_lag_min, 0, 1e4,
            "extra time constant of the enclosure sensor behind the die. Assumption"),
      field_or_off("thermal.sensor_resolution_c", &th.sensor_resolution_c, 1e-6, 10,
                   "temperature sensor LSB (0: continuous)"),
      field("thermal.sensor_noise_c", &th.sensor_noise_c, 0, 10,
            "temperature sensor noise (1 sigma)"),

      // measurement: timing and averaging
      field("measurement.shots", &m.shots, 1, kMaxShots, "shots averaged per output"),
      field("measurement.fixed_delay_ns", &m.fixed_delay_ns, 0, 1e4,
            "trigger-to-emission plus receive-chain delay at the nominal temperature. Assumption"),
      field("measurement.power_on_offset_ps", &m.power_on_offset_ps, 0, 1e6,
            "1 sigma delay offset drawn at each power-on (a run's seed). Assumption"),
      field("measurement.flicker_delay_ps", &m.flicker_delay_ps, 0, 1e6,
            "rms of a slow 1/f delay wander (averaging floor). Assumption"),
      field("measurement.delay_wander_ps", &m.delay_wander_ps, 0, 1e6,
            "rms of a random 1/f delay wander over the output's time (1 ms - 70 min). Assumption: "
            "the paper's Fig. 7 and 9 scatter"),
      field("measurement.stop_gate_ns", &m.stop_gate_ns, 0, 1e6,
            "false-stop rejection: drop stops this far from the median stop (0: off). Assumption"),
      field("measurement.stop_gate_min_share", &m.stop_gate_min_share, 0, 1,
            "no distance when the stop gate keeps less than this share of the stops (false stops "
            "outnumber the echo's; 0: off). Assumption: a majority"),
      field("measurement.window_ns", &m.window_ns, 0.01, 1e5,
            "waveform-mode record length around the echo"),
      field("measurement.sample_period_ps", &m.sample_period_ps, 1e-3, 1e6,
            "waveform-mode sampling period (at most: 6 per receiver pole time constant)"),
      field("measurement.reference_temperature_c", &m.reference_temperature_c, -100, 200,
            "air temperature the device assumes for the speed of light"),

      // scan: beam footprint sampling for ray casting (scan/)
      field("scan.rays_per_beam", &config.scan.rays_per_beam, 1, 4096,
            "sub-rays sampling the beam footprint, equal-area over the disk (1: axis only)"),
      field(
          "scan.crease_angle_deg", &config.scan.crease_angle_deg, 0, 90,
          "sub-ray hits on one primitive meeting at a sharper crease (or a step) are two surfaces"),

      // memory: receiver recovery in a scan sequence (device/echo_memory.hpp)
      field("memory.time_constant_ms", &config.memory.time_constant_ms, 0, 1e6,
            "AC coupling time constant before the comparator: the baseline follows the echo "
            "train, or the loop's square wave (0: DC coupled, no memory)"),
      field("memory.coupling_share", &config.memory.coupling_share, 0, 1,
            "share of the echo train's mean the coupling's baseline takes (1: plain capacitor; 0: "
            "DC coupled)"),

      // oscillator: the self-oscillating loop principle (device/oscillator_loop.hpp)
      field("oscillator.enabled", &config.oscillator.enabled,
            "measuring principle: true = self-oscillating loop (AccuRange), false = pulsed TDC"),
      field("oscillator.loop_delay_ns", &config.oscillator.loop_delay_ns, 0, 1e4,
            "per edge: laser driver turn-on/off, comparator and logic delay"),
      field("oscillator.zero_half_period_ns", &config.oscillator.zero_half_period_ns, 0, 1e4,
            "vendor zero: the loop half period reported as range 0"),
      field("oscillator.count_clock_mhz", &config.oscillator.count_clock_mhz, 1e-3, 1e5,
            "interface board's counting clock (thesis: 80 MHz)"),
      field("oscillator.gate_fraction", &config.oscillator.gate_fraction, 1e-6, 1,
            "share of each output period the period counter is gated on. Assumption"),
      field("oscillator.coupling_duty", &config.oscillator.coupling_duty, 1e-6, 1,
            "AC-coupled receiver baseline as a share of the signal swing (the loop's duty)"),
      field("oscillator.overdrive_jitter_ps_per_neper",
            &config.oscillator.overdrive_jitter_ps_per_neper, 0, 1e6,
            "extra edge jitter per neper of receiver overdrive (erratic in saturation)"),
      field("oscillator.flicker_delay_ps", &config.oscillator.flicker_delay_ps, 0, 1e6,
            "rms of the loop delay's slow wander, drawn per output (averaging floor)"),
      field("oscillator.duty_wander", &config.oscillator.duty_wander, 0, 0.5,
            "rms of the loop duty's unbalance at a laser switch-on (share), settling over the "
            "turn-on transient; the AC-coupled baseline follows it, and the edges' slopes turn "
            "it into time (grows on weak returns)"),
      field("oscillator.chip_bias_mm", &config.oscillator.chip_bias_mm, -1e3, 1e3,
            "range bias of a cold laser chip against a hot one (its turn-on delay), with the "
            "laser gated by the counting window: the mean over a gate depends on its length"),
      field("oscillator.chip_time_constant_us", &config.oscillator.chip_time_constant_us, 0, 1e6,
            "the laser chip's thermal time constant (heats in each gate, cools between)"),
      field("oscillator.comparator_hysteresis_mv", &config.oscillator.comparator_hysteresis_mv, 0,
            1e4,
            "comparator hysteresis: noise near a weak swing's top adds an edge only by "
            "dipping this far below the level"),
  };
}

double field_value(const ConfigField& field) {
  return std::visit(
      [](auto* p) -> double {
        using T = std::remove_pointer_t<decltype(p)>;
        if constexpr (std::is_same_v<T, bool>) {
          return *p ? 1.0 : 0.0;
        } else {
          return static_cast<double>(*p);
        }
      },
      field.value);
}

ranging::TimeToDistance nominal_time_to_distance(const DeviceConfig& config) {
  ranging::TimeToDistance t;
  t.wavelength_nm = config.link.laser.wavelength_nm;
  t.air.temperature_c = config.measurement.reference_temperature_c;
  t.air.pressure_hpa = config.link.environment.pressure_hpa;
  t.air.relative_humidity_pct = config.link.environment.relative_humidity_pct;
  return t;
}

double nominal_light_speed_m_per_ns(const DeviceConfig& config) {
  const ranging::TimeToDistance t = nominal_time_to_distance(config);
  return physics::speed_of_light_in_air_m_per_s(t.wavelength_nm, t.air) * 1e-9;
}

std::vector<std::string> validate(const DeviceConfig& config) {
  DeviceConfig copy = config;  // config_fields binds mutable pointers
  std::vector<std::string> messages;
  for (const auto& f : config_fields(copy)) {
    const double v = field_value(f);
    if (!in_range(f, v)) {
      messages.push_back(f.key + " = " + number_text(v) + " is out of range " + range_text(f));
    }
  }
  // Cross-field checks; each message starts with the key it blames.
  const auto& laser = config.link.laser;
  if (laser.pulse_width_ns > 0 && laser.repetition_hz > 0 &&
      laser.pulse_width_ns * 1e-9 * laser.repetition_hz >= 1.0) {
    messages.push_back("laser.pulse_width_ns = " + number_text(laser.pulse_width_ns) +
                       " is not shorter than the pulse period 1 / laser.repetition_hz");
  }
  if (laser.repetition_hz > 0 && config.discriminator.blanking_ns >= 1e9 / laser.repetition_hz) {
    messages.push_back(
        "discriminator.blanking_ns = " + number_text(config.discriminator.blanking_ns) +
        " is not shorter than the pulse period 1 / laser.repetition_hz");
  }
  const auto& m = config.measurement;
  if (m.window_ns > 0 && m.sample_period_ps > 0 && m.window_ns * 1e3 / m.sample_period_ps > 1e7) {
    messages.push_back("measurement.sample_period_ps = " + number_text(m.sample_period_ps) +
                       " gives more than 1e7 samples per measurement.window_ns");
  }
  // The interpolator's INL table holds one entry per fine bin of a coarse period.
  const auto& tdc = config.tdc;
  if (tdc.lsb_ps > 0 && tdc.coarse_clock_mhz > 0 &&
      1e6 / (tdc.coarse_clock_mhz * tdc.lsb_ps) > 1e7) {
    messages.push_back("tdc.lsb_ps = " + number_text(tdc.lsb_ps) +
                       " with tdc.coarse_clock_mhz = " + number_text(tdc.coarse_clock_mhz) +
                       " gives more than 1e7 interpolator bins per coarse period");
  }
  const auto& osc = config.oscillator;
  if (osc.enabled) {
    // The loop oscillates only if the AC-coupled swing can cross the threshold:
    // the clipped swing above the baseline must exceed it.
    const auto& rx = config.link.receiver;
    if (!(rx.saturation_v * (1.0 - osc.coupling_duty) > config.discriminator.threshold_v)) {
      messages.push_back(
          "oscillator.enabled = true needs receiver.saturation_v x (1 - "
          "oscillator.coupling_duty) above discriminator.threshold_v (the loop "
          "could never oscillate)");
    }
    // The counter's gate must hold loop periods: at least two of the zero-range period.
    if (laser.repetition_hz > 0 && m.shots > 0 &&
        osc.gate_fraction * m.shots / laser.repetition_hz * 1e9 < 4.0 * osc.loop_delay_ns) {
      messages.push_back("oscillator.gate_fraction = " + number_text(osc.gate_fraction) +
                         " with measurement.shots / laser.repetition_hz gates the counter for "
                         "less than two loop periods (oscillator.loop_delay_ns)");
    }
  }
  return messages;
}

DeviceConfig preset(std::string_view name) {
  if (name == "paper") return DeviceConfig{};
  if (name == "accurange") return accurange_preset();
  std::string names;
  for (const auto& n : preset_names()) names += (names.empty() ? "" : ", ") + n;
  throw std::invalid_argument("unknown preset '" + std::string(name) + "' (known: " + names + ")");
}

std::vector<std::string> preset_names() {
  return {"paper", "accurange"};
}

}  // namespace tofkit::device
