// Confidence models (thesis Section 4.8 and tofkit's calibrated metric), checked
// on synthetic heteroscedastic residuals whose true sigma is known, with
// coverage measured on a sample independent of the fitting sample.

#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <cstdio>
#include <functional>
#include <initializer_list>
#include <limits>
#include <random>
#include <stdexcept>
#include <string>
#include <vector>

#include "tofkit/calib/confidence_model.hpp"
#include "tofkit/calib/model_fit.hpp"
#include "tofkit/io/surface_json.hpp"
#include "tofkit/ranging/pipeline.hpp"

namespace tofkit::calib {
namespace {

struct Residuals {
  std::vector<double> range_m, amplitude, residual_m, true_sigma_m;
  [[nodiscard]] ConfidenceFitData data() const { return {range_m, amplitude, residual_m}; }
};

/// Jitter-like error: sigma ~ noise / slope ~ 1 / amplitude, growing with range
/// (longer, flatter echoes), on a floor from the TDC: 1 mm + 0.2 m / a * (1 + r / 20).
double true_sigma(double r, double a) {
  return 0.001 + 0.2 / a * (1.0 + r / 20.0);
}

/// Residuals of exactly +-sqrt(e2(a)), alternating in sign, at 400 intensities
/// over 10..390 (range 5 m): least squares on E^2 recovers e2.
template <class E2>
Residuals alternating_residuals(const E2& e2) {
  Residuals data;
  for (int k = 0; k < 400; ++k) {
    const double a = 10.0 + 380.0 * k / 399.0;
    data.range_m.push_back(5.0);
    data.amplitude.push_back(a);
    data.residual_m.push_back((k % 2 ? 1.0 : -1.0) * std::sqrt(e2(a)));
  }
  return data;
}

enum class Tail { gaussian, student5 };

/// Range uniform in [1, 30] m, amplitude log-uniform in [10, 5000].
Residuals make_residuals(std::size_t n, Tail tail, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  std::normal_distribution<double> gauss(0.0, 1.0);
  std::student_t_distribution<double> student(5.0);
  Residuals out;
  for (std::size_t k = 0; k < n; ++k) {
    const double r = 1.0 + 29.0 * unit(rng);
    const double a = 10.0 * std::pow(500.0, unit(rng));
    const double s = true_sigma(r, a);
    // Student t(5) scaled to unit variance: mildly heavy tails, same sigma.
    const double z = tail == Tail::gaussian ? gauss(rng) : student(rng) / std::sqrt(5.0 / 3.0);
    out.range_m.push_back(r);
    out.amplitude.push_back(a);
    out.residual_m.push_back(s * z);
    out.true_sigma_m.push_back(s);
  }
  return out;
}

TEST(CalibratedConfidence, HeldOutCoverageMeetsTargetOverallAndPerTercile) {
  for (Tail tail : {Tail::gaussian, Tail::student5}) {
    const char* name = tail == Tail::gaussian ? "gaussian" : "student-t(5)";
    const Residuals fit_sample = make_residuals(20000, tail, 100);
    const Residuals held_out = make_residuals(20000, tail, 200);
    const auto model = fit_calibrated_confidence(fit_sample.data());
    ASSERT_EQ(model->kind(), "calibrated");
    const ConfidenceCoverage c = coverage_2sigma(*model, held_out.data());
    const auto thesis = fit_thesis_confidence(fit_sample.data());
    const ConfidenceCoverage t = coverage_2sigma(*thesis, held_out.data());
    std::printf("%s held out: calibrated %s; thesis metric %s\n", name, c.summary().c_str(),
                t.summary().c_str());
    EXPECT_GE(c.within_2sigma, 0.93) << name;
    EXPECT_LE(c.within_2sigma, 0.97) << name;
    for (int k = 0; k < 3; ++k) {
      EXPECT_GE(c.within_2sigma_by_tercile[k], 0.93) << name << " tercile " << k;
      EXPECT_LE(c.within_2sigma_by_tercile[k], 0.97) << name << " tercile " << k;
    }
    // On its own fitting data the coverage is the target by construction.
    const auto& p = dynamic_cast<const CalibratedConfidence&>(*model).params();
    EXPECT_NEAR(p.fit_coverage_2sigma, 0.95, 0.005);
  }
}

/// Rows at 1.778 m, amplitude log-uniform over [10, 5000], and every
/// `far_every`-th row at `far_m` with amplitude far_amplitude(rng, unit, gauss);
/// residuals of true_sigma.
template <class FarAmplitude>
Residuals two_distance_sample(std::uint64_t seed, std::size_t far_every, double far_m,
                              FarAmplitude far_amplitude) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  std::normal_distribution<double> gauss(0.0, 1.0);
  Residuals sample;
  for (std::size_t k = 0; k < 4000; ++k) {
    const bool far = k % far_every == 0;
    const double r = (far ? far_m : 1.778) + 0.0003 * gauss(rng);
    const double a = far ? far_amplitude(rng, unit, gauss) : 10.0 * std::pow(500.0, unit(rng));
    sample.range_m.push_back(r);
    sample.amplitude.push_back(a);
    sample.residual_m.push_back(true_sigma(r, a) * gauss(rng));
    sample.true_sigma_m.push_back(true_sigma(r, a));
  }
  return sample;
}

/// The model's sigma within `tolerance` (relative) of true_sigma at every
/// (range, amplitude) pair.
void expect_near_truth(const ConfidenceModel& model, std::initializer_list<double> ranges,
                       std::initializer_list<double> amplitudes, double tolerance) {
  for (double range : ranges) {
    for (double amplitude : amplitudes) {
      double sigma = 0;
      model.sigma(std::span<const double>(&range, 1), std::span<const double>(&amplitude, 1),
                  std::span<double>(&sigma, 1));
      EXPECT_NEAR(sigma / true_sigma(range, amplitude), 1.0, tolerance)
          << "r " << range << " a " << amplitude;
    }
  }
}

// Rows at two distances only (plates at one distance and a temperature run at
// another): the range may enter linearly, no more. Found on such a
// calibration, where higher powers of range, free between the two distances,
// cancelled on them and gave sigma = 1e60 m (or infinity) at the distances
// between (here, with neither that rule nor the fit's check of its domain,
// 7e-14 x the truth: they may sink it too).
TEST(CalibratedConfidence, RowsAtTwoDistancesGiveAtMostALinearRangeTerm) {
  const Residuals sample = two_distance_sample(
      17, 2, 6.5, [](auto& rng, auto& unit, auto&) { return 10.0 * std::pow(500.0, unit(rng)); });
  const auto model = fit_calibrated_confidence(sample.data());
  const auto& p = dynamic_cast<const CalibratedConfidence&>(*model).params();
  for (const auto& e : p.exponents) EXPECT_LE(e[1], 1) << e[0] << " " << e[1];
  expect_near_truth(*model, {1.778, 2.5, 3.5, 4.2, 5.0, 6.5}, {20.0, 100.0, 500.0, 2500.0}, 0.2);
}

// Plates of many reflectances at 1.778 m, one plate at 4.5 m: how the
// variance changes with range is seen at one intensity only. Terms in range
// and intensity together are free away from it; kept, they gave 2.1 x and
// 0.54 x the truth here: the fit must drop them.
TEST(CalibratedConfidence, ADistanceWithOneIntensityGivesNoRangeIntensityTerm) {
  const Residuals sample = two_distance_sample(
      23, 4, 4.5, [](auto& rng, auto&, auto& gauss) { return 300.0 * (1 + 0.02 * gauss(rng)); });
  const auto model = fit_calibrated_confidence(sample.data());
  const auto& p = dynamic_cast<const CalibratedConfidence&>(*model).params();
  bool range_term = false;
  for (const auto& e : p.exponents) {
    EXPECT_FALSE(e[0] > 0 && e[1] > 0) << e[0] << " " << e[1];
    EXPECT_LE(e[1], 1);
    range_term |= e[1] == 1;
  }
  EXPECT_TRUE(range_term);
  // Near the truth where the rows are, and no further from it than the
  // truth's own mixing of range and intensity elsewhere.
  expect_near_truth(*model, {1.778, 2.5, 3.5, 4.5}, {20.0, 100.0, 300.0, 2500.0}, 0.25);
}

TEST(CalibratedConfidence, SigmaFollowsTheTrueSigma) {
  // For Gaussian residuals the 95 % two-sided quantile is 1.96 sigma, so the
  // calibrated sigma should be 0.98 of the true one wherever data are dense.
  const Residuals fit_sample = make_residuals(20000, Tail::gaussian, 300);
  const auto model = fit_calibrated_confidence(fit_sample.data());
  std::vector<double> r, a, expected;
  for (double range : {3.0, 10.0, 20.0, 28.0}) {
    for (double amplitude : {20.0, 100.0, 500.0, 2500.0}) {
      r.push_back(range);
      a.push_back(amplitude);
      expected.push_back(0.98 * true_sigma(range, amplitude));
    }
  }
  std::vector<double> sigma(r.size());
  model->sigma(r, a, sigma);
  for (std::size_t k = 0; k < r.size(); ++k) {
    EXPECT_NEAR(sigma[k] / expected[k], 1.0, 0.15) << "r " << r[k] << " a " << a[k];
  }
  // Outside the fitting domain sigma is clamped, not extrapolated.
  const std::vector<double> far_r = {1000.0, 30.0}, far_a = {1e9, 5000.0};
  std::vector<double> far_sigma(2);
  model->sigma(far_r, far_a, far_sigma);
  EXPECT_DOUBLE_EQ(far_sigma[0], far_sigma[1]);
}

TEST(ThesisConfidence, RecoversAPolynomialSquaredErrorAndAppliesTheFloor) {
  // Residuals of exactly +-sqrt(f(a)) with f cubic in intensity: least squares
  // on E^2 recovers f; where f falls below the floor sigma is sqrt(floor).
  const auto f = [](double a) {
    return 1e-4 * (1.0 - a / 150.0) * (1.0 - a / 150.0) * (1.0 - a / 400.0) + 2e-6;
  };
  const Residuals data = alternating_residuals(f);
  ThesisConfidenceOptions options;
  options.floor_m2 = 5e-6;
  const auto model = fit_thesis_confidence(data.data(), options);
  ASSERT_EQ(model->kind(), "thesis");
  std::vector<double> sigma(data.amplitude.size());
  model->sigma(data.range_m, data.amplitude, sigma);
  std::size_t floored = 0;
  for (std::size_t k = 0; k < sigma.size(); ++k) {
    const double e2 = f(data.amplitude[k]);
    if (e2 >= options.floor_m2) {
      EXPECT_NEAR(sigma[k], std::sqrt(e2), 1e-9) << "a " << data.amplitude[k];
    } else {
      EXPECT_DOUBLE_EQ(sigma[k], std::sqrt(options.floor_m2));
      ++floored;
    }
  }
  EXPECT_GT(floored, 10u);

  // Default floor: 5 % of the mean squared error.
  const auto by_default = fit_thesis_confidence(data.data());
  const auto& p = dynamic_cast<const ThesisConfidence&>(*by_default).params();
  double mean_e2 = 0;
  for (double e : data.residual_m) mean_e2 += e * e;
  mean_e2 /= static_cast<double>(data.residual_m.size());
  EXPECT_NEAR(p.floor_m2, 0.05 * mean_e2, 1e-15);
}

TEST(ThesisConfidence, UsesTheFloorAloneAboveTheStatedIntensity) {
  // Thesis Section 4.8: "above intensity 72 a floor of 0.005 in^2 is used". E^2
  // rising with intensity above the threshold (where the thesis's cubic would be
  // large) must still give sqrt(floor) there, and the polynomial below it.
  const auto f = [](double a) { return 1e-5 * (1.0 + (a - 100.0) * (a - 100.0) / 2500.0); };
  const Residuals data = alternating_residuals(f);
  ThesisConfidenceOptions options;
  options.floor_m2 = 0.005 * 0.0254 * 0.0254;
  options.floor_above_amplitude = 72.0;
  const auto model = fit_thesis_confidence(data.data(), options);
  std::vector<double> sigma(data.amplitude.size());
  model->sigma(data.range_m, data.amplitude, sigma);
  std::size_t above = 0;
  for (std::size_t k = 0; k < sigma.size(); ++k) {
    const double a = data.amplitude[k];
    if (a > 72.0) {
      EXPECT_DOUBLE_EQ(sigma[k], std::sqrt(options.floor_m2)) << "a " << a;
      ++above;
    } else {
      EXPECT_NEAR(sigma[k], std::sqrt(std::max(f(a), options.floor_m2)), 1e-9) << "a " << a;
    }
  }
  EXPECT_GT(above, 300u);
  // Without the threshold the floor is only a lower bound (f(390) = 3.5e-4 m^2).
  options.floor_above_amplitude = 0;
  const std::vector<double> r{5.0}, a{390.0};
  std::vector<double> s(1);
  fit_thesis_confidence(data.data(), options)->sigma(r, a, s);
  EXPECT_NEAR(s[0], std::sqrt(f(390.0)), 1e-9);
  options.floor_above_amplitude = -1;
  EXPECT_THROW((void)fit_thesis_confidence(data.data(), options), std::invalid_argument);
}

TEST(Confidence, DegenerateDataThrows) {
  Residuals few = make_residuals(20, Tail::gaussian, 400);
  EXPECT_THROW((void)fit_calibrated_confidence(few.data()), std::invalid_argument);
  Residuals bad = make_residuals(2000, Tail::gaussian, 401);
  bad.residual_m[5] = std::numeric_limits<double>::quiet_NaN();
  try {
    (void)fit_calibrated_confidence(bad.data());
    ADD_FAILURE() << "no exception";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("non-finite residual_m at row 5"), std::string::npos)
        << e.what();
  }
  EXPECT_THROW((void)fit_thesis_confidence(bad.data()), std::invalid_argument);
  Residuals zero = make_residuals(2000, Tail::gaussian, 402);
  std::fill(zero.residual_m.begin(), zero.residual_m.end(), 0.0);
  EXPECT_THROW((void)fit_calibrated_confidence(zero.data()), std::invalid_argument);
  CalibratedConfidenceOptions options;
  options.target_coverage_2sigma = 1.5;
  EXPECT_THROW(
      (void)fit_calibrated_confidence(make_residuals(2000, Tail::gaussian, 403).data(), options),
      std::invalid_argument);
}

