#include "tofkit/experiments/characterization_mixed_pixel.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <stdexcept>

#include "tofkit/physics/constants.hpp"
#include "tofkit/physics/link_budget.hpp"

namespace tofkit::experiments {

double disk_fraction_beyond_edge(double centre_offset_m, double footprint_diameter_m) {
  const double r = 0.5 * footprint_diameter_m;
  if (!(r > 0)) return centre_offset_m < 0 ? 1.0 : 0.0;
  const double h = std::clamp(centre_offset_m / r, -1.0, 1.0);  // chord distance, radii
  // Segment on the far side of the chord at h: acos(h) - h sqrt(1 - h^2), over pi.
  return (std::acos(h) - h * std::sqrt(1.0 - h * h)) / physics::kPi;
}

void MixedPixelOptions::validate() const {
  auto fail = [](const std::string& what) { throw std::invalid_argument("mixed pixel: " + what); };
  if (!(near_distance_m > 0)) fail("near_distance_m must be > 0");
  if (!(step_height_m > 0)) fail("step_height_m must be > 0");
  if (!(near_reflectance > 0 && near_reflectance <= 1)) fail("near_reflectance must be in (0, 1]");
  if (!(far_reflectance > 0 && far_reflectance <= 1)) fail("far_reflectance must be in (0, 1]");
  if (!(scan_half_width_mm > 0)) fail("scan_half_width_mm must be > 0");
  if (!(step_mm > 0 && step_mm <= scan_half_width_mm)) fail("step_mm must be in (0, half width]");
  if (samples_per_step < 2) fail("samples_per_step must be >= 2");
  if (shots < 0) fail("shots must be >= 0");
}

MixedPixelResult run_mixed_pixel(const device::VirtualRangefinder& device,
                                 const MixedPixelOptions& options, std::uint64_t seed) {
  options.validate();
  MixedPixelResult result;
  result.options = options;
  result.footprint_diameter_m =
      physics::footprint_diameter_m(device.config().link.laser, options.near_distance_m);
  const int shots = resolve_shots(device, options.shots);
  const auto per = static_cast<std::size_t>(options.samples_per_step);
  const auto n_steps =
      static_cast<int>(std::floor(2.0 * options.scan_half_width_mm / options.step_mm + 1e-9)) + 1;
  device::Conditions c;
  c.ambient_c = options.ambient_c;
  std::vector<PlannedMeasurement> plan;
  for (int k = 0; k < n_steps; ++k) {
    MixedPixelStep step;
    step.beam_offset_mm = -options.scan_half_width_mm + k * options.step_mm;
    // The near surface covers x < 0: the footprint's share there is the segment
    // beyond the chord at the (negated) centre offset.
    step.near_fraction =
        disk_fraction_beyond_edge(step.beam_offset_mm * 1e-3, result.footprint_diameter_m);
    device::Target target;
    if (step.near_fraction > 0)
      target.surfaces.push_back(
          {step.near_fraction, options.near_distance_m, options.near_reflectance});
    if (step.near_fraction < 1)
      target.surfaces.push_back({1.0 - step.near_fraction,
                                 options.near_distance_m + options.step_height_m,
                                 options.far_reflectance});
    ranging::GroundTruth truth{options.near_distance_m, options.near_reflectance, 0.0,
                               options.ambient_c};
    for (std::size_t s = 0; s < per; ++s) plan.push_back({{target, c, shots}, truth});
    result.steps.push_back(step);
  }
  result.records = run(device, plan, seed);

  std::vector<double> range(per), amplitude(per);
  for (std::size_t k = 0; k < result.steps.size(); ++k) {
    for (std::size_t s = 0; s < per; ++s) {
      const auto& raw = result.records[k * per + s].raw;
      range[s] = raw.has_echo() ? raw.distance_raw_m : ranging::kNaN;
      amplitude[s] = raw.amplitude;
    }
    const auto r = sample_stats(range);
    auto& step = result.steps[k];
    step.mean_range_m = r.mean;
    step.sd_range_m = r.sd;
    step.samples = r.count;
    step.mean_amplitude = sample_stats(amplitude).mean;
  }
  const auto& first = result.steps.front();
  const auto& last = result.steps.back();
  result.near_range_m = first.mean_range_m;
  result.far_range_m = last.mean_range_m;
  const double jump = result.far_range_m - result.near_range_m;
  // The range should never fall back toward the near surface as the beam moves onto the far one.
  double running_max = -1e300;
  for (const auto& s : result.steps) {
    running_max = std::max(running_max, s.mean_range_m);
    result.monotonicity_violation_mm =
        std::max(result.monotonicity_violation_mm, (running_max - s.mean_range_m) * 1e3);
    const double se_near = first.sd_range_m / std::sqrt(double(first.samples));
    const double se_far = last.sd_range_m / std::sqrt(double(last.samples));
    if (s.mean_range_m > result.near_range_m + 5.0 * se_near &&
        s.mean_range_m < result.far_range_m - 5.0 * se_far)
      ++result.intermediate_steps;
  }
  // 10 % and 90 % crossings of the jump, linearly interpolated between steps.
  auto crossing_mm = [&](double level) {
    const double target_m = result.near_range_m + level * jump;
    for (std::size_t k = 1; k < result.steps.size(); ++k) {
      const auto& a = result.steps[k - 1];
      const auto& b = result.steps[k];
      if (a.mean_range_m < target_m && b.mean_range_m >= target_m) {
        const double w = (target_m - a.mean_range_m) / (b.mean_range_m - a.mean_range_m);
        return a.beam_offset_mm + w * (b.beam_offset_mm - a.beam_offset_mm);
      }
    }
    return ranging::kNaN;
  };
  result.transition_width_mm = crossing_mm(0.9) - crossing_mm(0.1);
  return result;
}

std::vector<Finding> MixedPixelResult::findings() const {
  return {{"footprint_diameter_mm", footprint_diameter_m * 1e3, "mm"},
          {"near_range_m", near_range_m, "m"},
          {"far_range_m", far_range_m, "m"},
          {"intermediate_steps", double(intermediate_steps), ""},
          {"transition_width_mm", transition_width_mm, "mm"},
          {"monotonicity_violation_mm", monotonicity_violation_mm, "mm"}};
}

ResultTable MixedPixelResult::table() const {
  ResultTable t{"steps",
                {"beam_offset_mm", "near_fraction", "mean_range_m", "sd_range_m", "mean_amplitude",
                 "samples"},
                {}};
  for (const auto& s : steps) {
    t.rows.push_back({s.beam_offset_mm, s.near_fraction, s.mean_range_m, s.sd_range_m,
                      s.mean_amplitude, double(s.samples)});
  }
  return t;
}

std::string MixedPixelResult::summary() const {
  std::string out;
  char line[200];
  std::snprintf(line, sizeof line,
                "mixed pixels: %.2f mm footprint across a %.1f in step at %.1f in, %.2f mm steps, "
                "%d samples each\n   offset [mm]  near share   mean range [in]   sd [mm]\n",
                footprint_diameter_m * 1e3, m_to_inches(options.step_height_m),
                m_to_inches(options.near_distance_m), options.step_mm, options.samples_per_step);
  out += line;
  for (const auto& s : steps) {
    std::snprintf(line, sizeof line, "  %+10.2f  %10.3f  %16.4f  %8.3f\n", s.beam_offset_mm,
                  s.near_fraction, m_to_inches(s.mean_range_m), s.sd_range_m * 1e3);
    out += line;
  }
  std::snprintf(line, sizeof line,
                "  %d steps read between the surfaces; 10-90 %% transition over %.2f mm of beam "
                "travel; largest step backwards %.3f mm\n",
                intermediate_steps, transition_width_mm, monotonicity_violation_mm);
  return out + line;
}

}  // namespace tofkit::experiments
