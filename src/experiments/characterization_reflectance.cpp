#include "tofkit/experiments/characterization_reflectance.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <stdexcept>

namespace tofkit::experiments {
namespace {
// Assumption: as the thesis protocol's point_period_s, 2 s per station (move, settle, sample).
constexpr double kStationPeriodS = 2.0;
}  // namespace

void ReflectanceOptions::validate() const {
  auto fail = [](const std::string& what) { throw std::invalid_argument("reflectance: " + what); };
  if (grey_levels.empty()) fail("grey_levels is empty");
  for (const int g : grey_levels) {
    if (g < 0 || g > 255) fail("grey_levels must be in 0..255");
  }
  for (const double d : distances_m) {
    if (!(d > 0)) fail("distances_m must be > 0");
  }
  if (samples_per_point < 2) fail("samples_per_point must be >= 2");
  if (shots < 0) fail("shots must be >= 0");
}

std::vector<double> ReflectanceOptions::distances() const {
  if (!distances_m.empty()) return distances_m;
  std::vector<double> d;
  for (int in = 10; in <= 30; in += 2) d.push_back(inches_to_m(in));
  return d;
}

ReflectanceResult run_reflectance(const device::VirtualRangefinder& device,
                                  const ReflectanceOptions& options, std::uint64_t seed) {
  options.validate();
  ReflectanceResult result;
  result.options = options;
  const auto distances = options.distances();
  const int shots = resolve_shots(device, options.shots);
  const double rate_hz = device.config().link.laser.repetition_hz;
  const auto per = static_cast<std::size_t>(options.samples_per_point);
  device::Conditions c;
  c.ambient_c = options.ambient_c;
  std::vector<PlannedMeasurement> plan;
  double station = 0;
  for (const int g : options.grey_levels) {
    for (const double d : distances) {
      const auto target = device::Target::plate(d, grey_reflectance(g));
      // Stations are taken one after another (move, sample), kStationPeriodS apart.
      c.session_time_s = kStationPeriodS * station++;
      // Point by point on the stages: the laser is switched on at each (grey,
      // distance) station and its samples follow back to back.
      for (std::size_t k = 0; k < per; ++k) {
        c.ms_since_laser_on = static_cast<double>(k) * 1e3 * shots / rate_hz;
        plan.push_back(planned(target, c, shots));
      }
    }
  }
  result.records = run(device, plan, seed);
  const auto errors = range_errors_m(result.records);

  std::size_t i = 0;
  std::vector<double> amplitude(per);
  double ss_all = 0, ss_unsaturated = 0;
  std::size_t n_all = 0, n_unsaturated = 0;
  // Thesis numbering: 0 = white ... 255 = black.
  int darkest = -1, brightest = 256;
  for (const int g : options.grey_levels) {
    for (const double d : distances) {
      ReflectancePoint p;
      p.grey = g;
      p.reflectance = grey_reflectance(g);
      p.distance_m = d;
      std::size_t echoes = 0, saturated = 0;
      for (std::size_t k = 0; k < per; ++k) {
        const auto& rec = result.records[i + k];
        amplitude[k] = rec.raw.amplitude;
        echoes += rec.raw.has_echo();
        saturated += (rec.raw.flags & ranging::kRawSaturated) != 0;
      }
      const auto err = std::span<const double>(errors).subspan(i, per);
      const auto s = sample_stats(err);
      p.mean_error_m = s.mean;
      p.sd_m = s.sd;
      p.mean_amplitude = sample_stats(amplitude).mean;
      p.echo_share = static_cast<double>(echoes) / static_cast<double>(per);
      p.saturated_share = static_cast<double>(saturated) / static_cast<double>(per);
      if (std::abs(d - options.rms_distance_m) < 1e-9) {
        for (const double e : err) {
          if (!std::isfinite(e)) continue;
          ss_all += e * e;
          ++n_all;
          if (g >= options.unsaturated_grey_min) {
            ss_unsaturated += e * e;
            ++n_unsaturated;
          }
        }
        if (g > darkest) {
          darkest = g;
          result.darkest_error_m = s.mean;
        }
        if (g < brightest) {
          brightest = g;
          result.brightest_error_m = s.mean;
        }
      }
      result.points.push_back(p);
      i += per;
    }
  }
  if (n_all) result.rms_all_m = std::sqrt(ss_all / static_cast<double>(n_all));
  if (n_unsaturated)
    result.rms_unsaturated_m = std::sqrt(ss_unsaturated / static_cast<double>(n_unsaturated));

  std::vector<double> truth(result.records.size()), measured(result.records.size());
  for (std::size_t k = 0; k < result.records.size(); ++k) {
    truth[k] = result.records[k].truth.distance_m;
    measured[k] =
        result.records[k].raw.has_echo() ? result.records[k].raw.distance_raw_m : ranging::kNaN;
  }
  result.line = fit_line(truth, measured);
  return result;
}

std::vector<Finding> ReflectanceResult::findings() const {
  return {{"line_slope", line.slope, ""},
          {"line_intercept_in", m_to_inches(line.intercept), "in"},
          {"rms_all_greys_in", m_to_inches(rms_all_m), "in"},
          {"rms_greys_102_up_in", m_to_inches(rms_unsaturated_m), "in"},
          {"darkest_grey_error_mm", darkest_error_m * 1e3, "mm"},
          {"brightest_grey_error_mm", brightest_error_m * 1e3, "mm"}};
}

ResultTable ReflectanceResult::table() const {
  ResultTable t{"points",
                {"grey", "reflectance", "distance_m", "mean_error_m", "sd_m", "mean_amplitude",
                 "echo_share", "saturated_share"},
                {}};
  for (const auto& p : points) {
    t.rows.push_back({double(p.grey), p.reflectance, p.distance_m, p.mean_error_m, p.sd_m,
                      p.mean_amplitude, p.echo_share, p.saturated_share});
  }
  return t;
}

std::string ReflectanceResult::summary() const {
  std::string out =
      "reflectance x distance (grey 0 = white ... 255 = black, as the thesis): mean error "
      "measured - true [mm] (S: saturated)\n";
  const auto distances = options.distances();
  out += "  grey  rho  ";
  char cell[64];
  for (const double d : distances) {
    std::snprintf(cell, sizeof cell, " %6.0fin", m_to_inches(d));
    out += cell;
  }
  out += '\n';
  std::size_t i = 0;
  for (const int g : options.grey_levels) {
    std::snprintf(cell, sizeof cell, "  %4d %5.3f", g, grey_reflectance(g));
    out += cell;
    for (std::size_t k = 0; k < distances.size(); ++k, ++i) {
      const auto& p = points[i];
      if (p.echo_share == 0) {
        out += "    --   ";
      } else {
        std::snprintf(cell, sizeof cell, " %+7.1f%s", p.mean_error_m * 1e3,
                      p.saturated_share > 0.5 ? "S" : " ");
        out += cell;
      }
    }
    out += '\n';
  }
  char text[320];
  std::snprintf(text, sizeof text,
                "  line fit: measured = %.4f true %+.4f in (thesis: 0.9804 T - 0.6732 in)\n"
                "  RMS at %.0f in: all greys %.4f in (thesis 1.0693), grey >= %d %.4f in "
                "(thesis 0.2281)\n",
                line.slope, m_to_inches(line.intercept), m_to_inches(options.rms_distance_m),
                m_to_inches(rms_all_m), options.unsaturated_grey_min,
                m_to_inches(rms_unsaturated_m));
  return out + text;
}

}  // namespace tofkit::experiments