TEST(ConfidenceJson, RoundTripGivesIdenticalSigmas) {
  const Residuals sample = make_residuals(5000, Tail::gaussian, 500);
  const Residuals probe = make_residuals(1000, Tail::gaussian, 501);
  for (const auto& model :
       {fit_thesis_confidence(sample.data()), fit_calibrated_confidence(sample.data())}) {
    const std::string text = io::confidence_to_json(*model).dump();
    const auto loaded =
        io::confidence_from_json(nlohmann::json::parse(text), "model.json: confidence");
    EXPECT_EQ(loaded->kind(), model->kind());
    std::vector<double> before(probe.range_m.size()), after(probe.range_m.size());
    model->sigma(probe.range_m, probe.amplitude, before);
    loaded->sigma(probe.range_m, probe.amplitude, after);
    for (std::size_t k = 0; k < before.size(); ++k)
      ASSERT_EQ(before[k], after[k]) << model->kind() << " " << k;

    nlohmann::json broken = nlohmann::json::parse(text);
    broken.erase("coefficients");
    try {
      (void)io::confidence_from_json(broken, "model.json: confidence");
      ADD_FAILURE() << "no exception";
    } catch (const std::runtime_error& e) {
      const std::string what = e.what();
      EXPECT_NE(what.find("model.json: confidence"), std::string::npos) << what;
      EXPECT_NE(what.find("coefficients"), std::string::npos) << what;
    }
  }
}

