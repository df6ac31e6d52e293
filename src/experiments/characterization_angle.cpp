#include "tofkit/experiments/characterization_angle.hpp"

#include <cmath>
#include <cstdio>
#include <stdexcept>

namespace tofkit::experiments {

void AngleOptions::validate() const {
  auto fail = [](const std::string& what) { throw std::invalid_argument("angle: " + what); };
  if (grey_levels.empty()) fail("grey_levels is empty");
  for (const int g : grey_levels) {
    if (g < 0 || g > 255) fail("grey_levels must be in 0..255");
  }
  if (angles_deg.size() < 2 || angles_deg.front() != 0.0)
    fail("angles_deg needs at least two angles, the first 0");
  for (std::size_t k = 0; k < angles_deg.size(); ++k) {
    if (!(angles_deg[k] >= 0 && angles_deg[k] < 90)) fail("angles_deg must be in [0, 90)");
    if (k > 0 && !(angles_deg[k] > angles_deg[k - 1])) fail("angles_deg must ascend");
  }
  if (!(distance_m > 0)) fail("distance_m must be > 0");
  if (samples_per_point < 2) fail("samples_per_point must be >= 2");
  if (shots < 0) fail("shots must be >= 0");
  if (!(reference_angle_deg > 0)) fail("reference_angle_deg must be > 0");
}

AngleResult run_angle(const device::VirtualRangefinder& device, const AngleOptions& options,
                      std::uint64_t seed) {
  options.validate();
  AngleResult result;
  result.options = options;
  const int shots = resolve_shots(device, options.shots);
  const auto per = static_cast<std::size_t>(options.samples_per_point);
  device::Conditions c;
  c.ambient_c = options.ambient_c;
  std::vector<PlannedMeasurement> plan;
  for (const int g : options.grey_levels) {
    for (const double a : options.angles_deg) {
      const PlannedMeasurement p =
          plate(options.distance_m, grey_reflectance(g), c.ambient_c, a, shots);
      for (std::size_t k = 0; k < per; ++k) plan.push_back(p);
    }
  }
  result.records = run(device, plan, seed);
  const auto errors = range_errors_m(result.records);

  std::size_t i = 0;
  std::vector<double> amplitude(per);
  for (const int g : options.grey_levels) {
    AngleGrowth growth;
    growth.grey = g;
    std::vector<double> fit_angle, fit_error;
    double error_at_zero = ranging::kNaN;
    double reference_error = ranging::kNaN;
    for (const double a : options.angles_deg) {
      AnglePoint p;
      p.grey = g;
      p.angle_deg = a;
      std::size_t echoes = 0;
      for (std::size_t k = 0; k < per; ++k) {
        amplitude[k] = result.records[i + k].raw.amplitude;
        echoes += result.records[i + k].raw.has_echo();
      }
      const auto s = sample_stats(std::span<const double>(errors).subspan(i, per));
      p.mean_error_m = s.mean;
      p.sd_m = s.sd;
      p.mean_amplitude = sample_stats(amplitude).mean;
      p.echo_share = static_cast<double>(echoes) / static_cast<double>(per);
      if (a == 0.0) error_at_zero = s.mean;
      if (echoes == per) growth.max_usable_angle_deg = a;
      if (a <= options.reference_angle_deg + 1e-9 && echoes == per) {
        fit_angle.push_back(a);
        fit_error.push_back(s.mean * 1e3);
        reference_error = s.mean;  // the last usable angle up to the reference
        if (std::abs(a - options.reference_angle_deg) < 1e-9)
          growth.growth_at_reference_m = reference_error - error_at_zero;
      }
      result.points.push_back(p);
      i += per;
    }
    growth.slope_mm_per_deg = fit_line(fit_angle, fit_error).slope;
    result.growth.push_back(growth);
  }
  return result;
}

std::vector<Finding> AngleResult::findings() const {
  std::vector<Finding> f;
  char name[96];
  for (const auto& g : growth) {
    std::snprintf(name, sizeof name, "growth_mm_at_%.0f_deg_grey_%d", options.reference_angle_deg,
                  g.grey);
    f.push_back({name, g.growth_at_reference_m * 1e3, "mm"});
    std::snprintf(name, sizeof name, "slope_mm_per_deg_grey_%d", g.grey);
    f.push_back({name, g.slope_mm_per_deg, "mm/deg"});
    std::snprintf(name, sizeof name, "max_usable_angle_deg_grey_%d", g.grey);
    f.push_back({name, g.max_usable_angle_deg, "deg"});
  }
  return f;
}

ResultTable AngleResult::table() const {
  ResultTable t{
      "points", {"grey", "angle_deg", "mean_error_m", "sd_m", "mean_amplitude", "echo_share"}, {}};
  for (const auto& p : points) {
    t.rows.push_back(
        {double(p.grey), p.angle_deg, p.mean_error_m, p.sd_m, p.mean_amplitude, p.echo_share});
  }
  return t;
}

std::string AngleResult::summary() const {
  std::string out = "incidence angle at " +
                    std::to_string(m_to_inches(options.distance_m)).substr(0, 4) +
                    " in: mean error measured - true [mm] (--: no echo on some samples)\n  grey";
  char cell[64];
  for (const double a : options.angles_deg) {
    std::snprintf(cell, sizeof cell, " %6.0fdeg", a);
    out += cell;
  }
  out += "   slope [mm/deg]\n";
  std::size_t i = 0;
  for (const auto& g : growth) {
    std::snprintf(cell, sizeof cell, "  %4d", g.grey);
    out += cell;
    for (std::size_t k = 0; k < options.angles_deg.size(); ++k, ++i) {
      const auto& p = points[i];
      if (p.echo_share < 1.0) {
        out += "        --";
      } else {
        std::snprintf(cell, sizeof cell, " %+9.1f", p.mean_error_m * 1e3);
        out += cell;
      }
    }
    std::snprintf(cell, sizeof cell, "   %+.3f\n", g.slope_mm_per_deg);
    out += cell;
  }
  return out;
}

}  // namespace tofkit::experiments
