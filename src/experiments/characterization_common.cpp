#include "tofkit/experiments/characterization_common.hpp"

#include <cmath>
#include <cstdio>
#include <stdexcept>

namespace tofkit::experiments {

double SampleStats::standard_error() const {
  return count > 1 ? sd / std::sqrt(static_cast<double>(count)) : ranging::kNaN;
}

SampleStats sample_stats(std::span<const double> values) {
  // Two passes (mean, then squared deviations) for accuracy with large offsets.
  SampleStats s;
  double sum = 0;
  for (const double v : values) {
    if (!std::isfinite(v)) continue;
    sum += v;
    ++s.count;
  }
  if (s.count == 0) return s;
  s.mean = sum / static_cast<double>(s.count);
  if (s.count < 2) return s;
  double ss = 0;
  for (const double v : values) {
    if (std::isfinite(v)) ss += (v - s.mean) * (v - s.mean);
  }
  s.sd = std::sqrt(ss / static_cast<double>(s.count - 1));
  return s;
}

LineFit fit_line(std::span<const double> x, std::span<const double> y) {
  if (x.size() != y.size()) throw std::invalid_argument("fit_line: x and y differ in length");
  LineFit f;
  double sx = 0, sy = 0;
  for (std::size_t i = 0; i < x.size(); ++i) {
    if (!std::isfinite(x[i]) || !std::isfinite(y[i])) continue;
    sx += x[i];
    sy += y[i];
    ++f.rows;
  }
  if (f.rows < 2) return f;
  const double n = static_cast<double>(f.rows);
  const double mx = sx / n, my = sy / n;
  double sxx = 0, sxy = 0;
  for (std::size_t i = 0; i < x.size(); ++i) {
    if (!std::isfinite(x[i]) || !std::isfinite(y[i])) continue;
    sxx += (x[i] - mx) * (x[i] - mx);
    sxy += (x[i] - mx) * (y[i] - my);
  }
  if (!(sxx > 0)) return f;
  f.slope = sxy / sxx;
  f.intercept = my - f.slope * mx;
  if (f.rows > 2) {
    double ss = 0;
    for (std::size_t i = 0; i < x.size(); ++i) {
      if (!std::isfinite(x[i]) || !std::isfinite(y[i])) continue;
      const double r = y[i] - (f.slope * x[i] + f.intercept);
      ss += r * r;
    }
    f.residual_sd = std::sqrt(ss / (n - 2));
    f.slope_se = f.residual_sd / std::sqrt(sxx);
  }
  return f;
}

ExponentialSettling fit_exponential_settling(std::span<const double> time,
                                             std::span<const double> offset_mm,
                                             double tolerance_mm) {
  std::vector<double> t, log_offset;
  for (std::size_t i = 0; i < time.size() && i < offset_mm.size(); ++i) {
    if (!(offset_mm[i] > 2.0 * tolerance_mm)) continue;
    t.push_back(time[i]);
    log_offset.push_back(std::log(offset_mm[i]));
  }
  ExponentialSettling out;
  const auto fit = fit_line(t, log_offset);
  if (fit.slope < 0) {
    out.time_constant = -1.0 / fit.slope;
    out.time_to_tolerance = (std::log(tolerance_mm) - fit.intercept) / fit.slope;
  }
  return out;
}

int resolve_shots(const device::VirtualRangefinder& device, int shots) {
  return shots > 0 ? shots : device.config().measurement.shots;
}

double output_rate_hz(const device::VirtualRangefinder& device, int shots) {
  return device.config().link.laser.repetition_hz / resolve_shots(device, shots);
}

std::uint64_t derive_seed(std::uint64_t seed, std::uint64_t salt) {
  // SplitMix64 (Steele, Lea & Flood 2014) of the pair.
  std::uint64_t z = seed + 0x9E3779B97F4A7C15ull * (salt + 1);
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
  return z ^ (z >> 31);
}

std::vector<double> range_errors_m(std::span<const ranging::Record> records) {
  std::vector<double> e(records.size(), ranging::kNaN);
  for (std::size_t i = 0; i < records.size(); ++i) {
    if (records[i].raw.has_echo())
      e[i] = records[i].raw.distance_raw_m - records[i].truth.distance_m;
  }
  return e;
}

std::string findings_text(std::span<const Finding> findings) {
  std::string out;
  char line[256];
  for (const auto& f : findings) {
    std::snprintf(line, sizeof line, "  %-34s %12.6g %s\n", f.name.c_str(), f.value,
                  f.unit.c_str());
    out += line;
  }
  return out;
}

}  // namespace tofkit::experiments