// Oracle for the noise-plus-systematic model: targets whose repeats scatter
// with sd 0.3 mm / sqrt(I) (averaging noise ~ 1/SNR, SNR ~ I) about a mean
// error drawn once per target with sd 0.2 mm. The fit must recover
// sigma^2 = noise^2 + s^2 (closed form), scale the systematic part by the
// optimism, cover fresh targets at 2 sigma about 95 % (both parts Gaussian),
// and survive a JSON round trip with its pulse-width axis.
struct Targets {
  std::vector<double> range_m, intensity, residual_m;
  std::vector<std::uint32_t> group;
};

Targets make_targets(int count, int repeats, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> log_i(std::log(0.1), std::log(10.0)), range(0.5, 9.0);
  std::normal_distribution<double> unit;
  Targets t;
  for (int g = 0; g < count; ++g) {
    const double intensity = std::exp(log_i(rng)), r = range(rng);
    const double systematic = 0.2e-3 * unit(rng);
    for (int k = 0; k < repeats; ++k) {
      t.range_m.push_back(r);
      t.intensity.push_back(intensity);
      t.residual_m.push_back(systematic + 0.3e-3 / std::sqrt(intensity) * unit(rng));
      t.group.push_back(static_cast<std::uint32_t>(g));
    }
  }
  return t;
}

