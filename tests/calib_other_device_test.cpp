// Calibration on a device with other parts than the built-in one (issue 8):
// the paper's protocol (plates at one distance plus a temperature run) fitted
// by the chain, tested over 0.7-7.4 m x reflectance 0.06-0.85 x 8-37 C. The
// device is reached only through its public API and config keys.

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <map>
#include <numbers>
#include <numeric>
#include <random>
#include <span>
#include <string>
#include <tuple>
#include <variant>
#include <vector>

#include "other_parts_device.hpp"
#include "tofkit/calib/chain_fit.hpp"
#include "tofkit/calib/model_fit.hpp"
#include "tofkit/calib/statistics.hpp"
#include "tofkit/device/device_config.hpp"
#include "tofkit/device/virtual_rangefinder.hpp"
#include "tofkit/experiments/measurement_grid.hpp"
#include "tofkit/io/model_json.hpp"
#include "tofkit/ranging/record_columns.hpp"

namespace tofkit {
namespace {

using test::other_parts;
using test::set_key;

// The TDC: this device's firmware calibrates the carry chain's bins by a
// code-density test (other_parts()), so the synchronous laser's periodic INL
// error (6.8 mm worst uncorrected) is down to the counting error of 2^20 hits.
// Calibration and test rows are measured in one power-on (one run, other
// random streams): the delay offset drawn at each power-on
// (measurement.power_on_offset_ps, 1.5 mm rms) is a between-session error that
// plates cannot calibrate (measured: 3.4 mm worst when the test runs after
// another power-on), so it is not a calibration figure.
struct PaperData {
  std::vector<ranging::Record> calibration, test;
};

const PaperData& paper_data() {
  static const PaperData data = [] {
    const device::VirtualRangefinder device(other_parts());
    std::vector<experiments::PlannedMeasurement> calibration, test;
    for (double rho : {0.04, 0.06, 0.1, 0.15, 0.2, 0.3, 0.45, 0.6, 0.75, 0.9}) {
      for (int repeat = 0; repeat < 5; ++repeat) {
        calibration.push_back(experiments::plate(3.0, rho, 20.0));
      }
    }
    for (double t = 0; t <= 45; t += 2.5) {
      for (int repeat = 0; repeat < 5; ++repeat) {
        calibration.push_back(experiments::plate(3.0, 0.3, t));
      }
    }
    for (double d = 0.7; d <= 7.4 + 1e-9; d += 0.67) {
      for (double rho : {0.06, 0.12, 0.25, 0.45, 0.65, 0.85}) {
        for (double t = 8; t <= 37 + 1e-9; t += 5.8) test.push_back(experiments::plate(d, rho, t));
      }
    }
    std::vector<experiments::PlannedMeasurement> plan = calibration;
    plan.insert(plan.end(), test.begin(), test.end());
    const auto rows = experiments::run(device, plan, 1);
    PaperData out;
    out.calibration.assign(rows.begin(),
                           rows.begin() + static_cast<std::ptrdiff_t>(calibration.size()));
    out.test.assign(rows.begin() + static_cast<std::ptrdiff_t>(calibration.size()), rows.end());
    return out;
  }();
  return data;
}

TEST(CalibrationOnOtherParts, PaperProtocolChainIsWithinThreeMillimetresInItsDomain) {
  const std::vector<ranging::Record>& fit_rows = paper_data().calibration;
  const std::vector<ranging::Record>& test_rows = paper_data().test;
  const calib::ChainFitResult fit = calib::fit_chain(fit_rows);
  std::size_t in_domain = 0, echoes = 0;
  double worst = 0;
  for (const auto& r : test_rows) {
    const ranging::Range range = fit.pipeline.apply(r.raw);
    if (!std::isfinite(range.distance_m)) continue;
    ++echoes;
    if (range.correction_flags != 0) continue;
    ++in_domain;
    worst = std::max(worst, std::fabs(r.truth.distance_m - range.distance_m));
  }
  EXPECT_LE(worst, 0.003) << fit.summary();
  std::printf("paper protocol: worst in-domain %.3f mm, %zu of %zu rows with an echo in domain\n",
              worst * 1e3, in_domain, echoes);
  // The plates' pulse widths cover a good part of the field (the rest is flagged).
  EXPECT_GT(in_domain, echoes / 3) << in_domain << " of " << echoes;
}

// ---------------------------------------------------------------------------
// A 0.5-9 m grid of the other-parts device (indoors): the B-spline surface and
// the chain fitted on it by calib::fit_model (as `tofkit fit` runs it), judged
// on held-out rows of the same session (targets between the grid's, measured
// in the same power-on on other random streams), 500-shot rows at 25 C: the systematic residual
// (the error of the mean of a target's repeats, less that mean's own noise, as the demo and the
// field test take it) against the noise of one row, and the 2-sigma coverage of sigma_m overall
// and per amplitude tercile.

constexpr double kGridTemperatureC = 25.0;
constexpr int kGridShots = 500;

struct GridData {
  std::vector<ranging::Record> calibration, test;
  /// More held-out targets for the coverage: 34 distances a quarter of the
  /// grid step off its nodes (0.625-8.875 m) x 9 reflectances x 6 repeats.
  /// With the 14 targets per tercile of `test` a 95 % coverage has a binomial
  /// sd of 2.4 % (more, since a target's repeats share its systematic error),
  /// as wide as the 93-97 % band; here about 100 targets per tercile.
  std::vector<ranging::Record> coverage;
};

/// The grid's rows at run seed `seed`. in_time_order: the calibration rows
/// first, then `test`, then `coverage`, as a session would measure them;
/// false: the whole plan in one fixed shuffled order (each row keeps its place
/// in the returned sets), so the calibration spans the session.
GridData make_grid_data(std::uint64_t seed, bool in_time_order) {
  const device::VirtualRangefinder device(experiments::indoors(other_parts()));
  std::vector<experiments::PlannedMeasurement> plan;
  for (double d = 0.5; d <= 9.0 + 1e-9; d += 0.5) {
    for (double rho : {0.06, 0.12, 0.25, 0.45, 0.65, 0.85}) {
      for (int repeat = 0; repeat < 2; ++repeat) {
        plan.push_back(experiments::plate(d, rho, kGridTemperatureC, 0.0, kGridShots));
      }
    }
  }
  const std::size_t calibration_rows = plan.size();
  for (double d = 0.75; d <= 8.75 + 1e-9; d += 1.0) {
    for (double rho : {0.09, 0.2, 0.35, 0.55, 0.75}) {
      for (int repeat = 0; repeat < 6; ++repeat) {
        plan.push_back(experiments::plate(d, rho, kGridTemperatureC, 0.0, kGridShots));
      }
    }
  }
  const std::size_t test_end = plan.size();
  // Appended, so the rows above keep their random streams.
  for (double d = 0.625; d <= 8.875 + 1e-9; d += 0.25) {
    for (double rho : {0.09, 0.16, 0.2, 0.3, 0.35, 0.5, 0.55, 0.7, 0.75}) {
      for (int repeat = 0; repeat < 6; ++repeat) {
        plan.push_back(experiments::plate(d, rho, kGridTemperatureC, 0.0, kGridShots));
      }
    }
  }
  std::vector<std::size_t> order(plan.size());
  std::iota(order.begin(), order.end(), std::size_t{0});
  if (!in_time_order) std::shuffle(order.begin(), order.end(), std::mt19937_64(3));
  std::vector<experiments::PlannedMeasurement> measured;
  for (std::size_t k : order) measured.push_back(plan[k]);
  const std::vector<ranging::Record> run = experiments::run(device, measured, seed);
  std::vector<ranging::Record> rows(plan.size());
  for (std::size_t k = 0; k < order.size(); ++k) rows[order[k]] = run[k];
  const auto at = [&](std::size_t k) { return rows.begin() + static_cast<std::ptrdiff_t>(k); };
  GridData out;
  out.calibration.assign(rows.begin(), at(calibration_rows));
  out.test.assign(at(calibration_rows), at(test_end));
  out.coverage.assign(at(test_end), rows.end());
  return out;
}

const GridData& grid_data() {
  static const GridData data = make_grid_data(7, true);
  return data;
}

struct HeldOutFigures {
  /// RMS over targets of the mean error of their repeats, its own noise
  /// (var / repeats) taken off the squares: the part of a row's error that
  /// repeating it does not average away
  double systematic_m = 0;
  double mean_error_rms_m = 0;  ///< RMS over targets of the mean error as measured
  double noise_m = 0;           ///< RMS over targets of the standard deviation of one row
  double within_2sigma = 0;
  std::array<double, 3> within_2sigma_by_tercile{};
  std::size_t rows = 0;
  [[nodiscard]] std::string summary() const {
    char buffer[256];
    std::snprintf(buffer, sizeof buffer,
                  "%zu rows: systematic %.3f mm (mean error %.3f mm), noise %.3f mm; within 2 "
                  "sigma %.1f %% (terciles %.1f / %.1f / %.1f %%)",
                  rows, systematic_m * 1e3, mean_error_rms_m * 1e3, noise_m * 1e3,
                  100 * within_2sigma, 100 * within_2sigma_by_tercile[0],
                  100 * within_2sigma_by_tercile[1], 100 * within_2sigma_by_tercile[2]);
    return buffer;
  }
};

/// Held-out figures of `pipeline` on `rows` (rows with an echo; repeats are
/// rows of identical truth).
HeldOutFigures held_out_figures(const ranging::Pipeline& pipeline,
                                const std::vector<ranging::Record>& rows) {
  std::map<std::tuple<double, double, double>, std::vector<double>> errors_of;
  std::vector<double> error, sigma, amplitude;
  for (const auto& r : rows) {
    const ranging::Range range = pipeline.apply(r.raw);
    if (!std::isfinite(range.distance_m) || !std::isfinite(r.raw.amplitude)) continue;
    const double e = r.truth.distance_m - range.distance_m;
    errors_of[{r.truth.distance_m, r.truth.reflectance, r.truth.ambient_c}].push_back(e);
    error.push_back(e);
    sigma.push_back(range.sigma_m);
    amplitude.push_back(r.raw.amplitude);
  }
  HeldOutFigures f;
  f.rows = error.size();
  double mean2 = 0, systematic2 = 0, var = 0;
  for (const auto& [target, e] : errors_of) {
    double mean = 0;
    for (double v : e) mean += v;
    const auto k = static_cast<double>(e.size());
    mean /= k;
    double ss = 0;
    for (double v : e) ss += (v - mean) * (v - mean);
    const double row_var = e.size() > 1 ? ss / (k - 1) : 0.0;
    mean2 += mean * mean;
    systematic2 += mean * mean - row_var / k;
    var += row_var;
  }
  const auto targets = static_cast<double>(errors_of.size());
  f.mean_error_rms_m = std::sqrt(mean2 / targets);
  f.systematic_m = std::sqrt(std::max(systematic2 / targets, 0.0));
  f.noise_m = std::sqrt(var / targets);
  const auto c =
      calib::coverage(error, sigma, amplitude, 2.0, calib::amplitude_terciles(amplitude));
  f.within_2sigma = c.share;
  f.within_2sigma_by_tercile = c.tercile_share;
  return f;
}

/// The TDC's coarse clock period, as its datasheet gives it to the calibration.
double tdc_period_ns() {
  return 1e3 / other_parts().tdc.coarse_clock_mhz;
}

calib::ModelFitResult fit_grid(bool chain, bool refine_walk = true,
                               calib::SurfaceIntensity intensity = calib::SurfaceIntensity::choose,
                               calib::ConfidenceKind confidence = calib::ConfidenceKind::calibrated,
                               double periodic_ns = 0) {
  calib::ModelFitOptions options;
  options.confidence = confidence;
  options.tdc_period_ns = periodic_ns;
  options.surface_intensity = intensity;
  if (chain) {
    options.chain = calib::ChainSteps{true, true, false};
    options.refine_walk = refine_walk;
  } else {
    options.surface = calib::parse_surface_spec("bspline");
  }
  return calib::fit_model(grid_data().calibration, options);
}

// The acceptance on held-out rows: systematic residual no larger than
// the noise of one row (on `test`), and sigma covering 93-97 % within 2 sigma
// overall and in each amplitude tercile (on the larger `coverage` set). The
// correction has the periodic TDC step in front; the confidence is the
// noise-systematic kind (noise from the repeats, systematic
// from the targets' mean residuals times the optimism, on the correction's
// intensity axis); the default calibrated kind's figures are printed beside it.
void expect_noise_level_and_covering_sigma(bool chain) {
  const char* label = chain ? "chain" : "B-spline";
  const calib::ModelFitResult calibrated = fit_grid(chain);
  const calib::ModelFitResult fit =
      fit_grid(chain, true, calib::SurfaceIntensity::choose,
               calib::ConfidenceKind::noise_systematic, tdc_period_ns());
  const HeldOutFigures f = held_out_figures(fit.pipeline, grid_data().test);
  const HeldOutFigures c = held_out_figures(fit.pipeline, grid_data().coverage);
  const HeldOutFigures d = held_out_figures(calibrated.pipeline, grid_data().coverage);
  std::printf("%s: %s\ncoverage set, noise-systematic: %s\ncoverage set, calibrated: %s\n%s", label,
              f.summary().c_str(), c.summary().c_str(), d.summary().c_str(), fit.report.c_str());
  EXPECT_LE(f.systematic_m, f.noise_m) << f.summary();
  EXPECT_GE(c.within_2sigma, 0.93) << c.summary();
  EXPECT_LE(c.within_2sigma, 0.97) << c.summary();
  for (double share : c.within_2sigma_by_tercile) {
    EXPECT_GE(share, 0.93) << c.summary();
    EXPECT_LE(share, 0.97) << c.summary();
  }
}

// DISABLED (issue 8 open): the systematic half passes (see
// BSplineWithThePeriodicStepReachesTheNoise: 0.242 mm against 0.248 mm, with
// each axis's penalty weight chosen by cross-validation and the folds scored
// inside their training domain; 0.302 mm before); the coverage does not.
// Measured with the periodic TDC step and the noise-systematic confidence
// (noise from the repeats, the systematic part by maximum likelihood on the
// targets' mean residuals, each scaled by its own optimism (1 + h) / (1 - h)
// from its leverage h: mean 2.99, the leverages summing to 24.5 against
// p = 24.6): coverage set 95.8 % within 2 sigma, terciles 95.9 / 98.8 / 92.7 %
// (`test`: 98.4 %, 97.6 / 97.6 / 100 %); with one optimism (G + p) / (G - p)
// for all targets 93.2 %, 89.6 / 98.1 / 91.8 %; the default calibrated
// confidence 98.4 %, 97.8 / 97.6 / 99.8 %. Other run seeds (8, 9, 10): the
// wander (see CrossFittedSigmaCarriesTheWanderTheCalibrationSpans) takes it to
// 58.7 / 69.9 / 77.9 % (one optimism: 53.3 / 62.7 / 74.0 %); with
// measurement.flicker_delay_ps = 0, seeds 7-10: 96.2 / 91.2 / 92.6 / 92.4 %
// (one optimism: 94.9 / 89.0 / 89.0 / 90.8 %); on slower parts
// (receiver.bandwidth_mhz 60, laser.pulse_width_ns 3, discriminator.threshold_v
// 0.03) without the wander 96.1 / 94.9 / 95.7 / 96.3 % (one optimism: 95.7 /
// 94.6 / 94.6 / 95.1 %), its terciles 93.6-98.7 %. The coverage
// set has targets the surface does not reach (systematic 1.30 mm RMS there
// against 0.25 mm for the chain; 0.39 mm without the one target below):
// +-1-1.4 mm at 0.6-1.9 m for bright targets (pulse widths 9.2-10.2 ns, where
// the amplitude clips: 46 of the high tercile's 50 rows outside 2 sigma are
// 10 such targets; the calibration rows there are off as much) and -21 mm at
// 8.375 m, rho 0.16 (3 of 6 repeats with an echo, at the threshold). Knots at
// quantiles of the data do not reach the knee: cross-validation offers them
// (chosen for range, not for pulse width), but the grid's targets crowd at
// small pulse widths (12 quantile intervals leave 8.4-11.1 ns as one, against
// 1.5 ns uniform), and 16 uniform intervals, chosen by cross-validation when
// offered, made `test` worse (0.437 mm systematic, coverage set 92.0 %, 95.9 /
// 98.8 / 81.4 %). The middle tercile is over-covered either way: without the
// bright targets below 2 m and the rows with partial echoes the coverage set
// gives 96.4 %, 94.0 / 98.1 / 97.3 %. Each tercile's sigma rests on about 30
// of the 96 calibration targets: a variance from 30 values is uncertain by
// sqrt(2/30) = 26 % (sigma by 13 %), which moves a 2-sigma coverage by about
// 3 points, more than the band's half width.
// Tried for the sigma: the systematic part from cross-fitted residuals
// (5 or 20 folds of whole targets, mean less the noise of a mean, no optimism
// factor): 99.6 % (99.0 / 99.8 / 100 %) and 98.8 % (97.6 / 99.7 / 99.1 %) on the
// coverage set, the chain 99.4 % and 99.5 %: a grid node held out is predicted
// across a gap of two grid steps, a new target between nodes is not, so
// cross-fitting overstates the error of interpolation on this design.
TEST(CalibrationOnOtherParts, DISABLED_BSplineOnAGridReachesTheNoiseAndItsSigmaCoversEveryTercile) {
  expect_noise_level_and_covering_sigma(false);
}

// DISABLED (issue 8 open): the systematic half passes (see
// ChainWithThePeriodicStepReachesTheNoise: 0.234 mm against 0.252 mm); the
// coverage does not quite. Measured with the periodic step and the
// noise-systematic confidence, each target's systematic error scaled by its
// own optimism (1 + h) / (1 - h) from its leverage h (mean 4.49, largest 30.4;
// the leverages sum to 48.3 against p = 49.9 effective parameters): coverage
// set 96.5 % within 2 sigma, terciles 94.5 / 98.5 / 96.6 % (`test`: 96.0 %,
// 96.4 / 94.0 / 97.6 %). With one optimism (G + p) / (G - p) = 3.17 for all
// 96 targets it was 93.9 %, 92.2 / 96.4 / 93.2 %: the refinement is flexible
// where the targets are sparse (h 0.75-0.95 at pulse widths 3.9-5 ns, 0.25-0.5
// elsewhere), and there one optimism gave too little. The default calibrated
// confidence without the step: 97.4 %, 99.8 / 93.5 / 98.8 %.
// These figures are one draw (run seed 7). With seeds 8-10 the coverage set
// sits 0.43-0.54 mm off the calibration (the 1/f delay wander between the
// calibration rows and the later coverage rows, which the calibration cannot
// see: CrossFittedSigmaCarriesTheWanderTheCalibrationSpans) and every model
// falls short: noise-systematic 64.3 / 73.5 / 73.4 % (one optimism: 45.6 /
// 55.9 / 68.3 %), calibrated 81.0 / 89.2 / 92.8 %. With the wander at 0,
// seeds 7-10: noise-systematic 97.0 / 95.9 / 93.7 / 88.9 % (one optimism:
// 93.8 / 87.8 / 87.9 / 85.9 %), its middle tercile 88.9-99.1 % and high
// tercile 85.1-97.1 %; the default calibrated kind 97.2 / 97.0 / 97.2 / 96.5 %
// with its low tercile at 99.5-99.8 % every time (its 5-fold cross-fitting
// leaves gaps where the walk bends: a held-out bright plate at 1.5-2.5 m is
// predicted 1.2-2.8 mm off, while the coverage set's high tercile has 0.32-0.35
// mm of systematic error); and the test set's systematic 0.21-0.31 mm against 0.24-0.26 mm of noise
// (above it at seed 10). On slower parts (receiver.bandwidth_mhz 60, laser.pulse_width_ns 3,
// discriminator.threshold_v 0.03) without the wander: noise-systematic 95.5 / 95.2 / 95.3 / 94.8 %
// (one optimism: 92.8 / 91.6 / 95.2 / 94.7 %), its middle tercile over (94.2-99.7 %), its high one
// under (90.6-93.9 %); with the wander 96.1 / 88.4 / 87.1 / 87.5 %. An oracle sigma (each tercile's
// held-out RMS error) covers 94.2-96.2 % per tercile at these seeds without
// the wander: the band is reachable, but a model's tercile sigma rests on
// about 30 targets (see the B-spline's test above).
TEST(CalibrationOnOtherParts, DISABLED_ChainOnAGridReachesTheNoiseAndItsSigmaCoversEveryTercile) {
  expect_noise_level_and_covering_sigma(true);
}

// Why sigma has no drift term of its own. The device's 1/f delay wander
// (measurement.flicker_delay_ps, 5 ps rms over octaves from 1 mHz) moves the
// coverage rows, measured 0.3-2.3 s after the 0.2 s of calibration rows,
// 0.44-0.54 mm off at run seeds 8 and 9 (seed 7: 0.04 mm). The calibration
// cannot see that: its own residuals trend by 0.01-0.05 mm along its rows,
// below what 216 rows resolve, so no term fitted from them can. Measured in
// one shuffled order the calibration spans the session, and the wander is in
// every cross-fitted residual (a held-out target's rows lie at other times
// than its fold's training rows): the default calibrated confidence then
// covers 93 % or more at the seeds where the time-ordered session gives
// 81-89 %. A drift variance estimated from the calibration's time structure
// and added to sigma^2 would count what the residuals already carry twice.
TEST(CalibrationOnOtherParts, CrossFittedSigmaCarriesTheWanderTheCalibrationSpans) {
  for (std::uint64_t seed : {8, 9}) {
    for (bool in_time_order : {true, false}) {
      const GridData data = make_grid_data(seed, in_time_order);
      calib::ModelFitOptions options;
      options.chain = calib::ChainSteps{true, true, false};
      options.refine_walk = true;
      const calib::ModelFitResult fit = calib::fit_model(data.calibration, options);
      const HeldOutFigures f = held_out_figures(fit.pipeline, data.coverage);
      double mean = 0;
      std::size_t rows = 0;
      for (const auto& r : data.coverage) {
        const double e = r.truth.distance_m - fit.pipeline.apply(r.raw).distance_m;
        if (!std::isfinite(e)) continue;
        mean += e;
        ++rows;
      }
      mean /= static_cast<double>(rows);
      std::printf("seed %d, %s: mean error %.3f mm; %s\n", static_cast<int>(seed),
                  in_time_order ? "in time order" : "shuffled", mean * 1e3, f.summary().c_str());
      if (in_time_order) {
        EXPECT_GT(std::fabs(mean), 0.3e-3);
        EXPECT_LT(f.within_2sigma, 0.93) << f.summary();
      } else {
        EXPECT_LT(std::fabs(mean), 0.15e-3);
        EXPECT_GE(f.within_2sigma, 0.93) << f.summary();
      }
    }
  }
}

// The B-spline surface on the same grid, with the periodic step: each axis's
// second-difference penalty weighted separately (the walk bends in pulse
// width, the range axis stays straight) and the folds scored only inside the
// domain their training rows span (a surface is not applied outside it) must
// bring the held-out systematic residual within the noise of one row
// (measured: 0.229 mm against 0.248 mm of noise with the step at both stops.
// The means' RMS as measured, their own noise in it: 0.250 mm; so measured
// before, with the step at the rising stop alone: 0.242 mm, range knots at
// quantiles chosen by cross-validation; 0.241 mm with uniform knots only; one
// common penalty, folds scored on every row: 0.302 mm).
TEST(CalibrationOnOtherParts, BSplineWithThePeriodicStepReachesTheNoise) {
  const calib::ModelFitResult fit = fit_grid(false, true, calib::SurfaceIntensity::choose,
                                             calib::ConfidenceKind::calibrated, tdc_period_ns());
  const HeldOutFigures f = held_out_figures(fit.pipeline, grid_data().test);
  std::printf("%s\n%s", f.summary().c_str(), fit.report.c_str());
  ASSERT_TRUE(fit.summary.surface.has_value());
  EXPECT_EQ(fit.summary.surface_intensity, "pulse_width_ns");
  ASSERT_TRUE(fit.summary.periodic.has_value());
  EXPECT_LE(f.systematic_m, f.noise_m) << f.summary();
}

// With the laser fired on the TDC's clock, the residual INL of the fine codes
// (code density with 2^20 hits) and the bin-width error leave a range error
// periodic in the time of flight (period 1 / f_coarse = 5 ns, 0.75 m); the
// walk spreads the grid's stops over the whole period, so a periodic step in
// tof modulo the clock period can learn it. It must be chosen by
// cross-validation and bring the chain's held-out systematic residual within
// the noise of one row (measured: 0.282 -> 0.203 mm against 0.250 mm, the
// step at both stops; at the rising stop alone 0.285 -> 0.234 mm).
TEST(CalibrationOnOtherParts, ChainWithThePeriodicStepReachesTheNoise) {
  const HeldOutFigures without = held_out_figures(fit_grid(true).pipeline, grid_data().test);
  const calib::ModelFitResult fit = fit_grid(true, true, calib::SurfaceIntensity::choose,
                                             calib::ConfidenceKind::calibrated, tdc_period_ns());
  const HeldOutFigures with = held_out_figures(fit.pipeline, grid_data().test);
  std::printf("without: %s\nwith the periodic step: %s\n%s", without.summary().c_str(),
              with.summary().c_str(), fit.report.c_str());
  ASSERT_TRUE(fit.summary.periodic.has_value());
  EXPECT_GT(fit.summary.periodic->harmonics, 0);
  EXPECT_LT(fit.summary.periodic->cv_rms_m, fit.summary.periodic->cv_rms_without_m);
  ASSERT_FALSE(fit.pipeline.steps().empty());
  EXPECT_EQ(fit.pipeline.steps().front().kind, ranging::StepKind::kPeriodic);
  EXPECT_LT(with.systematic_m, without.systematic_m);
  EXPECT_LE(with.systematic_m, with.noise_m);
  // The model file keeps the step.
  const ranging::Pipeline loaded =
      io::pipeline_from_json(io::pipeline_to_json(fit.pipeline), "model.json");
  for (const auto& r : grid_data().test) {
    const ranging::Range x = fit.pipeline.apply(r.raw), y = loaded.apply(r.raw);
    if (std::isfinite(x.distance_m)) EXPECT_NEAR(x.distance_m, y.distance_m, 1e-12);
  }
}

/// Synthetic rows whose TDC reads every stop late by a known periodic error
/// E(t) (harmonics 1, 3, 6 and 9 of a 5 ns period, 1.2 mm rms at 25 C),
/// scaled by 1 + slope_per_c (T - 25 C) (a bin-width error grows with the
/// board's departure), on a walk that moves the rising edge by minus half the
/// width change (a symmetric pulse's), the width growing with ln amplitude;
/// the time of flight is the rising edge's stop, the width the falling one's
/// less it. 0.3 mm of noise on the tof and 2 ps on the width.
struct SyntheticTdc {
  static constexpr double kPeriod = 5.0, kNoise = 0.3e-3, kWidthNoise_ns = 0.002, kRefC = 25.0;
  double slope_per_c = 0;
  const double mpn = ranging::metres_per_ns(ranging::TimeToDistance{});
  // E's harmonics {cos, sin} in m, by harmonic number.
  const std::map<int, std::array<double, 2>> error_m = {
      {1, {0.8e-3, -0.5e-3}}, {3, {0.4e-3, 0.2e-3}}, {6, {-0.25e-3, 0.3e-3}}, {9, {0.15e-3, 0.0}}};
  std::mt19937_64 rng{11};
  std::normal_distribution<double> normal;

