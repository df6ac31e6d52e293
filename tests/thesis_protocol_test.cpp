// The thesis end to end on the accurange preset (reference/characterization_thesis.md,
// Sections 4.6-4.8): correction surfaces fitted at 15/17/20/22 in and judged on
// a held-out scan at 19 in (Fig. 4.18), and the confidence of corrected ranges
// fitted on a separate scan. Oracles: the thesis's own Fig. 4.18
// (reference/fig4_18_point_fit.csv), statistics recomputed from the returned
// rows, and the scans' independence.
#include "tofkit/experiments/thesis_protocol.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <fstream>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include "tofkit/device/accurange_preset.hpp"
#include "tofkit/physics/constants.hpp"

using namespace tofkit;
using namespace tofkit::experiments;

namespace {

bool sanitized() {
  return std::getenv("TOFKIT_SANITIZED") != nullptr;
}

/// Range per degree of a delay tempco (ps/C): the round trip's c / 2.
double range_m_per_c(double delay_tempco_ps_per_c) {
  return delay_tempco_ps_per_c * 1e-12 * physics::kSpeedOfLightVacuum_m_per_s / 2.0;
}

/// The temperature row's coverage: 93-97 % within 2 sigma, >= 93 % per
/// tercile (a sanitized build's fifth of the points: near 95 % only).
void expect_covers_the_warmer_session(const ThesisCoverageRow& row) {
  if (sanitized()) {
    EXPECT_NEAR(row.within_2_sigma.share, 0.95, 0.04);
    return;
  }
  EXPECT_GE(row.within_2_sigma.share, 0.93);
  EXPECT_LE(row.within_2_sigma.share, 0.97);
  for (int t = 0; t < 3; ++t) EXPECT_GE(row.within_2_sigma.tercile_share[t], 0.93) << t;
}

const device::VirtualRangefinder& accurange() {
  static const device::VirtualRangefinder dev(device::accurange_preset());
  return dev;
}

ThesisProtocolOptions test_options() {
  ThesisProtocolOptions o;
  if (sanitized()) {  // a fifth of the points: improvements still hold, coverage is coarse
    o.training_points_per_grey = 60;
    o.confidence_points_per_grey = 60;
    o.test_points_per_grey = 120;
  }
  return o;
}

/// One run shared by the tests (the protocol takes about 2 s).
const ThesisProtocolResult& result() {
  static const ThesisProtocolResult r = run_thesis_protocol(accurange(), test_options(), 2024);
  return r;
}

/// The thesis's Fig. 4.18 rows: order (0 = raw), bias, variance, rms [in], rms improvement.
std::vector<std::vector<double>> fig4_18() {
  std::ifstream in(std::string(TOFKIT_REFERENCE_DIR) + "/fig4_18_point_fit.csv");
  std::string line;
  std::getline(in, line);
  std::vector<std::vector<double>> rows;
  while (std::getline(in, line)) {
    std::stringstream ss(line);
    std::string cell;
    std::vector<double> row;
    while (std::getline(ss, cell, ',')) {
      row.push_back(cell == "raw" ? 0.0 : (cell.empty() ? NAN : std::stod(cell)));
    }
    rows.push_back(row);
  }
  return rows;
}

double rms(const std::vector<double>& v) {
  double s = 0;
  for (const double x : v) s += x * x;
  return std::sqrt(s / double(v.size()));
}

/// The temperature term's row recomputed from the test rows: each measured range
/// moved by the slope times its sensor's departure from `reference_c`, then the
/// B-spline evaluated there; error = true - corrected.
std::vector<double> temperature_residuals(const ThesisProtocolResult& r, double reference_c) {
  std::vector<double> range, amplitude, truth;
  std::size_t k = 0;
  for (const auto& rec : r.test) {
    if (!rec.raw.has_echo() || !std::isfinite(rec.raw.amplitude)) continue;
    const auto& row = r.test_rows[k++];
    range.push_back(row.measured_m +
                    r.temperature_term.slope_m_per_c * (rec.raw.temperature_c - reference_c));
    amplitude.push_back(row.amplitude);
    truth.push_back(row.truth_m);
  }
  std::vector<double> correction(range.size()), residual(range.size());
  std::vector<std::uint8_t> outside(range.size());
  r.bspline->evaluate({range, amplitude, {}}, correction, outside);
  for (std::size_t i = 0; i < range.size(); ++i) residual[i] = truth[i] - range[i] - correction[i];
  return residual;
}

}  // namespace