TEST(NoiseSystematicConfidence, RecoversNoiseAndSystematicAndCoversFreshTargets) {
  const Targets fit = make_targets(400, 3, 600);
  NoiseSystematicOptions options;
  options.intensity = ranging::IntensityInput::pulse_width;
  const auto model = fit_noise_systematic_confidence(
      {fit.range_m, fit.intensity, fit.residual_m, fit.group}, options);
  EXPECT_EQ(model->intensity_input(), ranging::IntensityInput::pulse_width);
  const std::vector<double> range{1.0, 4.0, 8.0}, intensity{0.15, 1.0, 8.0};
  std::vector<double> sigma(3);
  model->sigma(range, intensity, sigma);
  for (std::size_t k = 0; k < 3; ++k) {
    const double expected = std::sqrt(0.09e-6 / intensity[k] + 0.04e-6);
    EXPECT_NEAR(sigma[k], expected, 0.12 * expected) << "intensity " << intensity[k];
  }
  // Optimism 2 doubles the systematic variance only.
  options.optimism = 2.0;
  const auto inflated = fit_noise_systematic_confidence(
      {fit.range_m, fit.intensity, fit.residual_m, fit.group}, options);
  std::vector<double> sigma2(3);
  inflated->sigma(range, intensity, sigma2);
  // The difference is the fitted systematic variance, s^2 = 0.04 mm^2 where
  // the noise does not swamp it (at I = 0.15 the noise of a mean of three is
  // 5 times s^2).
  for (std::size_t k = 0; k < 3; ++k) {
    const double fitted_s2 = sigma2[k] * sigma2[k] - sigma[k] * sigma[k];
    EXPECT_GT(fitted_s2, 0);
    if (k > 0) EXPECT_NEAR(fitted_s2, 0.04e-6, 0.4 * 0.04e-6) << "intensity " << intensity[k];
  }
  // Fresh targets: 2 sigma covers about 95 % (20 000 rows: binomial sd 0.15 %,
  // 5000 targets' shared errors widen it to about 0.4 %).
  const Targets fresh = make_targets(5000, 4, 601);
  std::vector<double> s(fresh.residual_m.size());
  model->sigma(fresh.range_m, fresh.intensity, s);
  std::size_t inside = 0;
  for (std::size_t k = 0; k < s.size(); ++k) inside += std::abs(fresh.residual_m[k]) <= 2 * s[k];
  const double share = static_cast<double>(inside) / static_cast<double>(s.size());
  EXPECT_GT(share, 0.93);
  EXPECT_LT(share, 0.97);
  // The JSON form keeps both terms and the axis.
  const auto loaded = io::confidence_from_json(
      nlohmann::json::parse(io::confidence_to_json(*inflated).dump()), "model.json: confidence");
  EXPECT_EQ(loaded->intensity_input(), ranging::IntensityInput::pulse_width);
  std::vector<double> after(3);
  loaded->sigma(range, intensity, after);
  for (std::size_t k = 0; k < 3; ++k) EXPECT_EQ(after[k], sigma2[k]);
  // The pipeline hands the model the pulse-width column, not the amplitude.
  ranging::Pipeline pipeline;
  pipeline.add_step(ranging::make_offset_step(0.0));
  pipeline.set_confidence(model);
  ranging::RawMeasurement raw;
  raw.tof_ns = 20.0;
  raw.distance_raw_m = 3.0;
  raw.temperature_c = 25.0;
  raw.shots_valid = 100;
  raw.pulse_width_ns = intensity[0];
  raw.amplitude = intensity[2];
  EXPECT_DOUBLE_EQ(pipeline.apply(raw).sigma_m, sigma[0]);
  raw.amplitude = std::numeric_limits<double>::quiet_NaN();  // not read
  EXPECT_DOUBLE_EQ(pipeline.apply(raw).sigma_m, sigma[0]);
  // No repeats: the noise cannot be told from the systematic error.
  const Targets single = make_targets(100, 1, 602);
  EXPECT_THROW((void)fit_noise_systematic_confidence(
                   {single.range_m, single.intensity, single.residual_m, single.group}),
               std::invalid_argument);
  options.optimism = 0.5;
  EXPECT_THROW((void)fit_noise_systematic_confidence(
                   {fit.range_m, fit.intensity, fit.residual_m, fit.group}, options),
               std::invalid_argument);
}

