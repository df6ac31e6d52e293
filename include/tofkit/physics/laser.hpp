#pragma once
/// \file The pulsed laser emitter (paper Table 1; assumptions documented per field).

namespace tofkit::physics {

struct LaserConfig {
  double wavelength_nm = 905.0;        ///< Table 1
  double peak_power_w = 1.0;           ///< transmitted peak power Pt, Table 1
  double pulse_width_ns = 1.0;         ///< emitted pulse FWHM: Table 1's 0.1 % duty cycle at 1 MHz
  double repetition_hz = 1.0e6;        ///< Table 1
  double transmit_efficiency = 0.975;  ///< transmitting optics Tt, Table 1
  double beam_divergence_mrad = 3.0;   ///< full-angle divergence after collimation. Assumption:
                                       ///< Table 1's 11 x 23 deg is the bare diode's.
  double exit_beam_diameter_mm = 3.0;  ///< collimated beam diameter at the exit. Assumption.
  double power_temp_coeff_per_c = -0.001;  ///< relative change of Pt per degree. Assumption:
                                           ///< bare 905 nm diodes lose 0.3-0.5 %/C; the
                                           ///< driver's current regulation leaves 0.1 %/C.
  double turn_on_bias_mm = 25.0;           ///< range bias of the first shot after laser switch-on
                                           ///< (thermal chirp of the diode). Assumption.
  double turn_on_time_constant_ms = 40.0;  ///< decay time of that bias. Assumption.
  double lasing_onset_ns = 0.0;  ///< the diode emits nothing until its drive current crosses
                                 ///< the lasing threshold, this long before the pulse's peak,
                                 ///< so strong echoes' walk is bounded. 0: a whole Gaussian (the
                                 ///< paper device: a 0.6 ns onset doubles its Fig. 7 accuracy).
};

}  // namespace tofkit::physics