TEST(ThesisProtocol, ScansAreTheThesisDesignAndIndependent) {
  const auto& r = result();
  const auto& o = r.options;
  EXPECT_EQ(r.training.size(), o.training_distances_m.size() * 6 * o.training_points_per_grey);
  EXPECT_EQ(r.test.size(), 6u * o.test_points_per_grey);
  auto distances = [](const std::vector<ranging::Record>& recs) {
    std::set<long> in;
    for (const auto& x : recs) in.insert(std::lround(m_to_inches(x.truth.distance_m) * 10));
    return in;
  };
  EXPECT_EQ(distances(r.training), (std::set<long>{150, 170, 200, 220}));
  EXPECT_EQ(distances(r.test), (std::set<long>{190}));
  EXPECT_EQ(distances(r.confidence), (std::set<long>{160, 180, 210}));
  EXPECT_EQ(r.test_rows_without_echo, 0u);
  EXPECT_EQ(r.test_rows.size(), r.test.size());
  EXPECT_EQ(r.all_records().size(), r.training.size() + r.confidence.size() + r.test.size());
  // Reproducible from the seed; another seed gives other scans.
  const auto again = run_thesis_protocol(accurange(), test_options(), 2024);
  EXPECT_EQ(again.test.front().raw.tof_ns, r.test.front().raw.tof_ns);
  EXPECT_EQ(again.row("bspline").test.rms_m, r.row("bspline").test.rms_m);
  auto other_options = test_options();
  other_options.training_points_per_grey = 20;
  other_options.confidence_points_per_grey = 20;
  other_options.test_points_per_grey = 20;
  const auto other = run_thesis_protocol(accurange(), other_options, 2025);
  EXPECT_NE(other.test.front().raw.tof_ns, r.test.front().raw.tof_ns);
}

TEST(ThesisProtocol, RawErrorIsOfTheThesisOrder) {
  const auto& r = result();
  const auto fig = fig4_18();
  ASSERT_FALSE(fig.empty());
  const double thesis_raw_rms_in = fig[0][3];
  // Issue 12: raw RMS within +-25 % of the thesis's 1.2409 in at 19 in, and the
  // bias positive (the unit reads short) as in the thesis's table.
  const double raw_in = m_to_inches(r.row("raw").test.rms_m);
  EXPECT_GT(raw_in, 0.75 * thesis_raw_rms_in);
  EXPECT_LT(raw_in, 1.25 * thesis_raw_rms_in);
  EXPECT_GT(r.row("raw").test.bias_m, 0.0);
  EXPECT_NEAR(m_to_inches(r.row("raw").test.bias_m), fig[0][1], 0.25 * fig[0][1]);
  // The walk (thesis Section 4.4): dark greys read long, saturating bright ones
  // short: the mean error true - measured falls with the grey level (0 = white).
  std::vector<double> mean_error;
  for (const auto& g : r.per_grey) {
    double sum = 0;
    int n = 0;
    for (const auto& t : r.test_rows) {
      if (t.grey != g.grey) continue;
      sum += t.raw_error_m;
      ++n;
    }
    ASSERT_GT(n, 0);
    mean_error.push_back(sum / n);
    // The per-grey row's mean is the test rows' (an independent sum), and its
    // point-to-point spread makes up the rest of the grey's RMS.
    EXPECT_NEAR(g.raw_mean_m, sum / n, 1e-9) << g.grey;
    EXPECT_NEAR(std::hypot(g.raw_mean_m, g.raw_sd_m), g.raw_rms_m, 1e-9) << g.grey;
  }
  for (std::size_t k = 1; k < mean_error.size(); ++k) EXPECT_LT(mean_error[k], mean_error[k - 1]);
  EXPECT_GT(mean_error.front() - mean_error.back(), inches_to_m(0.5));
}

