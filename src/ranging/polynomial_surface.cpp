#include "tofkit/ranging/polynomial_surface.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

namespace tofkit::ranging {

namespace {

constexpr std::size_t kBlock = 256;  // rows per evaluation block (fits L1 with its scratch)

/// Tolerance for "inside the domain": a tiny share of the axis span, so a
/// training point itself is never flagged after a JSON round trip.
double domain_tolerance(double lo, double hi) {
  return 1e-9 * (hi - lo) + 1e-300;
}

/// Clamp one input column of a block to [lo, hi] and scale it; flags rows
/// outside (or not finite). NaN stays NaN, so its correction is NaN.
void clamp_and_scale(const double* x, std::size_t count, double lo, double hi,
                     const AxisScaling& scaling, double* scaled, std::uint8_t* flags) {
  const double tol = domain_tolerance(lo, hi);
  const double lo_tol = lo - tol;
  const double hi_tol = hi + tol;
  const double inv_half_width = 1.0 / scaling.half_width;
  for (std::size_t j = 0; j < count; ++j) {
    const double v = x[j];
    const bool outside = !(v >= lo_tol) || !(v <= hi_tol);
    flags[j] = static_cast<std::uint8_t>(flags[j] | static_cast<std::uint8_t>(outside));
    const double clamped = std::min(std::max(v, lo), hi);
    scaled[j] = (clamped - scaling.center) * inv_half_width;
  }
}

void require_scaling(const AxisScaling& s, const char* name) {
  if (!std::isfinite(s.center) || !std::isfinite(s.half_width) || !(s.half_width > 0)) {
    throw std::invalid_argument(std::string("PolynomialSurface: ") + name +
                                " must have a finite center and a positive half_width");
  }
}

void require_interval(double lo, double hi, const char* name) {
  if (!std::isfinite(lo) || !std::isfinite(hi) || !(lo < hi)) {
    throw std::invalid_argument(std::string("PolynomialSurface: domain ") + name +
                                " must be a finite interval with min < max");
  }
}

}  // namespace

std::vector<MonomialExponents> polynomial_exponents(int order, bool use_temperature) {
  if (order < 0) throw std::invalid_argument("polynomial_exponents: order must be >= 0");
  // Terms of (1 + r + i [+ t])^N: every monomial of total degree <= N.
  std::vector<MonomialExponents> out;
  for (int degree = 0; degree <= order; ++degree) {
    for (int a = degree; a >= 0; --a) {
      if (use_temperature) {
        for (int b = degree - a; b >= 0; --b) out.push_back({a, b, degree - a - b});
      } else {
        out.push_back({a, degree - a, 0});
      }
    }
  }
  return out;
}

PolynomialSurface::PolynomialSurface(PolynomialSurfaceParams params) : params_(std::move(params)) {
  const auto& p = params_;
  if (p.order < 0 || p.order > 20) {
    throw std::invalid_argument("PolynomialSurface: order must be in [0, 20]");
  }
  if (p.exponents.size() != p.coefficients.size()) {
    throw std::invalid_argument("PolynomialSurface: exponents and coefficients differ in length");
  }
  require_scaling(p.range_scaling, "range_scaling");
  require_scaling(p.amplitude_scaling, "amplitude_scaling");
  require_interval(p.domain.range_min_m, p.domain.range_max_m, "range");
  require_interval(p.domain.amplitude_min, p.domain.amplitude_max, "amplitude");
  if (p.use_temperature) {
    require_scaling(p.temperature_scaling, "temperature_scaling");
    require_interval(p.domain.temperature_min_c, p.domain.temperature_max_c, "temperature");
  }
  const int side = p.order + 1;
  horner_.assign(static_cast<std::size_t>(side) * side * side, 0.0);
  std::vector<bool> seen(horner_.size(), false);
  for (std::size_t k = 0; k < p.exponents.size(); ++k) {
    const auto [a, b, c] = p.exponents[k];
    if (a < 0 || b < 0 || c < 0 || a + b + c > p.order || (c > 0 && !p.use_temperature)) {
      throw std::invalid_argument("PolynomialSurface: exponents[" + std::to_string(k) +
                                  "] is not a monomial of total degree <= order" +
                                  (p.use_temperature ? "" : " without temperature"));
    }
    if (!std::isfinite(p.coefficients[k])) {
      throw std::invalid_argument("PolynomialSurface: coefficients[" + std::to_string(k) +
                                  "] is not finite");
    }
    const std::size_t index = (static_cast<std::size_t>(a) * side + b) * side + c;
    if (seen[index]) {
      throw std::invalid_argument("PolynomialSurface: exponents[" + std::to_string(k) +
                                  "] repeats a monomial");
    }
    seen[index] = true;
    horner_[index] = p.coefficients[k];
  }
}

void PolynomialSurface::evaluate(const SurfaceInputs& inputs, std::span<double> correction_m,
                                 std::span<std::uint8_t> out_of_domain) const {
  const std::size_t n = inputs.range_m.size();
  if (inputs.amplitude.size() != n || correction_m.size() != n || out_of_domain.size() != n ||
      (params_.use_temperature && inputs.temperature_c.size() != n)) {
    throw std::invalid_argument(
        "PolynomialSurface::evaluate: range_m, amplitude, correction_m, out_of_domain" +
        std::string(params_.use_temperature ? " and temperature_c" : "") +
        " must have the same length");
  }
  const auto& d = params_.domain;
  const int order = params_.order;
  const std::size_t side = static_cast<std::size_t>(order) + 1;
  const double* coeff = horner_.data();
  double r[kBlock], a[kBlock], t[kBlock], acc[kBlock], q[kBlock], s[kBlock];

  for (std::size_t start = 0; start < n; start += kBlock) {
    const std::size_t m = std::min(kBlock, n - start);
    std::uint8_t* flags = out_of_domain.data() + start;
    std::fill(flags, flags + m, std::uint8_t{0});
    clamp_and_scale(inputs.range_m.data() + start, m, d.range_min_m, d.range_max_m,
                    params_.range_scaling, r, flags);
    clamp_and_scale(inputs.amplitude.data() + start, m, d.amplitude_min, d.amplitude_max,
                    params_.amplitude_scaling, a, flags);
    if (params_.use_temperature) {
      clamp_and_scale(inputs.temperature_c.data() + start, m, d.temperature_min_c,
                      d.temperature_max_c, params_.temperature_scaling, t, flags);
    }
    // Nested Horner over the dense coefficient cube, p = sum_a r^a sum_b i^b
    // sum_c t^c c_abc, with the row loop innermost so it vectorizes.
    std::fill(acc, acc + m, 0.0);
    for (int ea = order; ea >= 0; --ea) {
      std::fill(q, q + m, 0.0);
      for (int eb = order - ea; eb >= 0; --eb) {
        const double* cab = coeff + (static_cast<std::size_t>(ea) * side + eb) * side;
        if (params_.use_temperature) {
          std::fill(s, s + m, 0.0);
          for (int ec = order - ea - eb; ec >= 0; --ec) {
            const double c = cab[ec];
            for (std::size_t j = 0; j < m; ++j) s[j] = s[j] * t[j] + c;
          }
          for (std::size_t j = 0; j < m; ++j) q[j] = q[j] * a[j] + s[j];
        } else {
          const double c = cab[0];
          for (std::size_t j = 0; j < m; ++j) q[j] = q[j] * a[j] + c;
        }
      }
      for (std::size_t j = 0; j < m; ++j) acc[j] = acc[j] * r[j] + q[j];
    }
    std::copy(acc, acc + m, correction_m.data() + start);
  }
}

}  // namespace tofkit::ranging
