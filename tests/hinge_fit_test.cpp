#include "tofkit/calib/hinge_fit.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <stdexcept>
#include <string>
#include <vector>

namespace tofkit::calib {
namespace {

/// The paper's gray-value shape: slope -36 mm/ns below the 6.5 ns inflection, +70 mm/ns above.
double paper_grayvalue_m(double pulse_width_ns) {
  return 0.010 - 0.036 * (pulse_width_ns - 6.5) + 0.106 * std::max(0.0, pulse_width_ns - 6.5);
}

struct Sample {
  std::vector<double> x, y;
};

Sample make_sample(std::size_t n, double x_lo, double x_hi, double noise_m, unsigned seed,
                   double (*f)(double)) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> ux(x_lo, x_hi);
  std::normal_distribution<double> noise(0.0, noise_m);
  Sample s;
  for (std::size_t i = 0; i < n; ++i) {
    const double x = ux(rng);
    s.x.push_back(x);
    s.y.push_back(f(x) + (noise_m > 0 ? noise(rng) : 0.0));
  }
  return s;
}

/// RSS of a fixed-knot ordinary least-squares fit, computed independently by SVD.
double svd_rss(const Sample& s, const std::vector<double>& knots) {
  const auto n = static_cast<Eigen::Index>(s.x.size());
  Eigen::MatrixXd a(n, static_cast<Eigen::Index>(2 + knots.size()));
  Eigen::VectorXd y(n);
  for (Eigen::Index i = 0; i < n; ++i) {
    const double x = s.x[static_cast<std::size_t>(i)];
    a(i, 0) = 1;
    a(i, 1) = x;
    for (std::size_t j = 0; j < knots.size(); ++j) {
      a(i, static_cast<Eigen::Index>(2 + j)) = std::max(0.0, x - knots[j]);
    }
    y(i) = s.y[static_cast<std::size_t>(i)];
  }
  const Eigen::VectorXd beta = a.jacobiSvd(Eigen::ComputeThinU | Eigen::ComputeThinV).solve(y);
  return (y - a * beta).squaredNorm();
}

TEST(HingeFit, RecoversPaperInflectionWithoutNoise) {
  const Sample s = make_sample(400, 3.0, 12.0, 0.0, 1, paper_grayvalue_m);
  const HingeFitResult r = fit_hinge(s.x, s.y);
  ASSERT_EQ(r.knots.size(), 1u) << r.summary();
  EXPECT_NEAR(r.knots[0], 6.5, 1e-3);
  const auto slopes = r.function.segment_slopes();
  EXPECT_NEAR(slopes[0], -0.036, 1e-5);
  EXPECT_NEAR(slopes[1], 0.070, 1e-5);
  for (double x : {3.0, 5.0, 6.5, 9.0, 12.0})
    EXPECT_NEAR(r.function(x), paper_grayvalue_m(x), 1e-6);
  EXPECT_DOUBLE_EQ(r.x_min, *std::min_element(s.x.begin(), s.x.end()));
  EXPECT_DOUBLE_EQ(r.x_max, *std::max_element(s.x.begin(), s.x.end()));
  EXPECT_EQ(r.rows, 400u);
}

TEST(HingeFit, RecoversTemperatureKneeWithNoise) {
  // Paper Section 5.2: flat below 16 C, 3.8 mm/C above; correction = -drift.
  const auto drift = [](double t) { return -0.0038 * std::max(0.0, t - 16.0); };
  const Sample s = make_sample(1500, 0.0, 40.0, 0.002, 2, +drift);
  HingeFitOptions options;
  options.column = "temperature_c";
  const HingeFitResult r = fit_hinge(s.x, s.y, options);
  ASSERT_EQ(r.knots.size(), 1u) << r.summary();
  EXPECT_NEAR(r.knots[0], 16.0, 0.5);
  EXPECT_NEAR(r.function.segment_slopes()[1], -0.0038, 2e-4);
  EXPECT_NEAR(r.residual_rms, 0.002, 2e-4);
}

TEST(HingeFit, ChoosesTwoKnotsByBic) {
  const auto f = [](double x) {
    return 0.01 * x - 0.03 * std::max(0.0, x - 3.0) + 0.05 * std::max(0.0, x - 7.0);
  };
  const Sample s = make_sample(2000, 0.0, 10.0, 0.001, 3, +f);
  const HingeFitResult r = fit_hinge(s.x, s.y);
  ASSERT_EQ(r.knots.size(), 2u) << r.summary();
  EXPECT_NEAR(r.knots[0], 3.0, 0.1);
  EXPECT_NEAR(r.knots[1], 7.0, 0.1);
  ASSERT_EQ(r.bic.size(), 4u);
  EXPECT_LT(r.bic[2], r.bic[1]);
  EXPECT_LT(r.bic[2], r.bic[0]);
}

TEST(HingeFit, ChoosesNoKnotForAStraightLine) {
  const Sample s = make_sample(800, -5.0, 5.0, 0.001, 4, [](double x) { return 0.2 + 0.01 * x; });
  const HingeFitResult r = fit_hinge(s.x, s.y);
  EXPECT_TRUE(r.knots.empty()) << r.summary();
  EXPECT_NEAR(r.function.slope0, 0.01, 2e-4);
}

TEST(HingeFit, KnotMinimisesTheProfileSumOfSquares) {
  // Oracle: a brute-force scan of knot positions with an independent SVD solve.
  const Sample s = make_sample(300, 3.0, 12.0, 0.004, 5, paper_grayvalue_m);
  HingeFitOptions options;
  options.robust.loss = RobustLoss::kNone;
  options.max_knots = 1;
  const HingeFitResult r = fit_hinge(s.x, s.y, options);
  ASSERT_EQ(r.knots.size(), 1u);
  const double found = svd_rss(s, r.knots);
  for (double knot = 4.0; knot <= 11.0; knot += 0.01) {
    EXPECT_LE(found, svd_rss(s, {knot}) * (1 + 1e-9)) << "knot " << knot;
  }
  EXPECT_NEAR(r.residual_rms, std::sqrt(found / 300.0), 1e-12);
}

TEST(HingeFit, FixedKnotsMatchIndependentLeastSquares) {
  const Sample s = make_sample(200, 3.0, 12.0, 0.004, 6, paper_grayvalue_m);
  HingeFitOptions options;
  options.robust.loss = RobustLoss::kNone;
  const std::vector<double> knots{6.0, 9.0};
  const HingeFitResult r = fit_hinge_fixed_knots(s.x, s.y, knots, options);
  EXPECT_NEAR(r.residual_rms, std::sqrt(svd_rss(s, knots) / 200.0), 1e-12);
}

TEST(HingeFit, RobustToThreePercentGrossOutliers) {
  Sample s = make_sample(1000, 3.0, 12.0, 0.002, 7, paper_grayvalue_m);
  std::mt19937_64 rng(8);
  std::uniform_real_distribution<double> big(0.05, 0.3);
  for (std::size_t i = 0; i < s.y.size(); i += 33) s.y[i] += (i % 2 ? 1 : -1) * big(rng);  // ~3 %
  const HingeFitResult r = fit_hinge(s.x, s.y);
  ASSERT_EQ(r.knots.size(), 1u) << r.summary();
  EXPECT_NEAR(r.knots[0], 6.5, 0.1);
  EXPECT_NEAR(r.function.segment_slopes()[0], -0.036, 1e-3);
  EXPECT_NEAR(r.function.segment_slopes()[1], 0.070, 1e-3);
  EXPECT_GE(r.rows_downweighted, 25u);
  EXPECT_NEAR(r.robust_scale, 0.002, 4e-4);
}

TEST(HingeFit, ReferenceAbscissaDoesNotChangeTheFunction) {
  const Sample s = make_sample(300, 3.0, 12.0, 0.0, 9, paper_grayvalue_m);
  HingeFitOptions options;
  options.x0 = 5.0;
  const HingeFitResult r = fit_hinge(s.x, s.y, options);
  EXPECT_DOUBLE_EQ(r.function.x0, 5.0);
  EXPECT_NEAR(r.function(5.0), paper_grayvalue_m(5.0), 1e-6);
  const auto moved = r.function.with_x0(10.0);
  for (double x : {3.0, 6.5, 11.0}) EXPECT_NEAR(moved(x), r.function(x), 1e-12);
}

TEST(HingeFit, RejectsTooFewRowsAndNoSpreadNamingTheColumn) {
  HingeFitOptions options;
  options.column = "pulse_width_ns";
  options.unit = "ns";
  const std::vector<double> few{1, 2, 3}, few_y{1, 2, 3};
  try {
    (void)fit_hinge(few, few_y, options);
    FAIL();
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("too few rows"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("pulse_width_ns"), std::string::npos) << e.what();
  }
  const std::vector<double> flat(20, 5.2), y(20, 0.01);
  try {
    (void)fit_hinge(flat, y, options);
    FAIL();
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("no spread in pulse_width_ns (all 5.20 ns)"),
              std::string::npos)
        << e.what();
  }
  EXPECT_THROW((void)fit_hinge(std::vector<double>(10, 1.0), std::vector<double>(9, 1.0)),
               std::invalid_argument);
}