// The systematic part by maximum likelihood on the targets' means, its
// degree by BIC: a systematic error that grows with intensity (sd 0.1 mm x
// sqrt(I), I over two decades) under the same noise must come out as that
// trend (within 30 % at both ends and the middle), and a systematic error of
// zero must stay small everywhere: a mean the noise explains is not a
// systematic error (a log fit of m^2 - noise^2 / n, floored, turned such
// targets into a steep curve that extrapolated to 20 x the error).
TEST(NoiseSystematicConfidence, SystematicTrendByMaximumLikelihood) {
  const auto make = [](double trend, std::uint64_t seed) {
    std::mt19937_64 rng(seed);
    std::uniform_real_distribution<double> log_i(std::log(0.1), std::log(10.0));
    std::normal_distribution<double> unit;
    Targets t;
    for (int g = 0; g < 600; ++g) {
      const double intensity = std::exp(log_i(rng));
      const double systematic = trend * 0.1e-3 * std::sqrt(intensity) * unit(rng);
      for (int k = 0; k < 3; ++k) {
        t.range_m.push_back(3.0 + 0.01 * g);
        t.intensity.push_back(intensity);
        t.residual_m.push_back(systematic + 0.3e-3 / std::sqrt(intensity) * unit(rng));
        t.group.push_back(static_cast<std::uint32_t>(g));
      }
    }
    return t;
  };
  const std::vector<double> intensity{0.12, 1.0, 8.0}, range{3.0, 3.0, 3.0};
  for (double trend : {1.0, 0.0}) {
    const Targets fit = make(trend, 700 + static_cast<std::uint64_t>(trend));
    NoiseSystematicOptions options;
    options.optimism = 1.0;
    const auto base = fit_noise_systematic_confidence(
        {fit.range_m, fit.intensity, fit.residual_m, fit.group}, options);
    options.optimism = 2.0;
    const auto doubled = fit_noise_systematic_confidence(
        {fit.range_m, fit.intensity, fit.residual_m, fit.group}, options);
    std::vector<double> a(3), b(3);
    base->sigma(range, intensity, a);
    doubled->sigma(range, intensity, b);
    for (std::size_t k = 0; k < 3; ++k) {
      const double s2 = b[k] * b[k] - a[k] * a[k];  // the fitted systematic variance
      const double truth = trend * 0.01e-6 * intensity[k];
      const double noise2 = 0.09e-6 / intensity[k];
      std::printf("trend %.0f, I %.2f: systematic sd %.4f mm (truth %.4f mm)\n", trend,
                  intensity[k], std::sqrt(std::max(s2, 0.0)) * 1e3, std::sqrt(truth) * 1e3);
      if (trend > 0 && k > 0) {  // at I = 0.12 the noise of a mean is 25 x s^2
        EXPECT_NEAR(std::sqrt(s2), std::sqrt(truth), 0.3 * std::sqrt(truth)) << intensity[k];
      }
      if (trend == 0) EXPECT_LT(s2, 0.1 * noise2) << intensity[k];
    }
  }
}

