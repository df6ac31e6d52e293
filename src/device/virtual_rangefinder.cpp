#include "tofkit/device/virtual_rangefinder.hpp"

#include <Random123/philox.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <stdexcept>
#include <string>
#include <vector>

#include "tofkit/device/oscillator_loop.hpp"
#include "tofkit/device/tdc.hpp"
#include "tofkit/device/thermal.hpp"
#include "tofkit/physics/air.hpp"
#include "tofkit/physics/constants.hpp"
#include "tofkit/physics/pulse_template.hpp"

namespace tofkit::device {
namespace {

using physics::kPi;
constexpr std::size_t kLevels = 129;       // entries of the level -> crossing-time tables
constexpr double kLevelSpanSigma = 6.0;    // the tables cover threshold +- 6 sigma
constexpr double kCompositeStepNs = 0.01;  // grid of the noise-free composite echo
constexpr std::uint32_t kMeasurementCounter = 0xFFFFFFFFu;  // per-measurement draws
constexpr int kFootprintNodes = 5;  // Gauss-Chebyshev nodes across a tilted footprint
constexpr std::uint64_t kPowerOnStream = ~std::uint64_t{0};  // per-run (power-on) draws
constexpr int kFlickerOctaves = 8;  // 1/f delay wander: octaves from kFlickerLowestHz
constexpr double kFlickerLowestHz = 1e-3;
constexpr double kSyncStartPhase = 0.37;  // laser_sync: the start's fixed place in a coarse period

/// Counter-based random numbers (Random123 Philox4x32-10): the draw for
/// (seed, stream, shot, block) is fixed whatever thread computes it.
class CounterRng {
 public:
  explicit CounterRng(std::uint64_t seed)
      : key_{{static_cast<std::uint32_t>(seed), static_cast<std::uint32_t>(seed >> 32)}} {}
  [[nodiscard]] std::array<std::uint32_t, 4> draw(std::uint64_t stream, std::uint32_t shot,
                                                  std::uint32_t block) const {
    const r123::Philox4x32::ctr_type ctr{{shot, block, static_cast<std::uint32_t>(stream),
                                          static_cast<std::uint32_t>(stream >> 32)}};
    const auto r = r123::Philox4x32{}(ctr, key_);
    return {r[0], r[1], r[2], r[3]};
  }

 private:
  r123::Philox4x32::key_type key_;
};

/// Uniform in the open interval (0, 1).
inline double unit_open(std::uint32_t u) {
  return (static_cast<double>(u >> 8) + 0.5) * (1.0 / 16777216.0);
}

/// Two independent standard normals (Box-Muller).
inline std::array<double, 2> normal_pair(std::uint32_t a, std::uint32_t b) {
  const double r = std::sqrt(-2.0 * std::log(unit_open(a)));
  double sin_phase = 0, cos_phase = 0;
  ::sincos(2.0 * kPi * unit_open(b), &sin_phase, &cos_phase);
  return {r * cos_phase, r * sin_phase};
}

/// Monotone table lookup: values y at equally spaced x from x0 with step dx.
inline double table_at(const std::array<double, kLevels>& y, double x0, double inv_dx, double x) {
  double f = (x - x0) * inv_dx;
  f = std::clamp(f, 0.0, static_cast<double>(kLevels - 1) - 1e-9);
  const auto i = static_cast<std::size_t>(f);
  const double w = f - static_cast<double>(i);
  return y[i] + w * (y[i + 1] - y[i]);
}

/// One delayed, scaled copy of the pulse template in the receiver.
struct EchoComponent {
  double amplitude_v;
  double delay_ns;
};

/// Everything that is the same for all shots of one measurement.
struct MeasurementSetup {
  // Noise-free linear echo on a fine grid (the sum of all components).
  std::vector<double> composite;
  std::vector<double> noise_sigma;  // waveform mode: noise (1 sigma) along the composite grid
  double grid_begin_ns = 0;
  double peak_v = 0;
  double peak_time_ns = 0;
  // Threshold-crossing tables over levels threshold +- 6 sigma (level-shift noise model).
  double level_begin_v = 0, inv_level_step = 0;
  std::array<double, kLevels> rise_ns{}, fall_ns{};
  double level_top_v = 0;  // largest level that is crossed at all
  double noise_at_threshold_v = 0;
  double noise_floor_var_v2 = 0;  // noise variance without signal
  double shot_var_per_v = 0;      // signal shot noise variance per volt of signal
  double edge_correlation = 0;    // correlation of the noise at the two crossings
  double recovery_ns = 0;         // extra clip time of an overdriven amplifier
  bool saturated = false;
  double fixed_delay_ns = 0;  // trigger + receive chain, incl. thermal drift
  double tdc_bin_scale = 1;   // fine-bin width relative to nominal (timing board temperature)
  double temperature_reading_c = 0;
  double amplitude_noise_rel = 0;
  double turn_on_start_ms = 0;
  // Noise alone crossing the threshold before the echo (false alarms).
  double false_alarm_rate_per_ns = 0;  // Rice: nu = exp(-u^2/2) / (2 pi tau_p), u = V_th / sigma_0
  double false_alarm_width_ns = 0;     // mean time above threshold of such an excursion
  double record_begin_ns = 0;          // waveform mode samples from here on
  double false_alarm_window_ns = 0;    // armed time before the explicitly modelled echo
  double false_alarm_probability = 0;  // 1 - exp(-nu window)
};

}  // namespace

struct VirtualRangefinder::Impl {
  DeviceConfig config;
  SimulationMode mode;
  physics::PulseTemplate pulse;
  Tdc tdc;
  double volts_per_watt_unity_gain;  // responsivity x transimpedance x bandwidth peak loss
  double c_nominal_m_per_ns;         // the device's assumed speed of light in air
  double pulse_period_ns;            // 1 / f_rep

