// Noise vs systematic split of repeated measurements, against synthetic data
// whose per-condition offsets and noise are known.
#include "tofkit/calib/repeatability.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <vector>

namespace tofkit::calib {
namespace {

struct Synthetic {
  std::vector<double> error;
  std::vector<std::size_t> group;
  double offset_rms = 0;
};

Synthetic make(int conditions, int repeats, double noise, double offset_scale, unsigned seed) {
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> n01(0.0, 1.0);
  Synthetic s;
  double sq = 0;
  for (int g = 0; g < conditions; ++g) {
    const double offset = offset_scale * n01(rng);
    sq += offset * offset;
    for (int k = 0; k < repeats; ++k) {
      s.error.push_back(offset + noise * n01(rng));
      s.group.push_back(static_cast<std::size_t>(g) * 7 + 3);  // any labels
    }
  }
  s.offset_rms = std::sqrt(sq / conditions);
  return s;
}

TEST(Repeatability, RecoversKnownNoiseAndSystematicParts) {
  const auto s = make(400, 8, 2e-3, 1e-3, 1);
  const auto r = split_noise_systematic(s.error, s.group);
  EXPECT_EQ(r.groups, 400u);
  EXPECT_EQ(r.rows, 3200u);
  // Pooled std from 2800 degrees of freedom: relative error ~ 1/sqrt(2 dof) = 1.3 %.
  EXPECT_NEAR(r.noise_m, 2e-3, 0.05 * 2e-3);
  EXPECT_NEAR(r.noise_of_mean_m, 2e-3 / std::sqrt(8.0), 0.05 * 2e-3 / std::sqrt(8.0));
  // Group means carry 0.71 mm of noise; removing it leaves the 1 mm offsets.
  EXPECT_NEAR(r.systematic_rms_m, s.offset_rms, 0.1 * s.offset_rms);
}

TEST(Repeatability, PureNoiseLeavesNoResolvedSystematicPart) {
  const auto s = make(300, 5, 1e-3, 0.0, 2);
  const auto r = split_noise_systematic(s.error, s.group);
  EXPECT_NEAR(r.noise_m, 1e-3, 0.05e-3);
  // The means scatter by noise / sqrt(5); after removing that, little is left.
  EXPECT_LT(r.systematic_rms_m, 0.5 * r.noise_of_mean_m);
  EXPECT_GT(r.systematic_max_abs_m, 0.0);
}

TEST(Repeatability, SkipsNonFiniteAndNeedsRepeatsForNoise) {
  const std::vector<double> e{1.0, NAN, 3.0};
  const std::vector<std::size_t> g{0, 0, 1};
  const auto r = split_noise_systematic(e, g);
  EXPECT_EQ(r.groups, 2u);
  EXPECT_EQ(r.rows, 2u);
  EXPECT_TRUE(std::isnan(r.noise_m));  // no condition has two finite repeats
  EXPECT_DOUBLE_EQ(r.systematic_max_abs_m, 3.0);
  EXPECT_DOUBLE_EQ(r.systematic_mean_m, 2.0);
  EXPECT_THROW((void)split_noise_systematic(e, std::vector<std::size_t>{0}), std::invalid_argument);
}

}  // namespace
}  // namespace tofkit::calib