TEST(HingeFit, FindsTheKneeOfAShortSweepBesideAClusteredMajority) {
  // 900 rows at one temperature (the plates) and a 100-row sweep over 0-40 C:
  // row quantiles all fall in the cluster; the distinct-value grid reaches the knee.
  const auto drift = [](double t) { return -0.0038 * std::max(0.0, t - 16.0); };
  std::mt19937_64 rng(12);
  std::normal_distribution<double> noise(0.0, 0.001);
  Sample s;
  for (int i = 0; i < 900; ++i) {
    s.x.push_back(25.0);
    s.y.push_back(drift(25.0) + noise(rng));
  }
  for (int i = 0; i < 100; ++i) {
    s.x.push_back(0.4 * i);
    s.y.push_back(drift(0.4 * i) + noise(rng));
  }
  HingeFitOptions options;
  options.min_segment_fraction = 0.0;
  options.robust.loss = RobustLoss::kNone;
  const HingeFitResult r = fit_hinge(s.x, s.y, options);
  ASSERT_EQ(r.knots.size(), 1u) << r.summary();
  EXPECT_NEAR(r.knots[0], 16.0, 1.0);
}

TEST(HingeFit, SkipsNonFiniteRows) {
  Sample s = make_sample(100, 3.0, 12.0, 0.0, 10, paper_grayvalue_m);
  s.x[3] = std::nan("");
  s.y[7] = std::numeric_limits<double>::infinity();
  const HingeFitResult r = fit_hinge(s.x, s.y);
  EXPECT_EQ(r.rows, 98u);
  EXPECT_EQ(r.rows_skipped, 2u);
  ASSERT_EQ(r.knots.size(), 1u);
  EXPECT_NEAR(r.knots[0], 6.5, 1e-2);
}

}  // namespace
}  // namespace tofkit::calib