  Impl(DeviceConfig cfg, SimulationMode m)
      : config(std::move(cfg)),
        mode(m),
        pulse(config.link.laser.pulse_width_ns, config.link.receiver.bandwidth_mhz),
        tdc(config.tdc) {
    const auto& rx = config.link.receiver;
    volts_per_watt_unity_gain =
        rx.responsivity_a_per_w * rx.transimpedance_kohm * 1e3 * pulse.peak_gain();
    physics::AirConditions air{config.measurement.reference_temperature_c,
                               config.link.environment.pressure_hpa,
                               config.link.environment.relative_humidity_pct};
    c_nominal_m_per_ns =
        physics::speed_of_light_in_air_m_per_s(config.link.laser.wavelength_nm, air) * 1e-9;
    pulse_period_ns = 1e9 / config.link.laser.repetition_hz;
  }

  [[nodiscard]] std::vector<EchoComponent> components(const Target& target, double ambient_c,
                                                      double gain, double power_scale) const {
    const auto& link = config.link;
    physics::AirConditions air{ambient_c, link.environment.pressure_hpa,
                               link.environment.relative_humidity_pct};
    const double c_m_per_ns =
        physics::speed_of_light_in_air_m_per_s(link.laser.wavelength_nm, air) * 1e-9;
    const double volts_per_watt = volts_per_watt_unity_gain * gain * power_scale;
    std::vector<EchoComponent> out;
    for (const auto& s : target.surfaces) {
      if (s.fraction <= 0.0 || s.reflectance <= 0.0 || s.angle_deg >= 90.0) continue;
      // Extended Lambertian target, paper Eq. 6, scaled by the share of the footprint.
      // Biaxial optics: only the share of the footprint inside the receiver's field.
      const double power_w =
          s.fraction * physics::overlap_fraction(link.laser, link.receiver, s.distance_m) *
          physics::received_power_extended_w(link, s.distance_m, s.reflectance, s.angle_deg);
      if (power_w <= 0.0) continue;
      const double amplitude = power_w * volts_per_watt;
      // The comparator is re-armed at every pulse: an echo later than the pulse
      // period arrives after a later pulse and is timed from that one (ambiguity).
      const double delay = std::fmod(2.0 * s.distance_m / c_m_per_ns, pulse_period_ns);
      // A tilted surface spreads the footprint over a depth D tan(phi): the echo is
      // the sum over the footprint (uniform disk -> semicircle weights, Gauss-Chebyshev).
      const double half_depth_m = 0.5 * physics::footprint_diameter_m(link.laser, s.distance_m) *
                                  std::tan(physics::deg_to_rad(s.angle_deg));
      if (half_depth_m * 2.0 / c_m_per_ns < 1e-4) {
        out.push_back({amplitude, delay});
        continue;
      }
      double weight_sum = 0;
      std::array<double, kFootprintNodes> w{};
      for (int k = 0; k < kFootprintNodes; ++k) {
        const double x = kPi * (k + 1) / (kFootprintNodes + 1);
        w[static_cast<std::size_t>(k)] = std::sin(x) * std::sin(x);
        weight_sum += w[static_cast<std::size_t>(k)];
      }
      for (int k = 0; k < kFootprintNodes; ++k) {
        const double u = std::cos(kPi * (k + 1) / (kFootprintNodes + 1));
        out.push_back({amplitude * w[static_cast<std::size_t>(k)] / weight_sum,
                       delay + 2.0 * u * half_depth_m / c_m_per_ns});
      }
    }
    return out;
  }

