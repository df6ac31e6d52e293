#pragma once
/// \file The discriminator stage: a fixed-threshold comparator on the
/// receiver's output (DESIGN, "Discriminator"). Its rising and falling
/// crossings time the echo (their difference is the echo's pulse width);
/// the receiver's band-limited noise moves them (jitter = noise / slope) and,
/// alone, crosses the threshold now and then (false alarms, Rice's formula).
/// Here the stage's physics as plain functions of the noise and the levels;
/// the pulsed core (virtual_rangefinder.cpp) applies them to its echoes.
///
/// The noise is white noise through the receiver's two equal poles (time
/// constant tau_p, physics/pulse_template.hpp): autocorrelation
/// R(tau) = (1 + |tau| / tau_p) exp(-|tau| / tau_p), so -R''(0) = 1 / tau_p^2.

#include <algorithm>
#include <cmath>
#include <cstddef>

#include "tofkit/physics/constants.hpp"

namespace tofkit::device {

/// Rice's formula: the mean rate (per ns) at which such noise upcrosses a
/// level u standard deviations above its mean, nu = exp(-u^2 / 2) / (2 pi tau_p).
[[nodiscard]] inline double rice_upcrossing_rate_per_ns(double threshold_over_noise,
                                                        double pole_time_constant_ns) {
  return std::exp(-0.5 * threshold_over_noise * threshold_over_noise) /
         (2.0 * physics::kPi * pole_time_constant_ns);
}

/// Echo level (V) at which the comparator fires when the noise, frozen over
/// the crossing at z standard deviations, grows with the signal s (shot
/// noise, variance floor_var_v2 + shot_var_per_v s): solves
/// s + sqrt(floor_var_v2 + shot_var_per_v s) z = threshold_v. Its mean over z
/// sits shot_var_per_v / 2 above the threshold: the late bias that
/// signal-modulated noise gives a rising edge.
[[nodiscard]] inline double crossing_level_v(double floor_var_v2, double shot_var_per_v,
                                             double threshold_v, double z) {
  const double k = shot_var_per_v;
  if (k <= 0) return threshold_v - std::sqrt(floor_var_v2) * z;
  const double c = floor_var_v2 + k * threshold_v;
  const double q = 0.5 * (-k * z + std::sqrt(k * k * z * z + 4.0 * c));
  return (q * q - floor_var_v2) / k;
}

/// Noise alone firing the comparator before the echo: a false alarm.
struct FalseAlarms {
  double rate_per_ns = 0;           ///< Rice's nu at the threshold
  double threshold_over_noise = 0;  ///< u = threshold / noise floor sigma
  double armed_ns = 0;              ///< the comparator's stops count from here
  double window_ns = 0;             ///< armed time before the explicitly modelled echo
  double probability = 0;           ///< a shot's chance of an alarm: 1 - exp(-nu window)

  /// Noise crossings count from the comparator's arming to `end_ns`.
  void set_window(double end_ns) {
    window_ns = std::max(end_ns - armed_ns, 0.0);
    probability = -std::expm1(-rate_per_ns * window_ns);
  }

  /// The alarm of a shot whose uniform draw is u (in (0, 1)): none when u is
  /// at or above the window's probability; else its first upcrossing after
  /// the arming, exponential with Rice's rate (the inverse CDF, given it falls
  /// in the window), and its fall after the mean excursion above the level,
  /// P(X > u) / nu.
  [[nodiscard]] bool first_crossing(double u, double& rise_ns, double& fall_ns) const {
    if (u >= probability) return false;
    rise_ns = armed_ns - std::log1p(-u) / rate_per_ns;
    fall_ns = rise_ns + 0.5 * std::erfc(threshold_over_noise / std::sqrt(2.0)) / rate_per_ns;
    return true;
  }
};

/// Extra crossings of a noisy edge: an edge crossing the threshold at slope a
/// through the band-limited noise (sigma, derivative sigma / tau_p) is crossed
/// 1 + 2 c(r) times on average (Rice's formula integrated over the edge),
/// c(r) = r phi(1/r) - Q(1/r), r = sigma / (a tau_p): its jitter over the
/// noise's correlation time.
[[nodiscard]] double extra_edge_crossings(double jitter_over_correlation);

/// The ratio r at which c(r) reaches `extra_crossings` (c grows with r;
/// bisection over [0.05, 5]): slower edges chatter more than that.
[[nodiscard]] double chatter_ratio_limit(double extra_crossings);

/// The comparator on a sampled waveform (waveform mode, the reference): the
/// receiver's band-limited noise (white noise through the two poles, sampled
/// every step_ns) added to the echo, the amplifier clipping, the comparator's
/// first rising crossing after its arming and the falling one after it found
/// on the samples.
struct SampledComparator {
  double threshold_v = 0;
  double baseline_v = 0;  ///< AC coupling's baseline: the comparator sees the output minus it
  double step_ns = 0;     ///< sampling step
  double pole_time_constant_ns = 0;
  double record_begin_ns = 0, record_end_ns = 0;  ///< the sampled span
  double armed_ns = 0;  ///< rising crossings before this are not seen (blanking, TDC start)
  double saturation_v = 0, recovery_ns_per_neper = 0;  ///< the amplifier's clip