// Oracle for the pointwise optimism: targets whose in-sample mean residual is
// shrunk as a fit of leverage h shrinks it, (b + noise mean) sqrt(1 - h) (a
// projection: variance (s^2 + nu)(1 - h)), with h rising from 0.1 to 0.8
// along log intensity, and fresh targets whose error adds the fit's own error
// at them, N(0, (s^2 + nu) h). With the leverages the model must give sigma^2
// = noise^2 + s^2 + (s^2 + nu) h within 12 % in sigma at both ends and the
// middle, and cover the fresh rows at 2 sigma 93-97 %; the global optimism
// (G + p) / (G - p) with p the leverages' sum must fall short where h is large.
struct ShrunkTargets {
  Targets rows;
  std::vector<double> leverage;
};

double leverage_at(double intensity) {
  return 0.1 + 0.7 * (std::log(intensity) - std::log(0.1)) / (std::log(10.0) - std::log(0.1));
}

constexpr double kNoise2AtUnitIntensity = 0.09e-6, kSystematic2 = 0.04e-6;
constexpr int kRepeats = 3;

double new_row_variance(double intensity) {
  const double noise2 = kNoise2AtUnitIntensity / intensity;
  return noise2 + kSystematic2 + (kSystematic2 + noise2 / kRepeats) * leverage_at(intensity);
}

ShrunkTargets make_shrunk_targets(int count, bool fresh, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> log_i(std::log(0.1), std::log(10.0));
  std::normal_distribution<double> unit;
  ShrunkTargets t;
  for (int g = 0; g < count; ++g) {
    const double intensity = std::exp(log_i(rng)), h = leverage_at(intensity);
    const double noise = std::sqrt(kNoise2AtUnitIntensity / intensity);
    const double systematic = std::sqrt(kSystematic2) * unit(rng);
    std::vector<double> e(kRepeats);
    double mean = 0;
    for (double& v : e) mean += (v = noise * unit(rng)) / kRepeats;
    // In-sample: the mean shrunk by the fit; fresh: the fit's error at the target added.
    const double shift =
        fresh ? systematic + std::sqrt((kSystematic2 + noise * noise / kRepeats) * h) * unit(rng)
              : std::sqrt(1 - h) * (systematic + mean) - mean;
    for (double v : e) {
      t.rows.range_m.push_back(3.0);
      t.rows.intensity.push_back(intensity);
      t.rows.residual_m.push_back(v + shift);
      t.rows.group.push_back(static_cast<std::uint32_t>(g));
      t.leverage.push_back(h);
    }
  }
  return t;
}

TEST(NoiseSystematicConfidence, PointwiseOptimismFromLeverages) {
  const ShrunkTargets fit = make_shrunk_targets(800, false, 900);
  const Targets& r = fit.rows;
  const auto model = fit_noise_systematic_confidence(
      {r.range_m, r.intensity, r.residual_m, r.group, fit.leverage});
  double mean_h = 0;
  for (double h : fit.leverage) mean_h += h / static_cast<double>(fit.leverage.size());
  NoiseSystematicOptions global;
  global.optimism = (1 + mean_h) / (1 - mean_h);  // (G + p) / (G - p), p = G mean_h
  const auto flat =
      fit_noise_systematic_confidence({r.range_m, r.intensity, r.residual_m, r.group}, global);
  const std::vector<double> range{3.0, 3.0, 3.0}, intensity{0.15, 1.0, 8.0};
  std::vector<double> sigma(3), sigma_flat(3);
  model->sigma(range, intensity, sigma);
  flat->sigma(range, intensity, sigma_flat);
  for (std::size_t k = 0; k < 3; ++k) {
    const double expected = std::sqrt(new_row_variance(intensity[k]));
    std::printf("I %.2f (h %.2f): sigma %.4f mm, global optimism %.4f mm, truth %.4f mm\n",
                intensity[k], leverage_at(intensity[k]), sigma[k] * 1e3, sigma_flat[k] * 1e3,
                expected * 1e3);
    EXPECT_NEAR(sigma[k], expected, 0.12 * expected) << "intensity " << intensity[k];
  }
  // Where h = 0.77 the global optimism misses a third of the variance or more.
  EXPECT_LT(sigma_flat[2], 0.85 * std::sqrt(new_row_variance(intensity[2])));
  const ShrunkTargets fresh = make_shrunk_targets(5000, true, 901);
  std::vector<double> s(fresh.rows.residual_m.size());
  model->sigma(fresh.rows.range_m, fresh.rows.intensity, s);
  std::size_t inside = 0;
  for (std::size_t k = 0; k < s.size(); ++k)
    inside += std::abs(fresh.rows.residual_m[k]) <= 2 * s[k];
  const double share = static_cast<double>(inside) / static_cast<double>(s.size());
  EXPECT_GT(share, 0.93);
  EXPECT_LT(share, 0.97);
  // Refusals name the problem.
  const auto refused = [&](std::vector<double> leverage, double optimism, const char* what) {
    NoiseSystematicOptions o;
    o.optimism = optimism;
    try {
      (void)fit_noise_systematic_confidence(
          {r.range_m, r.intensity, r.residual_m, r.group, leverage}, o);
      ADD_FAILURE() << "accepted: " << what;
    } catch (const std::invalid_argument& e) {
      EXPECT_NE(std::string(e.what()).find(what), std::string::npos) << e.what();
    }
  };
  refused(std::vector<double>(3, 0.5), 1.0, "leverage and residual_m differ in length");
  std::vector<double> bad = fit.leverage;
  bad[7] = 1.0;
  refused(bad, 1.0, "leverage at row 7 must be in [0, 1)");
  bad[7] = std::numeric_limits<double>::quiet_NaN();
  refused(bad, 1.0, "leverage at row 7 must be in [0, 1)");
  refused(fit.leverage, 2.0, "exclusive");
}