  /// Noise variance (V^2) at a signal level: amplifier/background/dark floor
  /// plus signal shot noise proportional to the instantaneous signal (Eq. 8 terms).
  [[nodiscard]] double noise_variance(double signal_v, double gain, double background_w) const {
    const auto& rx = config.link.receiver;
    const double z_ohm = rx.transimpedance_kohm * 1e3;
    const auto floor = physics::noise_currents(rx, 0.0, background_w, gain);
    const double floor_v2 =
        z_ohm * z_ohm *
        (floor.background_shot_a * floor.background_shot_a + floor.dark_shot_a * floor.dark_shot_a +
         floor.thermal_a * floor.thermal_a);
    // Signal shot noise: 2 q I_p M^2 F B with I_p = V / (Z M) -> 2 q M F B Z V.
    const double shot_v_per_v = 2.0 * physics::kElementaryCharge_c * gain * rx.excess_noise_factor *
                                rx.bandwidth_mhz * 1e6 * z_ohm;
    return floor_v2 + shot_v_per_v * std::max(signal_v, 0.0);
  }

  /// Sunlight scattered by the surfaces into the receiver (paper Eq. 9).
  [[nodiscard]] double background_power_w(const Target& target) const {
    double w = 0;
    for (const auto& s : target.surfaces)
      w += s.fraction *
           physics::background_power_w(config.link, s.reflectance, std::min(s.angle_deg, 89.9));
    return w;
  }