  /// Crossings of one shot; false when nothing rises through the threshold
  /// after the arming. `phase_u` in [0, 1) places the samples within a step;
  /// `white(k)` is the k-th white sample, a standard normal draw (called for
  /// k = 0, 1, ... in order): the receiver's noise is Gaussian, and through two
  /// poles sampled at tau / 6 a uniform draw would leave its tails short (Rice's
  /// rate at 3 sigma 15 % low); `amplifier_v(t, z)` the amplifier's output at t
  /// with the band-limited noise at z standard deviations. A record that
  /// ends above the threshold falls at its end.
  template <class White, class Amplifier>
  [[nodiscard]] bool crossings(double phase_u, White&& white, Amplifier&& amplifier_v, double& rise,
                               double& fall) const {
    const double threshold = threshold_v;
    const double baseline = baseline_v;
    const double dt = step_ns;
    const double tau = pole_time_constant_ns;
    const double a = std::exp(-dt / tau);
    // Two cascaded one-pole filters of white noise: var = (1-a)^4 (1+a^2) / (1-a^2)^3.
    const double filtered_var = std::pow(1.0 - a, 4) * (1.0 + a * a) / std::pow(1.0 - a * a, 3);
    const double norm = 1.0 / std::sqrt(filtered_var);
    // Record from before the earliest possible rise to after the latest fall.
    const double t_end = record_end_ns;
    const double t0 = record_begin_ns + phase_u * dt;
    const auto burn_in = static_cast<std::size_t>(std::ceil(6.0 * tau / dt));
    const auto n = static_cast<std::size_t>((t_end - t0) / dt) + 1;

    double y1 = 0, y2 = 0;
    for (std::size_t k = 0; k < burn_in; ++k) {
      y1 = a * y1 + (1.0 - a) * white(k);
      y2 = a * y2 + (1.0 - a) * y1;
    }
    // The sampled noise is band-limited (smooth over a sample period) and is
    // interpolated linearly; the echo is known at any time. A crossing bracketed
    // by two samples is refined on that continuous waveform (regula falsi).
    auto refine = [&](double t_a, double t_b, double n_a, double n_b, double level) {
      auto f = [&](double t) {
        const double w = (t - t_a) / dt;
        return amplifier_v(t, n_a + w * (n_b - n_a)) - baseline - level;
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
      const double output_v = amplifier_v(t, unit_noise);
      const double v = output_v - baseline;
      if (k > 0) {
        if (!above && prev_v < threshold && v >= threshold) {
          rise = refine(prev_t, t, prev_n, unit_noise, threshold);
          // A crossing before the comparator is armed (blanked, or before the
          // TDC's start) is not seen; a strong echo of a long pulse crosses
          // before the pulse's centre, t = 0, but after the light's onset.
          above = rise >= armed_ns;
        } else if (above) {
          if (output_v > saturation_v) {
            clipped = true;
            peak_v = std::max(peak_v, output_v);
          }
          if (prev_v >= threshold && v < threshold) {
            fall = refine(prev_t, t, prev_n, unit_noise, threshold);
            // After clipping, the output follows the input delayed by the recovery time.
            if (clipped) fall += recovery_ns_per_neper * std::log(peak_v / saturation_v);
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
};

}  // namespace tofkit::device