TEST(ThesisProtocol, HeldOutStatisticsAreConsistent) {
  const auto& r = result();
  // raw, the polynomials, the B-spline and the B-spline with the sensor's temperature term.
  ASSERT_EQ(r.rows.size(), 3 + r.options.polynomial_orders.size());
  std::vector<double> raw, spline, poly;
  for (const auto& t : r.test_rows) {
    raw.push_back(t.raw_error_m);
    spline.push_back(t.bspline_error_m);
    poly.push_back(t.best_polynomial_error_m);
    EXPECT_NEAR(t.raw_error_m, t.truth_m - t.measured_m, 1e-12);
  }
  EXPECT_NEAR(rms(raw), r.row("raw").test.rms_m, 1e-9);
  EXPECT_NEAR(rms(spline), r.row("bspline").test.rms_m, 1e-9);
  EXPECT_NEAR(rms(poly), r.row("poly" + std::to_string(r.best_polynomial_order)).test.rms_m, 1e-9);
  for (const auto& row : r.rows) {
    // Eq. 4.3: RMS^2 = bias^2 + variance.
    EXPECT_NEAR(row.test.rms_m * row.test.rms_m,
                row.test.bias_m * row.test.bias_m + row.test.variance_m2, 1e-12);
    if (row.model == "raw") continue;
    EXPECT_NEAR(row.rms_improvement_pct, 100 * (1 - row.test.rms_m / r.row("raw").test.rms_m),
                1e-9);
  }
}

TEST(ThesisProtocol, CorrectionSurfacesMeetTheAcceptance) {
  const auto& r = result();
  const auto fig = fig4_18();
  double thesis_best = 0;
  for (const auto& row : fig) {
    if (row[0] > 0) thesis_best = std::max(thesis_best, row[5]);
  }
  EXPECT_NEAR(thesis_best, 70.83, 1e-9);
  double best_poly = -1e9;
  for (const int order : r.options.polynomial_orders) {
    const auto& row = r.row("poly" + std::to_string(order));
    best_poly = std::max(best_poly, row.rms_improvement_pct);
    EXPECT_GT(row.rank, 0u);
    EXPECT_LE(row.rank, row.parameters);
  }
  // Best polynomial's held-out RMS improvement as the thesis's: 'at least 55 %'
  // (Section 4.6), best 70.8 % with order 4; issue 30's acceptance reads 50-80 %.
  // (It had to reach the thesis's 70.8 % on a twin whose raw error was almost all
  // a smooth function of range and intensity: 95 %.)
  EXPECT_GE(best_poly, 55.0);
  EXPECT_LE(best_poly, 80.0);
  EXPECT_NEAR(best_poly, thesis_best, 10.0);
  EXPECT_DOUBLE_EQ(best_poly,
                   r.row("poly" + std::to_string(r.best_polynomial_order)).rms_improvement_pct);
  // The B-spline (the thesis's future work) meets the thesis's conclusion, 'at
  // least 55 %', and stays within 10 % of the best polynomial's RMS. (It no longer
  // beats every order by far: at 19 in, inside the training domain, both are
  // limited by what no (range, intensity) surface removes, the per-point duty
  // wander and the test session's temperature, thesis Fig. 4.18's 0.26 in bias
  // and 0.06 in^2 variance; the 90 % it reached had measured a too-clean twin.)
  EXPECT_GE(r.row("bspline").rms_improvement_pct, 55.0);
  EXPECT_LT(r.row("bspline").test.rms_m,
            1.1 * r.row("poly" + std::to_string(r.best_polynomial_order)).test.rms_m);
  // Every grey level improves with the B-spline (Fig. 4.19).
  for (const auto& g : r.per_grey) EXPECT_LT(g.bspline_rms_m, 0.5 * g.raw_rms_m) << g.grey;
  // Section 4.8: the relative error of corrected ranges is roughly constant in
  // range: the thesis's four values (0.0117 ... 0.0046) span a factor 2.5.
  const auto& rel = r.relative_error_by_training_distance;
  ASSERT_EQ(rel.size(), 4u);
  EXPECT_LT(*std::max_element(rel.begin(), rel.end()),
            2.6 * *std::min_element(rel.begin(), rel.end()));
}