  [[nodiscard]] MeasurementSetup setup(const Target& target, const Conditions& cond) const {
    const auto& th = config.thermal;
    const auto& rx = config.link.receiver;
    MeasurementSetup m;
    const double internal_c =
        internal_temperature_c(th, cond.ambient_c, cond.minutes_since_power_on);
    // The front-end board (laser driver, APD, amplifier, comparator, TDC) sits
    // behind its heater; the APD's gain follows the board's temperature through
    // the bias loop's residual.
    const double board_c = timing_board_temperature_c(th, internal_c);
    const double gain = physics::apd_gain_at(rx, board_c);
    const double power_scale = std::max(0.0, 1.0 + config.link.laser.power_temp_coeff_per_c *
                                                       (internal_c - rx.nominal_temperature_c));
    const auto comps = components(target, cond.ambient_c, gain, power_scale);
    const double background_w = background_power_w(target);
    const double threshold = config.discriminator.threshold_v;
    m.noise_at_threshold_v = std::sqrt(noise_variance(threshold, gain, background_w));
    m.noise_floor_var_v2 = noise_variance(0.0, gain, background_w);
    m.shot_var_per_v = noise_variance(1.0, gain, background_w) - m.noise_floor_var_v2;
    {
      // Rice's formula for the upcrossing rate of band-limited Gaussian noise with
      // R(tau) = (1 + |tau|/tau_p) exp(-|tau|/tau_p), for which -R''(0) = 1 / tau_p^2.
      const double u = threshold / std::sqrt(noise_variance(0.0, gain, background_w));
      const double tau_p = pulse.pole_time_constant_ns();
      m.false_alarm_rate_per_ns = std::exp(-0.5 * u * u) / (2.0 * kPi * tau_p);
      // Mean excursion length above the level: P(X > u) / nu.
      m.false_alarm_width_ns = m.false_alarm_rate_per_ns > 0
                                   ? 0.5 * std::erfc(u / std::sqrt(2.0)) / m.false_alarm_rate_per_ns
                                   : 0.0;
    }

    // Delays: fixed chain delay plus the timing board's delay tempco and the
    // unseen warm-up gradient, as extra round-trip time.
    const double board_dt = board_c - rx.nominal_temperature_c;
    const double warmup_mm = warmup_drift_mm(th, cond.ambient_c, cond.minutes_since_power_on);
    m.fixed_delay_ns = config.measurement.fixed_delay_ns +
                       th.delay_tempco_ps_per_c * 1e-3 * board_dt +
                       2.0 * warmup_mm * 1e-3 / c_nominal_m_per_ns;
    m.tdc_bin_scale = 1.0 + config.tdc.bin_tempco_ppm_per_c * 1e-6 * board_dt;
    m.temperature_reading_c = sensor_temperature_c(th, cond.ambient_c, cond.minutes_since_power_on);
    m.amplitude_noise_rel = rx.amplitude_noise_rel;
    m.turn_on_start_ms = cond.ms_since_laser_on;
    if (comps.empty()) {
      set_false_alarm_window(m, 1e9 / config.link.laser.repetition_hz);  // armed until next pulse
      return m;
    }

    // Noise-free composite echo on a fine grid.
    double first = comps.front().delay_ns, last = first;
    for (const auto& c : comps) {
      first = std::min(first, c.delay_ns);
      last = std::max(last, c.delay_ns);
    }
    m.grid_begin_ns = first + pulse.begin_ns();
    const double grid_end = last + pulse.end_ns();
    const auto n = static_cast<std::size_t>((grid_end - m.grid_begin_ns) / kCompositeStepNs) + 2;
    m.composite.assign(n, 0.0);
    for (const auto& c : comps) {
      for (std::size_t i = 0; i < n; ++i) {
        const double t = m.grid_begin_ns + static_cast<double>(i) * kCompositeStepNs;
        m.composite[i] += c.amplitude_v * pulse(t - c.delay_ns);
      }
    }
    const auto peak_it = std::max_element(m.composite.begin(), m.composite.end());
    m.peak_v = *peak_it;
    m.peak_time_ns =
        m.grid_begin_ns + static_cast<double>(peak_it - m.composite.begin()) * kCompositeStepNs;
    m.saturated = m.peak_v > rx.saturation_v;
    // Overdriven amplifiers stay clipped longer the harder they are driven
    // (charge storage): recovery ~ tau ln(V_peak / V_sat).
    m.recovery_ns =
        m.saturated ? rx.recovery_ns_per_neper * std::log(m.peak_v / rx.saturation_v) : 0;

    // Crossing tables: for each comparator level L (threshold shifted by the
    // noise), the first upcrossing and the following downcrossing of the echo.
    const double sigma = m.noise_at_threshold_v;
    const double level_lo = std::max(threshold - kLevelSpanSigma * sigma, 0.05 * threshold);
    const double level_hi = threshold + kLevelSpanSigma * sigma;
    const double level_step = (level_hi - level_lo) / static_cast<double>(kLevels - 1);
    m.level_begin_v = level_lo;
    m.inv_level_step = 1.0 / level_step;
    m.level_top_v = 0;
    // The first upcrossing index never decreases with the level: one forward pointer.
    // The downcrossing after it is found with a coarse stride (echo features span
    // hundreds of grid steps), then refined step by step.
    constexpr std::size_t kStride = 8;
    std::size_t i_rise = 1;
    for (std::size_t j = 0; j < kLevels; ++j) {
      const double level = level_lo + static_cast<double>(j) * level_step;
      double rise = m.peak_time_ns, fall = m.peak_time_ns;
      while (i_rise < n && m.composite[i_rise] < level) ++i_rise;
      if (i_rise < n) {
        m.level_top_v = level;
        const double a = m.composite[i_rise - 1], b = m.composite[i_rise];
        rise = m.grid_begin_ns +
               (static_cast<double>(i_rise - 1) + (level - a) / (b - a)) * kCompositeStepNs;
        std::size_t i = i_rise;
        while (i + kStride < n && m.composite[i + kStride] >= level) i += kStride;
        while (i < n && m.composite[i] >= level) ++i;
        if (i < n) {
          const double c = m.composite[i - 1], d = m.composite[i];
          fall = m.grid_begin_ns +
                 (static_cast<double>(i - 1) + (c - level) / (c - d)) * kCompositeStepNs;
        }
      }
      m.rise_ns[j] = rise;
      m.fall_ns[j] = std::max(fall, rise);
    }
    // Noise at the two crossings is correlated through the receiver bandwidth.
    const double rise0 = table_at(m.rise_ns, m.level_begin_v, m.inv_level_step, threshold);
    const double fall0 = table_at(m.fall_ns, m.level_begin_v, m.inv_level_step, threshold);
    m.edge_correlation = pulse.noise_correlation(fall0 - rise0);
    const double tau = pulse.pole_time_constant_ns();
    m.record_begin_ns = std::min(m.rise_ns[kLevels - 1] - 4.0 - 6.0 * tau, m.rise_ns[0] - 4.0);
    if (mode == SimulationMode::kWaveform) {
      m.noise_sigma.resize(n);
      for (std::size_t i = 0; i < n; ++i)
        m.noise_sigma[i] = std::sqrt(m.noise_floor_var_v2 + m.shot_var_per_v * m.composite[i]);
    }
    set_false_alarm_window(m, mode == SimulationMode::kAnalytic ? m.rise_ns[0] : m.record_begin_ns);
    return m;
  }

  static void set_false_alarm_window(MeasurementSetup& m, double window_ns) {
    m.false_alarm_window_ns = std::max(window_ns, 0.0);
    m.false_alarm_probability = -std::expm1(-m.false_alarm_rate_per_ns * m.false_alarm_window_ns);
  }

