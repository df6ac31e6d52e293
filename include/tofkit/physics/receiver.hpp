#pragma once
/// \file The receiving channel: optics, APD, transimpedance amplifier, shaping.

namespace tofkit::physics {

struct ReceiverConfig {
  double aperture_diameter_mm = 26.0;   ///< receiving aperture, Table 1
  double optics_efficiency = 0.15;      ///< receiving optics Tr, Table 1
  double field_of_view_rad = 0.02;      ///< receiving field angle theta_r, Table 1
  double filter_bandwidth_nm = 20.0;    ///< optical filter, Table 1
  double bandwidth_mhz = 150.0;         ///< electrical -3 dB bandwidth B, Table 1
  double responsivity_a_per_w = 0.58;   ///< unity-gain responsivity; Table 1's 58 A/W read as
                                        ///< 0.58 A/W x gain 100 (reference/ranging_paper.md)
  double apd_gain = 100.0;              ///< multiplication M at the nominal temperature
  double excess_noise_factor = 3.0;     ///< F; Table 1's "noise figure 3"
  double nep_w_per_sqrt_hz = 2.0e-14;   ///< noise-equivalent power, Table 1 ("2-14 W")
  double dark_current_na = 0.5;         ///< primary (unmultiplied) dark current. Assumption:
                                        ///< typical Si APD (e.g. Hamamatsu S12023).
  double transimpedance_kohm = 50.0;    ///< gain converting APD current to volts at the
                                        ///< comparator (TIA + post-amplifier). Assumption.
  double saturation_v = 4.0;            ///< amplifier output clip level. Assumption, set so that
                                        ///< saturation starts at the paper's 6.5 ns echo width
                                        ///< (100 x threshold: the echo's width at 1 % of peak).
  double recovery_ns_per_neper = 2.0;   ///< extra time the amplifier stays clipped per e-fold of
                                        ///< overdrive (charge storage). Assumption.
  double amplitude_noise_rel = 0.01;    ///< relative noise of the amplitude (peak) reading.
  double nominal_temperature_c = 25.0;  ///< temperature at which apd_gain holds
  double breakdown_temp_coeff_v_per_c = 0.65;  ///< Si APD breakdown drift (DESIGN.md)
  double bias_margin_v = 10.0;  ///< V_br - V_bias at the nominal temperature (sets dM/dT)
  bool bias_temperature_compensated = true;   ///< the paper's design tracks V_br with the
                                              ///< temperature sensor, holding M nearly constant
  double bias_tracking_error_v_per_c = -0.3;  ///< residual of that bias loop: the bias follows
                                              ///< V_br with 0.65 V/C minus this error per degree,
                                              ///< so the margin grows by |error| per degree and M
                                              ///< falls (walk drifts with temperature and depends
                                              ///< on echo strength). Assumption: a thermistor-table
                                              ///< loop off by half its slope; gives the drift at
                                              ///< 2.402 m its 10 % dependence on reflectance.
  double amplitude_clip_v = 4.0;  ///< ceiling of the amplitude (peak-detector) reading: the stage
                                  ///< it taps clips here (0.05 m and 0.3 m at rho 0.99 read alike).
                                  ///< Assumption: the paper's peak detector follows the amplifier
                                  ///< (= saturation_v).
  double crosstalk_v = 0.0;       ///< emitter-to-receiver optical crosstalk: peak at the
                                  ///< comparator (nominal gain and laser power) of a copy of the
                                  ///< pulse at zero range. 0: none.
  double axis_offset_mm = 15.0;   ///< biaxial optics: distance between the emitter's and the
                                  ///< receiver's optical axes. The receiver's field (aperture plus
                                  ///< field angle) overlaps the beam only past a blind zone.
                                  ///< Assumption: side-by-side 3 mm beam and 26 mm lens.
  /// APD space charge: a strong pulse's own carriers screen the multiplication
  /// field, so the echo at the comparator is A / (1 + A / space_charge_v) of its
  /// linear amplitude A: no echo exceeds it, and the amplifier's overdrive (so
  /// walk and the recovery's stretch) is bounded. 0: none (the paper device:
  /// its Fig. 6 plates reach 7.5 ns; 20 V would stop them at 6.7 ns).
  double space_charge_v = 0.0;
  /// Receiver focus: the field stop (full angle field_of_view_rad) sits in the
  /// image plane of a target at this distance. Nearer targets image behind it,
  /// defocused, and only part of their light passes the stop
  /// (physics::field_stop_share): a coaxial short-range unit's near-field
  /// signal rises with range. 0: the far-field view, the stop passes every
  /// returned ray (the paper's budget, Eq. 6).
  double focus_distance_m = 0.0;
};

}  // namespace tofkit::physics
