#include "tofkit/experiments/characterization_turn_on.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <stdexcept>

namespace tofkit::experiments {

void TurnOnOptions::validate() const {
  auto fail = [](const std::string& what) { throw std::invalid_argument("turn-on: " + what); };
  if (!(distance_m > 0)) fail("distance_m must be > 0");
  if (!(reflectance > 0 && reflectance <= 1)) fail("reflectance must be in (0, 1]");
  if (!(duration_ms > 0)) fail("duration_ms must be > 0");
  if (shots < 0) fail("shots must be >= 0");
  if (!(block_ms > 0 && block_ms < duration_ms)) fail("block_ms must be in (0, duration_ms)");
  if (first_samples < 1) fail("first_samples must be >= 1");
  if (!(plateau_fraction > 0 && plateau_fraction < 1)) fail("plateau_fraction must be in (0, 1)");
  if (!(tolerance_mm > 0)) fail("tolerance_mm must be > 0");
}

TurnOnResult run_turn_on(const device::VirtualRangefinder& device, const TurnOnOptions& options,
                         std::uint64_t seed) {
  options.validate();
  TurnOnResult result;
  result.options = options;
  const int shots = resolve_shots(device, options.shots);
  result.sample_period_ms = 1e3 / output_rate_hz(device, shots);
  const auto n = static_cast<std::size_t>(std::ceil(options.duration_ms / result.sample_period_ms));
  if (n < static_cast<std::size_t>(options.first_samples)) {
    throw std::invalid_argument("turn-on: duration_ms holds fewer samples than first_samples");
  }
  const auto target = device::Target::plate(options.distance_m, options.reflectance);
  std::vector<PlannedMeasurement> plan;
  plan.reserve(n);
  for (std::size_t i = 0; i < n; ++i) {
    device::Conditions c;
    c.ambient_c = options.ambient_c;
    c.ms_since_laser_on = static_cast<double>(i) * result.sample_period_ms;  // back to back
    plan.push_back(planned(target, c, shots));
  }
  result.records = run(device, plan, seed);

  std::vector<double> range(n);
  for (std::size_t i = 0; i < n; ++i) {
    const auto& raw = result.records[i].raw;
    range[i] = raw.has_echo() ? raw.distance_raw_m : ranging::kNaN;
  }
  const auto per_block = std::max<std::size_t>(
      1, static_cast<std::size_t>(std::lround(options.block_ms / result.sample_period_ms)));
  for (std::size_t b = 0; b < n; b += per_block) {
    const std::size_t e = std::min(n, b + per_block);
    const auto s = sample_stats(std::span<const double>(range).subspan(b, e - b));
    result.blocks.push_back(
        {static_cast<double>(b) * result.sample_period_ms, s.mean, s.sd, s.count});
  }
  const auto plateau_begin = static_cast<std::size_t>(
      std::floor((1.0 - options.plateau_fraction) * static_cast<double>(n)));
  result.plateau_range_m = sample_stats(std::span<const double>(range).subspan(plateau_begin)).mean;
  result.first_samples_bias_mm =
      (sample_stats(std::span<const double>(range).first(options.first_samples)).mean -
       result.plateau_range_m) *
      1e3;

  // Time to plateau: end of the last block whose mean is off by more than the tolerance.
  std::size_t last_off = result.blocks.size();
  for (std::size_t k = 0; k < result.blocks.size(); ++k) {
    if (!(std::abs(result.blocks[k].mean_range_m - result.plateau_range_m) * 1e3 <=
          options.tolerance_mm))
      last_off = k;
  }
  const double block_length_ms = static_cast<double>(per_block) * result.sample_period_ms;
  result.time_to_plateau_ms =
      last_off == result.blocks.size() ? 0.0 : result.blocks[last_off].start_ms + block_length_ms;

  // Exponential decay of the bias, over the blocks up to the last one off the plateau.
  std::vector<double> t, offset_mm;
  for (std::size_t k = 0; k < result.blocks.size() && last_off != result.blocks.size(); ++k) {
    if (k > last_off) continue;
    t.push_back(result.blocks[k].start_ms + 0.5 * block_length_ms);
    offset_mm.push_back(std::abs(result.blocks[k].mean_range_m - result.plateau_range_m) * 1e3);
  }
  const auto settling = fit_exponential_settling(t, offset_mm, options.tolerance_mm);
  if (std::isfinite(settling.time_constant)) {
    result.time_constant_ms = settling.time_constant;
    result.time_to_plateau_fit_ms = settling.time_to_tolerance;
  }
  return result;
}

std::vector<Finding> TurnOnResult::findings() const {
  return {{"first_samples_bias_mm", first_samples_bias_mm, "mm"},
          {"first_samples_bias_in", first_samples_bias_mm / 25.4, "in"},
          {"time_to_plateau_ms", time_to_plateau_ms, "ms"},
          {"time_to_plateau_fit_ms", time_to_plateau_fit_ms, "ms"},
          {"time_constant_ms", time_constant_ms, "ms"},
          {"plateau_range_m", plateau_range_m, "m"},
          {"sample_period_ms", sample_period_ms, "ms"}};
}

ResultTable TurnOnResult::table() const {
  ResultTable t{"blocks", {"start_ms", "mean_range_m", "sd_range_m", "samples"}, {}};
  for (const auto& b : blocks)
    t.rows.push_back({b.start_ms, b.mean_range_m, b.sd_range_m, double(b.samples)});
  return t;
}

std::string TurnOnResult::summary() const {
  char text[512];
  std::snprintf(text, sizeof text,
                "laser turn-on at %.1f in, %zu samples every %.4f ms: the first %d samples are "
                "off by %+.2f mm (%+.3f in); the range stays within %.2f mm of its plateau "
                "after %.0f ms (exponential fit: %.0f ms, time constant %.1f ms)\n",
                m_to_inches(options.distance_m), records.size(), sample_period_ms,
                options.first_samples, first_samples_bias_mm, first_samples_bias_mm / 25.4,
                options.tolerance_mm, time_to_plateau_ms, time_to_plateau_fit_ms, time_constant_ms);
  return text;
}

}  // namespace tofkit::experiments
