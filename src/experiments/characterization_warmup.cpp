#include "tofkit/experiments/characterization_warmup.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <stdexcept>

namespace tofkit::experiments {

void WarmupOptions::validate() const {
  auto fail = [](const std::string& what) { throw std::invalid_argument("warm-up: " + what); };
  if (!(distance_m > 0)) fail("distance_m must be > 0");
  if (!(reflectance > 0 && reflectance <= 1)) fail("reflectance must be in (0, 1]");
  if (duration_min < 2) fail("duration_min must be >= 2");
  if (samples_per_minute < 1) fail("samples_per_minute must be >= 1");
  if (shots < 0) fail("shots must be >= 0");
  if (final_window_min < 1 || final_window_min >= duration_min)
    fail("final_window_min must be in [1, duration_min)");
  if (!(tolerance_mm > 0)) fail("tolerance_mm must be > 0");
  if (smoothing_min < 1 || smoothing_min > duration_min)
    fail("smoothing_min must be in [1, duration_min]");
}

WarmupResult run_warmup(const device::VirtualRangefinder& device, const WarmupOptions& options,
                        std::uint64_t seed) {
  options.validate();
  WarmupResult result;
  result.options = options;
  const auto target = device::Target::plate(options.distance_m, options.reflectance);
  const int shots = resolve_shots(device, options.shots);
  const std::size_t per_minute = static_cast<std::size_t>(options.samples_per_minute);
  const std::size_t n = per_minute * static_cast<std::size_t>(options.duration_min);
  std::vector<PlannedMeasurement> plan;
  plan.reserve(n);
  for (std::size_t i = 0; i < n; ++i) {
    const double minutes = (static_cast<double>(i) + 0.5) / static_cast<double>(per_minute);
    device::Conditions c;
    c.ambient_c = options.ambient_c;
    c.minutes_since_power_on = minutes;
    c.ms_since_laser_on = minutes * 60e3;  // laser on from power-on
    plan.push_back(planned(target, c, shots));
  }
  result.records = run(device, plan, seed);

  std::vector<double> range(per_minute), temperature(per_minute);
  for (int m = 0; m < options.duration_min; ++m) {
    for (std::size_t k = 0; k < per_minute; ++k) {
      const auto& raw = result.records[static_cast<std::size_t>(m) * per_minute + k].raw;
      range[k] = raw.has_echo() ? raw.distance_raw_m : ranging::kNaN;
      temperature[k] = raw.temperature_c;
    }
    const auto r = sample_stats(range);
    result.minutes.push_back({m, r.mean, r.sd, sample_stats(temperature).mean, r.count});
  }

  // Settled value: the mean over the final window.
  double sum = 0;
  const int first_final = options.duration_min - options.final_window_min;
  for (int m = first_final; m < options.duration_min; ++m)
    sum += result.minutes[static_cast<std::size_t>(m)].mean_range_m;
  result.final_range_m = sum / options.final_window_min;
  result.total_drift_mm = (result.final_range_m - result.minutes.front().mean_range_m) * 1e3;

  // Settle time: after the last minute whose smoothed mean is off by more than
  // the tolerance. The running mean always spans smoothing_min minutes (centred,
  // shifted inward at the ends of the record), so its noise is the same everywhere.
  const int n_minutes = options.duration_min;
  const int width = options.smoothing_min;
  int last_off = -1;
  for (int m = 0; m < n_minutes; ++m) {
    const int first = std::clamp(m - width / 2, 0, n_minutes - width);
    double s = 0;
    for (int k = first; k < first + width; ++k)
      s += result.minutes[static_cast<std::size_t>(k)].mean_range_m;
    const double smoothed = s / width;
    if (!(std::abs(smoothed - result.final_range_m) * 1e3 <= options.tolerance_mm)) last_off = m;
  }
  result.settle_time_min = last_off + 1.0;

  // First-order settling over the minutes before the last one off the final value;
  // the fitted time uses every minute, so it scatters less than the last crossing
  // of the noisy curve.
  std::vector<double> t, offset_mm;
  for (const auto& m : result.minutes) {
    if (m.minute >= last_off) continue;
    t.push_back(m.minute + 0.5);
    offset_mm.push_back(std::abs(m.mean_range_m - result.final_range_m) * 1e3);
  }
  const auto settling = fit_exponential_settling(t, offset_mm, options.tolerance_mm);
  if (std::isfinite(settling.time_constant)) {
    result.time_constant_min = settling.time_constant;
    result.settle_time_fit_min = settling.time_to_tolerance;
  }
  return result;
}

std::vector<Finding> WarmupResult::findings() const {
  return {{"settle_time_min", settle_time_min, "min"},
          {"total_drift_mm", total_drift_mm, "mm"},
          {"total_drift_in", total_drift_mm / 25.4, "in"},
          {"settle_time_fit_min", settle_time_fit_min, "min"},
          {"time_constant_min", time_constant_min, "min"},
          {"final_range_m", final_range_m, "m"}};
}

ResultTable WarmupResult::table() const {
  ResultTable t{
      "minutes", {"minute", "mean_range_m", "sd_range_m", "temperature_c", "samples"}, {}};
  for (const auto& m : minutes) {
    t.rows.push_back(
        {double(m.minute), m.mean_range_m, m.sd_range_m, m.mean_temperature_c, double(m.samples)});
  }
  return t;
}

std::string WarmupResult::summary() const {
  char text[512];
  std::snprintf(text, sizeof text,
                "cold-start warm-up at %.1f in, %d samples/min for %d min: the range %s by "
                "%.2f mm (%.3f in) and settles within %.2f mm after %.0f min "
                "(exponential fit: %.1f min, time constant %.1f min; thesis: 25-35 min)\n",
                m_to_inches(options.distance_m), options.samples_per_minute, options.duration_min,
                total_drift_mm >= 0 ? "inflates" : "shrinks", std::abs(total_drift_mm),
                std::abs(total_drift_mm) / 25.4, options.tolerance_mm, settle_time_min,
                settle_time_fit_min, time_constant_min);
  return text;
}

}  // namespace tofkit::experiments