// ---- chain fit (calib/chain_fit.hpp) ----

#include "tofkit/calib/chain_fit.hpp"

namespace tofkit::calib {
namespace {

/// Known chain: e = true - c_air tof / 2 = 50 mm + g(pulse width) + h(temperature),
/// g the paper's gray-value shape (knot 6.5 ns), h = -3.8 mm/C above 16 C.
double true_error_m(double pulse_width_ns, double temperature_c) {
  return 0.050 + paper_grayvalue_m(pulse_width_ns) - 0.0038 * std::max(0.0, temperature_c - 16.0);
}

std::vector<ranging::Record> chain_records(std::size_t n, double noise_m, unsigned seed,
                                           bool correlated = false) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> pw(3.0, 12.0), temp(5.0, 35.0), dist(1.0, 8.0);
  std::normal_distribution<double> noise(0.0, noise_m);
  const double k = ranging::metres_per_ns(ranging::TimeToDistance{});
  std::vector<ranging::Record> out;
  for (std::size_t i = 0; i < n; ++i) {
    ranging::Record r;
    r.truth.distance_m = dist(rng);
    r.raw.temperature_c = temp(rng);
    r.raw.pulse_width_ns =
        correlated ? 3.0 + 0.25 * (r.raw.temperature_c - 5.0) + 0.5 * pw(rng) / 3 : pw(rng);
    const double e = true_error_m(r.raw.pulse_width_ns, r.raw.temperature_c) + noise(rng);
    r.raw.tof_ns = (r.truth.distance_m - e) / k;
    r.raw.distance_raw_m = r.truth.distance_m - e;
    r.raw.amplitude = 0.5;
    r.raw.shots_valid = 100;
    out.push_back(r);
  }
  return out;
}

TEST(ChainFit, RecoversKnotsAndCorrectsToTheNoiseLevel) {
  const auto records = chain_records(3000, 0.002, 11);
  const ChainFitResult r = fit_chain(records);
  ASSERT_TRUE(r.converged) << r.summary();
  ASSERT_TRUE(r.grayvalue && r.temperature);
  ASSERT_EQ(r.grayvalue->knots.size(), 1u) << r.summary();
  ASSERT_EQ(r.temperature->knots.size(), 1u) << r.summary();
  EXPECT_NEAR(r.grayvalue->knots[0], 6.5, 0.15);
  EXPECT_NEAR(r.temperature->knots[0], 16.0, 1.0);
  EXPECT_NEAR(r.after.rms_m, 0.002, 2e-4);
  EXPECT_GT(r.before.rms_m, 0.02);
  ASSERT_EQ(r.pipeline.steps().size(), 3u);
  // Hinges vanish at their reference points (the constant lives in the offset).
  const auto& steps = r.pipeline.steps();
  EXPECT_NEAR(steps[1].function(steps[1].function.x0), 0.0, 1e-12);
  EXPECT_NEAR(steps[2].function(steps[2].function.x0), 0.0, 1e-12);
  // The corrected distance of a noise-free measurement equals the truth.
  const double k = ranging::metres_per_ns(ranging::TimeToDistance{});
  for (double pw : {3.5, 6.5, 9.0, 11.5}) {
    for (double t : {6.0, 16.0, 30.0}) {
      ranging::RawMeasurement m;
      m.pulse_width_ns = pw;
      m.temperature_c = t;
      m.shots_valid = 1;
      m.tof_ns = (5.0 - true_error_m(pw, t)) / k;
      const ranging::Range range = r.pipeline.apply(m);
      EXPECT_NEAR(range.distance_m, 5.0, 1.5e-3) << pw << " ns, " << t << " C";
      EXPECT_EQ(range.correction_flags, 0u);
      EXPECT_NEAR(range.sigma_m, r.after.rms_m, 1e-15);
    }
  }
}

TEST(ChainFit, JointSolveHandlesCorrelatedInputs) {
  const auto records = chain_records(3000, 0.001, 12, /*correlated=*/true);
  const ChainFitResult r = fit_chain(records);
  EXPECT_NEAR(r.after.rms_m, 0.001, 1.5e-4) << r.summary();
  EXPECT_TRUE(r.converged) << r.summary();
  ASSERT_EQ(r.grayvalue->knots.size(), 1u) << r.summary();
  ASSERT_EQ(r.temperature->knots.size(), 1u) << r.summary();
  EXPECT_NEAR(r.grayvalue->knots[0], 6.5, 0.1);
  EXPECT_NEAR(r.temperature->knots[0], 16.0, 1.0);
}

TEST(ChainFit, StepSubsets) {
  const auto records = chain_records(1000, 0.001, 13);
  ChainFitOptions options;
  options.steps = parse_chain_steps("offset");
  const ChainFitResult offset_only = fit_chain(records, options);
  ASSERT_EQ(offset_only.pipeline.steps().size(), 1u);
  EXPECT_NEAR(offset_only.after.bias_m, 0.0, 0.01);

  options.steps = parse_chain_steps("temperature,grayvalue");
  const ChainFitResult no_offset = fit_chain(records, options);
  ASSERT_EQ(no_offset.pipeline.steps().size(), 2u);
  EXPECT_EQ(no_offset.pipeline.steps()[0].kind, ranging::StepKind::kGrayvalue);
  EXPECT_NEAR(no_offset.after.rms_m, 0.001, 2e-4) << no_offset.summary();
  EXPECT_EQ(to_string(options.steps), "grayvalue,temperature");
}

TEST(ChainFit, ParseChainStepsRejectsUnknownAndRepeated) {
  EXPECT_THROW((void)parse_chain_steps("offset,gravy"), std::invalid_argument);
  EXPECT_THROW((void)parse_chain_steps("offset,offset"), std::invalid_argument);
  EXPECT_THROW((void)parse_chain_steps(""), std::invalid_argument);
  const ChainSteps all = parse_chain_steps("offset, grayvalue ,temperature");
  EXPECT_TRUE(all.offset && all.grayvalue && all.temperature);
}

std::string fit_error(const std::vector<ranging::Record>& records, const std::string& steps) {
  ChainFitOptions options;
  options.steps = parse_chain_steps(steps);
  try {
    (void)fit_chain(records, options);
  } catch (const std::invalid_argument& e) {
    return e.what();
  }
  return "";
}

/// The step a fit refuses (ChainStepRefused) and its message; "" when it fits.
std::string refused_step(const std::vector<ranging::Record>& records, const std::string& steps,
                         std::string* message = nullptr) {
  ChainFitOptions options;
  options.steps = parse_chain_steps(steps);
  options.walk_replicates = 0;
  try {
    (void)fit_chain(records, options);
  } catch (const ChainStepRefused& e) {
    if (message) *message = e.what();
    return to_string(e.step()) + " " + e.column();
  }
  return "";
}

TEST(ChainFit, RefusesAStepWhoseColumnSpreadsWithinOneTarget) {
  // Every row one target and one ambient: whatever the pulse widths and
  // temperature readings do, the truth says they can only be noise.
  auto records = chain_records(60, 0.001, 18);
  for (auto& r : records) r.truth = {2.0, 0.3, 0.0, 20.0};
  std::string message;
  EXPECT_EQ(refused_step(records, "offset,grayvalue", &message), "grayvalue pulse_width_ns");
  EXPECT_NE(message.find("no spread in pulse_width_ns between targets (every usable row is one "
                         "target, distance_true_m 2 m, reflectance 0.3, angle_deg 0 deg: "),
            std::string::npos)
      << message;
  EXPECT_NE(message.find(" ns is noise): the grayvalue step needs plates"), std::string::npos)
      << message;
  EXPECT_EQ(refused_step(records, "offset,walk"), "walk pulse_width_ns");
  EXPECT_EQ(refused_step(records, "offset,temperature", &message), "temperature temperature_c");
  EXPECT_NE(message.find("no spread in temperature_c between conditions (every usable row is at "
                         "one ambient_c, 20 C: "),
            std::string::npos)
      << message;
  // A refusal is an invalid_argument (the CLI's exit 1 with the message).
  EXPECT_NE(fit_error(records, "temperature").find("temperature_c"), std::string::npos);

  // Half the rows on a second plate: the widths change between targets.
  auto two_plates = records;
  for (std::size_t i = 0; i < two_plates.size(); i += 2) two_plates[i].truth.reflectance = 0.6;
  EXPECT_EQ(refused_step(two_plates, "offset,grayvalue"), "");
  EXPECT_EQ(refused_step(two_plates, "offset,temperature"), "temperature temperature_c");
  // Half at a second ambient: the readings change between conditions.
  auto two_ambients = records;
  for (std::size_t i = 0; i < two_ambients.size(); i += 2) two_ambients[i].truth.ambient_c = 30;
  EXPECT_EQ(refused_step(two_ambients, "offset,temperature"), "");
  // Warming up at one ambient, the electronics' self-heating moves the reading.
  auto warming = records;
  for (auto& r : warming) r.raw.flags |= ranging::kRawWarmingUp;
  EXPECT_EQ(refused_step(warming, "offset,temperature"), "");
  // Rows without an echo do not count: a second plate seen only there does not help.
  auto unseen = records;
  for (std::size_t i = 0; i < 5; ++i) {
    unseen[i].truth.reflectance = 0.6;
    unseen[i].raw.shots_valid = 0;
  }
  EXPECT_EQ(refused_step(unseen, "offset,grayvalue"), "grayvalue pulse_width_ns");

  // Field data, truth columns empty: rows at one distance may be plates of
  // different reflectance, taken at different ambients; nothing says they are
  // one target, so nothing is refused (a legitimate calibration must fit).
  auto field = records;
  for (auto& r : field) r.truth = {2.0, ranging::kNaN, ranging::kNaN, ranging::kNaN};
  EXPECT_EQ(refused_step(field, "offset,grayvalue"), "");
  EXPECT_EQ(refused_step(field, "offset,walk"), "");
  EXPECT_EQ(refused_step(field, "offset,temperature"), "");
}

TEST(ChainFit, ClearErrorsForDegenerateData) {
  auto records = chain_records(9, 0.001, 14);
  EXPECT_NE(fit_error(records, "offset").find("too few rows: 9 usable"), std::string::npos);

  records = chain_records(50, 0.001, 15);
  for (auto& r : records) r.raw.pulse_width_ns = 5.2;
  const std::string pw = fit_error(records, "offset,grayvalue");
  EXPECT_NE(pw.find("no spread in pulse_width_ns (all 5.20 ns)"), std::string::npos) << pw;
  EXPECT_NE(pw.find("reflectance"), std::string::npos) << pw;
  EXPECT_EQ(fit_error(records, "offset,temperature"), "");

  records = chain_records(50, 0.001, 16);
  for (auto& r : records) r.raw.temperature_c = 21.0;
  const std::string t = fit_error(records, "offset,grayvalue,temperature");
  EXPECT_NE(t.find("no spread in temperature_c (all 21.00 C)"), std::string::npos) << t;

  // Rows without an echo do not count.
  records = chain_records(20, 0.001, 17);
  for (std::size_t i = 0; i < 12; ++i) records[i].raw.shots_valid = 0;
  EXPECT_NE(fit_error(records, "offset").find("too few rows: 8 usable of 20"), std::string::npos);
}

// Issue 7: one cell >= 1e155 made the squared error overflow, no knot count
// was usable and the hinge fit read back() of an empty vector (SIGSEGV).
TEST(ChainFit, RefusesOverflowingCellsNamingColumnAndRow) {
  for (const char* steps :
       {"offset,grayvalue", "offset,temperature", "offset,grayvalue,temperature"}) {
    auto records = chain_records(200, 0.001, 18);
    records[8].truth.distance_m = 1e160;
    const std::string truth = fit_error(records, steps);
    EXPECT_NE(truth.find("distance_true_m = 1e+160 in data row 9"), std::string::npos) << truth;
    records = chain_records(200, 0.001, 18);
    records[41].raw.tof_ns = 1e155;
    const std::string tof = fit_error(records, steps);
    EXPECT_NE(tof.find("tof_ns = 1e+155 in data row 42"), std::string::npos) << tof;
    EXPECT_NE(tof.find("too large"), std::string::npos) << tof;
  }
  // The walk step fits the amplitude readings too: a corrupt one is refused
  // like any fitted cell; a chain without a walk step does not read them.
  auto records = chain_records(200, 0.001, 18);
  records[17].raw.amplitude = 1e150;
  const std::string amplitude = fit_error(records, "offset,walk");
  EXPECT_NE(amplitude.find("amplitude = 1e+150 in data row 18"), std::string::npos) << amplitude;
  EXPECT_EQ(fit_error(records, "offset,grayvalue"), "");
}

TEST(HingeFit, RefusesValuesWhoseSquaresOverflow) {
  std::vector<double> x, y;
  for (int i = 0; i < 50; ++i) {
    x.push_back(i);
    y.push_back(0.01 * i);
  }
  y[7] = 1e200;
  HingeFitOptions options;
  options.column = "pulse_width_ns";
  try {
    (void)fit_hinge(x, y, options);
    FAIL() << "accepted 1e200";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("pulse_width_ns: row 8"), std::string::npos) << e.what();
  }
}

}  // namespace
}  // namespace tofkit::calib
