#include "tofkit/calib/statistics.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

namespace tofkit::calib {
namespace {

TEST(Statistics, ErrorStatsHandComputed) {
  // e = true - measured = {0.1, -0.1, 0.2, 0.0}: bias 0.05, variance
  // ((0.05)^2 + (0.15)^2 + (0.15)^2 + (0.05)^2) / 4 = 0.0125, RMS sqrt(0.06 / 4).
  const std::vector<double> e{0.1, -0.1, 0.2, 0.0, std::nan("")};
  const ErrorStats s = error_stats(e);
  EXPECT_EQ(s.rows, 4u);
  EXPECT_NEAR(s.bias_m, 0.05, 1e-15);
  EXPECT_NEAR(s.abs_bias_m, 0.05, 1e-15);
  EXPECT_NEAR(s.variance_m2, 0.0125, 1e-15);
  EXPECT_NEAR(s.rms_m, std::sqrt(0.015), 1e-15);
  EXPECT_NEAR(s.max_abs_m, 0.2, 1e-15);
  const ErrorStats negative = error_stats(std::vector<double>{-0.3, -0.1});
  EXPECT_NEAR(negative.bias_m, -0.2, 1e-15);
  EXPECT_NEAR(negative.abs_bias_m, 0.2, 1e-15);
  EXPECT_EQ(error_stats(std::vector<double>{}).rows, 0u);
  EXPECT_TRUE(std::isnan(error_stats(std::vector<double>{}).rms_m));
}

TEST(Statistics, ThesisTablesObeyTheDefinitions) {
  // Oracle: the thesis's own tables (inches): RMS^2 = bias^2 + variance (Eq. 4.3)
  // and improvement = 100 (before - after) / before (Eqs. 4.10-4.11).
  for (const char* name :
       {"fig4_18_point_fit.csv", "fig4_23_line_fit.csv", "fig4_27_checker_fit.csv"}) {
    std::ifstream in(std::string(TOFKIT_REFERENCE_DIR) + "/" + name);
    ASSERT_TRUE(in) << name;
    std::string line;
    std::getline(in, line);  // header
    double raw_bias = 0, raw_rms = 0;
    int rows = 0;
    while (std::getline(in, line)) {
      std::vector<std::string> f;
      std::stringstream ss(line);
      for (std::string cell; std::getline(ss, cell, ',');) f.push_back(cell);
      const double bias = std::stod(f[1]), variance = std::stod(f[2]), rms = std::stod(f[3]);
      EXPECT_NEAR(std::sqrt(bias * bias + variance), rms, 2e-4) << name << ": " << line;
      if (f[0] == "raw") {
        raw_bias = bias;
        raw_rms = rms;
      } else {
        EXPECT_NEAR(improvement_pct(raw_rms, rms), std::stod(f[5]), 0.02) << name << ": " << line;
        EXPECT_NEAR(improvement_pct(std::fabs(raw_bias), std::fabs(bias)), std::stod(f[4]), 0.1)
            << name << ": " << line;
      }
      ++rows;
    }
    EXPECT_GE(rows, 4) << name;
  }
  EXPECT_TRUE(std::isnan(improvement_pct(0.0, 1.0)));
}

TEST(Statistics, TercilesAndCoverageHandComputed) {
  const std::vector<double> amplitude{1, 2, 3, 4, 5, 6};
  const TercileEdges t = amplitude_terciles(amplitude);
  // Linear-interpolated quantiles of 1..6: positions 5/3 and 10/3.
  EXPECT_NEAR(t.lower, 2.0 + 2.0 / 3.0, 1e-12);
  EXPECT_NEAR(t.upper, 4.0 + 1.0 / 3.0, 1e-12);
  EXPECT_EQ(t.tercile(2.0), 0);
  EXPECT_EQ(t.tercile(3.0), 1);
  EXPECT_EQ(t.tercile(5.0), 2);

  const std::vector<double> e{0.1, -0.1, 0.2, 0.0, 0.05, 0.3};
  const std::vector<double> sigma{0.1, 0.05, 0.15, 0.01, std::nan(""), 0.1};
  // 1 sigma: rows 0 (0.1 <= 0.1) and 3 -> 2 of 5; 2 sigma: rows 0, 1, 2, 3 -> 4 of 5.
  const Coverage one = coverage(e, sigma, amplitude, 1.0, t);
  EXPECT_EQ(one.rows, 5u);
  EXPECT_NEAR(one.share, 0.4, 1e-15);
  EXPECT_EQ(one.tercile_rows[0], 2u);
  EXPECT_EQ(one.tercile_rows[1], 2u);
  EXPECT_EQ(one.tercile_rows[2], 1u);
  EXPECT_NEAR(one.tercile_share[0], 0.5, 1e-15);  // rows 0 yes, 1 no
  EXPECT_NEAR(one.tercile_share[1], 0.5, 1e-15);  // rows 2 no, 3 yes
  EXPECT_NEAR(one.tercile_share[2], 0.0, 1e-15);  // row 5 no
  const Coverage two = coverage(e, sigma, amplitude, 2.0, t);
  EXPECT_NEAR(two.share, 0.8, 1e-15);
  EXPECT_NEAR(two.tercile_share[2], 0.0, 1e-15);  // 0.3 > 0.2
}

TEST(Statistics, EvaluateGroupsByKey) {
  const std::vector<double> truth{1, 1, 2, 2, 2};
  const std::vector<double> distance{0.99, 1.03, 2.0, std::nan(""), 1.98};
  const std::vector<double> raw{0.9, 0.95, 2.1, 2.2, 2.05};
  const std::vector<double> sigma{0.02, 0.02, 0.02, 0.02, 0.02};
  const std::vector<double> amplitude{1, 2, 3, 4, 5};
  const std::vector<double> key{10, 10, 20, 20, 20};
  const Evaluation ev = evaluate({truth, distance, raw, sigma, amplitude, key});
  ASSERT_EQ(ev.groups.size(), 2u);
  const GroupEvaluation& g10 = ev.groups[0];
  EXPECT_EQ(g10.key, 10);
  EXPECT_EQ(g10.rows, 2u);
  // corrected errors {0.01, -0.03}: bias -0.01, RMS sqrt(0.0005); raw {0.1, 0.05}.
  EXPECT_NEAR(g10.corrected.bias_m, -0.01, 1e-12);
  EXPECT_NEAR(g10.corrected.rms_m, std::sqrt(0.0005), 1e-12);
  EXPECT_NEAR(g10.raw.rms_m, std::sqrt((0.01 + 0.0025) / 2), 1e-12);
  EXPECT_NEAR(g10.rms_improvement_pct,
              100 * (std::sqrt(0.00625) - std::sqrt(0.0005)) / std::sqrt(0.00625), 1e-9);
  EXPECT_NEAR(g10.bias_improvement_pct, 100 * (0.075 - 0.01) / 0.075, 1e-9);
  EXPECT_NEAR(g10.within_1_sigma.share, 0.5, 1e-15);
  EXPECT_NEAR(g10.within_2_sigma.share, 1.0, 1e-15);
  const GroupEvaluation& g20 = ev.groups[1];
  EXPECT_EQ(g20.rows, 3u);
  EXPECT_EQ(g20.rows_without_range, 1u);
  EXPECT_EQ(g20.corrected.rows, 2u);
  // The raw error is taken on the same rows: {-0.1, -0.05}.
  EXPECT_NEAR(g20.raw.bias_m, -0.075, 1e-12);
  EXPECT_EQ(ev.overall.rows, 5u);
  EXPECT_EQ(ev.overall.corrected.rows, 4u);
  EXPECT_NEAR(ev.overall.corrected.max_abs_m, 0.03, 1e-12);
  EXPECT_FALSE(ev.summary().empty());
  EXPECT_THROW((void)evaluate({truth, distance, raw, sigma, amplitude, std::vector<double>{1}}),
               std::invalid_argument);
}

// Folds of a distance-major grid (6 reflectances per distance, 18 distances):
// with group % 5 every fold would be a set of diagonals, and no distance
// would lose more than two of its reflectances at once. The shuffled folds
// must be deterministic, in range, about balanced (108 groups: 21.6 each,
// binomial sd 4.2), and not the modulo.
TEST(Statistics, FoldsAreShuffledDeterministicallyAndBalanced) {
  constexpr std::size_t kGroups = 108, kFolds = 5;
  std::vector<std::size_t> count(kFolds, 0);
  std::size_t same_as_modulo = 0, distances_losing_three = 0;
  for (std::size_t distance = 0; distance < 18; ++distance) {
    std::vector<std::size_t> lost(kFolds, 0);
    for (std::size_t rho = 0; rho < 6; ++rho) {
      const std::size_t g = distance * 6 + rho;
      const std::size_t f = fold_of(g, kFolds);
      ASSERT_LT(f, kFolds);
      EXPECT_EQ(f, fold_of(g, kFolds));
      ++count[f];
      ++lost[f];
      same_as_modulo += f == g % kFolds ? 1 : 0;
    }
    for (std::size_t n : lost) distances_losing_three += n >= 3 ? 1 : 0;
  }
  for (std::size_t n : count) {
    EXPECT_GE(n, 10u);
    EXPECT_LE(n, 34u);
  }
  EXPECT_LT(same_as_modulo, kGroups / 2);
  // Random folds sometimes take three of a distance's six targets (the modulo never does).
  EXPECT_GT(distances_losing_three, 0u);
  EXPECT_EQ(fold_of(7, 1), 0u);
}

}  // namespace
}  // namespace tofkit::calib