  [[nodiscard]] double turn_on_bias_ns(const MeasurementSetup& m, std::uint32_t shot) const {
    const auto& laser = config.link.laser;
    const double t_ms = m.turn_on_start_ms + 1e3 * static_cast<double>(shot) / laser.repetition_hz;
    if (t_ms > 30.0 * laser.turn_on_time_constant_ms) return 0.0;
    const double bias_mm = laser.turn_on_bias_mm * std::exp(-t_ms / laser.turn_on_time_constant_ms);
    return 2.0 * bias_mm * 1e-3 / c_nominal_m_per_ns;
  }

  /// Rising and falling comparator times of one shot (analytic mode): the
  /// noise, band-limited like the echo, shifts the effective threshold; the
  /// crossing is read off the noise-free echo (first order: jitter = sigma / slope).
  /// Echo level at which the comparator fires when the noise, frozen over the
  /// crossing at z standard deviations, scales with the signal (shot noise):
  /// solves s + sqrt(sigma_0^2 + k s) z = V_th. Its mean sits k/2 above V_th,
  /// the late bias that signal-modulated noise gives a rising edge.
  [[nodiscard]] static double crossing_level(const MeasurementSetup& m, double threshold,
                                             double z) {
    const double k = m.shot_var_per_v;
    if (k <= 0) return threshold - std::sqrt(m.noise_floor_var_v2) * z;
    const double c = m.noise_floor_var_v2 + k * threshold;
    const double q = 0.5 * (-k * z + std::sqrt(k * k * z * z + 4.0 * c));
    return (q * q - m.noise_floor_var_v2) / k;
  }

  [[nodiscard]] bool crossings_analytic(const MeasurementSetup& m, double z_rise, double z_fall_ind,
                                        double& rise, double& fall) const {
    const double threshold = config.discriminator.threshold_v;
    const double level_rise = crossing_level(m, threshold, z_rise);
    if (m.composite.empty() || level_rise > m.peak_v || level_rise > m.level_top_v) return false;
    const double z_fall = m.edge_correlation * z_rise +
                          std::sqrt(1.0 - m.edge_correlation * m.edge_correlation) * z_fall_ind;
    const double level_fall = crossing_level(m, threshold, z_fall);
    rise = table_at(m.rise_ns, m.level_begin_v, m.inv_level_step, level_rise);
    fall = level_fall >= m.level_top_v
               ? m.peak_time_ns
               : table_at(m.fall_ns, m.level_begin_v, m.inv_level_step, level_fall);
    fall = std::max(fall, rise) + m.recovery_ns;
    return true;
  }