TEST(ThesisProtocol, CalibratedConfidenceCoversHeldOutData) {
  // Coverage is a claim about held-out data of the session the confidence was
  // fitted in: the test scan taken at the training's temperature (the default
  // protocol's warmer test session adds a bias no confidence fit can know).
  static const ThesisProtocolResult r = [] {
    auto o = test_options();
    o.test_ambient_offset_c = 0.0;
    o.test_temperature_offsets_c = {};
    return run_thesis_protocol(accurange(), o, 2024);
  }();
  const auto& cal = r.coverage_of("calibrated");
  const auto& thesis = r.coverage_of("thesis");
  ASSERT_EQ(cal.within_2_sigma.rows, r.test_rows.size());
  if (sanitized()) {  // 240 rows per tercile: only a coarse check
    EXPECT_NEAR(cal.within_2_sigma.share, 0.95, 0.04);
    return;
  }
  // Target: 93-97 % within 2 sigma overall and in each intensity tercile.
  EXPECT_GE(cal.within_2_sigma.share, 0.93);
  EXPECT_LE(cal.within_2_sigma.share, 0.97);
  for (int t = 0; t < 3; ++t) {
    EXPECT_GE(cal.within_2_sigma.tercile_share[t], 0.93) << t;
    EXPECT_LE(cal.within_2_sigma.tercile_share[t], 0.97) << t;
  }
  // Within 1 sigma: not below the Gaussian 68 %. The sigma is calibrated at
  // 2 sigma, and the per-point error is heavy-tailed (the duty wander passes
  // through the edges' logarithmic response: kurtosis 4-10 per grey), so more
  // than 68 % falls within 1 sigma (0.71-0.80 over seeds), never less.
  EXPECT_GE(cal.within_1_sigma.share, 0.683 - 0.05);
  EXPECT_LE(cal.within_1_sigma.share, 0.85);
  // Recomputed from the rows: the coverage is what the sigmas say.
  std::size_t inside = 0;
  for (const auto& t : r.test_rows)
    inside += std::abs(t.bspline_error_m) <= 2 * t.sigma_calibrated_m;
  EXPECT_NEAR(cal.within_2_sigma.share, double(inside) / r.test_rows.size(), 1e-12);
  // The thesis's metric is reported on the same rows.
  EXPECT_EQ(thesis.within_2_sigma.rows, cal.within_2_sigma.rows);
  EXPECT_GT(thesis.mean_sigma_m, 0.0);
}

