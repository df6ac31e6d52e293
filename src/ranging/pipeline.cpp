#include "tofkit/ranging/pipeline.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstddef>
#include <numbers>
#include <sstream>
#include <stdexcept>
#include <utility>

namespace tofkit::ranging {
namespace {

/// A number beyond kMaxMagnitude is a corrupt cell: read as missing.
double measured(double v) {
  return std::fabs(v) <= kMaxMagnitude ? v : kNaN;
}

/// Rows processed together: small enough that the column buffers stay in L1,
/// large enough that each step's loop over them vectorizes and amortizes the
/// dispatch on the step kind.
constexpr std::size_t kBlock = 256;

struct BlockBuffers {
  std::array<double, kBlock> distance;
  std::array<double, kBlock> tof;
  std::array<double, kBlock> pulse_width;
  std::array<double, kBlock> temperature;
  std::array<double, kBlock> amplitude;
  std::array<double, kBlock> scratch_a;
  std::array<double, kBlock> scratch_b;
  std::array<double, kBlock> scratch_c;
  /// > 0 once an input is outside a step's domain: the largest distance
  /// outside, in widths of that domain (a double, so the checks vectorize).
  std::array<double, kBlock> outside;
  /// Variance (m^2) a step knows it adds where it extrapolates (a walk step
  /// with its shape's bootstrap replicates), added to sigma^2 instead of the growth.
  std::array<double, kBlock> extra_variance;
  std::array<std::uint32_t, kBlock> flags;
  std::array<std::uint8_t, kBlock> out_of_domain;
};

/// Smallest recorded distance outside a domain (so a row just outside stays flagged).
constexpr double kMinOutside = 1e-12;

/// Distance of x outside [lo, hi] in widths of the interval (0 inside or NaN).
double outside_widths(double x, double lo, double hi) {
  const double width = hi - lo > 0 ? hi - lo : 1.0;
  const double d = std::max(lo - x, x - hi) / width;
  return d > 0 ? std::max(d, kMinOutside) : 0.0;
}

/// distance += y(x) for a hinge folded to y = c + b0 x + sum_k s_k max(0, x - knot_k);
/// x outside the fitted domain is marked (outside = its distance from the
/// domain in domain widths) but still corrected (linear continuation).
/// NaN x propagates into the distance (flagged non-finite at the end).
void add_hinge(const PiecewiseLinear& f, const InputDomain& domain, const double* __restrict x,
               double* __restrict distance, double* __restrict outside, std::size_t n) {
  const double constant = f.intercept - f.slope0 * f.x0;
  const double slope0 = f.slope0;
  const double lo = domain.min;
  const double hi = domain.max;
  for (std::size_t i = 0; i < n; ++i) distance[i] += constant + slope0 * x[i];
  for (std::size_t i = 0; i < n; ++i) {
    // A double select (and/andnot) vectorizes where a double -> integer flag does not.
    outside[i] = std::max(outside[i], outside_widths(x[i], lo, hi));
  }
  for (std::size_t k = 0; k < f.knots.size(); ++k) {
    const double knot = f.knots[k];
    const double slope = f.slopes[k];
    for (std::size_t i = 0; i < n; ++i) {
      const double over = x[i] - knot;
      // (over > 0 ? over : 0) keeps NaN as 0 here; the slope0 term already made it NaN.
      distance[i] += slope * (over > 0.0 ? over : 0.0);
    }
  }
}

/// distance += -(c_air / 2) (t_rise(w) - t_rise(w_ref)): a late rising crossing
/// reads long (walk, DESIGN.md "Discriminator"). Widths outside the fitted
/// domain are marked but corrected by the shape (its physics extrapolates).
/// With the shape's replicates, the uncertainty there is the walk's own: the
/// variance of its prediction at w beyond that at the domain's nearer edge
/// (inside, the confidence model measured the error already), so sigma grows
/// as the fitted shape's uncertainty does; without it, the generic growth.
void add_walk(const WalkModel& walk, const InputDomain& domain, double metres_per_ns,
              BlockBuffers& b, std::size_t n) {
  double* rise = b.scratch_a.data();
  walk.relative_rise_ns(b.pulse_width.data(), rise, n);
  for (std::size_t i = 0; i < n; ++i) b.distance[i] -= metres_per_ns * rise[i];
  if (!walk.has_replicates()) {
    for (std::size_t i = 0; i < n; ++i)
      b.outside[i] =
          std::max(b.outside[i], outside_widths(b.pulse_width[i], domain.min, domain.max));
    return;
  }
  const double at_min = walk.relative_rise_variance_ns2(domain.min);
  const double at_max = walk.relative_rise_variance_ns2(domain.max);
  for (std::size_t i = 0; i < n; ++i) {
    const double w = b.pulse_width[i];
    if (!(outside_widths(w, domain.min, domain.max) > 0)) continue;
    b.outside[i] = std::max(b.outside[i], kMinOutside);  // flagged, no generic growth
    const double excess = walk.relative_rise_variance_ns2(w) - (w < domain.min ? at_min : at_max);
    b.extra_variance[i] += metres_per_ns * metres_per_ns * std::max(excess, 0.0);
  }
}

double midpoint(double lo, double hi) {
  const double mid = 0.5 * (lo + hi);
  return std::isfinite(mid) ? mid : 0.0;
}

/// A surface step on one block. NaN inputs are replaced by the domain's
/// midpoint before evaluation (surfaces need not accept NaN) and the
/// correction is then set to NaN.
void add_surface(const CorrectionSurface& surface, BlockBuffers& b, std::size_t n) {
  const SurfaceDomain& d = surface.domain();
  const bool uses_temperature = surface.uses_temperature();
  double* range = b.scratch_a.data();
  double* amplitude = b.scratch_b.data();
  double* temperature = b.scratch_c.data();
  std::array<double, kBlock> correction;
  std::array<std::uint8_t, kBlock> missing;
  const double range_mid = midpoint(d.range_min_m, d.range_max_m);
  const double amplitude_mid = midpoint(d.amplitude_min, d.amplitude_max);
  const double temperature_mid = midpoint(d.temperature_min_c, d.temperature_max_c);
  const bool pulse_width = surface.intensity_input() == IntensityInput::pulse_width;
  const double* intensity = pulse_width ? b.pulse_width.data() : b.amplitude.data();
  const bool log_amplitude = !pulse_width && d.amplitude_min > 0;
  const double log_amplitude_lo = log_amplitude ? std::log(d.amplitude_min) : 0.0;
  const double log_amplitude_hi = log_amplitude ? std::log(d.amplitude_max) : 0.0;
  for (std::size_t i = 0; i < n; ++i) {
    const bool bad = !std::isfinite(b.distance[i]) || !std::isfinite(intensity[i]) ||
                     (uses_temperature && !std::isfinite(b.temperature[i]));
    missing[i] = bad ? 1 : 0;
    range[i] = std::isfinite(b.distance[i]) ? b.distance[i] : range_mid;
    amplitude[i] = std::isfinite(intensity[i]) ? intensity[i] : amplitude_mid;
    temperature[i] = std::isfinite(b.temperature[i]) ? b.temperature[i] : temperature_mid;
  }
  SurfaceInputs inputs{
      std::span<const double>(range, n), std::span<const double>(amplitude, n),
      uses_temperature ? std::span<const double>(temperature, n) : std::span<const double>()};
  surface.evaluate(inputs, std::span<double>(correction.data(), n),
                   std::span<std::uint8_t>(b.out_of_domain.data(), n));
  for (std::size_t i = 0; i < n; ++i) {
    if (missing[i] != 0) {
      b.distance[i] = kNaN;
      continue;
    }
    b.distance[i] += correction[i];
    if (b.out_of_domain[i] == 0) continue;
    // Distance outside the surface's box, in widths of each axis (amplitude
    // on a log scale when the domain is positive: intensity spans decades).
    double widths = outside_widths(range[i], d.range_min_m, d.range_max_m);
    widths = std::max(
        widths, log_amplitude
                    ? outside_widths(std::log(amplitude[i]), log_amplitude_lo, log_amplitude_hi)
                    : outside_widths(amplitude[i], d.amplitude_min, d.amplitude_max));
    if (uses_temperature) {
      widths = std::max(widths,
                        outside_widths(temperature[i], d.temperature_min_c, d.temperature_max_c));
    }
    b.outside[i] = std::max({b.outside[i], widths, kMinOutside});
  }
}

void fill_sigma(const ConfidenceModel* confidence, double residual_rms_m, BlockBuffers& b,
                std::size_t n, double* sigma) {
  if (confidence == nullptr) {
    for (std::size_t i = 0; i < n; ++i) sigma[i] = residual_rms_m;
  } else {
    double* range = b.scratch_a.data();
    double* amplitude = b.scratch_b.data();
    // The model's intensity axis: the amplitude, or the pulse width (which
    // keeps growing where the amplitude reading clips).
    const double* intensity = confidence->intensity_input() == IntensityInput::pulse_width
                                  ? b.pulse_width.data()
                                  : b.amplitude.data();
    for (std::size_t i = 0; i < n; ++i) {
      range[i] = std::isfinite(b.distance[i]) ? b.distance[i] : 1.0;
      amplitude[i] = std::isfinite(intensity[i]) ? intensity[i] : 1.0;
    }
    confidence->sigma(std::span<const double>(range, n), std::span<const double>(amplitude, n),
                      std::span<double>(sigma, n));
    for (std::size_t i = 0; i < n; ++i) {
      if (!std::isfinite(intensity[i])) sigma[i] = kNaN;
    }
  }
  for (std::size_t i = 0; i < n; ++i) {
    // Outside a step's domain the correction extrapolates: its expected error
    // grows with the distance from the domain (Pipeline::kOutOfDomainSigmaGrowth),
    // or by the variance the step knows it adds there.
    if (b.extra_variance[i] > 0) sigma[i] = std::sqrt(sigma[i] * sigma[i] + b.extra_variance[i]);
    sigma[i] *= 1.0 + Pipeline::kOutOfDomainSigmaGrowth * b.outside[i];
    if (!std::isfinite(b.distance[i])) sigma[i] = kNaN;
  }
}

std::string format_number(double value) {
  std::ostringstream out;
  out.precision(6);
  out << value;
  return out.str();
}

}  // namespace

std::string_view step_kind_name(StepKind kind) {
  switch (kind) {
    case StepKind::kOffset:
      return "offset";
    case StepKind::kGrayvalue:
      return "grayvalue";
    case StepKind::kTemperature:
      return "temperature";
    case StepKind::kSurface:
      return "surface";
    case StepKind::kWalk:
      return "walk";
    case StepKind::kPeriodic:
      return "periodic";
  }
  return "unknown";
}

StepKind step_kind_from_name(std::string_view name) {
  for (StepKind kind : {StepKind::kOffset, StepKind::kGrayvalue, StepKind::kTemperature,
                        StepKind::kSurface, StepKind::kWalk, StepKind::kPeriodic}) {
    if (step_kind_name(kind) == name) return kind;
  }
  throw std::invalid_argument(
      "unknown step kind \"" + std::string(name) +
      "\" (expected offset, grayvalue, temperature, surface, walk or periodic)");
}

void Step::validate() const {
  const std::string name(step_kind_name(kind));
  switch (kind) {
    case StepKind::kOffset:
      if (!std::isfinite(offset_m)) {
        throw std::invalid_argument("offset step: offset_m is not finite");
      }
      break;
    case StepKind::kGrayvalue:
    case StepKind::kTemperature:
      try {
        function.validate();
      } catch (const std::invalid_argument& e) {
        throw std::invalid_argument(name + " step: " + e.what());
      }
      if (std::isnan(domain.min) || std::isnan(domain.max) || domain.min > domain.max) {
        throw std::invalid_argument(name + " step: domain [" + format_number(domain.min) + ", " +
                                    format_number(domain.max) + "] is empty or NaN");
      }
      {
        // Linear between its knots: finite at the knots and the domain's
        // (finite) ends, finite everywhere it is evaluated. Slopes too large
        // (a corrupt model file) would turn every corrected row into inf.
        std::vector<double> at = function.knots;
        at.push_back(function.x0);
        for (double end : {domain.min, domain.max}) {
          if (std::isfinite(end)) at.push_back(end);
        }
        for (double x : at) {
          if (!std::isfinite(function(x))) {
            throw std::invalid_argument(name + " step: the function is not finite at " +
                                        format_number(x) + " (slopes too large)");
          }
        }
      }
      break;
    case StepKind::kSurface:
      if (!surface) throw std::invalid_argument("surface step: no surface");
      break;
    case StepKind::kWalk:
      if (!walk) throw std::invalid_argument("walk step: no walk model");
      if (std::isnan(domain.min) || std::isnan(domain.max) || domain.min > domain.max) {
        throw std::invalid_argument("walk step: domain [" + format_number(domain.min) + ", " +
                                    format_number(domain.max) + "] is empty or NaN");
      }
      break;
    case StepKind::kPeriodic:
      if (!(period_ns > 0) || !std::isfinite(period_ns)) {
        throw std::invalid_argument("periodic step: period_ns must be positive");
      }
      if (harmonics_m.empty() || harmonics_m.size() % 2 != 0) {
        throw std::invalid_argument(
            "periodic step: harmonics_m needs a cosine and a sine coefficient per harmonic");
      }
      for (double c : harmonics_m) {
        if (!std::isfinite(c))
          throw std::invalid_argument("periodic step: a harmonic is not finite");
      }
      if (!harmonics_per_c_m.empty() && harmonics_per_c_m.size() != harmonics_m.size()) {
        throw std::invalid_argument(
            "periodic step: harmonics_per_c_m needs as many coefficients as harmonics_m");
      }
      for (double c : harmonics_per_c_m) {
        if (!std::isfinite(c))
          throw std::invalid_argument(
              "periodic step: a harmonic's temperature slope is not finite");
      }
      if (!harmonics_per_c_m.empty() && !std::isfinite(reference_temperature_c)) {
        throw std::invalid_argument("periodic step: reference_temperature_c is not finite");
      }
      break;
  }
}

Step make_offset_step(double offset_m) {
  Step step;
  step.kind = StepKind::kOffset;
  step.offset_m = offset_m;
  return step;
}

Step make_grayvalue_step(PiecewiseLinear function, InputDomain pulse_width_domain_ns) {
  Step step;
  step.kind = StepKind::kGrayvalue;
  step.function = std::move(function);
  step.domain = pulse_width_domain_ns;
  return step;
}

Step make_temperature_step(PiecewiseLinear function, InputDomain temperature_domain_c) {
  Step step;
  step.kind = StepKind::kTemperature;
  step.function = std::move(function);
  step.domain = temperature_domain_c;
  return step;
}

Step make_surface_step(std::shared_ptr<const CorrectionSurface> surface) {
  Step step;
  step.kind = StepKind::kSurface;
  step.surface = std::move(surface);
  return step;
}

Step make_walk_step(std::shared_ptr<const WalkModel> walk, InputDomain pulse_width_domain_ns) {
  Step step;
  step.kind = StepKind::kWalk;
  step.walk = std::move(walk);
  step.domain = pulse_width_domain_ns;
  return step;
}

Step make_periodic_step(double period_ns, std::vector<double> harmonics_m, bool both_stops) {
  Step step;
  step.kind = StepKind::kPeriodic;
  step.period_ns = period_ns;
  step.harmonics_m = std::move(harmonics_m);
  step.both_stops = both_stops;
  return step;
}

double periodic_correction(const Step& step, double tof_ns, double temperature_c) {
  if (!std::isfinite(tof_ns)) return 0.0;
  // The phase from the remainder, so that large times keep their precision.
  const double phase = 2.0 * std::numbers::pi * std::fmod(tof_ns, step.period_ns) / step.period_ns;
  const auto& a = step.harmonics_m;
  const auto& slope = step.harmonics_per_c_m;
  const double dt = std::isfinite(temperature_c) && !slope.empty()
                        ? temperature_c - step.reference_temperature_c
                        : 0.0;
  double c = 0;
  for (std::size_t h = 0; 2 * h + 1 < a.size(); ++h) {
    const double angle = static_cast<double>(h + 1) * phase;
    const double ca = a[2 * h] + (dt != 0 ? slope[2 * h] * dt : 0.0);
    const double sa = a[2 * h + 1] + (dt != 0 ? slope[2 * h + 1] * dt : 0.0);
    c += ca * std::cos(angle) + sa * std::sin(angle);
  }
  return c;
}

Pipeline::Pipeline(TimeToDistance time_to_distance) : time_to_distance_(time_to_distance) {
  time_to_distance_.validate();
  metres_per_ns_ = metres_per_ns(time_to_distance_);
}

void Pipeline::add_step(Step step) {
  step.validate();
  steps_.push_back(std::move(step));
}

void Pipeline::set_confidence(std::shared_ptr<const ConfidenceModel> confidence) {
  confidence_ = std::move(confidence);
}

void Pipeline::set_residual_rms_m(double residual_rms_m) {
  if (!(residual_rms_m >= 0) && !std::isnan(residual_rms_m)) {
    throw std::invalid_argument("residual_rms_m must be >= 0");
  }
  residual_rms_m_ = residual_rms_m;
}

double Pipeline::start_distance_m(const RawMeasurement& in) const {
  // S = c_air t / 2 (paper Section 2); a source without a time of flight
  // (e.g. a CSV with distances only) supplies its own distance.
  const double tof = measured(in.tof_ns);
  return std::isfinite(tof) ? tof * metres_per_ns_ : measured(in.distance_raw_m);
}

RawColumns RawColumns::of(std::span<const RawMeasurement> rows) {
  return of(rows.data(), rows.size(), sizeof(RawMeasurement));
}

RawColumns RawColumns::of(std::span<const Record> records) {
  return records.empty() ? RawColumns{} : of(&records[0].raw, records.size(), sizeof(Record));
}

RawColumns RawColumns::of(const RawMeasurement* first, std::size_t size, std::ptrdiff_t stride) {
  if (size == 0 || first == nullptr) return RawColumns{};  // (no offsets from a null pointer)
  const auto* base = reinterpret_cast<const std::byte*>(first);
  const auto column = [&]<typename T>(std::size_t offset, T) {
    return StridedColumn<T>{base + offset, stride};
  };
  RawColumns c;
  c.size = size;
  c.tof_ns = column(offsetof(RawMeasurement, tof_ns), 0.0);
  c.distance_raw_m = column(offsetof(RawMeasurement, distance_raw_m), 0.0);
  c.pulse_width_ns = column(offsetof(RawMeasurement, pulse_width_ns), 0.0);
  c.amplitude = column(offsetof(RawMeasurement, amplitude), 0.0);
  c.temperature_c = column(offsetof(RawMeasurement, temperature_c), 0.0);
  c.shots_valid = column(offsetof(RawMeasurement, shots_valid), std::uint32_t{});
  c.flags = column(offsetof(RawMeasurement, flags), std::uint32_t{});
  return c;
}

void RawColumns::validate() const {
  if (size == 0) return;
  const struct {
    const char* name;
    const std::byte* data;
  } columns[] = {{"tof_ns", tof_ns.data},
                 {"distance_raw_m", distance_raw_m.data},
                 {"pulse_width_ns", pulse_width_ns.data},
                 {"amplitude", amplitude.data},
                 {"temperature_c", temperature_c.data},
                 {"shots_valid", shots_valid.data},
                 {"flags", flags.data}};
  for (const auto& c : columns) {
    if (c.data == nullptr) {
      throw std::invalid_argument(std::string("RawColumns: column ") + c.name + " is missing");
    }
  }
}

void Pipeline::apply(std::span<const RawMeasurement> in, std::span<Range> out) const {
  apply(RawColumns::of(in), out);
}

void Pipeline::apply(const RawColumns& in, std::span<Range> out) const {
  if (in.size != out.size()) {
    throw std::invalid_argument("Pipeline::apply: " + std::to_string(in.size) +
                                " measurements but room for " + std::to_string(out.size()));
  }
  in.validate();
  BlockBuffers b;
  std::array<double, kBlock> sigma;
  const ConfidenceModel* confidence = confidence_.get();
  for (std::size_t begin = 0; begin < in.size; begin += kBlock) {
    const std::size_t n = std::min(kBlock, in.size - begin);
    for (std::size_t i = 0; i < n; ++i) {
      const std::size_t row = begin + i;
      const double tof = measured(in.tof_ns[row]);
      const bool echo = in.shots_valid[row] > 0 && (in.flags[row] & kRawNoEcho) == 0;
      const double start =
          std::isfinite(tof) ? tof * metres_per_ns_ : measured(in.distance_raw_m[row]);
      b.distance[i] = echo ? start : kNaN;
      b.tof[i] = tof;
      b.flags[i] = echo ? 0u : kCorrNoEcho;
      b.outside[i] = 0.0;
      b.extra_variance[i] = 0.0;
      b.pulse_width[i] = measured(in.pulse_width_ns[row]);
      b.temperature[i] = measured(in.temperature_c[row]);
      b.amplitude[i] = measured(in.amplitude[row]);
    }
    for (const Step& step : steps_) {
      switch (step.kind) {
        case StepKind::kOffset: {
          const double offset = step.offset_m;
          for (std::size_t i = 0; i < n; ++i) b.distance[i] += offset;
          break;
        }
        case StepKind::kGrayvalue:
          add_hinge(step.function, step.domain, b.pulse_width.data(), b.distance.data(),
                    b.outside.data(), n);
          break;
        case StepKind::kTemperature:
          add_hinge(step.function, step.domain, b.temperature.data(), b.distance.data(),
                    b.outside.data(), n);
          break;
        case StepKind::kSurface:
          add_surface(*step.surface, b, n);
          break;
        case StepKind::kWalk:
          add_walk(*step.walk, step.domain, metres_per_ns_, b, n);
          break;
        case StepKind::kPeriodic:
          for (std::size_t i = 0; i < n; ++i) {
            const double rise = periodic_correction(step, b.tof[i], b.temperature[i]);
            b.distance[i] += rise;
            if (!step.both_stops) continue;
            // The falling edge's stop: the width the later steps read.
            const double fall =
                periodic_correction(step, b.tof[i] + b.pulse_width[i], b.temperature[i]);
            if (std::isfinite(b.pulse_width[i])) b.pulse_width[i] += (fall - rise) / metres_per_ns_;
            b.tof[i] += rise / metres_per_ns_;
          }
          break;
      }
    }
    fill_sigma(confidence, residual_rms_m_, b, n, sigma.data());
    Range* o = out.data() + begin;
    for (std::size_t i = 0; i < n; ++i) {
      const std::uint32_t flags = b.flags[i];
      // Only rows with an echo can be non-finite or outside; no-echo rows carry their own flag.
      const bool echo = (flags & kCorrNoEcho) == 0;
      const std::uint32_t non_finite =
          (echo && !std::isfinite(b.distance[i])) ? kCorrNonFinite : 0u;
      const std::uint32_t outside = (echo && b.outside[i] != 0.0) ? kCorrOutOfDomain : 0u;
      // (A model whose terms overflow gives no number either: NaN, not inf.)
      o[i].distance_m = non_finite != 0 ? kNaN : b.distance[i];
      o[i].sigma_m = sigma[i];
      o[i].correction_flags = flags | non_finite | outside;
    }
  }
}

Range Pipeline::apply(const RawMeasurement& in) const {
  Range out;
  apply(std::span<const RawMeasurement>(&in, 1), std::span<Range>(&out, 1));
  return out;
}

std::string Pipeline::summary() const {
  std::ostringstream out;
  out << "pipeline: c_air/2 = " << format_number(metres_per_ns_) << " m/ns ("
      << format_number(time_to_distance_.wavelength_nm) << " nm, "
      << format_number(time_to_distance_.air.temperature_c) << " C, "
      << format_number(time_to_distance_.air.pressure_hpa) << " hPa)\n";
  for (std::size_t s = 0; s < steps_.size(); ++s) {
    const Step& step = steps_[s];
    out << "  step " << s << ": " << step_kind_name(step.kind);
    switch (step.kind) {
      case StepKind::kOffset:
        out << " " << format_number(step.offset_m * 1e3) << " mm";
        break;
      case StepKind::kGrayvalue:
      case StepKind::kTemperature: {
        const char* unit = step.kind == StepKind::kGrayvalue ? " ns" : " C";
        const char* slope_unit = step.kind == StepKind::kGrayvalue ? " mm/ns" : " mm/C";
        out << ", knots [";
        for (std::size_t k = 0; k < step.function.knots.size(); ++k) {
          out << (k ? ", " : "") << format_number(step.function.knots[k]) << unit;
        }
        out << "], segment slopes [";
        const auto slopes = step.function.segment_slopes();
        for (std::size_t k = 0; k < slopes.size(); ++k) {
          out << (k ? ", " : "") << format_number(slopes[k] * 1e3);
        }
        out << "]" << slope_unit << ", domain [" << format_number(step.domain.min) << ", "
            << format_number(step.domain.max) << "]" << unit;
        break;
      }
      case StepKind::kWalk:
        out << ": " << step.walk->summary() << ", domain [" << format_number(step.domain.min)
            << ", " << format_number(step.domain.max) << "] ns";
        break;
      case StepKind::kSurface:
        out << " " << step.surface->kind()
            << (step.surface->uses_temperature() ? " (range, amplitude, temperature)"
                                                 : " (range, amplitude)");
        break;
      case StepKind::kPeriodic:
        out << (step.both_stops ? " at both stops (tof and tof + pulse width)" : " in tof")
            << " modulo " << format_number(step.period_ns) << " ns, " << step.harmonics_m.size() / 2
            << " harmonic(s)";
        if (!step.harmonics_per_c_m.empty())
          out << ", scaled with the temperature reading about "
              << format_number(step.reference_temperature_c) << " C";
        break;
    }
    if (step.fit.rows > 0) {
      out << "; fitted on " << step.fit.rows << " rows, residual RMS "
          << format_number(step.fit.residual_rms_m * 1e3) << " mm";
    }
    out << "\n";
  }
  out << "  sigma: "
      << (confidence_ ? confidence_->kind() + " confidence model"
                      : "residual RMS " + format_number(residual_rms_m_ * 1e3) + " mm")
      << "\n";
  return out.str();
}

}  // namespace tofkit::ranging
