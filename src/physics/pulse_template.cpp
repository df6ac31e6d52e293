#include "tofkit/physics/pulse_template.hpp"

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdint>

#include "tofkit/physics/constants.hpp"

namespace tofkit::physics {

double two_pole_time_constant_ns(double bandwidth_mhz) {
  // |H(f)|^2 = 1 / (1 + (f/fp)^2)^2 = 1/2  ->  f = fp sqrt(sqrt(2) - 1).
  const double pole_mhz = bandwidth_mhz / std::sqrt(std::sqrt(2.0) - 1.0);
  return 1e3 / (2.0 * kPi * pole_mhz);
}

PulseTemplate::PulseTemplate(double pulse_fwhm_ns, double bandwidth_mhz, double step_ps,
                             double lasing_onset_ns) {
  const double sigma_ns = pulse_fwhm_ns / (2.0 * std::sqrt(2.0 * std::log(2.0)));
  pole_tau_ns_ = two_pole_time_constant_ns(bandwidth_mhz);
  const double step_ns = step_ps * 1e-3;
  // The diode is dark before its current crosses the lasing threshold.
  begin_ns_ = lasing_onset_ns > 0.0 ? -std::min(lasing_onset_ns, 6.0 * sigma_ns) : -6.0 * sigma_ns;
  end_ns_ = 6.0 * sigma_ns + 20.0 * pole_tau_ns_;
  const auto n = static_cast<std::size_t>(std::ceil((end_ns_ - begin_ns_) / step_ns)) + 1;
  // Impulse response of two equal poles, unit area: h(t) = t / tau^2 exp(-t / tau).
  const auto n_h = static_cast<std::size_t>(std::ceil(20.0 * pole_tau_ns_ / step_ns)) + 1;
  std::vector<double> h(n_h);
  double h_sum = 0;
  for (std::size_t k = 0; k < n_h; ++k) {
    const double t = static_cast<double>(k) * step_ns;
    h[k] = t / (pole_tau_ns_ * pole_tau_ns_) * std::exp(-t / pole_tau_ns_);
    h_sum += h[k];
  }
  for (auto& v : h) v /= h_sum;  // discrete unit area
  std::vector<double> gauss(n);
  for (std::size_t i = 0; i < n; ++i) {
    const double t = begin_ns_ + static_cast<double>(i) * step_ns;
    gauss[i] = std::exp(-0.5 * t * t / (sigma_ns * sigma_ns));
  }
  values_.assign(n, 0.0);
  for (std::size_t i = 0; i < n; ++i) {
    double acc = 0;
    const std::size_t kmax = std::min(i + 1, n_h);
    for (std::size_t k = 0; k < kmax; ++k) acc += gauss[i - k] * h[k];
    values_[i] = acc;
  }
  const auto peak_it = std::max_element(values_.begin(), values_.end());
  peak_gain_ = *peak_it;
  peak_time_ns_ = begin_ns_ + static_cast<double>(peak_it - values_.begin()) * step_ns;
  for (auto& v : values_) v /= peak_gain_;
  inv_step_ = 1.0 / step_ns;
  last_index_ = static_cast<double>(n - 1);
  end_ns_ = begin_ns_ + last_index_ * step_ns;
}

void PulseTemplate::add_to(double amplitude, double delay_ns, double t0_ns, double dt_ns,
                           double* out, std::size_t n) const {
  const double x0 = (t0_ns - delay_ns - begin_ns_) * inv_step_;
  const double dx = dt_ns * inv_step_;
  const double m = std::round(dx);
  if (m < 1.0 || std::abs(dx - m) > 1e-9 || std::abs(x0) > 1e15) {
    for (std::size_t k = 0; k < n; ++k)
      out[k] += amplitude * (*this)(t0_ns + static_cast<double>(k) * dt_ns - delay_ns);
    return;
  }
  // x_k = j0 + f + k m with 0 <= f < 1: nonzero for 0 < x_k < last_index.
  const double j0_real = std::floor(x0);
  const double f = x0 - j0_real;
  const auto j0 = static_cast<std::int64_t>(j0_real);
  const auto step = static_cast<std::int64_t>(m);
  const auto last = static_cast<std::int64_t>(last_index_);
  // First k with x_k > 0, i.e. j_k >= 1 or (j_k == 0 and f > 0).
  const std::int64_t j_min = f > 0.0 ? 0 : 1;
  std::int64_t k_begin = 0;
  if (j0 < j_min) k_begin = (j_min - j0 + step - 1) / step;
  // Last k + 1 with j_k <= last - 1 (then x_k < last_index and j_k + 1 exists).
  if (j0 > last - 1) return;
  const std::int64_t k_end = std::min(static_cast<std::int64_t>(n), (last - 1 - j0) / step + 1);
  const double a = amplitude * (1.0 - f), b = amplitude * f;
  const double* v = values_.data();
  for (std::int64_t k = k_begin; k < k_end; ++k) {
    const std::int64_t j = j0 + k * step;
    out[k] += a * v[j] + b * v[j + 1];
  }
}

double PulseTemplate::width_at_level_ns(double level) const {
  const double step = 1.0 / inv_step_;
  double rise = begin_ns_, fall = end_ns_;
  bool above = false;
  for (std::size_t i = 1; i < values_.size(); ++i) {
    const double a = values_[i - 1], b = values_[i];
    const double t = begin_ns_ + static_cast<double>(i - 1) * step;
    if (!above && a < level && b >= level) {
      rise = t + step * (level - a) / (b - a);
      above = true;
    } else if (above && a >= level && b < level) {
      fall = t + step * (a - level) / (a - b);
      break;
    }
  }
  return fall - rise;
}

double PulseTemplate::noise_correlation(double lag_ns) const {
  const double x = std::abs(lag_ns) / pole_tau_ns_;
  return (1.0 + x) * std::exp(-x);
}

}  // namespace tofkit::physics
