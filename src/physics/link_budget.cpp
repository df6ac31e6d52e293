#include "tofkit/physics/link_budget.hpp"

#include <algorithm>
#include <cmath>

#include "tofkit/physics/constants.hpp"

namespace tofkit::physics {
namespace {

double snr_at(const LinkConfig& link, double distance_m, double reflectance, double angle_deg) {
  return link_budget_at(link, distance_m, reflectance, angle_deg,
                        link.receiver.nominal_temperature_c)
      .snr;
}

}  // namespace

double received_power_extended_w(const LinkConfig& link, double distance_m, double reflectance,
                                 double angle_deg) {
  return received_power_extended_cos_w(link, distance_m, reflectance,
                                       std::cos(deg_to_rad(angle_deg)));
}

double received_power_small_w(const LinkConfig& link, double distance_m, double cross_section_m2) {
  // Small target, paper Eq. 4 with sigma the laser-radar cross-section
  // (theta_t: half-angle divergence). The footprint pi R^2 theta_t^2 spreads
  // the power; the target returns sigma / (4 pi) of it per steradian, so the
  // aperture at R receives Pt sigma Ar / (pi R^2 theta_t^2 4 pi R^2): pi^2 in
  // the denominator. (As printed, 4 pi: sigma there is this sigma / pi, which
  // a Lambertian footprint's 4 pi rho R^2 theta_t^2 cos(phi) would not match.)
  const double theta_t = 0.5 * link.laser.beam_divergence_mrad * 1e-3;
  const double r2 = distance_m * distance_m;
  return link.laser.peak_power_w * aperture_area_m2(link.receiver) * cross_section_m2 /
         (4.0 * kPi * kPi * theta_t * theta_t * r2 * r2) * optics_and_atmosphere(link);
}

double background_power_w(const LinkConfig& link, double reflectance, double angle_deg) {
  return background_power_cos_w(link, reflectance, std::cos(deg_to_rad(angle_deg)));
}

double background_power_cos_w(const LinkConfig& link, double reflectance, double cos_angle) {
  // Paper Eq. 9. As printed it has rho twice (in the prefactor and in the sunlit
  // term); the radiometry has it once (the sunlit term). The printed form is kept
  // behind a switch because it is what reproduces the paper's Figure 3.
  const auto& rx = link.receiver;
  const auto& env = link.environment;
  const double d_r = rx.aperture_diameter_mm * 1e-3;
  const double dlambda_um = rx.filter_bandwidth_nm * 1e-3;
  const double ta = env.atmospheric_transmission;
  const double sunlit = ta * reflectance * env.solar_irradiance_w_per_m2_um *
                        std::cos(deg_to_rad(env.sun_angle_deg)) * cos_angle;
  const double sky = kPi * env.sky_radiance_w_per_m2_sr_um * (1.0 - ta);
  const double printed_rho = env.eq9_as_printed ? reflectance : 1.0;
  return kPi / 16.0 * rx.optics_efficiency * printed_rho * rx.field_of_view_rad *
         rx.field_of_view_rad * d_r * d_r * dlambda_um * (sunlit + sky);
}

double max_range_extended_m(const LinkConfig& link, double reflectance, double angle_deg,
                            double min_power_w) {
  // Paper Eq. 7: Eq. 6 solved for R at Pr = Pmin.
  return std::sqrt(link.laser.peak_power_w * aperture_area_m2(link.receiver) * reflectance *
                   std::cos(deg_to_rad(angle_deg)) * optics_and_atmosphere(link) /
                   (kPi * min_power_w));
}

double apd_gain_at(const ReceiverConfig& receiver, double temperature_c) {
  // Near breakdown M ~ const / (V_br - V_bias); V_br rises 0.65 V/C. A fixed bias
  // loses that margin's worth of gain; a tracking loop follows V_br up to its
  // residual error, so the margin changes by -error per degree.
  const double dt = temperature_c - receiver.nominal_temperature_c;
  const double margin_rate = receiver.bias_temperature_compensated
                                 ? -receiver.bias_tracking_error_v_per_c
                                 : receiver.breakdown_temp_coeff_v_per_c;
  const double margin = receiver.bias_margin_v + margin_rate * dt;
  const double min_margin = 0.05 * receiver.bias_margin_v;
  const double gain = receiver.apd_gain * receiver.bias_margin_v / std::max(margin, min_margin);
  return std::max(gain, 1.0);
}

namespace detail {

double overlap_lens_fraction(double a, double b, double d) {
  const double alpha = std::acos(std::clamp((d * d + a * a - b * b) / (2 * d * a), -1.0, 1.0));
  const double beta = std::acos(std::clamp((d * d + b * b - a * a) / (2 * d * b), -1.0, 1.0));
  const double lens =
      a * a * (alpha - std::sin(2 * alpha) / 2) + b * b * (beta - std::sin(2 * beta) / 2);
  return std::clamp(lens / (kPi * a * a), 0.0, 1.0);
}

}  // namespace detail

NoiseCurrents noise_currents(const ReceiverConfig& receiver, double signal_power_w,
                             double background_power_w, double apd_gain) {
  const double bandwidth_hz = receiver.bandwidth_mhz * 1e6;
  const double r0 = receiver.responsivity_a_per_w;
  // Multiplied shot noise: 2 q I_primary M^2 F B (paper Eq. 8 terms).
  const double shot_factor =
      2.0 * kElementaryCharge_c * apd_gain * apd_gain * receiver.excess_noise_factor * bandwidth_hz;
  NoiseCurrents n;
  n.signal_shot_a = std::sqrt(shot_factor * r0 * signal_power_w);
  n.background_shot_a = std::sqrt(shot_factor * r0 * background_power_w);
  n.dark_shot_a = std::sqrt(shot_factor * receiver.dark_current_na * 1e-9);
  // The amplifier's noise, referred to the APD output through the multiplied
  // responsivity at the nominal gain the NEP is specified at: it is the
  // amplifier's, so it does not follow the APD's actual gain.
  n.thermal_a = receiver.nep_w_per_sqrt_hz * r0 * receiver.apd_gain * std::sqrt(bandwidth_hz);
  n.total_a =
      std::sqrt(n.signal_shot_a * n.signal_shot_a + n.background_shot_a * n.background_shot_a +
                n.dark_shot_a * n.dark_shot_a + n.thermal_a * n.thermal_a);
  return n;
}

LinkBudgetPoint link_budget_at(const LinkConfig& link, double distance_m, double reflectance,
                               double angle_deg, double temperature_c) {
  LinkBudgetPoint p;
  p.distance_m = distance_m;
  p.received_power_w = received_power_extended_w(link, distance_m, reflectance, angle_deg);
  p.background_power_w = background_power_w(link, reflectance, angle_deg);
  const double gain = apd_gain_at(link.receiver, temperature_c);
  p.signal_current_a = link.receiver.responsivity_a_per_w * gain * p.received_power_w;
  p.noise = noise_currents(link.receiver, p.received_power_w, p.background_power_w, gain);
  p.snr = p.signal_current_a / p.noise.total_a;  // paper Eq. 8
  return p;
}

double range_at_snr(const LinkConfig& link, double snr, double reflectance, double angle_deg) {
  double near_m = 1e-3;
  double far_m = 1e5;
  if (snr_at(link, near_m, reflectance, angle_deg) < snr) return 0.0;
  if (snr_at(link, far_m, reflectance, angle_deg) > snr) return far_m;
  for (int i = 0; i < 200 && far_m - near_m > 1e-9 * far_m; ++i) {
    const double mid = std::sqrt(near_m * far_m);  // geometric bisection: SNR is a power law
    (snr_at(link, mid, reflectance, angle_deg) > snr ? near_m : far_m) = mid;
  }
  return 0.5 * (near_m + far_m);
}

}  // namespace tofkit::physics
