#pragma once
/// \file The optics stage: what one surface in the beam's footprint returns
/// to the receiver (DESIGN, "Link budget" and "Echo waveform"): the extended
/// Lambertian target's power (paper Eq. 6) scaled by the surface's share of
/// the footprint and the biaxial overlap, as a voltage at the comparator
/// (through the APD's space-charge limit), its round-trip delay (modulo the
/// pulse period: range ambiguity), and the spread in time a tilted surface
/// gives the footprint; and the sunlight the surfaces scatter into the
/// receiver (paper Eq. 9).

#include <algorithm>
#include <cmath>

#include "tofkit/device/front_end.hpp"
#include "tofkit/device/target.hpp"
#include "tofkit/physics/link_budget.hpp"

namespace tofkit::device {

/// One surface's echo: amplitude, delay and the round-trip spread over half the
/// footprint's depth (0 when below 1e-4 ns: a point echo).
struct SurfaceEcho {
  double amplitude_v = 0, delay_ns = 0, spread_ns = 0;
};

/// The echo of surface s; false when it returns nothing. `volts_per_watt`:
/// the receive chain's gain at the comparator (responsivity x APD gain x
/// transimpedance x bandwidth loss x laser power scale); `c_m_per_ns`: the
/// speed of light in air; `pulse_period_ns`: 1 / repetition rate.
[[nodiscard]] inline bool surface_echo(const physics::LinkConfig& link, const Surface& s,
                                       double volts_per_watt, double c_m_per_ns,
                                       double pulse_period_ns, SurfaceEcho& out) {
  if (s.fraction <= 0.0 || s.reflectance <= 0.0 || !(s.cos_incidence > 0.0)) return false;
  const double cos_phi = std::min(s.cos_incidence, 1.0);
  // Extended Lambertian target, paper Eq. 6, scaled by the share of the footprint.
  // Biaxial optics: only the share of the footprint inside the receiver's field;
  // a receiver focused at a finite distance: only the share its field stop passes.
  const double power_w =
      s.fraction * physics::overlap_fraction(link.laser, link.receiver, s.distance_m) *
      physics::field_stop_share(link.laser, link.receiver, s.distance_m) *
      physics::received_power_extended_cos_w(link, s.distance_m, s.reflectance, cos_phi);
  if (power_w <= 0.0) return false;
  out.amplitude_v = space_charge_limited_v(power_w * volts_per_watt, link.receiver.space_charge_v);
  // The comparator is re-armed at every pulse: an echo later than the pulse
  // period arrives after a later pulse and is timed from that one (ambiguity).
  out.delay_ns = 2.0 * s.distance_m / c_m_per_ns;
  if (out.delay_ns >= pulse_period_ns) out.delay_ns = std::fmod(out.delay_ns, pulse_period_ns);
  // A tilted surface spreads the footprint over a depth D tan(phi): the echo is
  // the sum over the footprint (uniform disk -> semicircle weights, Gauss-Chebyshev).
  const double half_depth_m = 0.5 * physics::footprint_diameter_m(link.laser, s.distance_m) *
                              std::sqrt(std::max(1.0 - cos_phi * cos_phi, 0.0)) / cos_phi;
  out.spread_ns = 2.0 * half_depth_m / c_m_per_ns;
  if (out.spread_ns < 1e-4) out.spread_ns = 0.0;
  return true;
}

/// Sunlight scattered by the target's surfaces into the receiver (W, paper
/// Eq. 9), each by its share of the footprint; a grazing surface is taken at
/// 89.9 degrees.
[[nodiscard]] double background_power_w(const physics::LinkConfig& link, const Target& target);

}  // namespace tofkit::device
