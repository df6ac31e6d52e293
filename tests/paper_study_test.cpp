// The paper's Section 5 on the default device: tofkit must reproduce the
// paper's figures (reference/ranging_paper.md) and do better on data the fit
// never saw.
#include "tofkit/experiments/paper_study.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <sstream>

#include "tofkit/device/device_config.hpp"
#include "tofkit/experiments/paper_reference.hpp"

using namespace tofkit;
using namespace tofkit::experiments;

namespace {

const PaperStudyResult& study() {
  static const PaperStudyResult result =
      run_paper_study(device::preset("paper"), PaperStudyOptions{}, paper::kTable2);
  return result;
}

}  // namespace

TEST(PaperStudy, EmbeddedTable2MatchesTheReferenceCsv) {
  std::ifstream in(std::string(TOFKIT_REFERENCE_DIR) + "/table2_accuracy.csv");
  ASSERT_TRUE(in) << "reference/table2_accuracy.csv";
  std::string line;
  std::getline(in, line);  // header
  std::size_t i = 0;
  while (std::getline(in, line)) {
    std::replace(line.begin(), line.end(), ',', ' ');
    std::istringstream fields(line);
    double ranging = 0, actual = 0, deviation = 0;
    fields >> ranging >> actual >> deviation;
    ASSERT_LT(i, paper::kTable2.size());
    EXPECT_DOUBLE_EQ(paper::kTable2[i].ranging_value_m, ranging);
    EXPECT_DOUBLE_EQ(paper::kTable2[i].actual_value_m, actual);
    EXPECT_DOUBLE_EQ(paper::kTable2[i].deviation_m, deviation);
    ++i;
  }
  EXPECT_EQ(i, paper::kTable2.size());
}

TEST(PaperStudy, ReproducesThePapersFigures) {
  const auto& r = study();
  EXPECT_GT(r.range_at_snr10_m, 9.0);
  EXPECT_LT(r.range_at_snr10_m, 11.0);
  EXPECT_GT(r.max_range_m, 7.0);
  EXPECT_LT(r.max_range_m, 10.5);
  // The device scatters as the paper's does (delay and comparator wander,
  // ~4.5 mm between conditions set minutes apart): one pass over the plates
  // has the paper's std within its band (Fig. 7: 4.60 +- 2 mm, issue 30:
  // 3-7 mm), and its largest error is a maximum of 54 (Fig. 9: 20) such
  // errors, within 3.5 of the pass's own std (a normal sample's maximum of 54
  // passes 3.5 sigma with a 2.5 % chance): no error beyond the noise.
  EXPECT_GE(r.grayvalue.std_mm, paper::kGrayvalueStd_mm - 2.0);
  EXPECT_LE(r.grayvalue.std_mm, paper::kGrayvalueStd_mm + 2.0);
  EXPECT_LE(r.grayvalue.accuracy_mm, 3.5 * r.grayvalue.std_mm);
  EXPECT_GE(r.grayvalue.rows, 50u);
  EXPECT_GE(r.grayvalue.raw_spread_mm, 20.0);  // there was a walk to correct
  EXPECT_LE(r.temperature.std_mm, paper::kTemperatureStd_mm + 2.0);
  EXPECT_LE(r.temperature.accuracy_mm, 3.5 * r.temperature.std_mm);
  ASSERT_EQ(r.verification_rows.size(), 8u);
  for (const auto& row : r.verification_rows) {
    // Table 2's deviation is the error of the mean of 8 readings minutes
    // apart: the paper's +-11 mm plus 3 x that mean's own noise.
    const double mean_noise_mm = row.noise_mm / std::sqrt(double(row.repeats));
    EXPECT_LE(std::abs(row.deviation_mm), paper::kVerificationAccuracy_mm + 3.0 * mean_noise_mm)
        << row.actual_m;
    EXPECT_TRUE(std::isfinite(row.paper_deviation_mm)) << row.actual_m;  // paper column filled
  }
}

