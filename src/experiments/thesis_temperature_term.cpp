#include "tofkit/experiments/thesis_temperature_term.hpp"

#include <cmath>
#include <cstdio>
#include <stdexcept>

#include "tofkit/experiments/characterization_temperature.hpp"
#include "tofkit/experiments/thesis_grey_chart.hpp"

namespace tofkit::experiments {
namespace {

constexpr double kMetersPer10cPerInchPer10c = kMetersPerInch / 10.0;  // in per 10 C -> m per C

/// The thesis's drift range as a type B input: its centre, and the standard
/// uncertainty of a rectangular distribution over it (half-width / sqrt(3)).
void fill_stated(const TemperatureTermOptions& o, TemperatureTerm& t) {
  t.slope_m_per_c = 0.5 * (o.stated_drift_min_in_per_10c + o.stated_drift_max_in_per_10c) *
                    kMetersPer10cPerInchPer10c;
  t.u_slope_m_per_c = 0.5 * (o.stated_drift_max_in_per_10c - o.stated_drift_min_in_per_10c) /
                      std::sqrt(3.0) * kMetersPer10cPerInchPer10c;
}

/// The device's own slope (type A): run_temperature per grey, then per distance
/// a line through the points' mean error true - measured against their mean
/// sensor reading (the term applies to readings, and the reading is what a
/// warmer session moves: die temperature through the case sensor's lag).
void fill_run(const device::VirtualRangefinder& device, const TemperatureTermOptions& o,
              const std::vector<double>& distances_m, std::uint64_t seed, TemperatureTerm& t) {
  TemperatureOptions run_options;
  run_options.distances_m = distances_m;
  run_options.ambient_c = o.run_ambient_c;
  run_options.samples_per_point = o.run_samples_per_point;
  for (std::size_t k = 0; k < o.run_grey_levels.size(); ++k) {
    const int grey = o.run_grey_levels[k];
    run_options.reflectance = grey_reflectance(grey);
    // Each grey its own session: the target is swapped between chamber sweeps.
    const auto run = run_temperature(device, run_options, derive_seed(seed, k));
    for (const double d : distances_m) {
      std::vector<double> reading_c, error_m;
      for (const auto& p : run.points) {
        if (p.distance_m != d) continue;
        reading_c.push_back(p.mean_sensor_c);
        error_m.push_back(d - p.mean_range_m);
      }
      const auto fit = fit_line(reading_c, error_m);
      if (!std::isfinite(fit.slope) || !std::isfinite(fit.slope_se)) {
        throw std::runtime_error("temperature term: the run at grey " + std::to_string(grey) +
                                 " and " + std::to_string(d) + " m left no slope (echoes?)");
      }
      t.lines.push_back({grey, d, fit.slope, fit.slope_se});
    }
  }
  // The test chart mixes greys and lies between the distances: the slope it
  // sees is one of the lines', so the centre is their mean, and the term's
  // uncertainty is the lines' spread (a single line's deviation from the mean)
  // with the mean's own standard error in quadrature (GUM type A).
  std::vector<double> slopes;
  double se2 = 0;
  for (const auto& l : t.lines) {
    slopes.push_back(l.slope_m_per_c);
    se2 += l.slope_se_m_per_c * l.slope_se_m_per_c;
  }
  const auto stats = sample_stats(slopes);
  t.slope_m_per_c = stats.mean;
  t.slope_se_m_per_c = std::sqrt(se2) / static_cast<double>(slopes.size());
  t.slope_spread_m_per_c = slopes.size() > 1 ? stats.sd : 0.0;
  t.u_slope_m_per_c = std::hypot(t.slope_se_m_per_c, t.slope_spread_m_per_c);
}

}  // namespace

const char* to_string(TemperatureTermSource source) {
  switch (source) {
    case TemperatureTermSource::run:
      return "run";
    case TemperatureTermSource::stated:
      return "stated";
    case TemperatureTermSource::none:
      return "none";
  }
  return "?";
}

void TemperatureTermOptions::validate() const {
  auto fail = [](const std::string& what) {
    throw std::invalid_argument("temperature term: " + what);
  };
  if (run_grey_levels.empty()) fail("run_grey_levels is empty");
  for (const int g : run_grey_levels) {
    if (g < 0 || g > 255) fail("run_grey_levels must be in 0..255");
  }
  if (run_ambient_c.size() < 3) fail("run_ambient_c needs at least three temperatures");
  for (const double c : run_ambient_c) {
    if (!(c >= -60 && c <= 150)) fail("run_ambient_c must be in [-60, 150]");
  }
  if (run_samples_per_point < 2) fail("run_samples_per_point must be >= 2");
  if (!(stated_drift_min_in_per_10c >= 0 &&
        stated_drift_max_in_per_10c >= stated_drift_min_in_per_10c &&
        stated_drift_max_in_per_10c <= 100.0))
    fail("stated_drift_min/max_in_per_10c must satisfy 0 <= min <= max <= 100");
}

double TemperatureTerm::correction_m(double t_c) const {
  return active() && std::isfinite(t_c) ? slope_m_per_c * (t_c - reference_c) : 0.0;
}

double TemperatureTerm::u_m(double t_c) const {
  return active() && std::isfinite(t_c) ? u_slope_m_per_c * std::abs(t_c - reference_c) : 0.0;
}

std::string TemperatureTerm::summary() const {
  if (!active()) return "temperature term: none\n";
  char line[320];
  const double in_per_10c = 1.0 / kMetersPer10cPerInchPer10c;
  std::snprintf(line, sizeof line,
                "temperature term (source %s): %+.3f +- %.3f mm per sensor C (%+.3f +- %.3f in "
                "per 10 C), from the training's mean reading %.2f C\n",
                to_string(source), 1e3 * slope_m_per_c, 1e3 * u_slope_m_per_c,
                in_per_10c * slope_m_per_c, in_per_10c * u_slope_m_per_c, reference_c);
  std::string out = line;
  if (source == TemperatureTermSource::run) {
    std::snprintf(line, sizeof line,
                  "  temperature run: %zu lines (greys x distances), mean's standard error %.4f "
                  "mm/C, spread (sd) %.4f mm/C\n",
                  lines.size(), 1e3 * slope_se_m_per_c, 1e3 * slope_spread_m_per_c);
    out += line;
  }
  return out;
}

TemperatureTerm make_temperature_term(const device::VirtualRangefinder& device,
                                      const TemperatureTermOptions& options,
                                      const std::vector<double>& distances_m,
                                      std::span<const double> training_readings_c,
                                      std::uint64_t seed) {
  options.validate();
  TemperatureTerm t;
  t.source = options.source;
  if (options.source == TemperatureTermSource::stated) fill_stated(options, t);
  if (options.source == TemperatureTermSource::run) fill_run(device, options, distances_m, seed, t);
  const auto reference = sample_stats(training_readings_c);
  t.reference_c = std::isfinite(reference.mean) ? reference.mean : 0.0;
  return t;
}

}  // namespace tofkit::experiments