TEST(ThesisProtocol, TheSensorsTemperatureTermCoversTheWarmerSession) {
  // The default test scan is a session 8 C warmer than the training (thesis
  // Section 4.4); the calibrated sigma saw one session only. The term's slope is
  // measured on the device in a temperature run of its own (source run).
  const auto& r = result();
  const auto& o = r.options;
  const auto& term = r.temperature_term;
  ASSERT_EQ(term.source, TemperatureTermSource::run);
  ASSERT_EQ(term.lines.size(),
            o.temperature_term.run_grey_levels.size() * o.training_distances_m.size());
  // Oracle 1: the run's slope is the device's delay tempco, c/2 x tempco of
  // range per degree of the timing board, which the sensor follows one to one
  // once warmed up (no heater on this unit): range falls, true - measured rises.
  // Every line within 3 of its standard errors, the mean within 3 of its
  // uncertainty (plus the sensor's 1/16 C steps' share, 1 %).
  const double tempco_m_per_c = -range_m_per_c(accurange().config().thermal.delay_tempco_ps_per_c);
  for (const auto& line : term.lines) {
    EXPECT_NEAR(line.slope_m_per_c, tempco_m_per_c,
                3 * line.slope_se_m_per_c + 0.01 * tempco_m_per_c)
        << line.grey << " " << line.distance_m;
  }
  EXPECT_NEAR(term.slope_m_per_c, tempco_m_per_c, 3 * term.u_slope_m_per_c + 0.01 * tempco_m_per_c);
  EXPECT_GT(term.u_slope_m_per_c, 0.0);
  EXPECT_NEAR(term.u_slope_m_per_c, std::hypot(term.slope_se_m_per_c, term.slope_spread_m_per_c),
              1e-15);
  // Oracle 2: the row is the B-spline's residual with each measured range moved
  // by the slope times the sensor's departure from the training scan's mean
  // reading before the surface is evaluated, recomputed here from the records.
  double sum = 0;
  std::size_t n = 0;
  for (const auto& rec : r.training) {
    if (rec.raw.has_echo() && std::isfinite(rec.raw.amplitude)) {
      sum += rec.raw.temperature_c;
      ++n;
    }
  }
  const double reference_c = sum / double(n);
  EXPECT_NEAR(term.reference_c, reference_c, 1e-9);
  const auto residual = temperature_residuals(r, reference_c);
  ASSERT_EQ(residual.size(), r.test_rows.size());
  EXPECT_NEAR(rms(residual), r.row("bspline_temp").test.rms_m, 1e-9);
  // Oracle 3: the same protocol with the test taken at the training's
  // temperature (same seed, so the same chart points and noise draws). The
  // sensor reads the session's 8 C, and what the term leaves is the measured
  // slope against the preset's own tempco over those 8 C, to the sensor's
  // 0.0625 C steps.
  auto same_session = test_options();
  same_session.test_ambient_offset_c = 0.0;
  same_session.test_temperature_offsets_c = {};
  const auto one = run_thesis_protocol(accurange(), same_session, 2024);
  const double left_m = (tempco_m_per_c - term.slope_m_per_c) * o.test_ambient_offset_c;
  const auto& spline = r.row("bspline").test;
  const auto& temp = r.row("bspline_temp").test;
  EXPECT_GT(std::abs(spline.bias_m), inches_to_m(0.2));  // the session's bias is there
  EXPECT_NEAR(temp.bias_m, one.row("bspline").test.bias_m + left_m, 0.5e-3);
  EXPECT_LT(std::abs(temp.bias_m), std::abs(spline.bias_m) / 5);
  // Coverage: the calibrated sigma alone misses the session; with the slope's
  // uncertainty over the same departure it covers 93-97 % within 2 sigma.
  const auto& cal = r.coverage_of("calibrated");
  const auto& cal_t = r.coverage_of("calibrated_temp");
  EXPECT_LT(cal.within_2_sigma.share, 0.85);
  expect_covers_the_warmer_session(cal_t);
  if (sanitized()) return;
  // Switched off, neither row appears.
  auto off = test_options();
  off.temperature_term.source = TemperatureTermSource::none;
  off.test_temperature_offsets_c = {};
  const auto plain = run_thesis_protocol(accurange(), off, 2024);
  EXPECT_EQ(plain.rows.size(), r.rows.size() - 1);
  EXPECT_THROW((void)plain.coverage_of("calibrated_temp"), std::out_of_range);
  EXPECT_EQ(plain.row("bspline").test.rms_m, spline.rms_m);
  ThesisProtocolOptions bad;
  bad.temperature_term.stated_drift_min_in_per_10c = 0.7;  // above the max
  EXPECT_THROW((void)run_thesis_protocol(accurange(), bad, 1), std::invalid_argument);
  bad = {};
  bad.temperature_term.run_ambient_c = {20, 30};  // a line needs three
  EXPECT_THROW((void)run_thesis_protocol(accurange(), bad, 1), std::invalid_argument);
}

TEST(ThesisProtocol, TheStatedDriftStillGivesTheThesisTerm) {
  // Source stated: the thesis's Section 4.4 range, 0.25-0.60 in per 10 C, as a
  // type B input: its centre as the slope, a rectangular distribution's
  // half-width / sqrt(3) as its standard uncertainty; no temperature run.
  auto o = test_options();
  o.temperature_term.source = TemperatureTermSource::stated;
  o.test_temperature_offsets_c = {};
  const auto r = run_thesis_protocol(accurange(), o, 2024);
  const auto& term = r.temperature_term;
  EXPECT_EQ(term.source, TemperatureTermSource::stated);
  EXPECT_TRUE(term.lines.empty());
  const double in_per_10c = 0.0254 / 10.0;  // m per C
  EXPECT_NEAR(term.slope_m_per_c, 0.425 * in_per_10c, 1e-15);
  EXPECT_NEAR(term.u_slope_m_per_c, 0.175 / std::sqrt(3.0) * in_per_10c, 1e-15);
  // The scans are the default protocol's (same seed): only the term differs.
  const auto& measured = result();
  EXPECT_EQ(r.row("bspline").test.rms_m, measured.row("bspline").test.rms_m);
  EXPECT_NEAR(term.reference_c, measured.temperature_term.reference_c, 1e-12);
  // The row: the ranges moved by the centre times the departure, then the B-spline.
  const auto residual = temperature_residuals(r, term.reference_c);
  EXPECT_NEAR(rms(residual), r.row("bspline_temp").test.rms_m, 1e-9);
  // The summary names the source used.
  EXPECT_NE(r.summary().find("source stated"), std::string::npos);
  EXPECT_NE(measured.summary().find("source run"), std::string::npos);
}

