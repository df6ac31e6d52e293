#include "tofkit/experiments/characterization_temperature.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <stdexcept>

namespace tofkit::experiments {

void TemperatureOptions::validate() const {
  auto fail = [](const std::string& what) { throw std::invalid_argument("temperature: " + what); };
  if (distances_m.empty()) fail("distances_m is empty");
  for (const double d : distances_m) {
    if (!(d > 0)) fail("distances_m must be > 0");
  }
  if (ambient_c.size() < 2) fail("ambient_c needs at least two temperatures");
  for (const double t : ambient_c) {
    if (!(t >= -60 && t <= 150)) fail("ambient_c must be in [-60, 150]");
  }
  if (!(reflectance > 0 && reflectance <= 1)) fail("reflectance must be in (0, 1]");
  if (samples_per_point < 2) fail("samples_per_point must be >= 2");
  if (shots < 0) fail("shots must be >= 0");
}

TemperatureResult run_temperature(const device::VirtualRangefinder& device,
                                  const TemperatureOptions& options, std::uint64_t seed) {
  options.validate();
  TemperatureResult result;
  result.options = options;
  const int shots = resolve_shots(device, options.shots);
  const auto per = static_cast<std::size_t>(options.samples_per_point);
  std::vector<PlannedMeasurement> plan;
  for (const double d : options.distances_m) {
    const auto target = device::Target::plate(d, options.reflectance);
    for (const double t : options.ambient_c) {
      device::Conditions c;
      c.ambient_c = t;
      for (std::size_t k = 0; k < per; ++k) plan.push_back(planned(target, c, shots));
    }
  }
  result.records = run(device, plan, seed);

  std::size_t i = 0;
  std::vector<double> range(per), sensor(per);
  for (const double d : options.distances_m) {
    std::vector<double> x, y;  // all samples of this distance: ambient, range in mm
    for (const double t : options.ambient_c) {
      for (std::size_t k = 0; k < per; ++k, ++i) {
        const auto& raw = result.records[i].raw;
        range[k] = raw.has_echo() ? raw.distance_raw_m : ranging::kNaN;
        sensor[k] = raw.temperature_c;
        x.push_back(t);
        y.push_back(range[k] * 1e3);
      }
      const auto r = sample_stats(range);
      result.points.push_back({d, t, r.mean, r.sd, sample_stats(sensor).mean, r.count});
    }
    const auto fit = fit_line(x, y);
    result.slopes.push_back({d, fit.slope, fit.slope_se});
  }
  double sum = 0, lo = 1e300, hi = -1e300, se_lo = 0, se_hi = 0;
  for (const auto& s : result.slopes) {
    sum += s.slope_mm_per_c;
    if (s.slope_mm_per_c < lo) {
      lo = s.slope_mm_per_c;
      se_lo = s.slope_se_mm_per_c;
    }
    if (s.slope_mm_per_c > hi) {
      hi = s.slope_mm_per_c;
      se_hi = s.slope_se_mm_per_c;
    }
  }
  result.mean_slope_mm_per_c = sum / static_cast<double>(result.slopes.size());
  result.slope_spread_mm_per_c = hi - lo;
  const double se = std::hypot(se_lo, se_hi);
  result.slope_spread_se = se > 0 ? (hi - lo) / se : 0.0;
  return result;
}

std::vector<Finding> TemperatureResult::findings() const {
  std::vector<Finding> f{{"mean_slope_mm_per_c", mean_slope_mm_per_c, "mm/C"},
                         {"mean_slope_in_per_10c", mean_slope_mm_per_c * 10.0 / 25.4, "in/10C"},
                         {"slope_spread_mm_per_c", slope_spread_mm_per_c, "mm/C"},
                         {"slope_spread_se", slope_spread_se, "sigma"}};
  for (const auto& s : slopes) {
    char name[64];
    std::snprintf(name, sizeof name, "slope_mm_per_c_at_%.0f_in", m_to_inches(s.distance_m));
    f.push_back({name, s.slope_mm_per_c, "mm/C"});
  }
  return f;
}

ResultTable TemperatureResult::table() const {
  ResultTable t{"points",
                {"distance_m", "ambient_c", "mean_range_m", "sd_range_m", "sensor_c", "samples"},
                {}};
  for (const auto& p : points) {
    t.rows.push_back({p.distance_m, p.ambient_c, p.mean_range_m, p.sd_range_m, p.mean_sensor_c,
                      double(p.samples)});
  }
  return t;
}

std::string TemperatureResult::summary() const {
  std::string out = "environmental temperature sweep (thesis: -0.25..-0.60 in per 10 C):\n";
  char line[200];
  for (const auto& s : slopes) {
    std::snprintf(line, sizeof line, "  %5.1f in: %+.3f +- %.3f mm/C  (%+.3f in per 10 C)\n",
                  m_to_inches(s.distance_m), s.slope_mm_per_c, s.slope_se_mm_per_c,
                  s.inches_per_10c());
    out += line;
  }
  std::snprintf(line, sizeof line,
                "  mean %+.3f mm/C (%+.3f in per 10 C); spread over distances %.4f mm/C = %.1f "
                "standard errors\n",
                mean_slope_mm_per_c, mean_slope_mm_per_c * 10.0 / 25.4, slope_spread_mm_per_c,
                slope_spread_se);
  return out + line;
}

}  // namespace tofkit::experiments
