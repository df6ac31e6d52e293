#pragma once
/// \file The shape of an echo at the comparator: the emitted Gaussian laser
/// pulse convolved with the receiver's impulse response (two equal real poles,
/// overall -3 dB bandwidth B; rise time about 0.35 / B). A laser diode emits
/// nothing until its drive current crosses the lasing threshold: with an
/// onset, the Gaussian starts there (zero before), so the echo has a first
/// instant no strong echo can cross before (bounded walk).

#include <cstddef>
#include <vector>

namespace tofkit::physics {

class PulseTemplate {
 public:
  /// `pulse_fwhm_ns`: emitted pulse FWHM; `bandwidth_mhz`: receiver -3 dB bandwidth;
  /// `lasing_onset_ns`: emission starts this long before the pulse's peak (0: a
  /// whole Gaussian, no onset).
  PulseTemplate(double pulse_fwhm_ns, double bandwidth_mhz, double step_ps = 5.0,
                double lasing_onset_ns = 0.0);

  /// Normalized shape (peak 1) at time t after the emitted pulse's centre.
  [[nodiscard]] double operator()(double t_ns) const {
    const double x = (t_ns - begin_ns_) * inv_step_;
    if (x <= 0.0 || x >= last_index_) return 0.0;
    const auto i = static_cast<std::size_t>(x);
    const double f = x - static_cast<double>(i);
    return values_[i] + f * (values_[i + 1] - values_[i]);
  }

  /// out[k] += amplitude * (*this)(t0_ns + k dt_ns - delay_ns) for k < n: a
  /// delayed, scaled copy added to a sampled waveform. When dt_ns is a whole
  /// number of the template's steps the interpolation weight is the same at
  /// every k, and the loop is a strided sum (no per-sample index arithmetic).
  void add_to(double amplitude, double delay_ns, double t0_ns, double dt_ns, double* out,
              std::size_t n) const;

  [[nodiscard]] double begin_ns() const { return begin_ns_; }  ///< shape is 0 before
  [[nodiscard]] double end_ns() const { return end_ns_; }      ///< and (below 1e-6) after
  [[nodiscard]] double peak_time_ns() const { return peak_time_ns_; }
  /// Peak of the filtered pulse relative to the unfiltered one (bandwidth loss, <= 1).
  [[nodiscard]] double peak_gain() const { return peak_gain_; }
  /// Full width at a fraction `level` (0..1) of the peak.
  [[nodiscard]] double width_at_level_ns(double level) const;
  /// Time constant of each of the two receiver poles.
  [[nodiscard]] double pole_time_constant_ns() const { return pole_tau_ns_; }

  /// Normalized autocorrelation of white noise filtered by the same receiver
  /// (two equal poles): (1 + |tau|/tau_p) exp(-|tau|/tau_p).
  [[nodiscard]] double noise_correlation(double lag_ns) const;

 private:
  std::vector<double> values_;
  double begin_ns_ = 0, end_ns_ = 0, inv_step_ = 0, last_index_ = 0;
  double peak_time_ns_ = 0, peak_gain_ = 1, pole_tau_ns_ = 0;
};

/// Time constant of each pole of a two-equal-pole low-pass whose overall -3 dB
/// bandwidth is `bandwidth_mhz`: f_pole = B / sqrt(sqrt(2) - 1).
[[nodiscard]] double two_pole_time_constant_ns(double bandwidth_mhz);

}  // namespace tofkit::physics