TEST(ThesisProtocol, TheRunsSlopeCoversADeviceOutsideTheStatedRange) {
  // A unit whose delay tempco is -15 ps/C (2.25 mm/C, 0.88 in per 10 C: above
  // the thesis's 0.25-0.60): the stated range under-corrects the warmer session,
  // the device's own temperature run does not. Oracle: c/2 x the configured
  // tempco, and the coverage target of the preset.
  auto config = device::accurange_preset();
  config.thermal.delay_tempco_ps_per_c = -15.0;
  const device::VirtualRangefinder steep(config);
  auto o = test_options();
  o.test_temperature_offsets_c = {};
  const auto r = run_thesis_protocol(steep, o, 2024);
  const double tempco_m_per_c = range_m_per_c(15.0);
  EXPECT_NEAR(r.temperature_term.slope_m_per_c, tempco_m_per_c,
              3 * r.temperature_term.u_slope_m_per_c + 0.01 * tempco_m_per_c);
  EXPECT_LT(std::abs(r.row("bspline_temp").test.bias_m),
            std::abs(r.row("bspline").test.bias_m) / 5);
  auto stated = o;
  stated.temperature_term.source = TemperatureTermSource::stated;
  const auto s = run_thesis_protocol(steep, stated, 2024);
  EXPECT_LT(s.coverage_of("calibrated_temp").within_2_sigma.share, 0.85);
  const auto& cal_t = r.coverage_of("calibrated_temp");
  expect_covers_the_warmer_session(cal_t);
}

TEST(ThesisProtocol, PlotDataAndSummary) {
  const auto& r = result();
  const auto& g = r.surface_grid;
  ASSERT_EQ(g.bspline_m.size(), g.range_m.size() * g.amplitude.size());
  ASSERT_EQ(g.best_polynomial_m.size(), g.bspline_m.size());
  // The B-spline surface follows the walk: at each grey's mean test point
  // (measured range, intensity) its correction true - measured differs between
  // white and black as the two greys' raw mean errors do (the test session's
  // common offset cancels), by more than 20 mm. (A point of the grid far from
  // any grey's data is extrapolation and proves nothing.)
  std::vector<double> at_range, at_amplitude, raw_mean;
  for (const int grey : {0, 255}) {
    double range = 0, amplitude = 0, raw = 0;
    int n = 0;
    for (const auto& t : r.test_rows) {
      if (t.grey != grey) continue;
      range += t.measured_m;
      amplitude += t.amplitude;
      raw += t.raw_error_m;
      ++n;
    }
    ASSERT_GT(n, 0) << grey;
    at_range.push_back(range / n);
    at_amplitude.push_back(amplitude / n);
    raw_mean.push_back(raw / n);
  }
  std::vector<double> surface(2);
  std::vector<std::uint8_t> outside(2);
  r.bspline->evaluate({at_range, at_amplitude, {}}, surface, outside);
  const double raw_step = raw_mean[0] - raw_mean[1], surface_step = surface[0] - surface[1];
  EXPECT_GT(std::abs(raw_step), 20e-3);
  EXPECT_NEAR(surface_step, raw_step, 0.25 * std::abs(raw_step));
  const auto tables = r.tables();
  ASSERT_EQ(tables.size(), 5u);
  EXPECT_EQ(tables[0].name, "models");
  EXPECT_EQ(tables[0].rows.size(), r.rows.size());
  for (const auto& t : tables) {
    for (const auto& row : t.rows) ASSERT_EQ(row.size(), t.columns.size()) << t.name;
  }
  const auto s = r.summary();
  EXPECT_NE(s.find("poly4"), std::string::npos);
  EXPECT_NE(s.find("bspline"), std::string::npos);
  EXPECT_NE(s.find("calibrated"), std::string::npos);
  ThesisProtocolOptions bad;
  bad.polynomial_orders = {};
  EXPECT_THROW((void)run_thesis_protocol(accurange(), bad, 1), std::invalid_argument);
  bad = {};
  bad.samples_per_point = 0;
  EXPECT_THROW((void)run_thesis_protocol(accurange(), bad, 1), std::invalid_argument);
}

