#pragma once
/// \file The receiver stage's front end, between the APD and the comparator
/// (DESIGN, "APD" and "Noise"): the noise at the comparator (paper Eq. 8's
/// terms as voltages), the APD's space-charge limit on strong pulses, the
/// amplifier's clipping recovery, and the AC coupling's baseline that an
/// echo train charges (the comparator sees the echo minus it).

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <vector>

#include "tofkit/physics/pulse_template.hpp"
#include "tofkit/physics/receiver.hpp"

namespace tofkit::device {

/// Noise variance at the comparator (V^2): the amplifier's, the dark current's
/// and the background light's shot noise (a floor, linear in the background
/// power since variances add) plus the signal's own shot noise,
/// proportional to the instantaneous signal.
struct FrontEndNoise {
  double floor_var_v2 = 0;     ///< floor without background light
  double floor_var_per_w = 0;  ///< the floor's growth per watt of background
  double shot_var_per_v = 0;   ///< signal shot noise variance per volt of signal

  [[nodiscard]] double variance_v2(double signal_v, double background_w) const {
    return floor_var_v2 + floor_var_per_w * background_w + shot_var_per_v * std::max(signal_v, 0.0);
  }
};

/// The noise of a receiver whose APD multiplies by `apd_gain`, from the link
/// budget's noise currents (physics::noise_currents) through the
/// transimpedance.
[[nodiscard]] FrontEndNoise front_end_noise(const physics::ReceiverConfig& rx, double apd_gain);

/// The APD's space charge: a strong pulse's own carriers screen the
/// multiplication field, so the gain falls as the current grows,
/// A / (1 + A / A_sc), and no echo exceeds A_sc however strong the return
/// (space_charge_v <= 0: no limit).
[[nodiscard]] inline double space_charge_limited_v(double linear_v, double space_charge_v) {
  return space_charge_v > 0.0 ? linear_v / (1.0 + linear_v / space_charge_v) : linear_v;
}

/// An overdriven amplifier stays clipped longer the harder it is driven
/// (charge storage): recovery ~ tau ln(V_peak / V_sat); 0 below saturation.
[[nodiscard]] inline double clip_recovery_ns(double peak_v, double saturation_v,
                                             double recovery_ns_per_neper) {
  return peak_v > saturation_v ? recovery_ns_per_neper * std::log(peak_v / saturation_v) : 0;
}

/// The share of an echo's charge that the amplifier passes when it clips:
/// integral of min(x p(t), 1) over x integral of p(t), for the pulse template
/// p (peak 1) overdriven x = peak / saturation times. 1 up to the clip; past
/// it the clipped top is flat, about 1 / x for a narrow pulse and larger for
/// one with long flanks (the flanks below the clip pass whole). Tabulated in
/// ln x from 1 to 1e6 at construction (interpolated; 1 / x beyond).
class ClippedChargeShare {
 public:
  ClippedChargeShare() = default;  ///< no table: share 1 (never clipped)
  explicit ClippedChargeShare(const physics::PulseTemplate& pulse);
  [[nodiscard]] double operator()(double overdrive) const;

 private:
  static constexpr double kLnStep = 0.05;
  std::vector<double> share_;  ///< at ln x = k kLnStep
};

/// The AC coupling's settled baseline on an echo train (V): its capacitor
/// charges to the train's mean, the charge of one echo as the amplifier
/// passes it (amplitude_sum_v x pulse_area_ns while linear; its clipped
/// share, `clipped_share` < 1, when overdriven, plus the recovery's
/// recovery_ns at saturation_v) times the repetition rate, times the
/// coupling's share.
[[nodiscard]] inline double coupling_baseline_v(double amplitude_sum_v, double pulse_area_ns,
                                                double clipped_share, double saturation_v,
                                                double recovery_ns, double coupling_share,
                                                double repetition_hz) {
  double charge_v_ns = amplitude_sum_v * pulse_area_ns * clipped_share;
  if (clipped_share < 1.0) charge_v_ns += saturation_v * recovery_ns;
  return coupling_share * charge_v_ns * repetition_hz * 1e-9;
}

/// The baseline's unrecovered offset at shot `shot` of a measurement: it
/// relaxes as exp(-shot / (f_rep tau)) from offset_v at the first shot.
[[nodiscard]] inline double coupling_offset_v(double offset_v, std::uint32_t shot,
                                              double shots_per_time_constant) {
  if (offset_v != 0.0 && shot > 0)
    offset_v *= std::exp(-static_cast<double>(shot) / shots_per_time_constant);
  return offset_v;
}

}  // namespace tofkit::device