  /// Waveform mode: band-limited noise added to the sampled echo, the amplifier
  /// clips and recovers, the comparator's crossings are found on the samples.
  [[nodiscard]] bool crossings_waveform(const MeasurementSetup& m, const CounterRng& rng,
                                        std::uint64_t stream, std::uint32_t shot, double phase_u,
                                        double& rise, double& fall) const {
    if (m.composite.empty()) return false;
    const auto& rx = config.link.receiver;
    const double threshold = config.discriminator.threshold_v;
    const double dt = config.measurement.sample_period_ps * 1e-3;
    const double tau = pulse.pole_time_constant_ns();
    const double a = std::exp(-dt / tau);
    // Two cascaded one-pole filters of white noise: var = (1-a)^4 (1+a^2) / (1-a^2)^3.
    const double var_white = 1.0 / 12.0;  // uniform in (-0.5, 0.5)
    const double filtered_var =
        var_white * std::pow(1.0 - a, 4) * (1.0 + a * a) / std::pow(1.0 - a * a, 3);
    const double norm = 1.0 / std::sqrt(filtered_var);
    // Record from before the earliest possible rise to after the latest fall.
    const double t_end = m.fall_ns[0] + m.recovery_ns + 4.0;
    const double t0 = m.record_begin_ns + phase_u * dt;
    const auto burn_in = static_cast<std::size_t>(std::ceil(6.0 * tau / dt));
    const auto n = static_cast<std::size_t>((t_end - t0) / dt) + 1;
    const double inv_grid = 1.0 / kCompositeStepNs;
    const auto grid_last = static_cast<double>(m.composite.size() - 1);

    double y1 = 0, y2 = 0;
    std::array<std::uint32_t, 4> block{};
    std::uint32_t block_index = 0;
    auto white = [&](std::size_t k) {
      if ((k & 3u) == 0) block = rng.draw(stream, shot, 1u + block_index++);
      return unit_open(block[k & 3u]) - 0.5;
    };
    for (std::size_t k = 0; k < burn_in; ++k) {
      y1 = a * y1 + (1.0 - a) * white(k);
      y2 = a * y2 + (1.0 - a) * y1;
    }
    auto input_at = [&](double t, double unit_noise) {
      const double g = std::clamp((t - m.grid_begin_ns) * inv_grid, 0.0, grid_last - 1e-9);
      const auto gi = static_cast<std::size_t>(g);
      const double w = g - static_cast<double>(gi);
      const double s = m.composite[gi] + w * (m.composite[gi + 1] - m.composite[gi]);
      const double sigma = m.noise_sigma[gi] + w * (m.noise_sigma[gi + 1] - m.noise_sigma[gi]);
      return s + sigma * unit_noise;
    };
    // The sampled noise is band-limited (smooth over a sample period) and is
    // interpolated linearly; the echo is known at any time. A crossing bracketed
    // by two samples is refined on that continuous waveform (regula falsi).
    auto refine = [&](double t_a, double t_b, double n_a, double n_b, double level) {
      auto f = [&](double t) {
        const double w = (t - t_a) / dt;
        return input_at(t, n_a + w * (n_b - n_a)) - level;
      };
      double fa = f(t_a), fb = f(t_b);
      for (int it = 0; it < 8 && t_b - t_a > 1e-6; ++it) {
        const double t = t_a + (t_b - t_a) * fa / (fa - fb);
        const double ft = f(t);
        if ((ft < 0) == (fa < 0)) {
          t_a = t;
          fa = ft;
        } else {
          t_b = t;
          fb = ft;
        }
      }
      return t_a + (t_b - t_a) * fa / (fa - fb);
    };
    bool above = false, clipped = false;
    double prev_v = 0, prev_t = 0, prev_n = 0, peak_v = 0;
    for (std::size_t k = 0; k < n; ++k) {
      y1 = a * y1 + (1.0 - a) * white(burn_in + k);
      y2 = a * y2 + (1.0 - a) * y1;
      const double t = t0 + static_cast<double>(k) * dt;
      const double unit_noise = norm * y2;
      const double v = input_at(t, unit_noise);
      if (k > 0) {
        if (!above && prev_v < threshold && v >= threshold) {
          rise = refine(prev_t, t, prev_n, unit_noise, threshold);
          above = true;
        } else if (above) {
          if (v > rx.saturation_v) {
            clipped = true;
            peak_v = std::max(peak_v, v);
          }
          if (prev_v >= threshold && v < threshold) {
            fall = refine(prev_t, t, prev_n, unit_noise, threshold);
            // After clipping, the output follows the input delayed by the recovery time.
            if (clipped) fall += rx.recovery_ns_per_neper * std::log(peak_v / rx.saturation_v);
            return true;
          }
        }
      }
      prev_v = v;
      prev_t = t;
      prev_n = unit_noise;
    }
    if (!above) return false;
    fall = t0 + static_cast<double>(n - 1) * dt;
    return true;
  }

  /// One shot, returning false when no echo crossed the threshold.
  /// Delay offset (ns) common to every shot of one measurement: the run's
  /// power-on offset plus the slow 1/f wander at the measurement's time
  /// (stream i starts i measurement periods after power-on).
  [[nodiscard]] double slow_offset_ns(const CounterRng& rng, std::uint64_t stream) const {
    const auto& mc = config.measurement;
    const auto power_on = rng.draw(kPowerOnStream, 0, 0);
    const double offset = mc.power_on_offset_ps * 1e-3 * normal_pair(power_on[0], power_on[1])[0];
    if (mc.flicker_delay_ps <= 0.0) return offset;
    // 1/f noise has equal power per octave: one sinusoid of random phase per
    // octave, each with rms flicker / sqrt(octaves), i.e. amplitude sqrt(2) times that.
    const double t_s = static_cast<double>(stream) * mc.shots / config.link.laser.repetition_hz;
    const double amplitude = mc.flicker_delay_ps * 1e-3 * std::sqrt(2.0 / kFlickerOctaves);
    double wander = 0;
    for (int k = 0; k < kFlickerOctaves; k += 4) {
      const auto r = rng.draw(kPowerOnStream, 1, static_cast<std::uint32_t>(k));
      for (int j = 0; j < 4 && k + j < kFlickerOctaves; ++j) {
        const double f_hz = kFlickerLowestHz * std::ldexp(1.0, k + j);
        wander += amplitude * std::sin(2.0 * kPi * (f_hz * t_s + unit_open(r[j])));
      }
    }
    return offset + wander;
  }