  [[nodiscard]] double tdc_error_m(double t_ns, double temperature_c) const {
    double e = 0;
    for (const auto& [h, c] : error_m) {
      const double a = 2 * std::numbers::pi * h * t_ns / kPeriod;
      e += c[0] * std::cos(a) + c[1] * std::sin(a);
    }
    return e * (1 + slope_per_c * (temperature_c - kRefC));
  }
  void measure(double distance_m, double reflectance, double temperature_c, int count,
               std::vector<ranging::Record>& rows) {
    const double amplitude = 2.0 * reflectance / (distance_m * distance_m);
    const double width_ns = 6.0 + 0.8 * std::log(amplitude);
    const double rise_ns = distance_m / mpn + 3.0 - 0.5 * (width_ns - 6.0);  // 3 ns of delay
    for (int k = 0; k < count; ++k) {
      ranging::Record r;
      r.truth = {distance_m, reflectance, 0.0, temperature_c};
      const double rise = rise_ns + tdc_error_m(rise_ns, temperature_c) / mpn;
      const double fall = rise_ns + width_ns + tdc_error_m(rise_ns + width_ns, temperature_c) / mpn;
      r.raw.tof_ns = rise + kNoise / mpn * normal(rng);
      r.raw.distance_raw_m = r.raw.tof_ns * mpn;
      r.raw.pulse_width_ns = fall - rise + kWidthNoise_ns * normal(rng);
      r.raw.amplitude = amplitude;
      r.raw.temperature_c = temperature_c;
      r.raw.shots_valid = 100;
      rows.push_back(r);
    }
  }
  /// Plates at two distances (8 reflectances) and a rail of one plate at 73
  /// distinct phases over 9 periods, 5 repeats, at 25 C.
  void calibration_rows(std::vector<ranging::Record>& rows) {
    for (const double d : {1.7, 4.0})
      for (int p = 0; p < 8; ++p) measure(d, 0.06 * std::pow(1.45, p), kRefC, 5, rows);
    const double period_m = kPeriod * mpn, step_m = period_m * 9 / 73;
    for (int k = 0; k < 73; ++k) measure(0.72 + step_m * k, 0.35, kRefC, 5, rows);
  }
  /// The noise in the range: the tof's and, through the gray value's slope of
  /// 1/2, the width's.
  [[nodiscard]] double range_noise_m() const {
    return std::hypot(kNoise, 0.5 * kWidthNoise_ns * mpn);
  }
  [[nodiscard]] static calib::ModelFitOptions fit_options() {
    calib::ModelFitOptions options;
    options.chain = calib::ChainSteps{true, true, false};
    options.tdc_period_ns = kPeriod;
    options.confidence = calib::ConfidenceKind::none;
    return options;
  }
  /// The corrected rows' error sd.
  [[nodiscard]] static double error_sd_m(const ranging::Pipeline& pipeline,
                                         std::span<const ranging::Record> rows) {
    std::vector<ranging::Range> out(rows.size());
    pipeline.apply(ranging::RawColumns::of(rows), out);
    double sum = 0, sum2 = 0;
    for (std::size_t i = 0; i < rows.size(); ++i) {
      const double e = out[i].distance_m - rows[i].truth.distance_m;
      sum += e;
      sum2 += e * e;
    }
    const double n = static_cast<double>(rows.size());
    return std::sqrt(sum2 / n - (sum / n) * (sum / n));
  }
};

// Oracle for the periodic step's fit (SyntheticTdc at one temperature): the
// gray value that reads the width carries half of E at the falling edge's
// phase, which moves with the echo. The fitted step's coefficients must be
// those of -E within 4 standard errors of the noise, and held-out targets
// (other reflectances and distances) must be corrected to the noise
// (measured: 9 harmonics chosen, held-out sd 0.337 mm against 0.335 mm).
// Fitted at the rising stop alone (the step before this fit) 9 of the 18
// coefficients missed by more than 4 standard errors (0.09 mm), the first
// harmonic's cosine by 0.18 mm, and the held-out sd was 0.87 mm.
TEST(PeriodicStepFit, RecoversATdcErrorAtBothStopsOnAWalkingRail) {
  SyntheticTdc tdc;
  std::vector<ranging::Record> calibration, test;
  tdc.calibration_rows(calibration);
  for (double d = 0.75; d < 7.4; d += 0.37)
    for (const double rho : {0.08, 0.2, 0.6}) tdc.measure(d, rho, SyntheticTdc::kRefC, 1, test);
  const calib::ModelFitResult fit = calib::fit_model(calibration, SyntheticTdc::fit_options());
  ASSERT_FALSE(fit.pipeline.steps().empty()) << fit.report;
  const ranging::Step& step = fit.pipeline.steps().front();
  ASSERT_EQ(step.kind, ranging::StepKind::kPeriodic) << fit.report;
  EXPECT_TRUE(step.both_stops);
  EXPECT_TRUE(step.harmonics_per_c_m.empty()) << "one temperature shows no slope";
  const int harmonics = static_cast<int>(step.harmonics_m.size() / 2);
  EXPECT_GE(harmonics, 9) << fit.report;
  // A coefficient's standard error: the range's noise over sqrt(rows / 2).
  const double noise = tdc.range_noise_m();
  const double se = noise * std::sqrt(2.0 / static_cast<double>(calibration.size()));
  for (int h = 1; h <= std::max(harmonics, 9); ++h) {
    const auto it = tdc.error_m.find(h);
    for (int k = 0; k < 2; ++k) {
      const double truth = it == tdc.error_m.end() ? 0.0 : -it->second[static_cast<std::size_t>(k)];
      const double fitted =
          h <= harmonics ? step.harmonics_m[static_cast<std::size_t>(2 * (h - 1) + k)] : 0.0;
      EXPECT_NEAR(fitted, truth, 4 * se) << "harmonic " << h << (k ? " sin" : " cos") << "\n"
                                         << fit.report;
    }
  }
  // Held out: the corrected rows' error is the noise.
  const double sd = SyntheticTdc::error_sd_m(fit.pipeline, test);
  std::printf("%d harmonics, held-out error sd %.3f mm against the noise %.3f mm\n%s", harmonics,
              sd * 1e3, noise * 1e3, fit.report.c_str());
  EXPECT_LE(sd, 1.25 * noise);
}

// Oracle for the periodic step's temperature slope: SyntheticTdc's error
// grows by 4 % per C (a bin-width error: 0.64 mm rms more at 45 C than at
// 25 C), and a temperature run reads one plate at 32 phases of the period at
// 5-45 C (enough for the slopes of 10 harmonics: E has 9), from 4 m. (From
// 1.7 m the same run, even at 25 C and without noise, left the series at 9
// harmonics with 0.18 mm of cross-validated misfit where 4 m leaves 0.04 mm:
// a limit of the backfitting with the gray-value hinge there, not of the
// slope; measured while writing this test.) The slopes must
// be -E's coefficients times 0.04 within 4 standard errors (the noise over
// sqrt(rows / 2) and the readings' rms departure), and held-out targets at 8
// and 42 C corrected to the noise; the fit without the temperature run (no
// slope) leaves them its share.
TEST(PeriodicStepFit, FollowsATdcErrorThatScalesWithTemperature) {
  SyntheticTdc tdc;
  tdc.slope_per_c = 0.04;
  std::vector<ranging::Record> calibration, run, test;
  tdc.calibration_rows(calibration);
  const double period_m = SyntheticTdc::kPeriod * tdc.mpn;
  for (int k = 0; k < 32; ++k)
    for (double t = 5; t <= 45; t += 5) tdc.measure(4.0 + period_m * k / 32, 0.35, t, 1, run);
  for (double d = 0.75; d < 7.4; d += 0.37)
    for (const double t : {8.0, 42.0}) tdc.measure(d, 0.2, t, 1, test);
  const calib::ModelFitResult without = calib::fit_model(calibration, SyntheticTdc::fit_options());
  calibration.insert(calibration.end(), run.begin(), run.end());
  const calib::ModelFitResult fit = calib::fit_model(calibration, SyntheticTdc::fit_options());
  const ranging::Step& step = fit.pipeline.steps().front();
  ASSERT_EQ(step.kind, ranging::StepKind::kPeriodic) << fit.report;
  ASSERT_EQ(step.harmonics_per_c_m.size(), step.harmonics_m.size()) << fit.report;
  ASSERT_TRUE(fit.summary.periodic && fit.summary.periodic->temperature_slope);
  // The slope's standard error: the run's rows carry it, their reading's rms
  // departure from the step's reference.
  double departure2 = 0;
  for (const auto& r : run)
    departure2 += std::pow(r.raw.temperature_c - step.reference_temperature_c, 2);
  const double se = tdc.range_noise_m() * std::sqrt(2.0 / departure2);
  const int harmonics = static_cast<int>(step.harmonics_m.size() / 2);
  EXPECT_GE(harmonics, 9) << fit.report;
  for (int h = 1; h <= harmonics; ++h) {
    const auto it = tdc.error_m.find(h);
    for (int k = 0; k < 2; ++k) {
      const double truth = it == tdc.error_m.end()
                               ? 0.0
                               : -tdc.slope_per_c * it->second[static_cast<std::size_t>(k)];
      EXPECT_NEAR(step.harmonics_per_c_m[static_cast<std::size_t>(2 * (h - 1) + k)], truth, 4 * se)
          << "harmonic " << h << (k ? " sin" : " cos") << "\n"
          << fit.report;
    }
  }
  const double sd = SyntheticTdc::error_sd_m(fit.pipeline, test);
  const double sd_without = SyntheticTdc::error_sd_m(without.pipeline, test);
  std::printf(
      "held-out at 8 and 42 C: error sd %.3f mm (without the run %.3f mm), noise %.3f mm\n%s",
      sd * 1e3, sd_without * 1e3, tdc.range_noise_m() * 1e3, fit.report.c_str());
  EXPECT_LE(sd, 1.25 * tdc.range_noise_m());
  EXPECT_GT(sd_without, 1.5 * tdc.range_noise_m());
}

// The hinge's three knots cannot follow the walk's curvature (2.5 mm
// systematic on this grid); the dense walk refinement, chosen by grouped
// cross-validation, must at least halve the systematic residual on held-out
// targets and bring it within 1.5 times the noise of one row.
TEST(CalibrationOnOtherParts, WalkRefinementHalvesTheChainsSystematicResidual) {
  const HeldOutFigures hinge = held_out_figures(fit_grid(true, false).pipeline, grid_data().test);
  const calib::ModelFitResult fit = fit_grid(true, true);
  const HeldOutFigures refined = held_out_figures(fit.pipeline, grid_data().test);
  std::printf("hinge: %s\nrefined: %s\n%s", hinge.summary().c_str(), refined.summary().c_str(),
              fit.report.c_str());
  ASSERT_TRUE(fit.summary.walk.has_value());
  EXPECT_GT(fit.summary.walk->nodes, 0);
  EXPECT_LT(fit.summary.walk->cv_rms_m, fit.summary.walk->cv_rms_without_m);
  EXPECT_LT(refined.systematic_m, 0.5 * hinge.systematic_m);
  EXPECT_LE(refined.systematic_m, 1.5 * refined.noise_m);
}

// The amplitude reading clips (receiver.amplitude_clip_v) while the walk keeps
// changing, so a B-spline over (range, amplitude) leaves millimetres; grouped
// cross-validation must pick the pulse-width axis, which brings the held-out
// systematic residual within 1.5 times the noise of one row. The surface reads
// the same column after a round trip through the model file.
TEST(CalibrationOnOtherParts, BSplineChoosesThePulseWidthAxisWhereTheAmplitudeClips) {
  const calib::ModelFitResult by_amplitude =
      fit_grid(false, false, calib::SurfaceIntensity::amplitude);
  const calib::ModelFitResult chosen = fit_grid(false);
  const HeldOutFigures a = held_out_figures(by_amplitude.pipeline, grid_data().test);
  const HeldOutFigures c = held_out_figures(chosen.pipeline, grid_data().test);
  std::printf("amplitude axis: %s\nchosen axis: %s\n%s", a.summary().c_str(), c.summary().c_str(),
              chosen.report.c_str());
  EXPECT_EQ(chosen.summary.surface_intensity, "pulse_width_ns");
  EXPECT_GT(chosen.summary.surface_cv_rms_other_m, chosen.summary.surface->cv_rms_m);
  EXPECT_GT(a.systematic_m, 5 * a.noise_m);
  EXPECT_LE(c.systematic_m, 1.5 * c.noise_m);
  const ranging::Pipeline loaded =
      io::pipeline_from_json(io::pipeline_to_json(chosen.pipeline), "model.json");
  for (const auto& r : grid_data().test) {
    const ranging::Range x = chosen.pipeline.apply(r.raw), y = loaded.apply(r.raw);
    if (std::isnan(x.distance_m)) {
      EXPECT_TRUE(std::isnan(y.distance_m));
      continue;
    }
    EXPECT_NEAR(x.distance_m, y.distance_m, 1e-12);
  }
}

// DISABLED (issue 8 open): the paper protocol's sigma on its test rows
// (0.7-7.4 m x 0.06-0.85 x 8-37 C, flagged rows included). Measured: fit_chain
// (sigma = residual RMS 0.51 mm, grown outside the steps' domains by
// Pipeline::kOutOfDomainSigmaGrowth) covers 44.1 % within 2 sigma (terciles
// 23.4 / 60.5 / 48.4 %; in-domain rows alone 54.1 %, 35 / 58 / 69 %);
// fit_model's calibrated confidence 68.5 % (36.3 / 79.0 / 90.3 %);
// noise-systematic 58.3 % (53.2 / 74.2 / 47.6 %; 48.9 %, 30.6 / 67.7 / 48.4 %
// with one optimism (G + p) / (G - p) for all targets). The in-domain error is
// 0.7-0.9 mm RMS at every test distance, 3.38 m included, against 0.25 mm on
// the calibration plates: not an error of range but of the chain's additive
// form, a walk and a temperature hinge fitted on two one-dimensional sweeps
// (reflectance at 20 C, temperature at rho 0.3), which cannot see how the
// walk changes with temperature (the APD bias tracking error changes the gain
// with temperature). The cross-fitted residuals (0.81 mm RMS) do see it, but
// the calibrated model's amplitude axis cannot place it (low tercile 36 %). A
// periodic TDC step does not help here (at one distance the walk and the
// clock phase are confounded: a spurious 0.66 mm harmonic, in-domain errors
// 0.9-1.3 mm). Flagged rows (28 mm RMS: the hinges continued linearly far
// outside the pulse widths the plates covered) need a growth of sigma with
// the distance outside that these rows cannot estimate.
TEST(CalibrationOnOtherParts, DISABLED_PaperProtocolSigmaCoversItsTestRows) {
  const calib::ChainFitResult chain = calib::fit_chain(paper_data().calibration);
  calib::ModelFitOptions options;
  options.chain = calib::ChainSteps{true, true, true};
  const calib::ModelFitResult calibrated = calib::fit_model(paper_data().calibration, options);
  options.confidence = calib::ConfidenceKind::noise_systematic;
  const calib::ModelFitResult repeats = calib::fit_model(paper_data().calibration, options);
  const HeldOutFigures f = held_out_figures(chain.pipeline, paper_data().test);
  std::printf("fit_chain: %s\nfit_model, calibrated: %s\nfit_model, noise-systematic: %s\n",
              f.summary().c_str(),
              held_out_figures(calibrated.pipeline, paper_data().test).summary().c_str(),
              held_out_figures(repeats.pipeline, paper_data().test).summary().c_str());
  EXPECT_GE(f.within_2sigma, 0.93) << f.summary();
  EXPECT_LE(f.within_2sigma, 0.97) << f.summary();
  for (double share : f.within_2sigma_by_tercile) {
    EXPECT_GE(share, 0.93) << f.summary();
    EXPECT_LE(share, 0.97) << f.summary();
  }
}

}  // namespace
}  // namespace tofkit
