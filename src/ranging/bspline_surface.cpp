#include "tofkit/ranging/bspline_surface.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <stdexcept>
#include <string>

namespace tofkit::ranging {

namespace {

constexpr std::size_t kBlock = 256;  // rows per evaluation block

/// Clamp one input column of a block to [lo, hi] (input units) and map it to
/// the axis coordinate; flags rows outside by more than a tiny tolerance or not
/// finite. NaN stays NaN (its correction is NaN).
void clamp_to_axis(const double* x, std::size_t count, double lo, double hi,
                   const BSplineAxis& axis, double* coordinate, std::uint8_t* flags) {
  const double tol = 1e-9 * (hi - lo) + 1e-300;
  const double lo_tol = lo - tol;
  const double hi_tol = hi + tol;
  for (std::size_t j = 0; j < count; ++j) {
    const double v = x[j];
    const bool outside = !(v >= lo_tol) || !(v <= hi_tol);
    flags[j] = static_cast<std::uint8_t>(flags[j] | static_cast<std::uint8_t>(outside));
    coordinate[j] = std::min(std::max(v, lo), hi);
  }
  if (axis.log_scale) {
    for (std::size_t j = 0; j < count; ++j) coordinate[j] = std::log(coordinate[j]);
  }
}

std::string number_text(double v) {
  char buffer[32];
  std::snprintf(buffer, sizeof buffer, "%.6g", v);
  return buffer;
}

void require_axis(const BSplineAxis& axis, double domain_min, double domain_max, const char* name) {
  const std::string prefix = std::string("BSplineSurface: ") + name;
  axis.validate(prefix);
  if (!std::isfinite(domain_min) || !std::isfinite(domain_max) || !(domain_min < domain_max)) {
    throw std::invalid_argument(prefix + " domain must be a finite interval with min < max");
  }
  if (axis.log_scale && !(domain_min > 0)) {
    throw std::invalid_argument(prefix + " axis is on a log scale but its domain is not positive");
  }
  // Inputs are clamped to the domain, and the spline is defined between its
  // first and last knot only: a domain wider than the knots evaluates the
  // basis outside its span (extrapolated, or coefficients read past the grid).
  const double lo = axis.log_scale ? std::log(domain_min) : domain_min;
  const double hi = axis.log_scale ? std::log(domain_max) : domain_max;
  const double tolerance = 1e-9 * (axis.hi() - axis.lo());
  if (!(lo >= axis.lo() - tolerance) || !(hi <= axis.hi() + tolerance)) {
    const auto input = [&](double u) { return axis.log_scale ? std::exp(u) : u; };
    throw std::invalid_argument(prefix + " domain [" + number_text(domain_min) + ", " +
                                number_text(domain_max) + "] exceeds the axis knots [" +
                                number_text(input(axis.lo())) + ", " +
                                number_text(input(axis.hi())) + "]");
  }
}

}  // namespace

BSplineSurface::BSplineSurface(BSplineSurfaceParams params) : params_(std::move(params)) {
  const auto& p = params_;
  require_axis(p.range, p.domain.range_min_m, p.domain.range_max_m, "range");
  require_axis(p.amplitude, p.domain.amplitude_min, p.domain.amplitude_max, "amplitude");
  std::size_t count = static_cast<std::size_t>(p.range.basis_count()) * p.amplitude.basis_count();
  if (p.use_temperature) {
    require_axis(p.temperature, p.domain.temperature_min_c, p.domain.temperature_max_c,
                 "temperature");
    count *= static_cast<std::size_t>(p.temperature.basis_count());
  }
  knots_.emplace_back(p.range);
  knots_.emplace_back(p.amplitude);
  if (p.use_temperature) knots_.emplace_back(p.temperature);
  if (p.coefficients.size() != count) {
    throw std::invalid_argument("BSplineSurface: coefficients has " +
                                std::to_string(p.coefficients.size()) + " entries, the grid " +
                                std::to_string(count));
  }
  for (std::size_t k = 0; k < count; ++k) {
    if (!std::isfinite(p.coefficients[k])) {
      throw std::invalid_argument("BSplineSurface: coefficients[" + std::to_string(k) +
                                  "] is not finite");
    }
  }
}

void BSplineSurface::evaluate(const SurfaceInputs& inputs, std::span<double> correction_m,
                              std::span<std::uint8_t> out_of_domain) const {
  const std::size_t n = inputs.range_m.size();
  const bool use_t = params_.use_temperature;
  if (inputs.amplitude.size() != n || correction_m.size() != n || out_of_domain.size() != n ||
      (use_t && inputs.temperature_c.size() != n)) {
    throw std::invalid_argument(
        "BSplineSurface::evaluate: range_m, amplitude, correction_m, out_of_domain" +
        std::string(use_t ? " and temperature_c" : "") + " must have the same length");
  }
  const auto& d = params_.domain;
  const BSplineAxis& ar = params_.range;
  const BSplineAxis& aa = params_.amplitude;
  const BSplineAxis& at = params_.temperature;
  const std::size_t na = static_cast<std::size_t>(aa.basis_count());
  const std::size_t nt = use_t ? static_cast<std::size_t>(at.basis_count()) : 1;
  const double* coeff = params_.coefficients.data();
  double ur[kBlock], ua[kBlock], ut[kBlock];

  for (std::size_t start = 0; start < n; start += kBlock) {
    const std::size_t m = std::min(kBlock, n - start);
    std::uint8_t* flags = out_of_domain.data() + start;
    double* out = correction_m.data() + start;
    std::fill(flags, flags + m, std::uint8_t{0});
    clamp_to_axis(inputs.range_m.data() + start, m, d.range_min_m, d.range_max_m, ar, ur, flags);
    clamp_to_axis(inputs.amplitude.data() + start, m, d.amplitude_min, d.amplitude_max, aa, ua,
                  flags);
    if (use_t) {
      clamp_to_axis(inputs.temperature_c.data() + start, m, d.temperature_min_c,
                    d.temperature_max_c, at, ut, flags);
    }
    for (std::size_t j = 0; j < m; ++j) {
      if (std::isnan(ur[j]) || std::isnan(ua[j]) || (use_t && std::isnan(ut[j]))) {
        out[j] = std::numeric_limits<double>::quiet_NaN();
        continue;
      }
      // Tensor product: f = sum_p sum_q [sum_s] Br_p Ba_q [Bt_s] c_pq[s].
      const BSplineSpan sr = knots_[0].span(ur[j]);
      const BSplineSpan sa = knots_[1].span(ua[j]);
      double value = 0;
      if (!use_t) {
        for (int p = 0; p < 4; ++p) {
          const double* row = coeff + (static_cast<std::size_t>(sr.first + p)) * na + sa.first;
          const double inner = sa.weight[0] * row[0] + sa.weight[1] * row[1] +
                               sa.weight[2] * row[2] + sa.weight[3] * row[3];
          value += sr.weight[p] * inner;
        }
      } else {
        const BSplineSpan st = knots_[2].span(ut[j]);
        for (int p = 0; p < 4; ++p) {
          double inner = 0;
          for (int q = 0; q < 4; ++q) {
            const double* cell =
                coeff + ((static_cast<std::size_t>(sr.first + p)) * na + sa.first + q) * nt +
                st.first;
            inner += sa.weight[q] * (st.weight[0] * cell[0] + st.weight[1] * cell[1] +
                                     st.weight[2] * cell[2] + st.weight[3] * cell[3]);
          }
          value += sr.weight[p] * inner;
        }
      }
      out[j] = value;
    }
  }
}

}  // namespace tofkit::ranging