  [[nodiscard]] bool shot(const MeasurementSetup& m, const CounterRng& rng, std::uint64_t stream,
                          std::uint32_t index, double offset_ns, double& start_ns,
                          double& stop_rise_ns, double& stop_fall_ns) const {
    const auto r = rng.draw(stream, index, 0);
    double rise = 0, fall = 0;
    bool echo = false;
    // Stationary noise far from the echo: its first threshold upcrossing after the
    // comparator is armed (at emission) is exponential with Rice's rate, in both modes.
    const double u_false = unit_open(r[3]);
    if (u_false < m.false_alarm_probability) {
      // Inverse CDF of the exponential first-upcrossing time, given it falls in the window.
      rise = -std::log1p(-u_false) / m.false_alarm_rate_per_ns;
      fall = rise + m.false_alarm_width_ns;
      echo = true;
    } else if (mode == SimulationMode::kAnalytic) {
      const auto z = normal_pair(r[0], r[1]);
      echo = crossings_analytic(m, z[0], z[1], rise, fall);
    } else {
      echo = crossings_waveform(m, rng, stream, index, unit_open(r[0]), rise, fall);
    }
    if (!echo) return false;
    // laser_sync: the laser fires on a clock edge, so the start has a fixed
    // phase and the stop's phase is set by the range: the INL stays, periodic
    // in range. Asynchronous: the start phase is uniform over a coarse period,
    // so quantization and INL average out.
    const double phase =
        (config.tdc.laser_sync ? kSyncStartPhase : unit_open(r[2])) * tdc.period_ns();
    const double delay = m.fixed_delay_ns + offset_ns + turn_on_bias_ns(m, index);
    start_ns = tdc.quantize_ns(phase, m.tdc_bin_scale);
    stop_rise_ns = tdc.quantize_ns(phase + delay + rise, m.tdc_bin_scale);
    stop_fall_ns = tdc.quantize_ns(phase + delay + fall, m.tdc_bin_scale);
    return true;
  }