// fit_model measures each target's leverage by refits: for an offset alone
// fitted by least squares (the mean of all rows' errors) a target of n rows among N has h = n / N
// exactly, the leverages sum to 1 (its one parameter) and the largest
// optimism is (1 + 3 / N) / (1 - 3 / N) for the targets of three rows.
std::vector<ranging::Record> offset_targets(int targets) {
  std::mt19937_64 rng(910);
  std::normal_distribution<double> unit;
  std::vector<ranging::Record> records;
  const double metres_per_ns = ranging::metres_per_ns(ranging::TimeToDistance{});
  for (int g = 0; g < targets; ++g) {
    const double distance = 1.0 + 0.2 * g, amplitude = 0.05 * (1 + g);
    const double systematic = 0.3e-3 * unit(rng);
    for (int k = 0; k < (g % 2 == 0 ? 3 : 2); ++k) {
      ranging::Record r;
      r.truth.distance_m = distance;
      r.truth.reflectance = 0.5;
      r.truth.angle_deg = 0;
      r.truth.ambient_c = 20;
      r.raw.distance_raw_m = distance + 0.05 + systematic + 0.2e-3 * unit(rng);
      r.raw.tof_ns = r.raw.distance_raw_m / metres_per_ns;
      r.raw.amplitude = amplitude;
      r.raw.pulse_width_ns = 3.0 + 0.1 * g;
      r.raw.temperature_c = 25;
      r.raw.shots_valid = 100;
      records.push_back(r);
    }
  }
  return records;
}

ModelFitOptions offset_options() {
  ModelFitOptions options;
  options.chain = ChainSteps{true, false, false};
  // Least squares: a robust loss weights rows by their residuals, and the
  // refits then measure the M-estimator's influence instead.
  options.chain_options.grayvalue.robust.loss = RobustLoss::kNone;
  options.chain_options.temperature.robust.loss = RobustLoss::kNone;
  options.confidence = ConfidenceKind::noise_systematic;
  options.confidence_required = true;
  return options;
}

TEST(NoiseSystematicConfidence, FitModelMeasuresLeveragesByRefits) {
  const std::vector<ranging::Record> records = offset_targets(40);
  const ModelFitResult fit = fit_model(records, offset_options());
  ASSERT_TRUE(fit.summary.confidence.has_value()) << fit.report;
  const auto& c = *fit.summary.confidence;
  const double n = static_cast<double>(records.size());
  std::printf("%s", fit.report.c_str());
  EXPECT_NEAR(c.effective_parameters, 1.0, 1e-12);
  EXPECT_NEAR(c.leverage_sum, 1.0, 1e-6);
  EXPECT_NEAR(c.optimism_max, (1 + 3 / n) / (1 - 3 / n), 1e-6);
  EXPECT_NEAR(c.optimism, ((1 + 3 / n) / (1 - 3 / n) + (1 + 2 / n) / (1 - 2 / n)) / 2, 1e-6);
}

