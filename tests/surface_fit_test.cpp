// Correction surfaces (thesis Section 4.6 and its B-spline future work): fits
// checked against known functions and against least squares solved another way.

#include "tofkit/calib/surface_fit.hpp"

#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <functional>
#include <limits>
#include <random>
#include <stdexcept>
#include <string>
#include <vector>

#include "tofkit/calib/bspline_surface.hpp"
#include "tofkit/calib/polynomial_surface.hpp"
#include "tofkit/io/surface_json.hpp"
#include "tofkit/ranging/bspline_basis.hpp"

namespace tofkit::calib {
namespace {

/// Columns of a synthetic data set (owning), viewable as SurfaceFitData.
struct Table {
  std::vector<double> range_m, amplitude, temperature_c, error_m;
  [[nodiscard]] SurfaceInputs inputs() const { return {range_m, amplitude, temperature_c}; }
  [[nodiscard]] SurfaceFitData data() const { return {inputs(), error_m}; }
  [[nodiscard]] std::size_t size() const { return range_m.size(); }
};

using Truth = std::function<double(double r, double a, double t)>;

/// Range uniform in [1, 30] m, amplitude log-uniform in [20, 4000], temperature
/// uniform in [0, 50] C; error = truth + Gaussian noise.
Table make_table(std::size_t n, const Truth& truth, double noise_m, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  std::normal_distribution<double> gauss(0.0, 1.0);
  Table t;
  for (std::size_t k = 0; k < n; ++k) {
    const double r = 1.0 + 29.0 * unit(rng);
    const double a = 20.0 * std::pow(200.0, unit(rng));
    const double c = 50.0 * unit(rng);
    t.range_m.push_back(r);
    t.amplitude.push_back(a);
    t.temperature_c.push_back(c);
    t.error_m.push_back(truth(r, a, c) + noise_m * gauss(rng));
  }
  return t;
}

std::vector<double> evaluate(const CorrectionSurface& s, const Table& t,
                             std::vector<std::uint8_t>* flags = nullptr) {
  std::vector<double> out(t.size());
  std::vector<std::uint8_t> f(t.size());
  SurfaceInputs in = t.inputs();
  if (!s.uses_temperature()) in.temperature_c = {};
  s.evaluate(in, out, f);
  if (flags) *flags = f;
  return out;
}

// A polynomial of total degree 3 in raw units (not in the fit's scaled inputs).
double cubic_truth(double r, double a, double /*t*/) {
  return 0.02 - 1.5e-3 * r + 4e-5 * r * r - 3e-5 * a + 2e-9 * a * a + 1e-7 * r * a -
         5e-7 * r * r * r + 1e-12 * a * a * a + 2e-9 * r * r * a;
}

TEST(PolynomialSurface, RecoversKnownPolynomialFromNoiselessData) {
  const Table train = make_table(400, cubic_truth, 0.0, 1);
  const Table probe = make_table(200, cubic_truth, 0.0, 2);
  for (int order : {3, 4, 5}) {
    PolynomialFitOptions options;
    options.order = order;
    options.rcond = 0;
    const SurfaceFitResult fit = fit_polynomial_surface(train.data(), options);
    EXPECT_EQ(fit.rank, fit.parameters);
    EXPECT_LT(fit.residual_rms_m, 1e-12);
    std::vector<std::uint8_t> flags;
    const std::vector<double> value = evaluate(*fit.surface, probe, &flags);
    for (std::size_t k = 0; k < probe.size(); ++k) {
      if (flags[k]) continue;  // probe rows just outside the training box are clamped
      EXPECT_NEAR(value[k], probe.error_m[k], 1e-9) << "order " << order << " row " << k;
    }
  }
}

TEST(PolynomialSurface, MatchesLeastSquaresByAnotherDecomposition) {
  // Total-degree polynomials are closed under affine changes of each input, so
  // the least-squares fit does not depend on the scaling: solve it here with
  // the test's own (standardized) inputs and a complete orthogonal decomposition.
  const Table train = make_table(3000, cubic_truth, 0.004, 3);
  for (int order : {2, 4, 6}) {
    PolynomialFitOptions options;
    options.order = order;
    options.rcond = 0;
    const SurfaceFitResult fit = fit_polynomial_surface(train.data(), options);
    const std::size_t n = train.size();
    Eigen::MatrixXd design(n, (order + 1) * (order + 2) / 2);
    Eigen::VectorXd y(n);
    for (std::size_t k = 0; k < n; ++k) {
      const double x1 = (train.range_m[k] - 15.0) / 8.0;
      const double x2 = (train.amplitude[k] - 1000.0) / 1000.0;
      int col = 0;
      for (int i = 0; i <= order; ++i) {
        for (int j = 0; i + j <= order; ++j) design(k, col++) = std::pow(x1, i) * std::pow(x2, j);
      }
      y(k) = train.error_m[k];
    }
    const Eigen::VectorXd reference = design * design.completeOrthogonalDecomposition().solve(y);
    const std::vector<double> value = evaluate(*fit.surface, train);
    const double scale = reference.cwiseAbs().maxCoeff();
    double worst = 0;
    for (std::size_t k = 0; k < n; ++k) worst = std::max(worst, std::abs(value[k] - reference(k)));
    EXPECT_LT(worst / scale, 1e-9) << "order " << order;
    const double reference_rms = std::sqrt((y - reference).squaredNorm() / static_cast<double>(n));
    EXPECT_NEAR(fit.residual_rms_m, reference_rms, 1e-9 * reference_rms);
  }
}

TEST(PolynomialSurface, SingularValueCutoffSetsRankAndCondition) {
  // Oracle: singular values of the design with the documented scaling ([-1, 1]
  // over the training box), by a bidiagonal divide-and-conquer SVD of the full matrix.
  const Table train = make_table(2000, cubic_truth, 0.004, 4);
  const int order = 5;
  const std::size_t n = train.size();
  const auto exps = polynomial_exponents(order, false);
  const double rmin = *std::min_element(train.range_m.begin(), train.range_m.end());
  const double rmax = *std::max_element(train.range_m.begin(), train.range_m.end());
  const double amin = *std::min_element(train.amplitude.begin(), train.amplitude.end());
  const double amax = *std::max_element(train.amplitude.begin(), train.amplitude.end());
  Eigen::MatrixXd design(n, exps.size());
  for (std::size_t k = 0; k < n; ++k) {
    const double x1 = (2 * train.range_m[k] - rmin - rmax) / (rmax - rmin);
    const double x2 = (2 * train.amplitude[k] - amin - amax) / (amax - amin);
    for (std::size_t c = 0; c < exps.size(); ++c)
      design(k, c) = std::pow(x1, exps[c][0]) * std::pow(x2, exps[c][1]);
  }
  const Eigen::VectorXd sv = Eigen::BDCSVD<Eigen::MatrixXd>(design).singularValues();
  std::size_t previous_rank = exps.size() + 1;
  double previous_rms = 0;
  for (double rcond : {0.0, 1e-3, 1e-2, 3e-2, 0.1, 0.3}) {
    PolynomialFitOptions options;
    options.order = order;
    options.rcond = rcond;
    const SurfaceFitResult fit = fit_polynomial_surface(train.data(), options);
    std::size_t expected = 0;
    for (Eigen::Index k = 0; k < sv.size(); ++k) expected += sv(k) >= rcond * sv(0) ? 1 : 0;
    EXPECT_EQ(fit.rank, expected) << "rcond " << rcond;
    EXPECT_LE(fit.rank, previous_rank);
    EXPECT_GE(fit.residual_rms_m, previous_rms * (1 - 1e-12));
    EXPECT_NEAR(fit.condition_number, sv(0) / sv(sv.size() - 1), 1e-6 * fit.condition_number);
    previous_rank = fit.rank;
    previous_rms = fit.residual_rms_m;
  }
  EXPECT_LT(previous_rank, exps.size());  // the largest cutoff did drop directions
}

TEST(PolynomialSurface, ThesisRecipeOnTheNormalEquationsIsRcondOnTheDesign) {
  // Oracle: the thesis's recipe written out (Section 4.6): SVD of A^T A, S's
  // diagonal divided by its first entry, entries below 1e-2 zeroed, then
  // x = V S^-1 U^T A^T b. kThesisRcond on A must give the same surface.
  const Table train = make_table(1500, cubic_truth, 0.004, 4);
  for (const int order : {3, 4, 5, 6}) {
    const std::size_t n = train.size();
    const auto exps = polynomial_exponents(order, false);
    const double rmin = *std::min_element(train.range_m.begin(), train.range_m.end());
    const double rmax = *std::max_element(train.range_m.begin(), train.range_m.end());
    const double amin = *std::min_element(train.amplitude.begin(), train.amplitude.end());
    const double amax = *std::max_element(train.amplitude.begin(), train.amplitude.end());
    Eigen::MatrixXd a(n, exps.size());
    Eigen::VectorXd b(n);
    for (std::size_t k = 0; k < n; ++k) {
      const double x1 = (2 * train.range_m[k] - rmin - rmax) / (rmax - rmin);
      const double x2 = (2 * train.amplitude[k] - amin - amax) / (amax - amin);
      for (std::size_t c = 0; c < exps.size(); ++c)
        a(k, c) = std::pow(x1, exps[c][0]) * std::pow(x2, exps[c][1]);
      b(k) = train.error_m[k];
    }
    const Eigen::MatrixXd ata = a.transpose() * a;
    Eigen::JacobiSVD<Eigen::MatrixXd> svd(ata, Eigen::ComputeFullU | Eigen::ComputeFullV);
    const Eigen::VectorXd s = svd.singularValues() / svd.singularValues()(0);
    Eigen::VectorXd s_inv = Eigen::VectorXd::Zero(s.size());
    std::size_t rank = 0;
    for (Eigen::Index k = 0; k < s.size(); ++k) {
      if (s(k) < 1e-2) continue;  // the thesis's cutoff
      s_inv(k) = 1.0 / svd.singularValues()(k);
      ++rank;
    }
    const Eigen::VectorXd x =
        svd.matrixV() * s_inv.asDiagonal() * svd.matrixU().transpose() * (a.transpose() * b);
    const Eigen::VectorXd reference = a * x;

    PolynomialFitOptions options;
    options.order = order;
    options.rcond = kThesisRcond;
    const SurfaceFitResult fit = fit_polynomial_surface(train.data(), options);
    EXPECT_EQ(fit.rank, rank) << "order " << order;
    const std::vector<double> value = evaluate(*fit.surface, train);
    const double scale = reference.cwiseAbs().maxCoeff();
    double worst = 0;
    for (std::size_t k = 0; k < n; ++k) worst = std::max(worst, std::abs(value[k] - reference(k)));
    EXPECT_LT(worst / scale, 1e-6) << "order " << order;
  }
}

// Range walk: weak echoes read long (exponential in intensity) plus a range slope.
double walk_truth(double r, double a, double /*t*/) {
  return 0.06 * std::exp(-a / 300.0) + 1e-3 * r - 0.01;
}

TEST(BSplineSurface, ReproducesSmoothNonPolynomialFunction) {
  const double noise = 0.002;
  const Table train = make_table(20000, walk_truth, noise, 5);
  const Table probe = make_table(2000, walk_truth, 0.0, 6);
  BSplineFitOptions options;
  const SurfaceFitResult fit = fit_bspline_surface(train.data(), options);
  EXPECT_EQ(fit.parameters, std::size_t{(6 + 3) * (8 + 3)});
  EXPECT_NEAR(fit.residual_rms_m, noise, 0.05 * noise);  // neither under- nor overfitted
  std::vector<std::uint8_t> flags;
  const std::vector<double> value = evaluate(*fit.surface, probe, &flags);
  double sum = 0, worst = 0;
  std::size_t inside = 0;
  for (std::size_t k = 0; k < probe.size(); ++k) {
    if (flags[k]) continue;
    const double e = value[k] - probe.error_m[k];
    sum += e * e;
    worst = std::max(worst, std::abs(e));
    ++inside;
  }
  EXPECT_GT(inside, probe.size() * 9 / 10);
  EXPECT_LT(std::sqrt(sum / static_cast<double>(inside)), 0.2 * noise);
  EXPECT_LT(worst, noise);
  // A polynomial of order 4 (the thesis's best) cannot follow the exponential as well.
  PolynomialFitOptions poly;
  poly.order = 4;
  const SurfaceFitResult pfit = fit_polynomial_surface(train.data(), poly);
  EXPECT_GT(pfit.residual_rms_m, fit.residual_rms_m);
}

TEST(BSplineSurface, GeneralizedCrossValidationPicksAReasonableSmoothing) {
  const double noise = 0.002;
  const Table train = make_table(5000, walk_truth, noise, 7);
  BSplineFitOptions options;
  options.choose_smoothing_by_gcv = true;
  const SurfaceFitResult fit = fit_bspline_surface(train.data(), options);
  EXPECT_GE(fit.smoothing, 1e-7);
  EXPECT_LE(fit.smoothing, 10.0);
  EXPECT_LT(fit.effective_parameters, static_cast<double>(fit.parameters) + 1e-9);
  EXPECT_NEAR(fit.residual_rms_m, noise, 0.1 * noise);
}

TEST(BSplineSurface, StaysNearLinearContinuationBeyondTheDataEdge) {
  // Realistic coverage: intensity falls as reflectance / r^2, so the box's
  // corners (bright and far, dim and near) hold no data. Truth is linear there
  // (the range-walk exponential has died out); the P-spline's penalty continues
  // it smoothly, while an order-6 polynomial swings away.
  const auto truth = [](double r, double a, double) {
    return 0.06 * std::exp(-a / 300.0) + 1e-3 * r;
  };
  std::mt19937_64 rng(8);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  std::normal_distribution<double> gauss(0.0, 0.002);
  Table train;
  for (int k = 0; k < 20000; ++k) {
    const double r = 2.0 + 28.0 * unit(rng);
    const double reflectance = 0.05 + 0.9 * unit(rng);
    const double a = 4e4 * reflectance / (r * r) * (1.0 + 0.1 * unit(rng));
    train.range_m.push_back(r);
    train.amplitude.push_back(a);
    train.error_m.push_back(truth(r, a, 0) + gauss(rng));
  }
  const SurfaceFitResult spline = fit_bspline_surface(train.data(), BSplineFitOptions{});
  PolynomialFitOptions poly;
  poly.order = 6;
  const SurfaceFitResult poly6 = fit_polynomial_surface(train.data(), poly);
  // Probes just beyond the data's edge, inside the box: far ranges at amplitudes
  // 1.5x to 3x brighter than the brightest return seen there.
  Table probe;
  for (double r = 16; r <= 29; r += 1) {
    for (double f : {1.5, 2.0, 3.0}) {
      probe.range_m.push_back(r);
      probe.amplitude.push_back(f * 4e4 * 0.95 * 1.1 / (r * r));
      probe.error_m.push_back(truth(r, probe.amplitude.back(), 0));
    }
  }
  std::vector<std::uint8_t> flags;
  const std::vector<double> s = evaluate(*spline.surface, probe, &flags);
  const std::vector<double> p = evaluate(*poly6.surface, probe);
  double spline_worst = 0, poly_worst = 0;
  for (std::size_t k = 0; k < probe.size(); ++k) {
    ASSERT_EQ(flags[k], 0);
    spline_worst = std::max(spline_worst, std::abs(s[k] - probe.error_m[k]));
    poly_worst = std::max(poly_worst, std::abs(p[k] - probe.error_m[k]));
  }
  std::printf("beyond the edge: worst error bspline %.2f mm, poly6 %.2f mm\n", 1e3 * spline_worst,
              1e3 * poly_worst);
  EXPECT_LT(spline_worst, 0.005);  // bounded: within a few noise sigmas of the continuation
  EXPECT_GT(poly_worst, 2.0 * spline_worst);
}

TEST(CorrectionSurface, OutOfDomainRowsAreFlaggedAndClamped) {
  const Table train = make_table(3000, walk_truth, 0.001, 9);
  PolynomialFitOptions poly;
  poly.order = 4;
  BSplineFitOptions spline;
  spline.use_temperature = true;
  for (const auto& surface : {fit_polynomial_surface(train.data(), poly).surface,
                              fit_bspline_surface(train.data(), spline).surface}) {
    const SurfaceDomain& d = surface->domain();
    const double r_mid = 0.5 * (d.range_min_m + d.range_max_m);
    const double a_mid = std::sqrt(d.amplitude_min * d.amplitude_max);
    const double t_mid = 0.5 * (d.temperature_min_c + d.temperature_max_c);
    const double nan = std::numeric_limits<double>::quiet_NaN();
    // Rows: inside, at the corners exactly, each axis beyond each end, NaN.
    const std::vector<double> r = {r_mid,
                                   d.range_min_m,
                                   d.range_max_m,
                                   d.range_max_m + 0.5,
                                   d.range_min_m - 0.5,
                                   r_mid,
                                   r_mid,
                                   r_mid,
                                   r_mid,
                                   nan};
    const std::vector<double> a = {a_mid,
                                   d.amplitude_min,
                                   d.amplitude_max,
                                   a_mid,
                                   a_mid,
                                   d.amplitude_max * 2,
                                   d.amplitude_min * 0.5,
                                   a_mid,
                                   a_mid,
                                   a_mid};
    const std::vector<double> t = {
        t_mid, d.temperature_min_c,     d.temperature_max_c,     t_mid, t_mid, t_mid,
        t_mid, d.temperature_max_c + 1, d.temperature_min_c - 1, t_mid};
    // The same rows clamped by hand.
    const std::vector<double> rc = {r_mid,         d.range_min_m, d.range_max_m, d.range_max_m,
                                    d.range_min_m, r_mid,         r_mid,         r_mid,
                                    r_mid,         r_mid};
    const std::vector<double> ac = {
        a_mid,           d.amplitude_min, d.amplitude_max, a_mid, a_mid,
        d.amplitude_max, d.amplitude_min, a_mid,           a_mid, a_mid};
    const std::vector<double> tc = {
        t_mid, d.temperature_min_c, d.temperature_max_c, t_mid, t_mid, t_mid,
        t_mid, d.temperature_max_c, d.temperature_min_c, t_mid};
    const bool temp = surface->uses_temperature();
    std::vector<double> out(r.size()), expected(r.size());
    std::vector<std::uint8_t> flags(r.size()), expected_flags(r.size());
    surface->evaluate({r, a, temp ? std::span<const double>(t) : std::span<const double>()}, out,
                      flags);
    surface->evaluate({rc, ac, temp ? std::span<const double>(tc) : std::span<const double>()},
                      expected, expected_flags);
    const std::uint8_t tflag = temp ? 1 : 0;
    const std::vector<std::uint8_t> want = {0, 0, 0, 1, 1, 1, 1, tflag, tflag, 1};
    for (std::size_t k = 0; k < r.size(); ++k) {
      EXPECT_EQ(flags[k], want[k]) << surface->kind() << " row " << k;
      EXPECT_EQ(expected_flags[k], 0) << surface->kind() << " row " << k;
      if (k + 1 < r.size()) EXPECT_EQ(out[k], expected[k]) << surface->kind() << " row " << k;
    }
    EXPECT_TRUE(std::isnan(out.back()));
    // Mismatched lengths are refused.
    std::vector<double> short_out(r.size() - 1);
    std::vector<std::uint8_t> short_flags(r.size() - 1);
    EXPECT_THROW(surface->evaluate({r, a, t}, short_out, short_flags), std::invalid_argument);
  }
}

void expect_invalid(const std::function<void()>& f, const std::string& needle) {
  try {
    f();
    ADD_FAILURE() << "no exception; expected one mentioning '" << needle << "'";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find(needle), std::string::npos) << e.what();
  }
}

// Issue 8: a penalized spline is well posed with fewer rows than
// coefficients; knots and smoothing come from the data (GCV). Forty noisy rows
// of a smooth walk: the fitted surface must beat the noise of one row on
// fresh points inside the data's hull (it averages), and GCV's predicted RMS
// must be an honest estimate of the held-out error against noisy data.
TEST(BSplineSurface, FortyRowsFitWithDataChosenKnotsAndSmoothing) {
  const double noise = 0.002;
  const Table train = make_table(40, walk_truth, noise, 21);
  BSplineFitOptions options;
  options.choose_intervals_by_gcv = true;
  const SurfaceFitResult fit = fit_bspline_surface(train.data(), options);
  EXPECT_GT(fit.parameters, 0u);
  EXPECT_GT(fit.intervals[0], 0);
  EXPECT_GT(fit.intervals[1], 0);
  EXPECT_LT(fit.effective_parameters, 40.0);
  EXPECT_GT(fit.cv_rms_m, 0.0);
  const Table probe = make_table(2000, walk_truth, noise, 22);
  std::vector<std::uint8_t> flags;
  const std::vector<double> value = evaluate(*fit.surface, probe, &flags);
  double truth_sq = 0, noisy_sq = 0;
  std::size_t inside = 0;
  for (std::size_t k = 0; k < probe.size(); ++k) {
    if (flags[k]) continue;
    const double exact = walk_truth(probe.range_m[k], probe.amplitude[k], probe.temperature_c[k]);
    truth_sq += (value[k] - exact) * (value[k] - exact);
    noisy_sq += (value[k] - probe.error_m[k]) * (value[k] - probe.error_m[k]);
    ++inside;
  }
  ASSERT_GT(inside, probe.size() / 2);
  const double systematic = std::sqrt(truth_sq / static_cast<double>(inside));
  const double held_out = std::sqrt(noisy_sq / static_cast<double>(inside));
  EXPECT_LT(systematic, noise) << fit.summary();
  // GCV estimates the held-out RMS within a factor 1.5 either way.
  EXPECT_LT(fit.cv_rms_m, 1.5 * held_out) << fit.summary();
  EXPECT_GT(fit.cv_rms_m, held_out / 1.5) << fit.summary();
}

// Repeats of one target share its systematic error (here: a per-target
// offset the surface cannot and should not follow). GCV treats the repeats as
// independent and lets the spline chase them; cross-validation over whole
// targets does not, so its fit is closer to the truth on new targets.
TEST(BSplineSurface, GroupCrossValidationDoesNotChaseRepeats) {
  std::mt19937_64 rng(31);
  std::normal_distribution<double> gauss(0.0, 1.0);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  Table train;
  std::vector<std::uint32_t> group;
  for (std::uint32_t target = 0; target < 60; ++target) {
    const double r = 1.0 + 29.0 * unit(rng);
    const double a = 20.0 * std::pow(200.0, unit(rng));
    const double target_error = 0.003 * gauss(rng);  // shared by the target's repeats
    for (int repeat = 0; repeat < 5; ++repeat) {
      train.range_m.push_back(r + 1e-4 * gauss(rng));
      train.amplitude.push_back(a * (1.0 + 1e-3 * gauss(rng)));
      train.temperature_c.push_back(20.0);
      train.error_m.push_back(walk_truth(r, a, 0) + target_error + 0.0003 * gauss(rng));
      group.push_back(target);
    }
  }
  BSplineFitOptions options;
  options.choose_intervals_by_gcv = true;
  const SurfaceFitResult gcv = fit_bspline_surface(train.data(), options);
  SurfaceFitData grouped = train.data();
  grouped.group = group;
  const SurfaceFitResult kfold = fit_bspline_surface(grouped, options);
  const Table probe = make_table(3000, walk_truth, 0.0, 32);
  const auto systematic = [&](const SurfaceFitResult& fit) {
    std::vector<std::uint8_t> flags;
    const std::vector<double> value = evaluate(*fit.surface, probe, &flags);
    double sum = 0;
    std::size_t inside = 0;
    for (std::size_t k = 0; k < probe.size(); ++k) {
      if (flags[k]) continue;
      sum += (value[k] - probe.error_m[k]) * (value[k] - probe.error_m[k]);
      ++inside;
    }
    return std::sqrt(sum / static_cast<double>(inside));
  };
  EXPECT_LT(kfold.effective_parameters, gcv.effective_parameters) << kfold.summary() << "\n"
                                                                  << gcv.summary();
  EXPECT_LT(systematic(kfold), systematic(gcv)) << kfold.summary() << "\n" << gcv.summary();
  // The cross-validated RMS of whole targets sees the per-target error (3 mm).
  EXPECT_GT(kfold.cv_rms_m, 0.002) << kfold.summary();
}

TEST(BSplineSurface, OneDistinctValueOnAnAxisIsRefusedNamingTheAxis) {
  Table t = make_table(40, walk_truth, 0.001, 23);
  BSplineFitOptions options;
  options.choose_intervals_by_gcv = true;
  Table one_range = t;
  std::fill(one_range.range_m.begin(), one_range.range_m.end(), 3.0);
  expect_invalid([&] { (void)fit_bspline_surface(one_range.data(), options); },
                 "no spread in range_m");
  Table one_amplitude = t;
  std::fill(one_amplitude.amplitude.begin(), one_amplitude.amplitude.end(), 300.0);
  expect_invalid([&] { (void)fit_bspline_surface(one_amplitude.data(), options); },
                 "no spread in amplitude");
  // Two distinct values per axis are enough (the penalty determines the rest).
  Table two = t;
  for (std::size_t k = 0; k < two.size(); ++k) {
    two.range_m[k] = k % 2 ? 2.0 : 5.0;
    two.amplitude[k] = (k / 2) % 2 ? 100.0 : 900.0;
  }
  EXPECT_NO_THROW((void)fit_bspline_surface(two.data(), options));
}

TEST(CorrectionSurface, DegenerateDataThrowsNamingTheProblem) {
  Table small = make_table(10, walk_truth, 0.001, 10);
  PolynomialFitOptions poly;
  poly.order = 4;
  expect_invalid([&] { (void)fit_polynomial_surface(small.data(), poly); },
                 "fewer rows than parameters");
  // The B-spline's penalty makes 10 rows for 99 coefficients well posed.
  EXPECT_NO_THROW((void)fit_bspline_surface(small.data(), BSplineFitOptions{}));

  Table flat = make_table(500, walk_truth, 0.001, 11);
  std::fill(flat.range_m.begin(), flat.range_m.end(), 5.0);
  expect_invalid([&] { (void)fit_polynomial_surface(flat.data(), poly); }, "no spread in range_m");
  expect_invalid([&] { (void)fit_bspline_surface(flat.data(), BSplineFitOptions{}); },
                 "no spread in range_m");

  Table dim = make_table(500, walk_truth, 0.001, 12);
  std::fill(dim.amplitude.begin(), dim.amplitude.end(), 100.0);
  expect_invalid([&] { (void)fit_polynomial_surface(dim.data(), poly); }, "no spread in amplitude");

  Table cold = make_table(500, walk_truth, 0.001, 13);
  std::fill(cold.temperature_c.begin(), cold.temperature_c.end(), 20.0);
  PolynomialFitOptions poly_t = poly;
  poly_t.use_temperature = true;
  expect_invalid([&] { (void)fit_polynomial_surface(cold.data(), poly_t); },
                 "no spread in temperature_c");
  (void)fit_polynomial_surface(cold.data(), poly);  // fine without the temperature axis

  Table broken = make_table(500, walk_truth, 0.001, 14);
  broken.error_m[17] = std::numeric_limits<double>::quiet_NaN();
  expect_invalid([&] { (void)fit_polynomial_surface(broken.data(), poly); },
                 "non-finite error_m at row 17");
  broken.error_m[17] = 0;
  broken.amplitude[3] = std::numeric_limits<double>::infinity();
  expect_invalid([&] { (void)fit_bspline_surface(broken.data(), BSplineFitOptions{}); },
                 "non-finite amplitude at row 3");

  Table negative = make_table(500, walk_truth, 0.001, 15);
  negative.amplitude[0] = -1.0;
  expect_invalid([&] { (void)fit_bspline_surface(negative.data(), BSplineFitOptions{}); }, "log");

  Table mismatched = make_table(500, walk_truth, 0.001, 16);
  mismatched.error_m.pop_back();
  expect_invalid([&] { (void)fit_polynomial_surface(mismatched.data(), poly); }, "same length");

  PolynomialFitOptions bad_rcond;
  bad_rcond.rcond = -1;
  expect_invalid([&] { (void)fit_polynomial_surface(small.data(), bad_rcond); }, "rcond");
}

TEST(CorrectionSurface, TemperatureAxisRecoversALinearTemperatureTerm) {
  // Thesis future work: temperature in the model. Timing drift of 3.8 mm/C
  // (the paper's figure above its knee) on top of the range walk.
  const double slope = -3.8e-3;
  const auto cubic_t = [&](double r, double a, double t) {
    return cubic_truth(r, a, t) + slope * (t - 25.0);
  };
  const Table exact = make_table(600, cubic_t, 0.0, 17);
  PolynomialFitOptions poly;
  poly.order = 3;
  poly.rcond = 0;
  poly.use_temperature = true;
  const SurfaceFitResult pfit = fit_polynomial_surface(exact.data(), poly);
  EXPECT_EQ(pfit.parameters, std::size_t{20});
  EXPECT_TRUE(pfit.surface->uses_temperature());
  const Table probe = make_table(300, cubic_t, 0.0, 18);
  std::vector<std::uint8_t> flags;
  const std::vector<double> pv = evaluate(*pfit.surface, probe, &flags);
  for (std::size_t k = 0; k < probe.size(); ++k) {
    if (!flags[k]) EXPECT_NEAR(pv[k], probe.error_m[k], 1e-9);
  }

  const auto walk_t = [&](double r, double a, double t) {
    return walk_truth(r, a, t) + slope * (t - 25.0);
  };
  const Table noisy = make_table(20000, walk_t, 0.002, 19);
  BSplineFitOptions spline;
  spline.use_temperature = true;
  const SurfaceFitResult sfit = fit_bspline_surface(noisy.data(), spline);
  EXPECT_EQ(sfit.parameters, std::size_t{9 * 11 * 6});
  // The fitted temperature slope at a few interior points, by central differences.
  for (double r : {5.0, 15.0, 25.0}) {
    for (double a : {50.0, 500.0, 3000.0}) {
      const std::vector<double> rr = {r, r}, aa = {a, a}, tt = {15.0, 35.0};
      std::vector<double> v(2);
      std::vector<std::uint8_t> f(2);
      sfit.surface->evaluate({rr, aa, tt}, v, f);
      EXPECT_NEAR((v[1] - v[0]) / 20.0, slope, 0.05 * std::abs(slope)) << "r " << r << " a " << a;
    }
  }
  // Without a temperature axis the drift would stay in the residual.
  const SurfaceFitResult blind = fit_bspline_surface(noisy.data(), BSplineFitOptions{});
  EXPECT_GT(blind.residual_rms_m, 5 * sfit.residual_rms_m);
}

TEST(SurfaceJson, RoundTripGivesIdenticalEvaluations) {
  const Table train = make_table(3000, walk_truth, 0.002, 20);
  const Table probe = make_table(500, walk_truth, 0.0, 21);
  PolynomialFitOptions poly;
  poly.order = 4;
  PolynomialFitOptions poly_t = poly;
  poly_t.use_temperature = true;
  BSplineFitOptions spline;
  BSplineFitOptions spline_t;
  spline_t.use_temperature = true;
  spline_t.log_amplitude = false;
  for (const auto& fit :
       {fit_polynomial_surface(train.data(), poly), fit_polynomial_surface(train.data(), poly_t),
        fit_bspline_surface(train.data(), spline), fit_bspline_surface(train.data(), spline_t)}) {
    const std::string text = io::surface_to_json(*fit.surface).dump();
    const auto loaded = io::surface_from_json(nlohmann::json::parse(text), "test");
    EXPECT_EQ(loaded->kind(), fit.surface->kind());
    EXPECT_EQ(loaded->uses_temperature(), fit.surface->uses_temperature());
    std::vector<std::uint8_t> f1, f2;
    const std::vector<double> before = evaluate(*fit.surface, probe, &f1);
    const std::vector<double> after = evaluate(*loaded, probe, &f2);
    for (std::size_t k = 0; k < probe.size(); ++k) {
      ASSERT_EQ(before[k], after[k]) << fit.summary() << " row " << k;  // bit-identical
      ASSERT_EQ(f1[k], f2[k]);
    }
    // Training rows stay inside the domain after the round trip.
    std::vector<std::uint8_t> train_flags;
    (void)evaluate(*loaded, train, &train_flags);
    EXPECT_EQ(std::count(train_flags.begin(), train_flags.end(), 1), 0);
    const auto j = nlohmann::json::parse(text);
    EXPECT_EQ(j.at("version"), 1);
    EXPECT_EQ(j.at("fit").at("rows"), train.size());
  }
}

TEST(SurfaceJson, BadInputNamesContextAndField) {
  const Table train = make_table(1000, walk_truth, 0.002, 22);
  const nlohmann::json good =
      io::surface_to_json(*fit_bspline_surface(train.data(), BSplineFitOptions{}).surface);
  const auto expect_error = [](const nlohmann::json& j, const std::string& needle) {
    try {
      (void)io::surface_from_json(j, "model.json: steps[1]");
      ADD_FAILURE() << "no exception; expected one mentioning '" << needle << "'";
    } catch (const std::runtime_error& e) {
      const std::string what = e.what();
      EXPECT_NE(what.find("model.json: steps[1]"), std::string::npos) << what;
      EXPECT_NE(what.find(needle), std::string::npos) << what;
    }
  };
  nlohmann::json j = good;
  j.erase("coefficients");
  expect_error(j, "coefficients");
  j = good;
  j["kind"] = "spline9";
  expect_error(j, "spline9");
  j = good;
  j["version"] = 7;
  expect_error(j, "version");
  j = good;
  j["axes"]["amplitude"]["intervals"] = "eight";
  expect_error(j, "axes.amplitude.intervals");
  j = good;
  j["coefficients"].erase(0);
  expect_error(j, "coefficients");
  j = good;
  j["domain"]["range_m"] = {3.0};
  expect_error(j, "domain.range_m");
  PolynomialFitOptions poly;
  poly.order = 2;
  nlohmann::json p = io::surface_to_json(*fit_polynomial_surface(train.data(), poly).surface);
  p["exponents"][1] = {9, 9};
  expect_error(p, "exponents[1]");
}

// ------------------------------------------------------- non-uniform knots

/// Strictly increasing breakpoints with spacings drawn over a decade (0.1 .. 1).
ranging::BSplineAxis random_axis(int intervals, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> spacing(0.1, 1.0);
  ranging::BSplineAxis axis;
  axis.breakpoints = {-0.7};
  for (int k = 0; k < intervals; ++k)
    axis.breakpoints.push_back(axis.breakpoints.back() + spacing(rng));
  return axis;
}

TEST(BSplineBasis, NonUniformBasisIsAPartitionOfUnity) {
  for (int intervals : {1, 2, 3, 7, 20}) {
    const ranging::BSplineAxis axis = random_axis(intervals, 40 + intervals);
    for (int k = 0; k <= 2000; ++k) {
      const double u = axis.lo() + (axis.hi() - axis.lo()) * k / 2000.0;
      const ranging::BSplineSpan span = ranging::cubic_bspline_span(axis, u);
      ASSERT_GE(span.first, 0);
      ASSERT_LE(span.first + 3, axis.basis_count() - 1);
      double sum = 0;
      for (double w : span.weight) {
        EXPECT_GE(w, -1e-15);
        sum += w;
      }
      EXPECT_NEAR(sum, 1.0, 1e-14) << "intervals " << intervals << " u " << u;
    }
  }
}

/// Marsden's identity: (u - y)^3 = sum_i psi_i(y) B_i(u) with psi_i(y) =
/// (t_{i-2} - y)(t_{i-1} - y)(t_i - y), the product over B_i's inner knots:
/// the spline's coefficients of a cubic in closed form, for any knots.
double marsden(const ranging::BSplineAxis& axis, int i, double y) {
  return (axis.knot(i - 2) - y) * (axis.knot(i - 1) - y) * (axis.knot(i) - y);
}

TEST(BSplineBasis, NonUniformBasisReproducesCubicsExactly) {
  const ranging::BSplineAxis axis = random_axis(9, 50);
  for (double y : {-2.0, 0.3, 1.7, 6.0}) {
    for (int k = 0; k <= 500; ++k) {
      const double u = axis.lo() + (axis.hi() - axis.lo()) * k / 500.0;
      const ranging::BSplineSpan span = ranging::cubic_bspline_span(axis, u);
      double value = 0;
      for (int q = 0; q < 4; ++q) value += span.weight[q] * marsden(axis, span.first + q, y);
      const double exact = (u - y) * (u - y) * (u - y);
      EXPECT_NEAR(value, exact, 1e-12 * (1.0 + std::abs(exact))) << "y " << y << " u " << u;
    }
  }
  // A tensor-product surface with a log amplitude axis reproduces the product
  // (r - 2)^3 (ln a - 4)^3 through BSplineSurface::evaluate.
  BSplineSurfaceParams p;
  p.range = random_axis(6, 51);
  for (double& t : p.range.breakpoints) t = 1.0 + 3.0 * (t + 0.7);  // r in [1, ...]
  p.amplitude.breakpoints = {std::log(20.0), std::log(25.0),  std::log(60.0),
                             std::log(70.0), std::log(400.0), std::log(4000.0)};
  p.amplitude.log_scale = true;
  for (int i = 0; i < p.range.basis_count(); ++i) {
    for (int q = 0; q < p.amplitude.basis_count(); ++q) {
      p.coefficients.push_back(marsden(p.range, i, 2.0) * marsden(p.amplitude, q, 4.0));
    }
  }
  p.domain.range_min_m = p.range.lo();
  p.domain.range_max_m = p.range.hi();
  p.domain.amplitude_min = 20.0;
  p.domain.amplitude_max = 4000.0;
  const BSplineSurface surface(p);
  std::vector<double> r, a;
  for (int k = 0; k <= 40; ++k) {
    for (int m = 0; m <= 40; ++m) {
      r.push_back(p.range.lo() + (p.range.hi() - p.range.lo()) * k / 40.0);
      a.push_back(20.0 * std::pow(200.0, m / 40.0));
    }
  }
  std::vector<double> value(r.size());
  std::vector<std::uint8_t> flags(r.size());
  surface.evaluate({r, a, {}}, value, flags);
  for (std::size_t k = 0; k < r.size(); ++k) {
    const double exact = std::pow(r[k] - 2.0, 3) * std::pow(std::log(a[k]) - 4.0, 3);
    ASSERT_EQ(flags[k], 0);
    EXPECT_NEAR(value[k], exact, 1e-10 * (1.0 + std::abs(exact))) << r[k] << " " << a[k];
  }
}

/// The cardinal cubic B-spline weights the uniform basis used before knots
/// were stored (de Boor's uniform case in closed form), as an independent oracle.
void cardinal_weights(double t, double* w) {
  const double s = 1.0 - t;
  w[0] = s * s * s / 6.0;
  w[1] = (3.0 * t * t * t - 6.0 * t * t + 4.0) / 6.0;
  w[2] = (-3.0 * t * t * t + 3.0 * t * t + 3.0 * t + 1.0) / 6.0;
  w[3] = t * t * t / 6.0;
}

TEST(BSplineBasis, UniformKnotsGiveTheCardinalBasis) {
  for (int intervals : {1, 4, 11}) {
    const auto axis =
        ranging::BSplineAxis::uniform(std::log(20.0), std::log(4000.0), intervals, true);
    EXPECT_TRUE(axis.is_uniform());
    const double h = (axis.hi() - axis.lo()) / intervals;
    for (int k = 0; k <= 1000; ++k) {
      const double u = axis.lo() + (axis.hi() - axis.lo()) * k / 1000.0;
      const double x = (u - axis.lo()) / h;
      const int j = std::clamp(static_cast<int>(x), 0, intervals - 1);
      double w[4];
      cardinal_weights(x - j, w);
      const ranging::BSplineSpan span = ranging::cubic_bspline_span(axis, u);
      // The interval may differ only at a breakpoint, where the weights agree anyway.
      if (span.first != j) {
        EXPECT_NEAR(u, axis.knot(span.first > j ? span.first : j), 1e-12 * h);
        continue;
      }
      for (int q = 0; q < 4; ++q) EXPECT_NEAR(span.weight[q], w[q], 1e-13) << u;
    }
  }
}

// Data dense at short range (r = 1 + 29 v^3) with a wiggle there: quantile
// knots put the intervals where the rows are, and cross-validation must choose
// them for the range axis over uniform ones and report them.
TEST(BSplineSurface, CrossValidationChoosesQuantileKnotsWhereTheDataCrowd) {
  std::mt19937_64 rng(60);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  std::normal_distribution<double> gauss(0.0, 0.0005);
  const auto truth = [](double r, double a) {
    return 0.004 * std::sin(3.0 * r) / r + 0.01 * std::exp(-a / 300.0);
  };
  Table train;
  for (int k = 0; k < 3000; ++k) {
    const double v = unit(rng);
    const double r = 1.0 + 29.0 * v * v * v;
    const double a = 20.0 * std::pow(200.0, unit(rng));
    train.range_m.push_back(r);
    train.amplitude.push_back(a);
    train.error_m.push_back(truth(r, a) + gauss(rng));
  }
  BSplineFitOptions options;
  options.choose_intervals_by_gcv = true;
  const SurfaceFitResult fit = fit_bspline_surface(train.data(), options);
  EXPECT_EQ(fit.placement[0], KnotPlacement::quantile) << fit.summary();
  ASSERT_EQ(fit.knots[0].size(), static_cast<std::size_t>(fit.intervals[0]) + 1);
  // Quantile knots: data values, the ends at the data's extremes, and about
  // equal numbers of rows in each interval.
  const auto [lo, hi] = std::minmax_element(train.range_m.begin(), train.range_m.end());
  EXPECT_EQ(fit.knots[0].front(), *lo);
  EXPECT_EQ(fit.knots[0].back(), *hi);
  for (std::size_t k = 1; k < fit.knots[0].size(); ++k) {
    const auto inside = std::count_if(train.range_m.begin(), train.range_m.end(), [&](double r) {
      return r >= fit.knots[0][k - 1] && r < fit.knots[0][k];
    });
    EXPECT_NEAR(static_cast<double>(inside), 3000.0 / fit.intervals[0], 2.0) << k;
  }
  EXPECT_NE(fit.summary().find("knots range quantile ["), std::string::npos) << fit.summary();
  // Against the uniform knots of the same counts and smoothing choice, on fresh points.
  BSplineFitOptions uniform;
  uniform.intervals_range = fit.intervals[0];
  uniform.intervals_amplitude = fit.intervals[1];
  uniform.choose_smoothing_by_gcv = true;
  BSplineFitOptions quantile = uniform;
  quantile.knot_placement.fill(KnotPlacement::quantile);
  const SurfaceFitResult u = fit_bspline_surface(train.data(), uniform);
  const SurfaceFitResult q = fit_bspline_surface(train.data(), quantile);
  EXPECT_EQ(u.placement[0], KnotPlacement::uniform);
  EXPECT_LT(q.cv_rms_m, u.cv_rms_m) << q.summary() << "\n" << u.summary();
}

// A result's choices (intervals, placement per axis, smoothing, axis
// weights) given back as fixed options refit the same surface: what
// fit_model's leverage refits rely on (a refit linear in the data, without
// the cross-validated search). The data crowd at short range, so the range
// axis gets quantile knots and the amplitude axis may not.
TEST(BSplineSurface, ARefitWithAResultsChoicesReproducesItsSurface) {
  std::mt19937_64 rng(61);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  std::normal_distribution<double> gauss(0.0, 0.0005);
  Table train;
  for (int k = 0; k < 1500; ++k) {
    const double v = unit(rng);
    const double r = 1.0 + 29.0 * v * v * v, a = 20.0 * std::pow(200.0, unit(rng));
    train.range_m.push_back(r);
    train.amplitude.push_back(a);
    train.error_m.push_back(0.004 * std::sin(3.0 * r) / r + 0.01 * std::exp(-a / 300.0) +
                            gauss(rng));
  }
  BSplineFitOptions options;
  options.choose_intervals_by_gcv = true;
  const SurfaceFitResult fit = fit_bspline_surface(train.data(), options);
  BSplineFitOptions fixed;
  fixed.intervals_range = fit.intervals[0];
  fixed.intervals_amplitude = fit.intervals[1];
  fixed.smoothing = fit.smoothing;
  fixed.knot_placement = {fit.placement[0], fit.placement[1], fit.placement[2]};
  for (int k = 0; k < 3; ++k) fixed.axis_weight[k] = fit.axis_weight[k];
  const SurfaceFitResult again = fit_bspline_surface(train.data(), fixed);
  EXPECT_EQ(fit.placement[0], KnotPlacement::quantile) << fit.summary();
  for (int k = 0; k < 2; ++k) {
    EXPECT_EQ(again.placement[k], fit.placement[k]);
    EXPECT_EQ(again.knots[k], fit.knots[k]);
    EXPECT_EQ(again.axis_weight[k], fit.axis_weight[k]);
  }
  EXPECT_NEAR(again.effective_parameters, fit.effective_parameters, 1e-9);
  const std::size_t n = train.range_m.size();
  std::vector<double> a(n), b(n), t(n, 20.0);
  std::vector<std::uint8_t> fa(n), fb(n);
  fit.surface->evaluate({train.range_m, train.amplitude, t}, a, fa);
  again.surface->evaluate({train.range_m, train.amplitude, t}, b, fb);
  for (std::size_t k = 0; k < n; ++k) EXPECT_NEAR(a[k], b[k], 1e-12) << k;
  fixed.axis_weight[1] = 0;
  try {
    fixed.validate();
    ADD_FAILURE() << "axis_weight 0 accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("axis_weight[1]"), std::string::npos) << e.what();
  }
}

TEST(SurfaceJson, NonUniformKnotsRoundTripAndOldFilesLoadUniform) {
  const Table train = make_table(3000, walk_truth, 0.002, 61);
  const Table probe = make_table(500, walk_truth, 0.0, 62);
  BSplineFitOptions options;
  options.knot_placement.fill(KnotPlacement::quantile);
  options.use_temperature = true;
  const SurfaceFitResult fit = fit_bspline_surface(train.data(), options);
  const auto& spline = dynamic_cast<const BSplineSurface&>(*fit.surface);
  EXPECT_FALSE(spline.params().range.is_uniform());
  const nlohmann::json j = io::surface_to_json(*fit.surface);
  EXPECT_EQ(j.at("axes").at("amplitude").at("knots").size(),
            spline.params().amplitude.breakpoints.size());
  const auto loaded = io::surface_from_json(nlohmann::json::parse(j.dump()), "model.json");
  std::vector<std::uint8_t> f1, f2;
  const std::vector<double> before = evaluate(*fit.surface, probe, &f1);
  const std::vector<double> after = evaluate(*loaded, probe, &f2);
  for (std::size_t k = 0; k < probe.size(); ++k) {
    EXPECT_NEAR(before[k], after[k], 1e-12);
    EXPECT_EQ(f1[k], f2[k]);
  }
  // A file written before knots were stored (intervals, lo, hi only) loads
  // with uniform knots and evaluates as the same axes with the knots written out.
  const SurfaceFitResult uniform = fit_bspline_surface(train.data(), BSplineFitOptions{});
  nlohmann::json old = io::surface_to_json(*uniform.surface);
  for (auto& [name, axis] : old.at("axes").items()) axis.erase("knots");
  const auto old_loaded = io::surface_from_json(old, "old.json");
  const std::vector<double> u0 = evaluate(*uniform.surface, probe);
  const std::vector<double> u1 = evaluate(*old_loaded, probe);
  for (std::size_t k = 0; k < probe.size(); ++k) EXPECT_EQ(u0[k], u1[k]);
}

TEST(SurfaceJson, MalformedKnotsAreRefusedNamingTheKey) {
  const Table train = make_table(1000, walk_truth, 0.002, 63);
  BSplineFitOptions options;
  options.knot_placement.fill(KnotPlacement::quantile);
  const nlohmann::json good =
      io::surface_to_json(*fit_bspline_surface(train.data(), options).surface);
  const auto expect_error = [](const nlohmann::json& j, const std::string& needle) {
    try {
      (void)io::surface_from_json(j, "model.json: steps[0]");
      ADD_FAILURE() << "no exception; expected one mentioning '" << needle << "'";
    } catch (const std::runtime_error& e) {
      EXPECT_NE(std::string(e.what()).find("model.json: steps[0]" + needle), std::string::npos)
          << e.what();
    }
  };
  ASSERT_GE(good["axes"]["amplitude"]["knots"].size(), 4u);
  nlohmann::json j = good;
  j["axes"]["amplitude"]["knots"][2] = j["axes"]["amplitude"]["knots"][1];  // repeated
  expect_error(j, ".axes.amplitude.knots[2]: must be above knots[1]");
  j = good;
  std::swap(j["axes"]["range_m"]["knots"][1], j["axes"]["range_m"]["knots"][2]);  // decreasing
  expect_error(j, ".axes.range_m.knots[2]: must be above knots[1]");
  j = good;
  j["axes"]["range_m"]["knots"][1] = std::numeric_limits<double>::infinity();
  expect_error(j, ".axes.range_m.knots[1]: must be finite");
  j = good;
  j["axes"]["range_m"]["knots"][1] = nullptr;  // how a NaN is written
  expect_error(j, ".axes.range_m.knots[1]: expected a number");
  j = good;
  j["axes"]["range_m"]["knots"] = {3.0};  // fewer than a cubic axis needs
  expect_error(j, ".axes.range_m.knots: has 1 breakpoints");
  j = good;
  j["axes"]["range_m"]["knots"] = "0 1 2";
  expect_error(j, ".axes.range_m.knots: expected an array of numbers");
  // One breakpoint more: the intervals beside it disagree, and without them
  // the coefficient grid does not match the knots.
  j = good;
  auto& knots = j["axes"]["amplitude"]["knots"];
  knots.insert(knots.begin() + 1, 0.5 * (knots[0].get<double>() + knots[1].get<double>()));
  expect_error(j, ".axes.amplitude.intervals: is ");
  j["axes"]["amplitude"].erase("intervals");
  expect_error(j, ".shape[1]: must be the axis's knot intervals + 3");
  j = good;
  j["axes"]["amplitude"]["lo"] = j["axes"]["amplitude"]["knots"][0].get<double>() - 1.0;
  expect_error(j, ".axes.amplitude.lo: differs from knots[0]");
  // Without knots, the uniform axis's fields are checked.
  j = good;
  j["axes"]["range_m"].erase("knots");
  j["axes"]["range_m"]["intervals"] = 0;
  expect_error(j, ".axes.range_m.intervals: must be in [1, 1000]");
  j["axes"]["range_m"]["intervals"] = 4;
  j["axes"]["range_m"]["hi"] = j["axes"]["range_m"]["lo"];
  expect_error(j, ".axes.range_m.hi: must be finite and above lo");
}

}  // namespace
}  // namespace tofkit::calib
