#include "tofkit/ranging/fixed_point_chain.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>
#include <utility>

namespace tofkit::ranging {
namespace {

constexpr double kMicrometresPerMetre = 1e6;

std::int32_t to_int32(double value, const std::string& what, const FixedPointFormat& format) {
  const double rounded = std::nearbyint(value);
  if (!(rounded >= static_cast<double>(std::numeric_limits<std::int32_t>::min()) &&
        rounded <= static_cast<double>(std::numeric_limits<std::int32_t>::max()))) {
    throw std::invalid_argument(
        "fixed-point chain: " + what + " = " + std::to_string(value) +
        " does not fit int32 (fraction_bits = " + std::to_string(format.fraction_bits) +
        ", knot_fraction_bits = " + std::to_string(format.knot_fraction_bits) +
        "); use fewer fraction bits or a finer input LSB");
  }
  return static_cast<std::int32_t>(rounded);
}

/// A domain bound in input LSB * 2^K, saturated to int32 (infinite bounds stay open).
std::int32_t bound_to_int32(double value) {
  constexpr double lo = static_cast<double>(std::numeric_limits<std::int32_t>::min());
  constexpr double hi = static_cast<double>(std::numeric_limits<std::int32_t>::max());
  if (std::isnan(value)) throw std::invalid_argument("fixed-point chain: NaN domain bound");
  return static_cast<std::int32_t>(std::nearbyint(std::clamp(value, lo, hi)));
}

/// Quantizes one hinge y(x) [m], x = code * lsb; returns the folded constant in um * 2^F.
long double quantize_hinge(const Step& step, double lsb, const FixedPointFormat& format,
                           const std::string& name, FixedPointHinge& hinge) {
  const PiecewiseLinear& f = step.function;
  if (f.knots.size() > FixedPointChain::kMaxKnots) {
    throw std::invalid_argument("fixed-point chain: the " + name + " step has " +
                                std::to_string(f.knots.size()) + " knots (at most " +
                                std::to_string(FixedPointChain::kMaxKnots) + ")");
  }
  const double coefficient_scale = std::ldexp(1.0, format.fraction_bits);
  const double knot_scale = std::ldexp(1.0, format.knot_fraction_bits);
  hinge.enabled = true;
  // y_um = 1e6 (intercept - slope0 x0) + 1e6 slope0 lsb code + sum 1e6 s_k lsb max(0, code -
  // knot/lsb)
  hinge.slope0_q = to_int32(kMicrometresPerMetre * f.slope0 * lsb * coefficient_scale,
                            name + ".slope0_q", format);
  hinge.knots_q.clear();
  hinge.slopes_q.clear();
  for (std::size_t k = 0; k < f.knots.size(); ++k) {
    hinge.knots_q.push_back(to_int32(f.knots[k] / lsb * knot_scale,
                                     name + ".knots_q[" + std::to_string(k) + "]", format));
    hinge.slopes_q.push_back(to_int32(kMicrometresPerMetre * f.slopes[k] * lsb * coefficient_scale,
                                      name + ".slopes_q[" + std::to_string(k) + "]", format));
  }
  hinge.domain_min_q = bound_to_int32(step.domain.min / lsb * knot_scale);
  hinge.domain_max_q = bound_to_int32(step.domain.max / lsb * knot_scale);
  return static_cast<long double>(kMicrometresPerMetre) *
         (static_cast<long double>(f.intercept) -
          static_cast<long double>(f.slope0) * static_cast<long double>(f.x0)) *
         static_cast<long double>(coefficient_scale);
}

void validate_hinge(const FixedPointHinge& h, const std::string& name) {
  if (h.knots_q.size() != h.slopes_q.size()) {
    throw std::invalid_argument("fixed-point chain: " + name + " has " +
                                std::to_string(h.knots_q.size()) + " knots but " +
                                std::to_string(h.slopes_q.size()) + " slopes");
  }
  if (h.knots_q.size() > FixedPointChain::kMaxKnots) {
    throw std::invalid_argument("fixed-point chain: " + name + " has more than " +
                                std::to_string(FixedPointChain::kMaxKnots) + " knots");
  }
  for (std::size_t k = 1; k < h.knots_q.size(); ++k) {
    if (h.knots_q[k] <= h.knots_q[k - 1]) {
      throw std::invalid_argument("fixed-point chain: " + name + ".knots_q must be ascending");
    }
  }
  if (h.domain_min_q > h.domain_max_q) {
    throw std::invalid_argument("fixed-point chain: " + name + " domain_min_q > domain_max_q");
  }
}

/// slope0_q x_q + sum_k slopes_q[k] max(0, x_q - knots_q[k]), in um 2^-(F+K).
inline std::int64_t hinge_sum(const FixedPointHinge& h, std::int32_t code, int knot_bits) {
  const std::int64_t x_q = static_cast<std::int64_t>(code) * (std::int64_t{1} << knot_bits);
  std::int64_t sum = static_cast<std::int64_t>(h.slope0_q) * x_q;
  for (std::size_t k = 0; k < h.knots_q.size(); ++k) {
    const std::int64_t over = x_q - h.knots_q[k];
    sum += static_cast<std::int64_t>(h.slopes_q[k]) * (over > 0 ? over : 0);
  }
  return sum;
}

inline bool outside(const FixedPointHinge& h, std::int32_t code, int knot_bits) {
  const std::int64_t x_q = static_cast<std::int64_t>(code) * (std::int64_t{1} << knot_bits);
  return x_q < h.domain_min_q || x_q > h.domain_max_q;
}

}  // namespace

void FixedPointFormat::validate() const {
  const auto positive = [](double v, const char* field) {
    if (!(v > 0) || !std::isfinite(v)) {
      throw std::invalid_argument(std::string("fixed-point format: ") + field + " = " +
                                  std::to_string(v) + " must be positive");
    }
  };
  positive(tdc_lsb_ps, "tdc_lsb_ps");
  positive(pulse_width_lsb_ps, "pulse_width_lsb_ps");
  positive(temperature_lsb_c, "temperature_lsb_c");
  if (fraction_bits < 1 || fraction_bits > 30) {
    throw std::invalid_argument("fixed-point format: fraction_bits = " +
                                std::to_string(fraction_bits) + " is out of range [1, 30]");
  }
  if (knot_fraction_bits < 0 || knot_fraction_bits > 14) {
    throw std::invalid_argument("fixed-point format: knot_fraction_bits = " +
                                std::to_string(knot_fraction_bits) + " is out of range [0, 14]");
  }
}

FixedPointChain::FixedPointChain(FixedPointCoefficients coefficients)
    : c_(std::move(coefficients)) {
  c_.format.validate();
  validate_hinge(c_.grayvalue, "grayvalue");
  validate_hinge(c_.temperature, "temperature");
  if (!c_.grayvalue.enabled) c_.grayvalue = FixedPointHinge{};
  if (!c_.temperature.enabled) c_.temperature = FixedPointHinge{};
}

FixedPointChain FixedPointChain::from_pipeline(const Pipeline& pipeline,
                                               const FixedPointFormat& format) {
  format.validate();
  FixedPointCoefficients c;
  c.format = format;
  const double coefficient_scale = std::ldexp(1.0, format.fraction_bits);
  // um per TDC LSB: c_air / 2 [m/ns] * lsb [ns] * 1e6.
  c.tof_scale_q = to_int32(metres_per_ns(pipeline.time_to_distance()) * format.tdc_lsb_ps * 1e-3 *
                               kMicrometresPerMetre * coefficient_scale,
                           "tof_scale_q", format);
  long double constant = 0;
  bool seen[6] = {false, false, false, false, false, false};
  for (const Step& step : pipeline.steps()) {
    const auto index = static_cast<std::size_t>(step.kind);
    if (seen[index]) {
      throw std::invalid_argument("fixed-point chain: more than one " +
                                  std::string(step_kind_name(step.kind)) + " step");
    }
    seen[index] = true;
    switch (step.kind) {
      case StepKind::kOffset:
        constant += static_cast<long double>(step.offset_m) * kMicrometresPerMetre *
                    static_cast<long double>(coefficient_scale);
        break;
      case StepKind::kGrayvalue:
        constant += quantize_hinge(step, format.pulse_width_lsb_ps * 1e-3, format, "grayvalue",
                                   c.grayvalue);
        break;
      case StepKind::kTemperature:
        constant +=
            quantize_hinge(step, format.temperature_lsb_c, format, "temperature", c.temperature);
        break;
      case StepKind::kSurface:
      case StepKind::kWalk:
      case StepKind::kPeriodic:
        throw std::invalid_argument("fixed-point chain: a " +
                                    std::string(step_kind_name(step.kind)) +
                                    " step cannot be exported (only offset, grayvalue and "
                                    "temperature steps)");
    }
  }
  if (!(std::fabs(constant) < 9.0e18L)) {
    throw std::invalid_argument("fixed-point chain: constant_q does not fit int64");
  }
  c.constant_q = static_cast<std::int64_t>(std::llround(constant));
  return FixedPointChain(std::move(c));
}

FixedPointOutput FixedPointChain::apply(const FixedPointInput& in) const {
  FixedPointOutput out;
  apply(std::span<const FixedPointInput>(&in, 1), std::span<FixedPointOutput>(&out, 1));
  return out;
}

void FixedPointChain::apply(std::span<const FixedPointInput> in,
                            std::span<FixedPointOutput> out) const {
  if (in.size() != out.size()) {
    throw std::invalid_argument("FixedPointChain::apply: input and output sizes differ");
  }
  const int f_bits = c_.format.fraction_bits;
  const int k_bits = c_.format.knot_fraction_bits;
  const std::int64_t half = std::int64_t{1} << (f_bits - 1);
  const std::int64_t constant = c_.constant_q;
  const std::int64_t tof_scale = c_.tof_scale_q;
  const FixedPointHinge& g = c_.grayvalue;
  const FixedPointHinge& h = c_.temperature;
  for (std::size_t i = 0; i < in.size(); ++i) {
    const FixedPointInput& m = in[i];
    std::int64_t acc = constant + static_cast<std::int64_t>(m.tof_code) * tof_scale;
    std::uint32_t flags = 0;
    if (g.enabled) {
      acc += hinge_sum(g, m.pulse_width_code, k_bits) >> k_bits;  // arithmetic shift: floor
      flags |= outside(g, m.pulse_width_code, k_bits) ? kCorrOutOfDomain : 0u;
    }
    if (h.enabled) {
      acc += hinge_sum(h, m.temperature_code, k_bits) >> k_bits;
      flags |= outside(h, m.temperature_code, k_bits) ? kCorrOutOfDomain : 0u;
    }
    const bool no_echo = (m.flags & kRawNoEcho) != 0;
    out[i].distance_um =
        no_echo ? kFixedNoDistance : static_cast<std::int32_t>((acc + half) >> f_bits);
    out[i].correction_flags = no_echo ? kCorrNoEcho : flags;
  }
}

RawMeasurement FixedPointChain::to_raw(const FixedPointInput& in) const {
  RawMeasurement m;
  m.tof_ns = in.tof_code * c_.format.tdc_lsb_ps * 1e-3;
  m.pulse_width_ns = in.pulse_width_code * c_.format.pulse_width_lsb_ps * 1e-3;
  m.temperature_c = in.temperature_code * c_.format.temperature_lsb_c;
  m.flags = in.flags;
  m.shots_valid = (in.flags & kRawNoEcho) != 0 ? 0 : 1;
  return m;
}

FixedPointInput FixedPointChain::to_codes(const RawMeasurement& in) const {
  FixedPointInput codes;
  // A value the 32-bit register cannot hold (NaN, or beyond its range) is no
  // reading: the row goes to the chain as one without an echo.
  bool representable = true;
  const auto code = [&](double value, double lsb) {
    const double q = value / lsb;
    if (!(std::fabs(q) < 2147483647.0)) {  // (NaN fails too)
      representable = false;
      return std::int32_t{0};
    }
    return static_cast<std::int32_t>(std::lround(q));
  };
  codes.tof_code = code(in.tof_ns, c_.format.tdc_lsb_ps * 1e-3);
  codes.pulse_width_code = code(in.pulse_width_ns, c_.format.pulse_width_lsb_ps * 1e-3);
  codes.temperature_code = code(in.temperature_c, c_.format.temperature_lsb_c);
  codes.flags = in.flags | (in.has_echo() && representable ? 0u : kRawNoEcho);
  return codes;
}

}  // namespace tofkit::ranging