TEST(ThesisProtocol, WarmerTestScansExplainTheThesisResidual) {
  // Thesis Section 4.4: temperature not constant between scans; the range falls
  // 0.25-0.60 in per 10 C. Oracle: the preset's delay tempco moves every range
  // (raw and corrected alike) by c/2 x tempco per degree; the surfaces do not see it.
  const auto& r = result();
  ASSERT_EQ(r.temperature.size(), r.options.test_temperature_offsets_c.size());
  const double mm_per_c = range_m_per_c(accurange().config().thermal.delay_tempco_ps_per_c) * 1e3;
  // The repeats are warmer than the training by offset_c; the test scan itself by
  // test_ambient_offset_c (a separate session). Each shift is measured against
  // the test scan, within 10 % plus 3 standard errors of the two scans' means
  // (every point carries its own duty-wander draw).
  const auto& test = r.row("raw").test;
  for (const auto& t : r.temperature) {
    const double dt = t.offset_c - r.options.test_ambient_offset_c;
    const double expected_shift_m = -mm_per_c * 1e-3 * dt;  // true - measured rises
    const double se =
        std::sqrt(t.raw.variance_m2 / double(t.raw.rows) + test.variance_m2 / double(test.rows));
    const double raw_shift = t.raw.bias_m - test.bias_m;
    const double spline_shift = t.bspline.bias_m - r.row("bspline").test.bias_m;
    const double tol = 0.1 * std::abs(expected_shift_m) + 3 * se;
    EXPECT_NEAR(raw_shift, expected_shift_m, tol) << t.offset_c;
    EXPECT_NEAR(spline_shift, expected_shift_m, tol) << t.offset_c;
    if (std::abs(dt) < 3.0) continue;  // too small a step for the thesis's rate
    const double in_per_10c = m_to_inches(raw_shift) * 10.0 / dt;
    EXPECT_GT(in_per_10c, 0.25);
    EXPECT_LT(in_per_10c, 0.60);
  }
}

TEST(ThesisProtocol, ChartPointsSitInTheLasersTurnOnTransient) {
  // Thesis: point by point, 'laser on -> N samples -> averaged -> move'. Every
  // chart point switches the laser on, so its samples carry the turn-on transient's
  // mean over the point's window W = samples x shots / repetition rate (the loop:
  // b tau / W (1 - exp(-W / tau))). Oracle: that closed form against the raw bias
  // of the same protocol (same seed: same points, draws and counts) with the
  // transient switched off. Error = true - measured, so a short reading raises it.
  ThesisProtocolOptions o;
  o.training_points_per_grey = 40;
  o.confidence_points_per_grey = 40;
  o.test_points_per_grey = 40;
  o.test_temperature_offsets_c = {};
  auto off = device::accurange_preset();
  off.link.laser.turn_on_bias_mm = 0.0;
  const auto with = run_thesis_protocol(accurange(), o, 7);
  const auto without = run_thesis_protocol(device::VirtualRangefinder(off), o, 7);
  const auto& laser = accurange().config().link.laser;
  const double shots = o.samples_per_point * accurange().config().measurement.shots;
  const double w_ms = 1e3 * shots / laser.repetition_hz;
  const double tau = laser.turn_on_time_constant_ms;
  const double expected_m = -1e-3 * laser.turn_on_bias_mm * tau / w_ms * -std::expm1(-w_ms / tau);
  EXPECT_NEAR(with.row("raw").test.bias_m - without.row("raw").test.bias_m, expected_m,
              0.02 * std::abs(expected_m));
  // The transient is common to every point, so the corrections fitted on the
  // training scan (taken the same way) remove it: corrected biases hardly move.
  EXPECT_NEAR(with.row("poly4").test.bias_m, without.row("poly4").test.bias_m,
              0.1 * std::abs(expected_m));
}
