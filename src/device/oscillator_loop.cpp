#include "tofkit/device/oscillator_loop.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <utility>
#include <vector>

#include "random_draws.hpp"
#include "tofkit/device/thermal.hpp"
#include "tofkit/physics/air.hpp"
#include "tofkit/physics/constants.hpp"
#include "tofkit/physics/link_budget.hpp"

namespace tofkit::device {
namespace {

using physics::kPi;
// Salt that keeps the loop's draws apart from the pulsed core's blocks.
constexpr std::uint32_t kLoopBlock = 0x4F534331u;  // "OSC1"
// The duty a switch-on starts with is drawn once per second of session time:
// a point-by-point scan switches the laser on at every point (seconds apart),
// and the outputs of one switch-on share its draw.
constexpr double kDutyWanderCorrelationS = 1.0;

/// The pulsed core's counter-based draws (Random123 Philox4x32-10).
std::array<std::uint32_t, 4> philox(std::uint64_t seed, std::uint64_t stream, std::uint32_t index,
                                    std::uint32_t block) {
  return detail::CounterRng(seed).draw(stream, index, block);
}
using detail::normal_pair;
using detail::unit_open;

/// One surface's return: a step of amplitude_v arriving delay_ns after the laser edge.
struct Step {
  double delay_ns;
  double amplitude_v;
};

/// First time the single-pole state x (x' = (u - x) / tau, clipped at clip_v)
/// crosses `level`, for an input that is piecewise constant between the steps'
/// delays. Rising: starts at x0 below the level, input = sum of the steps that
/// have arrived. Falling: starts at x0 above it, input = sum of those still to go.
/// Returns {time, input at the crossing}; time < 0 if it never crosses.
std::pair<double, double> crossing(const std::vector<Step>& steps, bool rising, double x0,
                                   double level, double clip_v, double tau) {
  double total = 0;
  for (const auto& s : steps) total += s.amplitude_v;
  double x = x0, t = 0, input = rising ? 0.0 : total;
  for (std::size_t k = 0; k <= steps.size(); ++k) {
    const double t_end = k < steps.size() ? steps[k].delay_ns : 1e300;
    const double span = t_end - t;
    if (span > 0) {
      const bool can = rising ? (input > level && x < level) : (input < level && x > level);
      if (can) {
        const double dt = tau * std::log((input - x) / (input - level));
        if (dt <= span) return {t + dt, input};
      }
      if (k == steps.size()) break;
      x = std::min(input + (x - input) * std::exp(-span / tau), clip_v);
      t = t_end;
    }
    input += rising ? steps[k].amplitude_v : -steps[k].amplitude_v;
  }
  return {-1.0, input};
}

/// The laser's turn-on transient exp(-t / tau) averaged over an output window
/// of window_ms starting t0_ms after the switch-on:
/// exp(-t0 / tau) (1 - exp(-W / tau)) / (W / tau); 0 past 30 tau.
double turn_on_window_mean(double t0_ms, double window_ms, double tau_ms) {
  if (!(t0_ms < 30.0 * tau_ms)) return 0.0;
  const double x = window_ms / tau_ms;
  return x < 1e-9 ? std::exp(-t0_ms / tau_ms) : std::exp(-t0_ms / tau_ms) * -std::expm1(-x) / x;
}

}  // namespace

NearTopEdges near_top_edges(double margin_v, double noise_v, double bandwidth_mhz, double high_ns,
                            double hysteresis_v) {
  NearTopEdges e;
  if (!(noise_v > 0) || !(bandwidth_mhz > 0)) return e;
  const double z = margin_v / noise_v;
  if (z >= kNearTopSigmas) return e;
  if (!(z > -kNearTopSigmas)) {  // the top far below the level: no edges at all
    e.missed_wait_ns = std::numeric_limits<double>::infinity();
    return e;
  }
  // Rice: a band-limited Gaussian noise of rms sigma crosses the level u (in
  // either direction) at B / sqrt(3) exp(-u^2 / 2 sigma^2) for an ideal low pass
  // of bandwidth B (here per ns).
  const double rice_per_ns = bandwidth_mhz * 1e-3 / std::sqrt(3.0);
  const double rate_per_ns = rice_per_ns * std::exp(-0.5 * z * z);
  const double below = 0.5 * std::erfc(z / std::sqrt(2.0));  // Phi(-z)
  // A chatter edge needs a dip below level - hysteresis: margin + hysteresis
  // under the top.
  const double zh = (margin_v + std::max(hysteresis_v, 0.0)) / noise_v;
  e.extra_edges_per_period = std::max(high_ns, 0.0) * rice_per_ns * std::exp(-0.5 * zh * zh);
  e.missed_wait_ns = below * below / rate_per_ns;
  return e;
}

OscillatorLoop::OscillatorLoop(DeviceConfig config) : config_(std::move(config)) {
  c_nominal_m_per_ns_ = nominal_light_speed_m_per_ns(config_);
  tau_ns_ = 1e3 / (2.0 * kPi * config_.link.receiver.bandwidth_mhz);
}

double OscillatorLoop::tof_to_distance_m(double tof_ns) const {
  return 0.5 * tof_ns * c_nominal_m_per_ns_;
}

LoopState OscillatorLoop::state(const Target& target, const Conditions& cond,
                                double duty_offset) const {
  const auto& link = config_.link;
  const auto& rx = link.receiver;
  const auto& th = config_.thermal;
  const auto& osc = config_.oscillator;
  LoopState s;
  // Temperatures, APD gain and laser power as in the pulsed core.
  const double internal_c = internal_temperature_c(th, cond.ambient_c, cond.minutes_since_power_on);
  const double board_c = timing_board_temperature_c(th, internal_c);
  const double gain = physics::apd_gain_at(rx, board_c);
  const double power_scale = std::max(
      0.0, 1.0 + link.laser.power_temp_coeff_per_c * (internal_c - rx.nominal_temperature_c));
  const double volts_per_watt =
      rx.responsivity_a_per_w * gain * rx.transimpedance_kohm * 1e3 * power_scale;
  physics::AirConditions air{cond.ambient_c, link.environment.pressure_hpa,
                             link.environment.relative_humidity_pct};
  const double c_m_per_ns =
      physics::speed_of_light_in_air_m_per_s(link.laser.wavelength_nm, air) * 1e-9;

  // The return: a step of optical power per surface (extended Lambertian target,
  // paper Eq. 6, times the footprint share and the biaxial overlap), spread over
  // the depth of a tilted footprint like the pulsed core.
  std::vector<Step> steps;
  double background_w = 0;
  for (const auto& surf : target.surfaces) {
    if (surf.fraction <= 0.0 || surf.reflectance <= 0.0 || !(surf.cos_incidence > 0.0)) continue;
    const double cos_phi = std::min(surf.cos_incidence, 1.0);
    background_w +=
        surf.fraction * physics::background_power_cos_w(
                            link, surf.reflectance, std::max(cos_phi, detail::kBackgroundCosFloor));
    const double power_w =
        surf.fraction * physics::overlap_fraction(link.laser, rx, surf.distance_m) *
        physics::field_stop_share(link.laser, rx, surf.distance_m) *
        physics::received_power_extended_cos_w(link, surf.distance_m, surf.reflectance, cos_phi);
    if (power_w <= 0.0) continue;
    const double amplitude = power_w * volts_per_watt;
    const double delay = 2.0 * surf.distance_m / c_m_per_ns;
    const double half_depth_m = 0.5 * physics::footprint_diameter_m(link.laser, surf.distance_m) *
                                std::sqrt(std::max(1.0 - cos_phi * cos_phi, 0.0)) / cos_phi;
    if (half_depth_m * 2.0 / c_m_per_ns < 1e-4) {
      steps.push_back({delay, amplitude});
      continue;
    }
    const auto& nodes = detail::footprint_nodes();
    for (std::size_t k = 0; k < nodes.u.size(); ++k) {
      steps.push_back(
          {delay + 2.0 * nodes.u[k] * half_depth_m / c_m_per_ns, amplitude * nodes.w[k]});
    }
  }
  std::sort(steps.begin(), steps.end(),
            [](const Step& a, const Step& b) { return a.delay_ns < b.delay_ns; });
  for (const auto& st : steps) s.amplitude_v += st.amplitude_v;
  if (steps.empty()) return s;

  // AC coupling: on the loop's square wave the baseline sits at the duty share
  // of the (clipped) swing; the comparator fires `threshold` above it.
  const double threshold = config_.discriminator.threshold_v;
  // The receiver limits softly (tanh): linear for weak returns, saturation_v for
  // strong ones, without a kink at the onset of saturation.
  s.swing_v = rx.saturation_v * std::tanh(s.amplitude_v / rx.saturation_v);
  s.saturated = s.amplitude_v > rx.saturation_v;
  // In a scan the coupling may not have settled on this target yet
  // (device/echo_memory.hpp): its unrecovered baseline moves the level too.
  const double level =
      (osc.coupling_duty + duty_offset) * s.swing_v + threshold + cond.baseline_offset_v;
  if (!(s.swing_v > level)) return s;  // too weak: the loop cannot oscillate
  const auto on = crossing(steps, true, 0.0, level, rx.saturation_v, tau_ns_);
  // The falling edge starts from the limited swing; while returns are still
  // arriving the limiter holds the state there.
  const auto off = crossing(steps, false, s.swing_v, level, s.swing_v, tau_ns_);
  if (on.first < 0 || off.first < 0) return s;
  s.oscillates = true;
  s.on_detect_ns = on.first;
  s.off_detect_ns = off.first;

  // Thermal drift of the loop's delays (round-trip equivalent, as the pulsed
  // core): the board's delay tempco and the unseen warm-up gradient.
  const double board_dt = board_c - rx.nominal_temperature_c;
  const double warmup_mm = warmup_drift_mm(th, cond.ambient_c, cond.minutes_since_power_on);
  const double thermal_ns =
      th.delay_tempco_ps_per_c * 1e-3 * board_dt + 2.0 * warmup_mm * 1e-3 / c_nominal_m_per_ns_;
  s.period_ns = s.on_detect_ns + s.off_detect_ns + 2.0 * osc.loop_delay_ns + 2.0 * thermal_ns;
  s.comparator_high_ns = osc.loop_delay_ns + s.off_detect_ns;

  // Edge jitter: receiver noise (paper Eq. 8 terms at the crossing level) over
  // the slope there; an overdriven receiver also recovers erratically.
  const double signal_w = level / volts_per_watt;
  const double noise_a = physics::noise_currents(rx, signal_w, background_w, gain).total_a;
  s.noise_v = noise_a * rx.transimpedance_kohm * 1e3 * power_scale;
  s.rise_slope_v_per_ns = (on.second - level) / tau_ns_;
  const double fall_slope = (level - off.second) / tau_ns_;
  s.fall_slope_v_per_ns = fall_slope;
  const double sigma_on = s.noise_v / s.rise_slope_v_per_ns;
  const double sigma_off = s.noise_v / fall_slope;
  const double overdrive = s.saturated ? osc.overdrive_jitter_ps_per_neper * 1e-3 *
                                             std::log(s.amplitude_v / rx.saturation_v)
                                       : 0.0;
  s.period_jitter_ns =
      std::sqrt(sigma_on * sigma_on + sigma_off * sigma_off + overdrive * overdrive);
  return s;
}

EchoShape OscillatorLoop::echo(const Target& target, const Conditions& conditions) const {
  const auto s = state(target, conditions);
  EchoShape e;
  e.peak_v = s.amplitude_v;
  e.saturated = s.saturated;
  e.detected = s.oscillates;
  e.noise_at_rise_v = s.noise_v;
  if (!s.oscillates) return e;
  e.rise_crossing_ns = s.on_detect_ns;
  e.fall_crossing_ns = s.on_detect_ns + s.comparator_high_ns;
  e.rise_slope_v_per_ns = s.rise_slope_v_per_ns;
  return e;
}

Shot OscillatorLoop::shoot(const Target& target, const Conditions& conditions, std::uint64_t seed,
                           std::uint64_t stream, std::uint32_t shot) const {
  const auto s = state(target, conditions);
  Shot out;
  if (!s.oscillates) return out;
  const auto r = philox(seed, stream, shot, kLoopBlock + 2);
  const double period = s.period_ns + s.period_jitter_ns * normal_pair(r[0], r[1])[0];
  out.echo = true;
  out.tof_ns = 0.5 * period - config_.oscillator.zero_half_period_ns;
  out.pulse_width_ns = s.comparator_high_ns;
  return out;
}

double OscillatorLoop::resolution_m(const Target& target, const Conditions& conditions,
                                    int shots) const {
  const auto s = state(target, conditions);
  if (!s.oscillates) return ranging::kNaN;
  const int n = shots > 0 ? shots : config_.measurement.shots;
  const double gate_ns =
      config_.oscillator.gate_fraction * n / config_.link.laser.repetition_hz * 1e9;
  const double clock_ns = 1e3 / config_.oscillator.count_clock_mhz;
  // One count moves the mean period by t_clk / M, M = gate / T periods; range = c/2 x T/2.
  return 0.25 * c_nominal_m_per_ns_ * clock_ns * s.period_ns / gate_ns;
}

double OscillatorLoop::chip_cold_share(double gate_ms, double off_ms, double tau_ms) {
  if (!(tau_ms > 0) || !(gate_ms > 0)) return 0.5;
  const double a = gate_ms / tau_ms, b = std::max(off_ms, 0.0) / tau_ms;
  // Heat share h at the gate's start in the periodic state: heating
  // h -> 1 - (1 - h) e^-a over the gate, cooling h -> h e^-b over the pause.
  const double ea = -std::expm1(-a);  // 1 - e^-a
  const double denominator = -std::expm1(-a - b);
  const double h0 = denominator > 0 ? ea * std::exp(-b) / denominator : 0.0;
  // The cold share 1 - h decays as (1 - h0) e^-t/tau over the gate: its mean.
  return (1.0 - h0) * (a < 1e-9 ? 1.0 : ea / a);
}

double OscillatorLoop::duty_offset(const Conditions& cond, std::uint64_t seed,
                                   double window_ms) const {
  const double wander = config_.oscillator.duty_wander;
  const auto& laser = config_.link.laser;
  const double tau = laser.turn_on_time_constant_ms;
  if (!(wander > 0) || !(tau > 0)) return 0.0;
  // A switch-on's unbalance settles as the junction heats (the laser's turn-on
  // time constant): past the transient the loop runs at its settled duty, so a
  // continuous acquisition (thesis Fig. 4.4) shows none of it.
  const double settle =
      turn_on_window_mean(std::max(cond.ms_since_laser_on, 0.0), std::max(window_ms, 0.0), tau);
  if (settle == 0.0) return 0.0;
  // One draw per switch-on (per second of the session, the run's seed fixes them).
  const double bucket = std::floor(cond.session_time_s / kDutyWanderCorrelationS);
  const auto p = philox(seed, static_cast<std::uint64_t>(std::max(bucket, 0.0)), 0, kLoopBlock + 3);
  // The delays' asymmetry has a finite range: the draw stops at 2.5 rms.
  return wander * std::clamp(normal_pair(p[0], p[1])[0], -2.5, 2.5) * settle;
}

ranging::RawMeasurement OscillatorLoop::measure(const Target& target, const Conditions& cond,
                                                std::uint64_t seed, std::uint64_t stream, int shots,
                                                int gate_shots) const {
  const auto& cfg = config_;
  const auto& osc = cfg.oscillator;
  const auto& laser = cfg.link.laser;
  const auto& th = cfg.thermal;
  const int n = shots > 0 ? shots : cfg.measurement.shots;
  const double window_ms = 1e3 * n / laser.repetition_hz;
  const double gate_ns = osc.gate_fraction * window_ms * 1e6;
  const auto r1 = philox(seed, stream, 0, kLoopBlock);
  const auto r2 = philox(seed, stream, 0, kLoopBlock + 1);
  const auto z1 = normal_pair(r1[2], r1[3]);
  const auto z2 = normal_pair(r2[0], r2[1]);
  // The duty this switch-on started with (oscillator.duty_wander), settling over
  // the laser's turn-on transient, moves the AC-coupled baseline, so the
  // comparator's level, on both edges: the rise comes later by about
  // dv / rise slope, the fall earlier by dv / fall slope (its mean over the
  // window, as the turn-on bias below).
  const auto s = state(target, cond, duty_offset(cond, seed, window_ms));

  ranging::RawMeasurement out;
  const double internal_c = sensor_temperature_c(th, cond.ambient_c, cond.minutes_since_power_on);
  out.temperature_c = sensor_reading_c(th, internal_c, z2[0]);
  if (cond.ms_since_laser_on < 5.0 * laser.turn_on_time_constant_ms)
    out.flags |= ranging::kRawTurnOnTransient;
  if (cond.minutes_since_power_on < 4.0 * th.warmup_time_constant_min)
    out.flags |= ranging::kRawWarmingUp;
  if (!s.oscillates) {
    out.flags |= ranging::kRawNoEcho;
    return out;
  }
  // Laser turn-on transient (laser.turn_on_bias_mm, either sign: the diode's
  // emission delay while its junction heats), averaged over the window:
  // b tau / W exp(-t0 / tau) (1 - exp(-W / tau)), as extra round trip.
  double turn_on_ns = 0;
  if (laser.turn_on_bias_mm != 0 && laser.turn_on_time_constant_ms > 0) {
    const double mean =
        turn_on_window_mean(cond.ms_since_laser_on, window_ms, laser.turn_on_time_constant_ms);
    turn_on_ns = 2.0 * laser.turn_on_bias_mm * mean * 1e-3 / c_nominal_m_per_ns_;
  }
  // The laser gated by the counting window: the chip's cold share over the gate
  // shortens the turn-on delay (oscillator.chip_bias_mm, as extra round trip).
  // An output that averages several of the board's samples (a point of the
  // thesis's chart: 20 samples) is counted here as one gate of all its shots.
  if (osc.chip_bias_mm != 0 && osc.chip_time_constant_us > 0) {
    const double output_ms = gate_shots > 0 ? 1e3 * gate_shots / laser.repetition_hz : window_ms;
    const double share =
        chip_cold_share(osc.gate_fraction * output_ms, (1.0 - osc.gate_fraction) * output_ms,
                        osc.chip_time_constant_us * 1e-3);
    turn_on_ns += 2.0 * osc.chip_bias_mm * share * 1e-3 / c_nominal_m_per_ns_;
  }
  // The loop delay's slow wander (1/f: its mean over a window hardly averages).
  const double period = s.period_ns + 2.0 * (turn_on_ns + osc.flicker_delay_ps * 1e-3 * z2[1]);
  // Reciprocal counting: the first loop edge falls a uniform share of a period
  // into the gate; M whole periods follow inside it; the clock (asynchronous to
  // the loop) is counted from that edge to the M-th one.
  const double first_edge = unit_open(r1[0]) * period;
  const double whole = std::floor((gate_ns - first_edge) / period);
  if (whole < 1) {
    out.flags |= ranging::kRawNoEcho;
    return out;
  }
  // Each period's jitter is independent: the span of M periods has sqrt(M) sigma_T.
  const double span_ns = whole * period + std::sqrt(whole) * s.period_jitter_ns * z1[0];
  const double clock_ns = 1e3 / osc.count_clock_mhz;
  const double counts = std::floor(unit_open(r1[1]) + span_ns / clock_ns);
  const double mean_period = counts * clock_ns / whole;
  out.tof_ns = 0.5 * mean_period - osc.zero_half_period_ns;
  out.distance_raw_m = tof_to_distance_m(out.tof_ns);
  out.pulse_width_ns = s.comparator_high_ns;
  out.shots_valid = static_cast<std::uint32_t>(n);
  // The intensity output: a peak detector on the linear stage (clips at amplitude_clip_v)
  // behind the loop's AC coupling. It sees the return's swing above the coupling's
  // baseline: settled, (1 - coupling_duty) of the step, which the vendor's scale reads
  // as the step itself. In a scan a baseline left high by a stronger return
  // (conditions.baseline_offset_v, device/echo_memory.hpp) lowers it by
  // offset / (1 - coupling_duty), so a pixel the memory disturbs also reads a lower
  // intensity (thesis Fig. 4.23: a surface over range and intensity removes most of
  // the line scans' extra error). While the loop is locked the swing above the
  // baseline exceeds the threshold, so the reading stays above threshold / (1 - duty).
  const auto& rx = cfg.link.receiver;
  double peak = std::min(s.amplitude_v, rx.amplitude_clip_v);
  if (cond.baseline_offset_v != 0.0) {
    const double share = 1.0 - osc.coupling_duty;
    peak = std::min(
        std::max(peak - cond.baseline_offset_v / share, cfg.discriminator.threshold_v / share),
        rx.amplitude_clip_v);
  }
  out.amplitude = std::min(peak * (1.0 + rx.amplitude_noise_rel * z1[1] / std::sqrt(double(n))),
                           rx.amplitude_clip_v);
  if (s.saturated) out.flags |= ranging::kRawSaturated;
  return out;
}

}  // namespace tofkit::device
