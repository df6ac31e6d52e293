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

}  // namespace tofkit::device