// Above 500 targets a refit per target costs too much: one optimism
// (G + p) / (G - p) for all, said in the report, no leverages.
TEST(NoiseSystematicConfidence, ManyTargetsTakeOneOptimism) {
  const ModelFitResult fit = fit_model(offset_targets(501), offset_options());
  ASSERT_TRUE(fit.summary.confidence.has_value()) << fit.report;
  const auto& c = *fit.summary.confidence;
  EXPECT_EQ(c.groups, 501u);
  EXPECT_EQ(c.leverage_sum, 0.0);
  EXPECT_NEAR(c.optimism, 502.0 / 500.0, 1e-12);
  EXPECT_EQ(c.optimism_max, c.optimism);
  EXPECT_NE(fit.report.find("more than 500 targets"), std::string::npos) << fit.report;
}

}  // namespace
}  // namespace tofkit::calib

namespace tofkit::calib {
namespace {

// A calibration whose rows all stand at one distance cannot see errors that
// change with range: the fit says so (and counts the distances); with a
// second distance it does not. Ranges that are not finite are not counted.
TEST(ModelFit, ACalibrationAtOneDistanceSaysSoInItsReport) {
  const auto rows_at = [](std::vector<double> distances) {
    std::vector<ranging::Record> rows;
    for (double d : distances) {
      for (int k = 0; k < 12; ++k) {
        ranging::Record r;
        r.truth.distance_m = d;
        r.raw.tof_ns = 2.0 * (d + 0.2 + 1e-4 * k) / 0.2997;
        r.raw.shots_valid = 100;
        r.raw.amplitude = 0.5 + 0.1 * k;
        r.raw.pulse_width_ns = 5.0;
        r.raw.temperature_c = 20.0;
        rows.push_back(r);
      }
    }
    return rows;
  };
  ModelFitOptions options;
  options.chain = ChainSteps{true, false, false};
  options.confidence = ConfidenceKind::none;
  const ModelFitResult one = fit_model(rows_at({2.0}), options);
  EXPECT_EQ(one.summary.distances, 1);
  EXPECT_NE(one.report.find("one distance (2.000 m)"), std::string::npos) << one.report;
  const ModelFitResult two = fit_model(rows_at({2.0, 3.5}), options);
  EXPECT_EQ(two.summary.distances, 2);
  EXPECT_EQ(two.report.find("one distance"), std::string::npos) << two.report;
  const std::vector<double> ranges{1.0, std::numeric_limits<double>::quiet_NaN(), 1.01, 3.0};
  EXPECT_EQ(distinct_distances(ranges), 2);
}

// Fewer truth groups than folds: each group is its own fold (leave one group
// out). Three plates of 12 rows and an offset fitted by least squares: too
// few rows for the calibrated kind, so sigma is the RMS of the out-of-fold
// residuals, each row's against the mean offset of the other two plates
// (worked out here). Before, cross-fitting was refused and sigma was the
// in-sample RMS (the plates' own scatter about the common mean).
TEST(ModelFit, FewerGroupsThanFoldsLeaveOneGroupOut) {
  std::mt19937_64 rng(77);
  std::normal_distribution<double> unit;
  const double metres_per_ns = ranging::metres_per_ns(ranging::TimeToDistance{});
  const double systematic[3] = {0.6e-3, -0.4e-3, 0.1e-3};
  std::vector<ranging::Record> rows;
  for (int g = 0; g < 3; ++g) {
    for (int k = 0; k < 12; ++k) {
      ranging::Record r;
      r.truth.distance_m = 1.0 + g;
      r.raw.distance_raw_m = r.truth.distance_m + 0.2 + systematic[g] + 0.1e-3 * unit(rng);
      r.raw.tof_ns = r.raw.distance_raw_m / metres_per_ns;
      r.raw.shots_valid = 100;
      r.raw.amplitude = 0.5 * (g + 1);
      r.raw.pulse_width_ns = 5.0;
      r.raw.temperature_c = 20.0;
      rows.push_back(r);
    }
  }
  ModelFitOptions options;
  options.chain = ChainSteps{true, false, false};
  options.chain_options.grayvalue.robust.loss = RobustLoss::kNone;
  options.chain_options.temperature.robust.loss = RobustLoss::kNone;
  const ModelFitResult fit = fit_model(rows, options);
  double sum2 = 0;
  for (int g = 0; g < 3; ++g) {
    double offset = 0;  // the other plates' mean raw - true
    for (const auto& r : rows) {
      if (r.truth.distance_m != 1.0 + g) offset += r.raw.distance_raw_m - r.truth.distance_m;
    }
    offset /= 24.0;
    for (const auto& r : rows) {
      if (r.truth.distance_m != 1.0 + g) continue;
      const double e = r.truth.distance_m - (r.raw.distance_raw_m - offset);
      sum2 += e * e;
    }
  }
  EXPECT_NEAR(fit.pipeline.residual_rms_m(), std::sqrt(sum2 / 36.0), 1e-9) << fit.report;
  EXPECT_NE(fit.report.find("36 out-of-fold rows"), std::string::npos) << fit.report;
}

}  // namespace
}  // namespace tofkit::calib
