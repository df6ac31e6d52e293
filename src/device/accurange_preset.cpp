#include "tofkit/device/accurange_preset.hpp"

namespace tofkit::device {

DeviceConfig accurange_preset() {
  DeviceConfig c;
  c.name = "accurange";

  // ---------------------------------------------------------------- laser
  auto& laser = c.link.laser;
  laser.wavelength_nm = 780.0;  // thesis title: 780 nm diode
  laser.peak_power_w = 0.020;   // thesis title: 20 mW
  // Pulsed core only (oscillator.enabled = false; the loop keeps the laser on
  // for a half period): a gain-switched diode pulse of 0.3 ns. Assumption.
  laser.pulse_width_ns = 0.3;
  laser.repetition_hz = 312500.0;         // thesis: sampling rate = 312,500 / 2^N samples/s
  laser.transmit_efficiency = 0.9;        // Assumption: uncoated collimator + window
  laser.beam_divergence_mrad = 0.8;       // Assumption: with the exit diameter, a 3.0 mm
  laser.exit_beam_diameter_mm = 2.6;      // footprint at 0.5 m (thesis: ~3 mm oval footprint)
  laser.power_temp_coeff_per_c = -0.001;  // Assumption: automatic power control via the
                                          // diode's monitor photodiode leaves 0.1 %/C
  // Thesis: "the first samples after switching on are wrong, then a plateau". In the
  // loop the diode is switched on every half period; just after the laser is turned
  // on its junction is cold, its threshold current low and its turn-on delay short,
  // so the loop runs fast and reads short until the junction heats (tens of ms).
  // The point-by-point scans switch the laser on at every point and average ~1 ms
  // of samples (thesis Section 3: laser on -> N samples -> averaged -> move), so
  // they sit in the transient: the grey chart reads ~1.1 in short (Figs. 4.9 and
  // 4.18 raw, r = 0.9804 T - 0.6732) while Fig. 4.4's continuous acquisitions on
  // one target, past the transient, read 19.64-20.16 in at 20 in. -29 mm (1.14 in)
  // is that difference plus the walk between the light grey of Fig. 4.4 and the
  // chart's six-grey mean.
  laser.turn_on_bias_mm = -29.0;
  laser.turn_on_time_constant_ms = 40.0;

  // ------------------------------------------------------------- receiver
  auto& rx = c.link.receiver;
  rx.aperture_diameter_mm = 63.5;  // 2.5 in collecting lens (AccuRange 3000 class)
  rx.optics_efficiency = 0.5;      // Assumption: lens, filter, coaxial mirror obstruction
  rx.field_of_view_rad = 0.005;    // Assumption: 5 mrad field stop (short-range unit)
  rx.filter_bandwidth_nm = 10.0;   // Assumption: 10 nm interference filter at 780 nm
  // Assumption: a 360 MHz receiver (pole 0.44 ns). In the loop, the walk between
  // the weakest and the strongest returns is a fraction of that pole (the AC-coupled
  // step response crossing a fixed threshold), so it sets the spread across greys;
  // with the duty wander's per-point scatter (oscillator.duty_wander) it makes the
  // thesis's Fig. 4.18 raw variance, 0.177 in^2 over the six greys at 19 in.
  rx.bandwidth_mhz = 360.0;
  rx.responsivity_a_per_w = 0.5;   // Si at 780 nm (about 0.5 A/W unity gain)
  rx.apd_gain = 30.0;              // Assumption: low gain, echoes are strong at < 1 m
  rx.excess_noise_factor = 3.0;    // Si APD at M = 30 (k about 0.02-0.05)
  rx.nep_w_per_sqrt_hz = 2.0e-14;  // same amplifier class as the paper's (Table 1)
  rx.dark_current_na = 0.5;        // typical Si APD, as the paper preset
  // Assumption: sets the echo scale. The loop sees a step of optical power (the
  // laser stays on), so the full transimpedance gain applies: a grey-255 (black,
  // thesis numbering) chart (rho 0.03) at 19 in gives about 0.19 V, 12 times the
  // threshold, so every grey oscillates over the thesis's 10-30 in reflectance
  // study; with the threshold it places the walk between the greys (Fig. 4.18's
  // raw variance) and the intensity at which the duty wander matters.
  rx.transimpedance_kohm = 10.8;
  // Assumption: clips above 1 V, so grey 0 (white, rho 0.93) saturates out to 22 in
  // and grey 51 (rho 0.58) inside about 20 in (thesis: "very bright targets saturate";
  // in the loop a saturated return rises ever faster while it falls from the clip
  // level, so it reads short).
  rx.saturation_v = 1.0;
  // Assumption: the intensity output taps the linear transimpedance stage ahead
  // of the comparator's limiting gain, linear to 4 V: grey 0 (white, ~5.8 V at
  // 19 in) reads the clip over the thesis's 15-22 in working range and grey 51
  // inside ~20 in (the thesis's 'saturating' bright greys); the other greys stay
  // distinct. (An 8 V clip moves the Fig. 4.18 rows by < 0.01 in.)
  rx.amplitude_clip_v = 4.0;
  rx.recovery_ns_per_neper = 2.0;          // Assumption, as the paper preset
  rx.amplitude_noise_rel = 0.01;           // Assumption: 1 % peak-detector noise per output
  rx.nominal_temperature_c = 25.0;         // gain specified at room temperature
  rx.breakdown_temp_coeff_v_per_c = 0.65;  // Si APD (DESIGN.md)
  rx.bias_margin_v = 10.0;                 // Assumption, as the paper preset
  rx.bias_temperature_compensated = true;  // Assumption: the temperature sensor in the unit
                                           // (thesis) tracks the APD bias

  // ---------------------------------------------------------- environment
  auto& env = c.link.environment;
  env.solar_irradiance_w_per_m2_um = 0.0;  // thesis: indoor laboratory, no sunlight
  env.sun_angle_deg = 0.0;
  env.sky_radiance_w_per_m2_sr_um = 0.0;
  env.atmospheric_transmission = 1.0;  // < 1 m of laboratory air
  env.pressure_hpa = 1013.25;
  env.relative_humidity_pct = 50.0;

  // ----------------------------------------------------- discriminator, TDC
  // Assumption: 15 mV, far above the amplifier's noise (0.06 mV rms at 360 MHz
  // through 10.8 kOhm): no false alarms. The loop stops when the return's swing
  // above the AC-coupled baseline no longer reaches it: on white beyond ~5 m,
  // black beyond ~1.5 m (the thesis measures at 10-30 in). The walk between the
  // chart's greys hardly depends on it (1 mV moves the Fig. 4.18 rows by < 0.02 in).
  c.discriminator.threshold_v = 0.015;
  c.tdc.coarse_clock_mhz = 80.0;  // thesis: 80 MHz timing clock
  c.tdc.lsb_ps = 25.0;            // Assumption: carry-chain interpolator, 3.7 mm of
                                  // range per code; with the laser firing asynchronously
                                  // 8-shot outputs spread < 1 mm (thesis Fig. 4.4)
  c.tdc.inl_lsb = 0.5;            // Assumption, as the paper preset

  // -------------------------------------------------------------- thermal
  // Thesis Section 4.4: range decreases 0.25-0.60 in per 10 C. A delay tempco
  // of -6.7 ps/C of round trip (-1.0 mm/C, -0.39 in per 10 C) does that; the
  // unit has no heater (it works in a laboratory), so the drift is linear.
  c.thermal.delay_tempco_ps_per_c = -6.67;
  c.thermal.heater_setpoint_c = -100.0;  // no heater
  c.thermal.heater_loop_gain = 0.0;
  c.link.receiver.bias_tracking_error_v_per_c = 0.0;  // Assumption: not characterised by the
                                                      // thesis; drift is delay-only
  c.link.receiver.axis_offset_mm = 0.0;               // coaxial optics (mirror in the 2.5 in lens)
  c.tdc.laser_sync = false;        // the loop's period is counted, not fired from the clock
  c.thermal.self_heating_c = 8.0;  // Assumption: enclosed electronics
  // Thesis: 25-35 min warm-up before the range is stable. With tau = 7.75 min the
  // warm-up drift (8 C x (2.5 - 1.0) mm/C = 12 mm = 0.47 in) falls below 0.25 mm
  // after ln(48) tau = 30 min.
  c.thermal.warmup_time_constant_min = 7.75;
  // Assumption: the timing electronics lag the sensor and drift faster than the
  // settled coefficient while they warm, so the range inflates during warm-up
  // (thesis: "range inflates while electronics warm up").
  c.thermal.warmup_delay_coeff_mm_per_c = -2.5;
  c.thermal.sensor_resolution_c = 0.0625;  // 12-bit digital sensor
  c.thermal.sensor_noise_c = 0.05;         // Assumption

  // ---------------------------------------------------------- measurement
  // Assumption: no separate power-on offset or 1/f wander; the thesis explains
  // its scan-to-scan residual by temperature not being constant between scans
  // (Section 4.4), which its protocol models.
  c.measurement.power_on_offset_ps = 0.0;
  c.measurement.flicker_delay_ps = 0.0;
  // The paper device's wanders (its Figs. 7 and 9 scatter) are not the
  // loop's: its slow wander is oscillator.duty_wander.
  c.measurement.delay_wander_ps = 0.0;
  c.discriminator.level_wander_mv = 0.0;
  c.measurement.shots = 16;  // N = 4: 312,500 / 16 = 19,531 samples/s (thesis Fig. 4.4)
  // Pulsed core only (the loop's zero is oscillator.zero_half_period_ns): a
  // chain delay that zeroes a mid-grey target at 20 in on the pulsed variant.
  c.measurement.fixed_delay_ns = 0.077;
  c.measurement.window_ns = 30.0;
  c.measurement.sample_period_ps = 50.0;  // waveform mode: 20 samples per ns (fast edge)
  c.measurement.reference_temperature_c = 20.0;

  // --------------------------------------------------------------- memory
  // Thesis Fig. 4.28 (in its line-scan section): on black after mid grey the
  // range swings erratically (15.65-23.91 in) over half the black area.
  // Assumption: the loop's AC coupling (its baseline at coupling_duty of the
  // square wave's swing) recovers with a 30 ms time constant (a ~5 Hz corner):
  // after a stronger return the comparator's level stays high, a weak return
  // reads long or loses lock (device/echo_memory.hpp, device/loop_window.hpp).
  // At the line scans' 0.15 m/s that is about 5 mm of a 2 in black area. Set
  // for a 6-7 in swing when black's swing was 4.7 times the threshold; with
  // this receiver (12.6 times) the lock margin is wider and the swing is
  // 3.3-4.5 in for any time constant from 20 to 80 ms (3.8-6.9 in with the
  // comparator near the top, oscillator.comparator_hysteresis_mv). The same state gives
  // the mirror's edge spikes (Figs. 3.4-3.5; here 2-6 mm against ~15 mm) and,
  // held out, part of the line and checkerboard scans' larger raw spread
  // (Figs. 4.23, 4.27).
  c.memory.time_constant_ms = 30.0;

  // ----------------------------------------------------------- the loop
  // Thesis Section 3.1, Fig. 3.2: the AccuRange 3000 is a self-oscillating loop
  // (device/oscillator_loop.hpp): the laser stays on until the detector sees the
  // return, then off until the return has gone. Period ~20 ns at zero range and
  // 280 ns at 20 m (thesis); here 16.5 ns and 283 ns.
  auto& osc = c.oscillator;
  osc.enabled = true;
  // Assumption: laser driver turn-on/off, comparator and logic per edge. With the
  // receiver's latency (~3 ns at 0.5 m, including the round trip) it makes the
  // thesis's ~20 ns period at zero range and 280 ns at 20 m (slope 4/c: two round
  // trips per period).
  osc.loop_delay_ns = 8.0;
  // Thesis Section 4.4: the unit reads about an inch short over the grey chart:
  // its reflectance fit r = 0.9804 T - 0.6732 in gives 1.065 in short at 20 in.
  // The vendor zero (the half period read as range 0) is set so that the mean over
  // the six greys at 20 in, 20 C, warmed up and in the turn-on transient of a
  // point-by-point scan (laser.turn_on_bias_mm), reads about 1.04 in short, while
  // Fig. 4.4's light grey at 20 in, past the transient, reads 19.5-19.9 in (the
  // laser chip's heating in the board's gate, oscillator.chip_*; thesis:
  // 19.64-19.90 in from 19,531 samples/s down).
  osc.zero_half_period_ns = 8.167;
  osc.count_clock_mhz = 80.0;  // thesis: 80 MHz timing clock on the interface board
  // Assumption: the board counts during half of each output period (and transfers
  // during the other half). Then one count is c/4 x 12.5 ns x T / gate = 1.71 mm at
  // 39,062.5 samples/s at 20 in (T = 23 ns): thesis Fig. 4.4, 1.756 mm, halving with
  // each halving of the sampling rate.
  osc.gate_fraction = 0.5;
  osc.coupling_duty = 0.5;  // AC coupling of the loop's ~50 % duty square wave
  // Assumption: an overdriven receiver recovers with a storage-time jitter that
  // grows with the overdrive (thesis Section 4.4: saturation makes the range erratic).
  osc.overdrive_jitter_ps_per_neper = 50.0;
  // Assumption: slow wander of the loop delay, 2.2 ps (0.33 mm of range) per output,
  // which no averaging removes: thesis Fig. 4.4's variance floor, 1.75e-4 in^2 on
  // average over 152-4883 samples/s, where the 80 MHz count's quantization no
  // longer dominates.
  osc.flicker_delay_ps = 2.2;
  // Assumption: at each switch-on of the laser its driver's turn-on and turn-off
  // delays start apart by a share of the period (13 % rms, one draw per switch-on)
  // and settle together as the junction heats (laser.turn_on_time_constant_ms),
  // moving the AC-coupled baseline: each point of a point-by-point chart (the
  // laser switched on at every point) gets its own error, largest on the weakest
  // and the saturated returns, that no surface over (range, intensity) can remove.
  // Thesis Fig. 4.18: its corrections leave 0.036-0.10 in^2 of variance at 19 in,
  // although a point's own sample noise is only ~1e-4 in^2 (Fig. 4.4), whose
  // continuous acquisitions on one spot (past the transient) show none of it.
  // (Not the chart's texture: the loop's walk is 0.1-0.17 in per neper of
  // reflectance, Fig. 4.18's greys at 19 in, so a 0.25 in point scatter would need
  // the reflectance over a 3 mm footprint to vary by e^1.5; paper and halftone
  // vary by a few %, and speckle through a 63.5 mm aperture averages ~10^5 grains.)
  osc.duty_wander = 0.13;
  // Assumption: the board gates the laser with its counting window (on while it
  // counts, off while it transfers and reads the ambient channel), so the laser
  // chip heats in each gate and cools between with its thermal time constant; a
  // cold chip's lower threshold current shortens the turn-on delay and the loop
  // reads short. Short gates keep the chip half warm, long ones let it reach hot
  // early: the mean rises as the sampling rate falls. Thesis Fig. 4.4: 19.64 in at
  // 4883 samples/s to 19.90 in at 153 samples/s; the periodic heating's closed
  // form (OscillatorLoop::chip_cold_share) fitted to its eight settings from
  // 19,531 samples/s down gives tau = 0.21 ms (a chip's, against the package's
  // 40 ms of laser.turn_on_time_constant_ms) and -14 mm cold against hot, within
  // 0.017 in rms. (A count offset, bias ~ resolution, would put 19,531 samples/s
  // 0.23 in above 9,766; the thesis has 0.045 in. Its 20.16 in at 39 kHz has no
  // cause here.)
  osc.chip_bias_mm = -14.0;
  osc.chip_time_constant_us = 210.0;
  // Assumption: the comparator's hysteresis. Where a baseline left high by a
  // stronger return brings the level within a few noise sigmas of a weak swing's
  // top, the noise adds edges (reads short) or delays rises (reads long)
  // (near_top_edges, device/oscillator_loop.hpp); the hysteresis sets how deep
  // a dip must go to add an edge. Thesis Fig. 4.28 (black after mid grey at
  // 19 in: erratic, at most 23.91 in): with 10 mV (~3 noise sigmas on black) the
  // loop reads at most 23.6-24.5 in after re-locking (seeds 1-3, 2022; one seed of
  // five 26.7 in). Without hysteresis the chatter reads negative ranges; with
  // 5-8 mV both short and long readings appear, down to 14-17 in and below.
  osc.comparator_hysteresis_mv = 10.0;
  return c;
}

}  // namespace tofkit::device
