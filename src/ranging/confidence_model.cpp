#include "tofkit/ranging/confidence_model.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>
#include <vector>

#include "tofkit/ranging/raw_measurement.hpp"

namespace tofkit::ranging {

namespace {

void check_lengths(std::size_t range, std::size_t amplitude, std::size_t out, const char* who) {
  if (range != amplitude || out != amplitude) {
    throw std::invalid_argument(std::string(who) +
                                ": range_m, amplitude and sigma_m must have the same length");
  }
}

double clamp_to(double x, double lo, double hi) {
  return std::min(std::max(x, lo), hi);
}

/// A model's sigma must be finite wherever it is evaluated (its inputs are
/// clamped to the domain): checked on a grid over the domain, log-spaced in
/// amplitude when the model reads it on a log scale. Coefficients too large
/// (a corrupt model file: 1e300 in a log-variance gave sigma = inf) are refused.
void require_finite_sigma(const ConfidenceModel& model, double amplitude_min, double amplitude_max,
                          double range_min, double range_max, bool log_amplitude, const char* who) {
  constexpr int kGrid = 17;
  std::vector<double> range, amplitude;
  for (int i = 0; i < kGrid; ++i) {
    const double w = static_cast<double>(i) / (kGrid - 1);
    const double a = log_amplitude ? amplitude_min * std::pow(amplitude_max / amplitude_min, w)
                                   : amplitude_min + w * (amplitude_max - amplitude_min);
    for (int j = 0; j < kGrid; ++j) {
      amplitude.push_back(std::clamp(a, amplitude_min, amplitude_max));
      range.push_back(range_min + (range_max - range_min) * j / (kGrid - 1));
    }
  }
  std::vector<double> sigma(amplitude.size());
  model.sigma(range, amplitude, sigma);
  for (std::size_t k = 0; k < sigma.size(); ++k) {
    if (!(std::isfinite(sigma[k]) && sigma[k] > 0)) {
      throw std::invalid_argument(
          std::string(who) + ": sigma at amplitude " + std::to_string(amplitude[k]) + ", range " +
          std::to_string(range[k]) + " m is not finite and positive (coefficients too large)");
    }
  }
}

}  // namespace

double polynomial_2d(const std::vector<std::array<int, 2>>& exps, const std::vector<double>& c,
                     double x, double y) {
  // Orders are small (<= 6), so explicit powers cost little.
  double px[8], py[8];
  px[0] = py[0] = 1.0;
  for (int k = 1; k < 8; ++k) {
    px[k] = px[k - 1] * x;
    py[k] = py[k - 1] * y;
  }
  double v = 0;
  for (std::size_t k = 0; k < exps.size(); ++k) v += c[k] * px[exps[k][0]] * py[exps[k][1]];
  return v;
}

double band_factor(const std::vector<double>& centre, const std::vector<double>& scale, double u) {
  if (centre.size() == 1 || u <= centre.front()) return scale.front();
  if (u >= centre.back()) return scale.back();
  const auto it = std::upper_bound(centre.begin(), centre.end(), u);
  const std::size_t hi = static_cast<std::size_t>(it - centre.begin());
  const std::size_t lo = hi - 1;
  const double w = (u - centre[lo]) / (centre[hi] - centre[lo]);
  return std::exp((1 - w) * std::log(scale[lo]) + w * std::log(scale[hi]));
}

// ------------------------------------------------------------------ thesis

ThesisConfidence::ThesisConfidence(ThesisConfidenceParams params) : params_(std::move(params)) {
  const auto& p = params_;
  if (p.coefficients.empty()) throw std::invalid_argument("ThesisConfidence: no coefficients");
  for (std::size_t k = 0; k < p.coefficients.size(); ++k) {
    if (!std::isfinite(p.coefficients[k])) {
      throw std::invalid_argument("ThesisConfidence: coefficients[" + std::to_string(k) +
                                  "] is not finite");
    }
  }
  if (!std::isfinite(p.amplitude_scaling.center) || !(p.amplitude_scaling.half_width > 0) ||
      !std::isfinite(p.amplitude_scaling.half_width)) {
    throw std::invalid_argument("ThesisConfidence: amplitude_scaling needs a positive half_width");
  }
  if (!std::isfinite(p.amplitude_min) || !std::isfinite(p.amplitude_max) ||
      !(p.amplitude_min < p.amplitude_max)) {
    throw std::invalid_argument("ThesisConfidence: amplitude domain must have min < max");
  }
  if (!(p.floor_m2 > 0) || !std::isfinite(p.floor_m2)) {
    throw std::invalid_argument("ThesisConfidence: floor_m2 must be positive");
  }
  if (!(p.floor_above_amplitude >= 0) || !std::isfinite(p.floor_above_amplitude)) {
    throw std::invalid_argument("ThesisConfidence: floor_above_amplitude must be finite and >= 0");
  }
  require_finite_sigma(*this, p.amplitude_min, p.amplitude_max, 1.0, 1.0, false,
                       "ThesisConfidence");
}

void ThesisConfidence::sigma(std::span<const double> range_m, std::span<const double> amplitude,
                             std::span<double> sigma_m) const {
  // The thesis's metric ignores range, so range_m may also be empty.
  if (!range_m.empty())
    check_lengths(range_m.size(), amplitude.size(), sigma_m.size(), "ThesisConfidence::sigma");
  if (amplitude.size() != sigma_m.size()) {
    throw std::invalid_argument("ThesisConfidence::sigma: amplitude and sigma_m differ in length");
  }
  const auto& p = params_;
  for (std::size_t k = 0; k < amplitude.size(); ++k) {
    if (!std::isfinite(amplitude[k])) {
      sigma_m[k] = kNaN;
      continue;
    }
    // Clamped to the fitting domain: a cubic explodes outside it.
    const double x =
        p.amplitude_scaling.apply(clamp_to(amplitude[k], p.amplitude_min, p.amplitude_max));
    double e2 = 0;
    for (std::size_t j = p.coefficients.size(); j-- > 0;) e2 = e2 * x + p.coefficients[j];
    // Thesis Section 4.8: the cubic goes negative at high intensity, so E^2 is
    // floored; the thesis uses the floor alone above a stated intensity.
    const bool above = p.floor_above_amplitude > 0 && amplitude[k] > p.floor_above_amplitude;
    sigma_m[k] = std::sqrt(above ? p.floor_m2 : std::max(e2, p.floor_m2));
  }
}

CalibratedConfidence::CalibratedConfidence(CalibratedConfidenceParams params)
    : params_(std::move(params)) {
  const auto& p = params_;
  const std::string who = "CalibratedConfidence";
  if (p.exponents.empty() || p.exponents.size() != p.coefficients.size()) {
    throw std::invalid_argument(
        who + ": exponents and coefficients must be non-empty and of equal length");
  }
  if (p.systematic_exponents.size() != p.systematic_coefficients.size()) {
    throw std::invalid_argument(
        who + ": systematic_exponents and systematic_coefficients must be of equal length");
  }
  const auto check_terms = [&](const std::vector<std::array<int, 2>>& exps,
                               const std::vector<double>& c, const std::string& prefix) {
    for (std::size_t k = 0; k < exps.size(); ++k) {
      const auto [a, b] = exps[k];
      if (a < 0 || b < 0 || a > 7 || b > 7) {
        throw std::invalid_argument(who + ": " + prefix + "exponents[" + std::to_string(k) +
                                    "] must be in [0, 7]");
      }
      if (!std::isfinite(c[k])) {
        throw std::invalid_argument(who + ": " + prefix + "coefficients[" + std::to_string(k) +
                                    "] is not finite");
      }
    }
  };
  check_terms(p.exponents, p.coefficients, "");
  check_terms(p.systematic_exponents, p.systematic_coefficients, "systematic_");
  for (const AxisScaling* s : {&p.amplitude_scaling, &p.range_scaling}) {
    if (!std::isfinite(s->center) || !std::isfinite(s->half_width) || !(s->half_width > 0)) {
      throw std::invalid_argument(who + ": scalings need a finite center and positive half_width");
    }
  }
  const auto& d = p.domain;
  if (!(d.range_min_m < d.range_max_m) || !std::isfinite(d.range_min_m) ||
      !std::isfinite(d.range_max_m)) {
    throw std::invalid_argument(who + ": domain range must have min < max");
  }
  if (!(d.amplitude_min < d.amplitude_max) || !std::isfinite(d.amplitude_min) ||
      !std::isfinite(d.amplitude_max) || (p.log_amplitude && !(d.amplitude_min > 0))) {
    throw std::invalid_argument(
        who + ": domain amplitude must have min < max (and be positive on a log scale)");
  }
  if (p.band_coordinate.empty() || p.band_coordinate.size() != p.band_scale.size()) {
    throw std::invalid_argument(
        who + ": band_coordinate and band_scale must be non-empty and of equal length");
  }
  for (std::size_t k = 0; k < p.band_scale.size(); ++k) {
    if (!(p.band_scale[k] > 0) || !std::isfinite(p.band_scale[k]) ||
        !std::isfinite(p.band_coordinate[k]) ||
        (k > 0 && !(p.band_coordinate[k] > p.band_coordinate[k - 1]))) {
      throw std::invalid_argument(
          who + ": band " + std::to_string(k) +
          " needs a positive scale and a coordinate above the previous band's");
    }
  }
  require_finite_sigma(*this, d.amplitude_min, d.amplitude_max, d.range_min_m, d.range_max_m,
                       p.log_amplitude, "CalibratedConfidence");
}

void CalibratedConfidence::sigma(std::span<const double> range_m, std::span<const double> amplitude,
                                 std::span<double> sigma_m) const {
  check_lengths(range_m.size(), amplitude.size(), sigma_m.size(), "CalibratedConfidence::sigma");
  const auto& p = params_;
  const auto& d = p.domain;
  for (std::size_t k = 0; k < amplitude.size(); ++k) {
    if (!std::isfinite(amplitude[k]) || !std::isfinite(range_m[k])) {
      sigma_m[k] = kNaN;
      continue;
    }
    // Clamped to the fitting domain: no extrapolation of a fitted polynomial.
    const double a = clamp_to(amplitude[k], d.amplitude_min, d.amplitude_max);
    const double u = p.log_amplitude ? std::log(a) : a;
    const double y = p.range_scaling.apply(clamp_to(range_m[k], d.range_min_m, d.range_max_m));
    const double x = p.amplitude_scaling.apply(u);
    double e2 = std::exp(polynomial_2d(p.exponents, p.coefficients, x, y));
    // Noise and systematic error are independent: their variances add.
    if (!p.systematic_coefficients.empty())
      e2 += std::exp(polynomial_2d(p.systematic_exponents, p.systematic_coefficients, x, y));
    sigma_m[k] = band_factor(p.band_coordinate, p.band_scale, u) * std::sqrt(e2);
  }
}

}  // namespace tofkit::ranging
