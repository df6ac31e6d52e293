#include "tofkit/experiments/paper_method.hpp"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <stdexcept>
#include <string>

#include "tofkit/calib/hinge_fit.hpp"
#include "tofkit/experiments/characterization_common.hpp"

namespace tofkit::experiments {
namespace {

bool near(double a, double b) {
  return std::abs(a - b) < 1e-9;
}

/// Straight line through (x, y); slope NaN with fewer than 3 points.
double slope_of(const std::vector<double>& x, const std::vector<double>& y) {
  if (x.size() < 3) return ranging::kNaN;
  return fit_line(x, y).slope;
}

/// The paper's figures of a corrected test set: one pass over its conditions
/// (the first of each `repeats` consecutive measurements).
AccuracyFigures figures_of(const std::vector<ranging::Record>& records,
                           const std::vector<double>& corrected_m, int repeats, double distance_m) {
  AccuracyFigures f;
  f.distance_m = distance_m;
  std::vector<double> errors;
  for (std::size_t i = 0; i < records.size(); i += static_cast<std::size_t>(repeats)) {
    if (std::isfinite(corrected_m[i]))
      errors.push_back(corrected_m[i] - records[i].truth.distance_m);
  }
  f.rows = errors.size();
  if (errors.empty()) return f;
  const auto s = sample_stats(errors);
  double worst = 0, var = 0;
  for (const double e : errors) {
    worst = std::max(worst, std::abs(e));
    var += (e - s.mean) * (e - s.mean);
  }
  f.std_mm = 1e3 * std::sqrt(var / static_cast<double>(errors.size()));  // as paper_study
  f.accuracy_mm = 1e3 * worst;
  f.mean_error_mm = 1e3 * s.mean;
  return f;
}

}  // namespace

double PaperMethodResult::correct_m(const ranging::RawMeasurement& raw,
                                    const ranging::Pipeline& start) const {
  if (!raw.has_echo()) return ranging::kNaN;
  const double t = raw.temperature_c;
  const double h = temperature_coefficient_m_per_c *
                   (std::max(0.0, t - temperature_knee_c) -
                    std::max(0.0, temperature_reference_c - temperature_knee_c));
  return start.start_distance_m(raw) + grayvalue_correction(raw.pulse_width_ns) + h;
}

PaperMethodResult run_paper_method(const PaperStudyResult& study,
                                   const PaperStudyOptions& study_options,
                                   const PaperMethodOptions& options) {
  PaperMethodResult result;
  result.temperature_knee_c = options.temperature_knee_c;
  const auto& start = study.fit.pipeline;  // only its c_air t / 2 is used

  // Gray value (Section 5.1): the plates at 2.355 m, calibration ambient.
  std::vector<double> width, offset, sensor_c;
  for (const auto& r : study.calibration) {
    if (!r.raw.has_echo() || !near(r.truth.distance_m, options.grayvalue_distance_m) ||
        !near(r.truth.ambient_c, study_options.calibration_ambient_c))
      continue;
    width.push_back(r.raw.pulse_width_ns);
    offset.push_back(r.truth.distance_m - start.start_distance_m(r.raw));
    sensor_c.push_back(r.raw.temperature_c);
  }
  const auto below =
      std::count_if(width.begin(), width.end(), [&](double w) { return w < options.knee_ns; });
  if (below < 3 || static_cast<std::size_t>(below) + 3 > width.size()) {
    char why[200];
    std::snprintf(why, sizeof why,
                  "paper method: the plates at %g m leave fewer than 3 echoes on a side of the "
                  "%g ns knee",
                  options.grayvalue_distance_m, options.knee_ns);
    throw std::runtime_error(why);
  }
  calib::HingeFitOptions hinge;
  hinge.robust.loss = calib::RobustLoss::kNone;  // the paper: plain least squares
  hinge.min_segment_rows = 3;
  hinge.min_segment_fraction = 0;
  hinge.column = "pulse_width_ns";
  hinge.unit = "ns";
  const double knee[] = {options.knee_ns};
  const auto gray = calib::fit_hinge_fixed_knots(width, offset, knee, hinge);
  result.grayvalue_correction = gray.function;
  result.grayvalue_rows = gray.rows;
  const auto slopes = gray.function.segment_slopes();
  // The correction is true - measured: the offset (measured - true) has the opposite slope.
  result.slope_below_knee_mm_per_ns = -1e3 * slopes.front();
  result.slope_above_knee_mm_per_ns = -1e3 * slopes.back();
  result.temperature_reference_c = sample_stats(sensor_c).mean;

  // Temperature (Section 5.2): the sweep after the gray-value correction.
  std::vector<double> t_lo, e_lo, t_hi, e_hi, hinge_x, residual;
  for (const auto& r : study.calibration) {
    if (!r.raw.has_echo() || !near(r.truth.distance_m, options.temperature_distance_m)) continue;
    const double e = start.start_distance_m(r.raw) +
                     result.grayvalue_correction(r.raw.pulse_width_ns) - r.truth.distance_m;
    const double t = r.raw.temperature_c;
    (t < options.temperature_knee_c ? t_lo : t_hi).push_back(t);
    (t < options.temperature_knee_c ? e_lo : e_hi).push_back(1e3 * e);
    hinge_x.push_back(std::max(0.0, t - options.temperature_knee_c));
    residual.push_back(-e);  // what the correction must add
  }
  result.temperature_rows = residual.size();
  result.temperature_slope_above_mm_per_c = slope_of(t_hi, e_hi);
  result.temperature_slope_below_mm_per_c = slope_of(t_lo, e_lo);
  if (t_hi.size() >= 3) {
    // residual = a + k max(0, T - 16): the paper's one coefficient above the knee.
    const LineFit k = fit_line(hinge_x, residual);
    result.temperature_coefficient_m_per_c = std::isfinite(k.slope) ? k.slope : 0.0;
  }

  // The test sets, corrected the paper's way.
  const int repeats = std::max(1, study_options.test_repeats);
  auto corrected = [&](const std::vector<ranging::Record>& records) {
    std::vector<double> out;
    out.reserve(records.size());
    for (const auto& r : records) out.push_back(result.correct_m(r.raw, start));
    return out;
  };
  result.grayvalue = figures_of(study.grayvalue_test, corrected(study.grayvalue_test), repeats,
                                options.grayvalue_distance_m);
  result.temperature = figures_of(study.temperature_test, corrected(study.temperature_test),
                                  repeats, options.temperature_distance_m);
  // Table 2: the mean of each distance's repeats (as the study's own rows).
  const auto ver = corrected(study.verification);
  for (std::size_t begin = 0; begin < ver.size(); begin += static_cast<std::size_t>(repeats)) {
    std::vector<double> m;
    for (std::size_t i = begin; i < std::min(ver.size(), begin + repeats); ++i)
      if (std::isfinite(ver[i])) m.push_back(ver[i]);
    VerificationRow row;
    row.actual_m = study.verification[begin].truth.distance_m;
    row.repeats = static_cast<int>(m.size());
    const auto s = sample_stats(m);
    row.measured_m = s.mean;
    row.noise_mm = 1e3 * s.sd;
    row.deviation_mm = 1e3 * (row.actual_m - row.measured_m);  // Table 2's sign
    result.verification_rows.push_back(row);
  }
  return result;
}

}  // namespace tofkit::experiments
