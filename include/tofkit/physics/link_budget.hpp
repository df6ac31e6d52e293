#pragma once
/// \file Optical link budget of a pulsed ToF rangefinder (paper Eqs. 4-9) and the
/// receiver's noise currents and SNR (Eq. 8).

#include <algorithm>
#include <cmath>
#include <vector>

#include "tofkit/physics/constants.hpp"
#include "tofkit/physics/environment.hpp"
#include "tofkit/physics/laser.hpp"
#include "tofkit/physics/receiver.hpp"

namespace tofkit::physics {

/// Everything the link budget needs.
struct LinkConfig {
  LaserConfig laser;
  ReceiverConfig receiver;
  EnvironmentConfig environment;
};

/// Receiving aperture area Ar.
[[nodiscard]] inline double aperture_area_m2(const ReceiverConfig& receiver) {
  const double d = receiver.aperture_diameter_mm * 1e-3;
  return kPi * d * d / 4.0;
}

/// Transmit and receive optics and the atmosphere both ways: Tt Tr Ta^2.
[[nodiscard]] inline double optics_and_atmosphere(const LinkConfig& link) {
  const double ta = link.environment.atmospheric_transmission;
  return link.laser.transmit_efficiency * link.receiver.optics_efficiency * ta * ta;
}

/// Beam footprint diameter at distance R (exit diameter plus divergence).
[[nodiscard]] inline double footprint_diameter_m(const LaserConfig& laser, double distance_m) {
  return laser.exit_beam_diameter_mm * 1e-3 + distance_m * laser.beam_divergence_mrad * 1e-3;
}

/// Received peak power from an extended Lambertian target that fills the beam,
/// paper Eq. 6: Pr = Pt Ar rho cos(phi) / (pi R^2) Tt Tr Ta^2.
[[nodiscard]] double received_power_extended_w(const LinkConfig& link, double distance_m,
                                               double reflectance, double angle_deg);
/// The same with cos(phi) given (the same value for cos_angle = cos(phi)).
[[nodiscard]] inline double received_power_extended_cos_w(const LinkConfig& link, double distance_m,
                                                          double reflectance, double cos_angle) {
  // Extended Lambertian target, paper Eq. 6.
  return link.laser.peak_power_w * aperture_area_m2(link.receiver) * reflectance * cos_angle /
         (kPi * distance_m * distance_m) * optics_and_atmosphere(link);
}

/// Received peak power from a target smaller than the footprint, paper Eq. 4
/// with its pi right: Pr = Pt Ar sigma / (4 pi^2 theta_t^2 R^4) Tt Tr Ta^2 with
/// theta_t the half-angle divergence and sigma the laser-radar cross-section
/// (4 rho A cos^2(phi) for a Lambertian area A; a corner cube's
/// 4 pi A^2 / lambda^2). The paper prints 4 pi, which matches its Eq. 6 only
/// with its sigma = 4 rho R^2 theta_t^2 cos(phi): the footprint's area without
/// its pi (the footprint's cross-section is 4 pi rho R^2 theta_t^2 cos(phi)).
[[nodiscard]] double received_power_small_w(const LinkConfig& link, double distance_m,
                                            double cross_section_m2);

/// Background power from sunlit target and sky, paper Eq. 9 with one rho:
/// Pb = (pi/16) Tr theta_r^2 d_r^2 dlambda [Ta rho H cos(theta) cos(phi) + pi N (1 - Ta)];
/// with environment.eq9_as_printed, the printed form (an extra rho in front).
[[nodiscard]] double background_power_w(const LinkConfig& link, double reflectance,
                                        double angle_deg);
/// The same for cos(phi) given.
[[nodiscard]] double background_power_cos_w(const LinkConfig& link, double reflectance,
                                            double cos_angle);

/// Maximum range for a minimum detectable power, paper Eq. 7.
[[nodiscard]] double max_range_extended_m(const LinkConfig& link, double reflectance,
                                          double angle_deg, double min_power_w);

/// APD gain M at a temperature: M ~ M0 * margin0 / margin(T) with margin =
/// V_br - V_bias. A fixed bias loses 0.65 V/C of margin; a compensated bias
/// loop tracks V_br up to receiver.bias_tracking_error_v_per_c.
[[nodiscard]] double apd_gain_at(const ReceiverConfig& receiver, double temperature_c);

namespace detail {
/// The lens-shaped intersection of discs of radii a (the footprint) and b,
/// centres d apart, over the first disc's area (overlap_fraction's partial case).
[[nodiscard]] double overlap_lens_fraction(double a, double b, double d);
}  // namespace detail

/// Share of the beam footprint the receiver sees at a distance (biaxial
/// optics): 0 in the near blind zone, 1 once the field covers the footprint.
/// Inline, as the formulas above: the device asks at every beam.
[[nodiscard]] inline double overlap_fraction(const LaserConfig& laser,
                                             const ReceiverConfig& receiver, double distance_m) {
  // Two discs at distance R: the beam footprint (radius a) and the receiver's
  // field (radius b = aperture / 2 + R theta_r / 2), centres apart by the axis
  // offset d. The received share is their intersection over the beam's area.
  const double a = 0.5 * footprint_diameter_m(laser, distance_m);
  const double b =
      0.5 * (receiver.aperture_diameter_mm * 1e-3 + distance_m * receiver.field_of_view_rad);
  const double d = receiver.axis_offset_mm * 1e-3;
  if (d >= a + b) return 0.0;
  if (d <= std::abs(b - a)) return b >= a ? 1.0 : (b * b) / (a * a);
  return detail::overlap_lens_fraction(a, b, d);
}

/// Share of the light returned from distance R that passes the receiver's field
/// stop when the receiver is focused at receiver.focus_distance_m (1 when that
/// is 0: the far-field budget). Thin lens: a point at R images off the stop's
/// plane, its rays spread over a blur of angular width beta = D |1/R - 1/R_focus|
/// (D the aperture; object-space angle); the beam footprint subtends
/// alpha = footprint / R. The footprint's image on the stop is the two
/// convolved; taken as a Gaussian spot whose widths add in quadrature,
/// w^2 = alpha^2 + beta^2, a circular stop of full angle theta
/// (field_of_view_rad) passes 1 - exp(-theta^2 / w^2) of it (the power of a
/// Gaussian spot inside a circle): theta^2 / w^2 far out of focus, all of it
/// in focus, with no kink between. Far inside the focus (beta >> alpha) the
/// share grows as R^2, cancelling Eq. 6's 1 / R^2: a defocused near target's
/// received power hardly depends on range (the near-field overlap of coaxial
/// rangefinders).
[[nodiscard]] inline double field_stop_share(const LaserConfig& laser,
                                             const ReceiverConfig& receiver, double distance_m) {
  if (!(receiver.focus_distance_m > 0.0) || !(distance_m > 0.0)) return 1.0;
  const double beta = receiver.aperture_diameter_mm * 1e-3 *
                      std::abs(1.0 / distance_m - 1.0 / receiver.focus_distance_m);
  const double alpha = footprint_diameter_m(laser, distance_m) / distance_m;
  const double w2 = alpha * alpha + beta * beta;
  const double theta = receiver.field_of_view_rad;
  return -std::expm1(-theta * theta / w2);
}

/// Noise currents at the APD output (multiplied), paper Eq. 8.
struct NoiseCurrents {
  double signal_shot_a = 0;      ///< sqrt(2 q I_p M^2 F B), I_p = R0 Pr
  double background_shot_a = 0;  ///< same with I_p = R0 Pb
  double dark_shot_a = 0;        ///< same with the primary dark current
  double thermal_a = 0;          ///< amplifier/thermal noise from the NEP: NEP R0 M sqrt(B)
  double total_a = 0;            ///< root sum of squares
};

[[nodiscard]] NoiseCurrents noise_currents(const ReceiverConfig& receiver, double signal_power_w,
                                           double background_power_w, double apd_gain);

/// One row of the link-budget table.
struct LinkBudgetPoint {
  double distance_m = 0;
  double received_power_w = 0;
  double background_power_w = 0;
  double signal_current_a = 0;  ///< R0 M Pr
  NoiseCurrents noise;
  double snr = 0;  ///< I_s / I_n, paper Eq. 8
};

/// Evaluate the budget at one distance (extended target).
[[nodiscard]] LinkBudgetPoint link_budget_at(const LinkConfig& link, double distance_m,
                                             double reflectance, double angle_deg = 0.0,
                                             double temperature_c = 25.0);

/// Distance at which the SNR falls to `snr` (bisection on the monotone SNR(R)).
[[nodiscard]] double range_at_snr(const LinkConfig& link, double snr, double reflectance,
                                  double angle_deg = 0.0);

}  // namespace tofkit::physics
