#include "tofkit/experiments/characterization_sampling.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <optional>
#include <stdexcept>

#include "tofkit/device/oscillator_loop.hpp"

namespace tofkit::experiments {
namespace {
// Assumption: a minute between the settings' acquisitions (change the setting, start).
constexpr double kSettingPeriodS = 60.0;
}  // namespace

void SamplingOptions::validate() const {
  auto fail = [](const std::string& what) { throw std::invalid_argument("sampling: " + what); };
  if (!(distance_m > 0)) fail("distance_m must be > 0");
  if (!(reflectance > 0 && reflectance <= 1)) fail("reflectance must be in (0, 1]");
  if (min_exponent < 0 || max_exponent > 20 || min_exponent > max_exponent)
    fail("exponents must satisfy 0 <= min_exponent <= max_exponent <= 20");
  if (samples_per_setting < 3) fail("samples_per_setting must be >= 3");
}

SamplingResult run_sampling(const device::VirtualRangefinder& device,
                            const SamplingOptions& options, std::uint64_t seed) {
  options.validate();
  SamplingResult result;
  result.options = options;
  const auto target = device::Target::plate(options.distance_m, options.reflectance);
  device::Conditions c;
  c.ambient_c = options.ambient_c;
  const auto per = static_cast<std::size_t>(options.samples_per_setting);
  std::vector<PlannedMeasurement> plan;
  for (int e = options.min_exponent; e <= options.max_exponent; ++e) {
    // One acquisition per setting, taken one after another (the experimenter
    // changes the setting between them): each has its own time in the session,
    // so the loop's slow wander holds within a setting and differs between them.
    c.session_time_s = kSettingPeriodS * static_cast<double>(e - options.min_exponent);
    for (std::size_t k = 0; k < per; ++k) plan.push_back(planned(target, c, 1 << e));
  }
  result.records = run(device, plan, seed);
  std::optional<device::OscillatorLoop> loop;
  if (device.config().oscillator.enabled) loop.emplace(device.config());

  const auto errors = range_errors_m(result.records);
  std::vector<double> log_shots, log_sd;
  for (int e = options.min_exponent; e <= options.max_exponent; ++e) {
    const std::size_t begin = static_cast<std::size_t>(e - options.min_exponent) * per;
    const auto err = std::span<const double>(errors).subspan(begin, per);
    const auto s = sample_stats(err);
    double ss = 0;
    for (const double v : err) {
      if (std::isfinite(v)) ss += v * v;
    }
    SamplingRow row;
    row.exponent = e;
    row.shots = 1 << e;
    row.sampling_rate_hz = output_rate_hz(device, row.shots);
    row.mean_range_m = options.distance_m + s.mean;
    row.sd_range_m = s.sd;
    row.rms_error_m = s.count ? std::sqrt(ss / static_cast<double>(s.count)) : ranging::kNaN;
    row.sd_times_sqrt_shots_m = s.sd * std::sqrt(static_cast<double>(row.shots));
    if (loop) row.resolution_m = loop->resolution_m(target, c, row.shots);
    result.rows.push_back(row);
    log_shots.push_back(std::log(static_cast<double>(row.shots)));
    log_sd.push_back(std::log(s.sd));
  }
  result.log_slope = fit_line(log_shots, log_sd).slope;
  std::vector<double> scaled;
  for (const auto& r : result.rows) scaled.push_back(r.sd_times_sqrt_shots_m);
  std::sort(scaled.begin(), scaled.end());
  const double median = scaled[scaled.size() / 2];
  result.max_scaling_deviation = 0;
  for (const auto& r : result.rows) {
    result.max_scaling_deviation =
        std::max(result.max_scaling_deviation, std::abs(r.sd_times_sqrt_shots_m / median - 1.0));
  }
  return result;
}

std::vector<Finding> SamplingResult::findings() const {
  std::vector<Finding> f{{"log_slope_sd_vs_shots", log_slope, ""},
                         {"max_scaling_deviation", max_scaling_deviation, ""}};
  for (const auto& r : rows) {
    f.push_back({"sd_mm_at_" + std::to_string(r.shots) + "_shots", r.sd_range_m * 1e3, "mm"});
  }
  return f;
}

ResultTable SamplingResult::table() const {
  ResultTable t{"settings",
                {"exponent", "shots", "sampling_rate_hz", "mean_range_m", "sd_range_m",
                 "rms_error_m", "sd_times_sqrt_shots_m", "resolution_m"},
                {}};
  for (const auto& r : rows) {
    t.rows.push_back({double(r.exponent), double(r.shots), r.sampling_rate_hz, r.mean_range_m,
                      r.sd_range_m, r.rms_error_m, r.sd_times_sqrt_shots_m, r.resolution_m});
  }
  return t;
}

std::string SamplingResult::summary() const {
  std::string out = "sampling rate vs resolution (thesis Fig. 4.4) at " +
                    std::to_string(m_to_inches(options.distance_m)).substr(0, 5) + " in:\n";
  out +=
      "     N   shots   rate [1/s]   mean [in]   sd [mm]   rms [in]   sd*sqrt(n) [mm]   "
      "resolution [mm]   variance [in^2]\n";
  char line[160];
  for (const auto& r : rows) {
    std::snprintf(line, sizeof line,
                  "  %4d  %6d  %11.3f  %10.4f  %8.4f  %9.4f  %10.3f  %16.4f  %16.5f\n", r.exponent,
                  r.shots, r.sampling_rate_hz, m_to_inches(r.mean_range_m), r.sd_range_m * 1e3,
                  m_to_inches(r.rms_error_m), r.sd_times_sqrt_shots_m * 1e3, r.resolution_m * 1e3,
                  m_to_inches(r.sd_range_m) * m_to_inches(r.sd_range_m));
    out += line;
  }
  std::snprintf(line, sizeof line,
                "  spread ~ shots^%.3f (1/sqrt: -0.5); sd*sqrt(n) within %.1f %% of its median\n",
                log_slope, 100.0 * max_scaling_deviation);
  return out + line;
}

}  // namespace tofkit::experiments