  [[nodiscard]] ranging::RawMeasurement measure(const Target& target, const Conditions& cond,
                                                std::uint64_t seed, std::uint64_t stream,
                                                int shots) const {
    const CounterRng rng(seed);
    const auto m = setup(target, cond);
    const double internal_c = m.temperature_reading_c;
    const int n = shots > 0 ? shots : config.measurement.shots;
    const double offset_ns = slow_offset_ns(rng, stream);
    // The firmware keeps each shot's stop, then rejects false stops before
    // averaging: stops farther than measurement.stop_gate_ns from the median
    // stop (range gate around the median). Rejected stops lower shots_valid.
    thread_local std::vector<std::array<double, 2>> stops;
    stops.clear();
    for (int i = 0; i < n; ++i) {
      double start = 0, rise = 0, fall = 0;
      if (!shot(m, rng, stream, static_cast<std::uint32_t>(i), offset_ns, start, rise, fall))
        continue;
      stops.push_back({rise - start, fall - rise});
    }
    double sum_tof = 0, sum_width = 0;
    std::uint32_t valid = 0;
    const double gate = config.measurement.stop_gate_ns;
    double median = 0;
    if (gate > 0 && !stops.empty()) {
      thread_local std::vector<double> tofs;
      tofs.clear();
      for (const auto& st : stops) tofs.push_back(st[0]);
      const auto mid = tofs.begin() + static_cast<std::ptrdiff_t>(tofs.size() / 2);
      std::nth_element(tofs.begin(), mid, tofs.end());
      median = *mid;
    }
    for (const auto& st : stops) {
      if (gate > 0 && std::abs(st[0] - median) > gate) continue;
      sum_tof += st[0];
      sum_width += st[1];
      ++valid;
    }
    ranging::RawMeasurement out;
    const auto extra = rng.draw(stream, kMeasurementCounter, 0);
    const auto z = normal_pair(extra[0], extra[1]);
    // Temperature sensor: noise, then its resolution.
    const auto& th = config.thermal;
    const double reading = internal_c + th.sensor_noise_c * z[0];
    out.temperature_c = std::round(reading / th.sensor_resolution_c) * th.sensor_resolution_c;
    out.shots_valid = valid;
    if (valid == 0) {
      out.flags |= ranging::kRawNoEcho;
    } else {
      out.tof_ns = sum_tof / valid;
      out.pulse_width_ns = sum_width / valid;
      out.distance_raw_m = 0.5 * out.tof_ns * c_nominal_m_per_ns;
      // Peak amplitude from the receiver's peak detector, averaged over the shots;
      // it follows the amplifier, so it reads no more than the clip level.
      const double peak = std::min(m.peak_v, config.link.receiver.amplitude_clip_v);
      out.amplitude =
          std::min(peak * (1.0 + m.amplitude_noise_rel * z[1] / std::sqrt(double(valid))),
                   config.link.receiver.amplitude_clip_v);
      if (valid < static_cast<std::uint32_t>(n)) out.flags |= ranging::kRawPartialEchoes;
      if (m.saturated) out.flags |= ranging::kRawSaturated;
    }
    const auto& laser = config.link.laser;
    if (cond.ms_since_laser_on < 5.0 * laser.turn_on_time_constant_ms)
      out.flags |= ranging::kRawTurnOnTransient;
    if (cond.minutes_since_power_on < 4.0 * th.warmup_time_constant_min)
      out.flags |= ranging::kRawWarmingUp;
    return out;
  }
};

VirtualRangefinder::VirtualRangefinder(DeviceConfig config, SimulationMode mode) {
  const auto errors = validate(config);
  if (!errors.empty()) {
    std::string message = "invalid device configuration:";
    for (const auto& e : errors) message += "\n  " + e;
    throw std::invalid_argument(message);
  }
  if (config.oscillator.enabled) oscillator_ = std::make_unique<const OscillatorLoop>(config);
  impl_ = std::make_unique<Impl>(std::move(config), mode);
}

VirtualRangefinder::~VirtualRangefinder() = default;
VirtualRangefinder::VirtualRangefinder(VirtualRangefinder&&) noexcept = default;
VirtualRangefinder& VirtualRangefinder::operator=(VirtualRangefinder&&) noexcept = default;

const DeviceConfig& VirtualRangefinder::config() const {
  return impl_->config;
}
SimulationMode VirtualRangefinder::mode() const {
  return impl_->mode;
}

EchoShape VirtualRangefinder::echo(const Target& target, const Conditions& conditions) const {
  if (oscillator_) return oscillator_->echo(target, conditions);
  const auto m = impl_->setup(target, conditions);
  EchoShape e;
  e.peak_v = m.peak_v;
  e.saturated = m.saturated;
  e.noise_at_rise_v = m.noise_at_threshold_v;
  const double threshold = impl_->config.discriminator.threshold_v;
  e.detected = !m.composite.empty() && m.peak_v >= threshold;
  if (!e.detected) return e;
  e.rise_crossing_ns = table_at(m.rise_ns, m.level_begin_v, m.inv_level_step, threshold);
  e.fall_crossing_ns =
      table_at(m.fall_ns, m.level_begin_v, m.inv_level_step, threshold) + m.recovery_ns;
  // Slope from two nearby levels of the crossing table.
  const double dl = 0.01 * m.noise_at_threshold_v;
  const double dt = table_at(m.rise_ns, m.level_begin_v, m.inv_level_step, threshold + dl) -
                    table_at(m.rise_ns, m.level_begin_v, m.inv_level_step, threshold - dl);
  e.rise_slope_v_per_ns = dt > 0 ? 2.0 * dl / dt : 0.0;
  return e;
}

Shot VirtualRangefinder::shoot(const Target& target, const Conditions& conditions,
                               std::uint64_t seed, std::uint64_t stream, std::uint32_t shot) const {
  if (oscillator_) return oscillator_->shoot(target, conditions, seed, stream, shot);
  const CounterRng rng(seed);
  const auto m = impl_->setup(target, conditions);
  Shot s;
  double start = 0, rise = 0, fall = 0;
  s.echo = impl_->shot(m, rng, stream, shot, impl_->slow_offset_ns(rng, stream), start, rise, fall);
  if (s.echo) {
    s.tof_ns = rise - start;
    s.pulse_width_ns = fall - rise;
  }
  return s;
}

ranging::RawMeasurement VirtualRangefinder::measure(const Target& target,
                                                    const Conditions& conditions,
                                                    std::uint64_t seed, std::uint64_t stream,
                                                    int shots) const {
  if (oscillator_) return oscillator_->measure(target, conditions, seed, stream, shots);
  return impl_->measure(target, conditions, seed, stream, shots);
}

void VirtualRangefinder::measure_batch(std::span<const MeasureRequest> requests, std::uint64_t seed,
                                       std::span<ranging::RawMeasurement> out) const {
  if (out.size() != requests.size())
    throw std::invalid_argument("measure_batch: output span size differs from the request count");
  tbb::parallel_for(
      tbb::blocked_range<std::size_t>(0, requests.size()),
      [&](const tbb::blocked_range<std::size_t>& range) {
        for (std::size_t i = range.begin(); i != range.end(); ++i) {
          const auto& r = requests[i];
          out[i] = oscillator_ ? oscillator_->measure(r.target, r.conditions, seed, i, r.shots)
                               : impl_->measure(r.target, r.conditions, seed, i, r.shots);
        }
      });
}

double VirtualRangefinder::tof_to_distance_m(double tof_ns) const {
  return 0.5 * tof_ns * impl_->c_nominal_m_per_ns;
}

}  // namespace tofkit::device