TEST(PaperStudy, VerificationResidualIsWithinTheTwinsUncorrectableErrors) {
  // What no gray-value or temperature fit can remove: the TDC's INL (the laser
  // fires on the clock, so it stays, periodic in range) and the run's power-on
  // offset (the test is a later power-on than the calibration). The old
  // twin's "within 3 mm" came from a twin built from the fitted corrections.
  // And the slow wander, of which the mean of the row's repeats keeps its
  // noise of the mean (3 x that).
  const auto cfg = device::preset("paper");
  const double mm_per_ps = 0.5 * 299792458.0 * 1e-12 * 1e3;
  const double inl_mm = cfg.tdc.inl_lsb * cfg.tdc.lsb_ps * mm_per_ps;
  const double power_on_mm = std::sqrt(2.0) * cfg.measurement.power_on_offset_ps * mm_per_ps;
  for (const auto& row : study().verification_rows) {
    const double mean_noise_mm = row.noise_mm / std::sqrt(double(row.repeats));
    EXPECT_LE(std::abs(row.deviation_mm), 2.0 * inl_mm + 3.0 * power_on_mm + 3.0 * mean_noise_mm)
        << row.actual_m;
  }
}

TEST(PaperStudy, EveryAccuracyFigureSplitsNoiseFromSystematicResidual) {
  const auto& r = study();
  for (const auto* split :
       {&r.grayvalue.split, &r.temperature.split, &r.verification_split, &r.holdout_split}) {
    EXPECT_GE(split->groups, 8u);
    EXPECT_TRUE(std::isfinite(split->noise_m));
    EXPECT_GT(split->noise_m, 0.0);
    EXPECT_TRUE(std::isfinite(split->systematic_rms_m));
    // The worst group mean is at least the RMS of the means (noise removed).
    EXPECT_GE(split->systematic_max_abs_m + 1e-12, split->systematic_rms_m);
  }
  // Table 2 rows: the deviation is the error of the mean of the repeats, and
  // the row carries the repeatability of one measurement beside it.
  for (const auto& row : r.verification_rows) {
    EXPECT_GE(row.repeats, 2) << row.actual_m;
    EXPECT_GT(row.noise_mm, 0.0) << row.actual_m;
  }
  // Noise grows with distance (weaker echo, paper Eq. 8): 8 m is noisier than 1 m.
  EXPECT_GT(r.verification_rows.back().noise_mm, r.verification_rows.front().noise_mm);
}

TEST(PaperStudy, FindsThePapersKnees) {
  const auto& fit = study().fit;
  ASSERT_TRUE(fit.grayvalue.has_value());
  ASSERT_TRUE(fit.temperature.has_value());
  // Saturation bends the offset curve near 6.5 ns (paper Section 5.1).
  double nearest = 1e9;
  for (double k : fit.grayvalue->knots) nearest = std::min(nearest, std::abs(k - 6.5));
  EXPECT_LT(nearest, 0.6);
  // The delay drift starts at 16 C (paper Section 5.2).
  nearest = 1e9;
  for (double k : fit.temperature->knots) nearest = std::min(nearest, std::abs(k - 16.0));
  EXPECT_LT(nearest, 2.0);
}

TEST(PaperStudy, HeldOutGridIsCorrectedAndFixedPointAgrees) {
  const auto& r = study();
  EXPECT_GT(r.holdout_stats.rows, 400u);
  // The paper's +-11 mm (Table 2) is an accuracy of averaged readings: over
  // the grid's 648 conditions the error of the mean of each condition's 8
  // readings (minutes apart) stays within it, plus 3 x that mean's own noise
  // (the device's single readings scatter by ~5 mm, so single rows' largest
  // error over 5184 rows is 4-5 of that). The systematic RMS (noise removed)
  // is a small share of the uncorrected RMS.
  const auto& split = r.holdout_split;
  EXPECT_LT(split.systematic_rms_m, 0.02 * r.holdout_raw_stats.rms_m);
  EXPECT_LT(1e3 * split.systematic_max_abs_m, 11.0 + 3e3 * split.noise_of_mean_m);
  // The integer chain agrees with the floating-point one on every demo row.
  EXPECT_LT(r.fixed_vs_float_max_diff_mm, 0.5);
}
