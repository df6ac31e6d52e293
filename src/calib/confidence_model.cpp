#include "tofkit/calib/confidence_model.hpp"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <numeric>
#include <stdexcept>
#include <string>
#include <vector>

#include "tofkit/ranging/confidence_model.hpp"

namespace tofkit::calib {

using ranging::band_factor;

namespace {

using Eigen::Index;
using Eigen::MatrixXd;
using Eigen::VectorXd;

/// log E[y] = X beta by gamma quasi-likelihood with a log link and prior
/// weights w (McCullagh & Nelder, Generalized Linear Models, ch. 8): minimises
/// sum w (y / mu + log mu) by Fisher scoring, z = eta + (y - mu) / mu regressed
/// on X, halving steps that do not decrease the objective (it is convex in
/// beta). Unlike least squares on log(y) it needs no epsilon for zero values
/// and has no log bias.
VectorXd gamma_log_fit(const MatrixXd& design, const VectorXd& y, const VectorXd& w) {
  const Index terms = design.cols();
  const double mean_y = (w.array() * y.array()).sum() / w.sum();
  VectorXd beta = VectorXd::Zero(terms);
  beta(0) = std::log(mean_y);
  const double eta_lo = std::log(mean_y) - 60.0, eta_hi = std::log(mean_y) + 60.0;
  const auto objective = [&](const VectorXd& b, VectorXd& eta) {
    eta = (design * b).cwiseMax(eta_lo).cwiseMin(eta_hi);
    return (w.array() * (y.array() * (-eta.array()).exp() + eta.array())).sum();
  };
  const VectorXd root_w = w.cwiseSqrt();
  const Eigen::ColPivHouseholderQR<MatrixXd> qr(root_w.asDiagonal() * design);
  VectorXd eta;
  double loss = objective(beta, eta);
  for (int iteration = 0; iteration < 100; ++iteration) {
    const VectorXd z = eta.array() + y.array() * (-eta.array()).exp() - 1.0;
    const VectorXd step = qr.solve(root_w.asDiagonal() * z) - beta;
    double t = 1.0;
    VectorXd trial_eta;
    double trial_loss = objective(beta + step, trial_eta);
    while (trial_loss > loss && t > 1e-6) {
      t *= 0.5;
      trial_loss = objective(beta + t * step, trial_eta);
    }
    if (trial_loss > loss) break;
    beta += t * step;
    eta = trial_eta;
    const bool converged = loss - trial_loss <= 1e-12 * std::abs(loss) + 1e-300;
    loss = trial_loss;
    if (converged) break;
  }
  return beta;
}

/// Validates fit data; returns the amplitude and range extents. `intensity`
/// names the amplitude column in messages. need_range_spread: a range column
/// without spread is refused (with need_range); without it, the range domain
/// is widened to 1 m (a model that does not depend on range only needs a
/// valid one).
SurfaceDomain validate_data(const ConfidenceFitData& data, bool need_range, const std::string& who,
                            bool need_range_spread = true,
                            const std::string& intensity = "amplitude") {
  const std::size_t n = data.residual_m.size();
  if (data.amplitude.size() != n || (need_range && data.range_m.size() != n)) {
    throw std::invalid_argument(who + ": " + (need_range ? "range_m, " : "") + intensity +
                                " and residual_m must have the same length");
  }
  if (n == 0) throw std::invalid_argument(who + ": no rows");
  SurfaceDomain d;
  d.amplitude_min = d.range_min_m = std::numeric_limits<double>::infinity();
  d.amplitude_max = d.range_max_m = -std::numeric_limits<double>::infinity();
  for (std::size_t k = 0; k < n; ++k) {
    if (!std::isfinite(data.residual_m[k])) {
      throw std::invalid_argument(who + ": non-finite residual_m at row " + std::to_string(k));
    }
    if (!std::isfinite(data.amplitude[k])) {
      throw std::invalid_argument(who + ": non-finite " + intensity + " at row " +
                                  std::to_string(k));
    }
    d.amplitude_min = std::min(d.amplitude_min, data.amplitude[k]);
    d.amplitude_max = std::max(d.amplitude_max, data.amplitude[k]);
    if (need_range) {
      if (!std::isfinite(data.range_m[k])) {
        throw std::invalid_argument(who + ": non-finite range_m at row " + std::to_string(k));
      }
      d.range_min_m = std::min(d.range_min_m, data.range_m[k]);
      d.range_max_m = std::max(d.range_max_m, data.range_m[k]);
    }
  }
  if (!(d.amplitude_min < d.amplitude_max)) {
    throw std::invalid_argument(who + ": no spread in " + intensity);
  }
  if (need_range && !(d.range_min_m < d.range_max_m)) {
    if (need_range_spread) throw std::invalid_argument(who + ": no spread in range_m");
    d.range_max_m = d.range_min_m + 1.0;
  }
  return d;
}

/// Smallest max/min ratio of the fitting data's ranges for range terms.
constexpr double kMinRangeRatio = 1.5;

/// Monomials x^a y^b with a + b <= order.
std::vector<std::array<int, 2>> exponents_2d(int order) {
  std::vector<std::array<int, 2>> out;
  for (int degree = 0; degree <= order; ++degree) {
    for (int a = degree; a >= 0; --a) out.push_back({a, degree - a});
  }
  return out;
}

/// k-th smallest of values (0-based), by partial selection on a copy.
double order_statistic(std::vector<double> values, std::size_t k) {
  k = std::min(k, values.size() - 1);
  std::nth_element(values.begin(), values.begin() + static_cast<std::ptrdiff_t>(k), values.end());
  return values[k];
}

std::string percent(double v) {
  char buffer[32];
  std::snprintf(buffer, sizeof buffer, "%.1f %%", 100.0 * v);
  return buffer;
}

}  // namespace

int distinct_distances(std::span<const double> range_m) {
  constexpr double kGapM = 0.02;
  std::vector<double> r;
  for (double v : range_m)
    if (std::isfinite(v)) r.push_back(v);
  std::sort(r.begin(), r.end());
  int clusters = r.empty() ? 0 : 1;
  for (std::size_t k = 1; k < r.size(); ++k) clusters += r[k] - r[k - 1] > kGapM ? 1 : 0;
  return clusters;
}

// ------------------------------------------------------------------ thesis

std::shared_ptr<const ConfidenceModel> fit_thesis_confidence(
    const ConfidenceFitData& data, const ThesisConfidenceOptions& options) {
  const std::string who = "fit_thesis_confidence";
  if (options.order < 0 || options.order > 10) {
    throw std::invalid_argument("ThesisConfidenceOptions.order must be in [0, 10]");
  }
  if (!(options.floor_m2 >= 0) || !std::isfinite(options.floor_m2)) {
    throw std::invalid_argument("ThesisConfidenceOptions.floor_m2 must be finite and >= 0");
  }
  if (!(options.floor_above_amplitude >= 0) || !std::isfinite(options.floor_above_amplitude)) {
    throw std::invalid_argument(
        "ThesisConfidenceOptions.floor_above_amplitude must be finite and >= 0");
  }
  const SurfaceDomain d = validate_data(data, false, who);
  const std::size_t n = data.residual_m.size();
  const Index terms = options.order + 1;
  if (n < static_cast<std::size_t>(terms)) {
    throw std::invalid_argument(who + ": " + std::to_string(n) + " rows for " +
                                std::to_string(terms) + " coefficients");
  }
  ThesisConfidenceParams p;
  p.amplitude_min = d.amplitude_min;
  p.amplitude_max = d.amplitude_max;
  p.amplitude_scaling = AxisScaling::over(d.amplitude_min, d.amplitude_max);
  p.rows = n;
  // Least squares of E^2 = (T - Rc)^2 on a polynomial in intensity (thesis: cubic).
  MatrixXd design(static_cast<Index>(n), terms);
  VectorXd e2(static_cast<Index>(n));
  double mean_e2 = 0;
  for (std::size_t k = 0; k < n; ++k) {
    const double x = p.amplitude_scaling.apply(data.amplitude[k]);
    double power = 1;
    for (Index j = 0; j < terms; ++j, power *= x) design(static_cast<Index>(k), j) = power;
    e2(static_cast<Index>(k)) = data.residual_m[k] * data.residual_m[k];
    mean_e2 += e2(static_cast<Index>(k));
  }
  mean_e2 /= static_cast<double>(n);
  if (!(mean_e2 > 0)) throw std::invalid_argument(who + ": every residual is zero");
  const VectorXd c = design.colPivHouseholderQr().solve(e2);
  p.coefficients.assign(c.data(), c.data() + c.size());
  p.floor_m2 = options.floor_m2 > 0 ? options.floor_m2 : 0.05 * mean_e2;
  p.floor_above_amplitude = options.floor_above_amplitude;
  return std::make_shared<const ThesisConfidence>(std::move(p));
}

// -------------------------------------------------------------- calibrated

void CalibratedConfidenceOptions::validate() const {
  if (!(target_coverage_2sigma > 0.5 && target_coverage_2sigma < 1)) {
    throw std::invalid_argument(
        "CalibratedConfidenceOptions.target_coverage_2sigma must be in (0.5, 1)");
  }
  if (order < 0 || order > 6) {
    throw std::invalid_argument("CalibratedConfidenceOptions.order must be in [0, 6]");
  }
  if (intensity_bands < 1 || intensity_bands > 100) {
    throw std::invalid_argument("CalibratedConfidenceOptions.intensity_bands must be in [1, 100]");
  }
}

std::shared_ptr<const ConfidenceModel> fit_calibrated_confidence(
    const ConfidenceFitData& data, const CalibratedConfidenceOptions& options) {
  options.validate();
  const std::string who = "fit_calibrated_confidence";
  const SurfaceDomain d = validate_data(data, true, who);
  if (options.log_amplitude && !(d.amplitude_min > 0)) {
    throw std::invalid_argument(who + ": amplitude must be positive with log_amplitude");
  }
  const std::size_t n = data.residual_m.size();
  CalibratedConfidenceParams p;
  p.exponents = exponents_2d(options.order);
  // Range terms only when the data span ranges: rows at one distance (plates
  // at one distance, the paper's protocol) cannot tell how the noise depends
  // on range, and a polynomial in their narrow range spread would be
  // extrapolated (clamped, but at its worst edge value) everywhere else.
  if (!(d.range_max_m >= kMinRangeRatio * d.range_min_m)) {
    std::erase_if(p.exponents, [](const std::array<int, 2>& e) { return e[1] != 0; });
  }
  // No power of range the distances cannot pin down: range^k needs k + 1 of
  // them. With fewer, higher powers are free between them (at two distances
  // y^2 equals 1 and y^3 equals y on both; their coefficients may cancel
  // there and explode, or sink, between).
  const int distances = distinct_distances(data.range_m);
  std::erase_if(p.exponents, [&](const std::array<int, 2>& e) { return e[1] >= distances; });
  p.log_amplitude = options.log_amplitude;
  p.domain = d;
  p.target_coverage_2sigma = options.target_coverage_2sigma;
  p.rows = n;
  const Index terms = static_cast<Index>(p.exponents.size());
  const std::size_t min_rows = std::max<std::size_t>(50, 10 * static_cast<std::size_t>(terms));
  if (n < min_rows) {
    throw std::invalid_argument(who + ": " + std::to_string(n) + " rows; at least " +
                                std::to_string(min_rows) + " are needed to calibrate coverage");
  }
  const auto coordinate = [&](double a) { return options.log_amplitude ? std::log(a) : a; };
  p.amplitude_scaling = AxisScaling::over(coordinate(d.amplitude_min), coordinate(d.amplitude_max));
  p.range_scaling = AxisScaling::over(d.range_min_m, d.range_max_m);

  std::vector<double> u(n), xs(n), ys(n);
  VectorXd e2(static_cast<Index>(n));
  double mean_e2 = 0;
  for (std::size_t k = 0; k < n; ++k) {
    u[k] = coordinate(data.amplitude[k]);
    xs[k] = p.amplitude_scaling.apply(u[k]);
    ys[k] = p.range_scaling.apply(data.range_m[k]);
    e2(static_cast<Index>(k)) = data.residual_m[k] * data.residual_m[k];
    mean_e2 += e2(static_cast<Index>(k));
  }
  mean_e2 /= static_cast<double>(n);
  if (!(mean_e2 > 0)) throw std::invalid_argument(who + ": every residual is zero");

  // 1. log E[e^2] = X beta by gamma quasi-likelihood (unit weights). Terms the
  //    rows do not pin down (plates at one distance and a temperature run of
  //    one plate at another show how the variance changes with range at one
  //    intensity only) show as a fitted sigma somewhere in the domain (the box
  //    the model is evaluated in) over 4 x the rows' largest or under 1/4 of
  //    their smallest: then the terms in range and intensity together go, and
  //    if need be every range term, and the fit is repeated.
  constexpr double kMaxExcess = 2.772588722239781;  // ln 16: sigma 4 x beyond the rows'
  constexpr int kGrid = 33;
  VectorXd beta, eta;
  for (int stage = 0;; ++stage) {
    const auto columns = static_cast<Index>(p.exponents.size());
    MatrixXd design(static_cast<Index>(n), columns);
    for (std::size_t k = 0; k < n; ++k) {
      for (Index j = 0; j < columns; ++j) {
        const auto& e = p.exponents[static_cast<std::size_t>(j)];
        design(static_cast<Index>(k), j) = std::pow(xs[k], e[0]) * std::pow(ys[k], e[1]);
      }
    }
    beta = gamma_log_fit(design, e2, VectorXd::Ones(static_cast<Index>(n)));
    p.coefficients.assign(beta.data(), beta.data() + beta.size());
    // The fitted log-variance (within the fit's clamp of +-60 around the mean's log).
    eta = (design * beta).cwiseMax(std::log(mean_e2) - 60.0).cwiseMin(std::log(mean_e2) + 60.0);
    double box_max = -std::numeric_limits<double>::infinity();
    double box_min = std::numeric_limits<double>::infinity();
    for (int i = 0; i < kGrid; ++i) {
      for (int j = 0; j < kGrid; ++j) {
        const double v =
            ranging::polynomial_2d(p.exponents, p.coefficients, -1.0 + 2.0 * i / (kGrid - 1),
                                   -1.0 + 2.0 * j / (kGrid - 1));
        box_max = std::max(box_max, v);
        box_min = std::min(box_min, v);
      }
    }
    if (stage == 2 ||
        (box_max <= eta.maxCoeff() + kMaxExcess && box_min >= eta.minCoeff() - kMaxExcess))
      break;
    std::erase_if(p.exponents, [&](const std::array<int, 2>& e) {
      return e[1] > 0 && (stage == 1 || e[0] > 0);
    });
  }

  // 2. Coverage per intensity band: bands of equal counts along u; k at each
  //    band centre (median u) is set so that the band's share of
  //    |e| <= 2 k(u) sigma_hat equals the target, with k(u) interpolated
  //    between the centres (log-linear). Since k(u) within a band depends on
  //    its neighbours, the factors are refined by a few fixed-point passes.
  std::vector<std::size_t> order(n);
  std::iota(order.begin(), order.end(), std::size_t{0});
  std::sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) { return u[a] < u[b]; });
  const std::size_t bands = std::clamp<std::size_t>(
      std::min<std::size_t>(static_cast<std::size_t>(options.intensity_bands), n / 200), 1, 100);
  std::vector<std::size_t> band_begin(bands + 1);
  for (std::size_t b = 0; b <= bands; ++b) band_begin[b] = n * b / bands;
  std::vector<double> centre, scale;
  for (std::size_t b = 0; b < bands; ++b) {
    const double c = u[order[(band_begin[b] + band_begin[b + 1]) / 2]];
    if (!centre.empty() && !(c > centre.back())) continue;  // ties in u: merge bands
    centre.push_back(c);
  }
  // Re-derive band edges from the unique centres (midpoints between centres).
  const std::size_t used = centre.size();
  std::vector<std::vector<std::size_t>> members(used);
  for (std::size_t k = 0; k < n; ++k) {
    const auto it = std::upper_bound(centre.begin(), centre.end(), u[k]);
    std::size_t b = static_cast<std::size_t>(it - centre.begin());
    if (b == used)
      b = used - 1;
    else if (b > 0 && u[k] - centre[b - 1] < centre[b] - u[k])
      b = b - 1;
    members[b].push_back(k);
  }
  std::vector<double> z(n);  // |e| / sigma_hat
  for (std::size_t k = 0; k < n; ++k)
    z[k] = std::abs(data.residual_m[k]) * std::exp(-0.5 * eta(static_cast<Index>(k)));
  scale.assign(used, 1.0);
  const double target = options.target_coverage_2sigma;
  for (int pass = 0; pass < 8; ++pass) {
    for (std::size_t b = 0; b < used; ++b) {
      if (members[b].empty()) continue;
      std::vector<double> ratio;
      ratio.reserve(members[b].size());
      for (std::size_t k : members[b]) ratio.push_back(z[k] / band_factor(centre, scale, u[k]));
      // Smallest r with share(ratio <= r) >= target; the band's factor is scaled by r / 2.
      const std::size_t m = ratio.size();
      const auto index = static_cast<std::size_t>(std::ceil(target * static_cast<double>(m))) - 1;
      const double r = order_statistic(std::move(ratio), index);
      if (r > 0) scale[b] *= r / 2.0;
    }
  }
  // Drop empty bands (possible only with heavy ties).
  for (std::size_t b = 0; b < used; ++b) {
    if (!members[b].empty()) {
      p.band_coordinate.push_back(centre[b]);
      p.band_scale.push_back(scale[b]);
    }
  }
  std::size_t covered = 0;
  for (std::size_t k = 0; k < n; ++k) {
    covered += z[k] <= 2.0 * band_factor(p.band_coordinate, p.band_scale, u[k]) ? 1 : 0;
  }
  p.fit_coverage_2sigma = static_cast<double>(covered) / static_cast<double>(n);
  return std::make_shared<const CalibratedConfidence>(std::move(p));
}

// -------------------------------------------------------- noise + systematic

namespace {

MatrixXd power_design(const std::vector<double>& x, int order) {
  MatrixXd d(static_cast<Index>(x.size()), order + 1);
  for (std::size_t i = 0; i < x.size(); ++i) {
    double power = 1;
    for (int k = 0; k <= order; ++k, power *= x[i]) d(static_cast<Index>(i), k) = power;
  }
  return d;
}

/// Variance components by maximum likelihood: target means m_g ~ N(0, v_g),
/// v_g = exp(x_g^T beta) + nu_g with nu_g (the noise of a mean) known; log s^2
/// a polynomial of degree 0 .. max_order in x, the degree chosen by BIC.
/// Fisher scoring in beta (information sum (s^2 / v)^2 x x^T / 2), steps halved
/// until the likelihood rises. Unlike a log fit of m^2 - nu (negative where
/// the noise explains a mean, so floored), no floor pulls the curve.
VectorXd systematic_log_fit(const std::vector<double>& x, const std::vector<double>& m2,
                            const std::vector<double>& nu, int max_order) {
  const Index g = static_cast<Index>(x.size());
  double excess = 0, m2_mean = 0;
  for (Index i = 0; i < g; ++i) {
    excess += (m2[static_cast<std::size_t>(i)] - nu[static_cast<std::size_t>(i)]) / double(g);
    m2_mean += m2[static_cast<std::size_t>(i)] / double(g);
  }
  // log s^2 is kept within 30 e-folds below the mean square (s^2 -> 0 is a boundary).
  const double eta_lo = std::log(m2_mean + 1e-300) - 30.0,
               eta_hi = std::log(m2_mean + 1e-300) + 5.0;
  VectorXd best;
  double best_bic = std::numeric_limits<double>::infinity();
  for (int order = 0; order <= std::max(0, max_order); ++order) {
    const MatrixXd design = power_design(x, order);
    const auto nll = [&](const VectorXd& b, VectorXd& eta) {
      eta = (design * b).cwiseMax(eta_lo).cwiseMin(eta_hi);
      double sum = 0;
      for (Index i = 0; i < g; ++i) {
        const double v = std::exp(eta(i)) + nu[static_cast<std::size_t>(i)];
        sum += 0.5 * (std::log(v) + m2[static_cast<std::size_t>(i)] / v);
      }
      return sum;
    };
    VectorXd beta = VectorXd::Zero(order + 1);
    beta(0) = std::clamp(std::log(std::max(excess, 1e-3 * m2_mean) + 1e-300), eta_lo, eta_hi);
    VectorXd eta;
    double loss = nll(beta, eta);
    for (int iteration = 0; iteration < 200; ++iteration) {
      VectorXd score = VectorXd::Zero(order + 1);
      MatrixXd information = MatrixXd::Zero(order + 1, order + 1);
      for (Index i = 0; i < g; ++i) {
        const double s2 = std::exp(eta(i));
        const double v = s2 + nu[static_cast<std::size_t>(i)];
        const double r = s2 / v;
        score += 0.5 * r * (1.0 - m2[static_cast<std::size_t>(i)] / v) * design.row(i).transpose();
        information += 0.5 * r * r * design.row(i).transpose() * design.row(i);
      }
      information.diagonal().array() += 1e-12 * information.diagonal().maxCoeff() + 1e-300;
      const VectorXd step = -information.ldlt().solve(score);
      double t = 1.0, trial_loss = loss;
      VectorXd trial_eta;
      for (; t > 1e-6; t *= 0.5) {
        trial_loss = nll(beta + t * step, trial_eta);
        if (trial_loss < loss) break;
      }
      if (!(trial_loss < loss)) break;
      beta += t * step;
      eta = trial_eta;
      const bool converged = loss - trial_loss <= 1e-12 * std::abs(loss) + 1e-300;
      loss = trial_loss;
      if (converged) break;
    }
    const double bic = 2.0 * loss + static_cast<double>(order + 1) * std::log(double(g));
    if (bic < best_bic) {
      best_bic = bic;
      best = beta;
    }
  }
  return best;
}

}  // namespace

void NoiseSystematicOptions::validate() const {
  if (order < 0 || order > 6) {
    throw std::invalid_argument("NoiseSystematicOptions.order must be in [0, 6]");
  }
  if (!(optimism >= 1) || !std::isfinite(optimism)) {
    throw std::invalid_argument("NoiseSystematicOptions.optimism must be finite and >= 1");
  }
}

std::shared_ptr<const ConfidenceModel> fit_noise_systematic_confidence(
    const NoiseSystematicFitData& data, const NoiseSystematicOptions& options) {
  options.validate();
  const std::string who = "fit_noise_systematic_confidence";
  const std::size_t n = data.residual_m.size();
  if (data.group.size() != n) {
    throw std::invalid_argument(who + ": group and residual_m differ in length");
  }
  const bool pointwise = !data.leverage.empty();
  if (pointwise) {
    if (data.leverage.size() != n) {
      throw std::invalid_argument(who + ": leverage and residual_m differ in length");
    }
    if (options.optimism != 1.0) {
      throw std::invalid_argument(who + ": leverage and an optimism other than 1 are exclusive");
    }
    for (std::size_t k = 0; k < n; ++k) {
      if (!(data.leverage[k] >= 0 && data.leverage[k] < 1)) {
        throw std::invalid_argument(who + ": leverage at row " + std::to_string(k) +
                                    " must be in [0, 1)");
      }
    }
  }
  // (Intensity in the amplitude's place; sigma does not depend on range here.)
  const SurfaceDomain d =
      validate_data({data.range_m, data.intensity, data.residual_m}, true, who, false, "intensity");
  if (!(d.amplitude_min > 0)) {
    throw std::invalid_argument(who + ": intensity must be positive (a log axis)");
  }

  CalibratedConfidenceParams p;
  p.intensity = options.intensity;
  p.log_amplitude = true;
  p.domain = d;
  p.rows = n;
  p.amplitude_scaling = AxisScaling::over(std::log(d.amplitude_min), std::log(d.amplitude_max));
  p.range_scaling = AxisScaling::over(d.range_min_m, d.range_max_m);

  // Per target: rows, mean log intensity, mean and sample variance of the residual.
  struct Target {
    std::size_t rows = 0;
    double u = 0, sum = 0, sum2 = 0, leverage = 0;
  };
  std::vector<Target> targets;
  std::vector<std::size_t> index_of;  // group id -> index in targets (+1; 0: none yet)
  for (std::size_t k = 0; k < n; ++k) {
    const std::uint32_t g = data.group[k];
    if (g >= index_of.size()) index_of.resize(g + 1, 0);
    if (index_of[g] == 0) {
      targets.emplace_back();
      index_of[g] = targets.size();
    }
    Target& t = targets[index_of[g] - 1];
    ++t.rows;
    t.u += std::log(data.intensity[k]);
    t.sum += data.residual_m[k];
    if (pointwise) t.leverage += data.leverage[k];
  }
  for (Target& t : targets) {
    t.u /= static_cast<double>(t.rows);
    t.sum /= static_cast<double>(t.rows);  // now the mean
    t.leverage = std::min(t.leverage / static_cast<double>(t.rows), kMaxLeverage);
  }
  for (std::size_t k = 0; k < n; ++k) {
    Target& t = targets[index_of[data.group[k]] - 1];
    t.sum2 += (data.residual_m[k] - t.sum) * (data.residual_m[k] - t.sum);
  }
  std::vector<double> x_rep, var, dof, x_all, mean2, rows_of;
  for (const Target& t : targets) {
    const double x = p.amplitude_scaling.apply(t.u);
    x_all.push_back(x);
    // Pointwise optimism: the in-sample mean's variance (s^2 + nu)(1 - h)
    // scaled to a new target's (s^2 + nu)(1 + h); nu is kept below, so the
    // fitted excess is s^2 (1 + h) + nu h.
    mean2.push_back(t.sum * t.sum * (1.0 + t.leverage) / (1.0 - t.leverage));
    rows_of.push_back(static_cast<double>(t.rows));
    if (t.rows < 2) continue;
    x_rep.push_back(x);
    var.push_back(t.sum2 / static_cast<double>(t.rows - 1));
    dof.push_back(static_cast<double>(t.rows - 1));
  }
  const auto order_for = [&](std::size_t count) {
    return std::min(options.order, static_cast<int>(count / 10) - 1);
  };
  const int noise_order = order_for(x_rep.size());
  if (noise_order < 0) {
    throw std::invalid_argument(who + ": " + std::to_string(x_rep.size()) +
                                " targets with repeats; at least 10 are needed for the noise");
  }
  double var_sum = 0;
  for (double v : var) var_sum += v;
  if (!(var_sum > 0)) throw std::invalid_argument(who + ": the repeats do not scatter");
  const VectorXd noise = gamma_log_fit(power_design(x_rep, noise_order),
                                       Eigen::Map<const VectorXd>(var.data(), Index(var.size())),
                                       Eigen::Map<const VectorXd>(dof.data(), Index(dof.size())));
  const auto noise2_at = [&](double x) {
    double v = 0, power = 1;
    for (Index k = 0; k < noise.size(); ++k, power *= x) v += noise(k) * power;
    return std::exp(v);
  };
  // Systematic: each target's mean residual m ~ N(0, s^2(x) + noise^2(x) / n),
  // log s^2 a polynomial of the order BIC prefers (0 .. the data's).
  std::vector<double> noise_of_mean(x_all.size());
  for (std::size_t i = 0; i < x_all.size(); ++i)
    noise_of_mean[i] = noise2_at(x_all[i]) / rows_of[i];
  const VectorXd systematic =
      systematic_log_fit(x_all, mean2, noise_of_mean, order_for(x_all.size()));
  for (Index k = 0; k < noise.size(); ++k) {
    p.exponents.push_back({static_cast<int>(k), 0});
    p.coefficients.push_back(noise(k));
  }
  for (Index k = 0; k < systematic.size(); ++k) {
    p.systematic_exponents.push_back({static_cast<int>(k), 0});
    // A new target's systematic error: the calibration targets' times the optimism.
    p.systematic_coefficients.push_back(systematic(k) + (k == 0 ? std::log(options.optimism) : 0));
  }
  std::vector<double> u_sorted;
  for (std::size_t k = 0; k < n; ++k) u_sorted.push_back(std::log(data.intensity[k]));
  p.band_coordinate = {order_statistic(u_sorted, n / 2)};
  p.band_scale = {1.0};
  p.target_coverage_2sigma = 0.95;
  auto model = std::make_shared<const CalibratedConfidence>(p);
  std::vector<double> sigma(n);
  model->sigma(data.range_m, data.intensity, sigma);
  std::size_t covered = 0;
  for (std::size_t k = 0; k < n; ++k) covered += std::abs(data.residual_m[k]) <= 2 * sigma[k];
  p.fit_coverage_2sigma = static_cast<double>(covered) / static_cast<double>(n);
  return std::make_shared<const CalibratedConfidence>(std::move(p));
}

// ---------------------------------------------------------------- coverage

std::string ConfidenceCoverage::summary() const {
  return std::to_string(rows) + " rows: " + percent(within_2sigma) + " within 2 sigma (terciles " +
         percent(within_2sigma_by_tercile[0]) + ", " + percent(within_2sigma_by_tercile[1]) + ", " +
         percent(within_2sigma_by_tercile[2]) + ")";
}

ConfidenceCoverage coverage_2sigma(const ConfidenceModel& model, const ConfidenceFitData& data) {
  const std::size_t n = data.residual_m.size();
  if (data.range_m.size() != n || data.amplitude.size() != n) {
    throw std::invalid_argument(
        "coverage_2sigma: range_m, amplitude and residual_m differ in length");
  }
  ConfidenceCoverage c;
  c.rows = n;
  if (n == 0) return c;
  std::vector<double> sigma(n);
  model.sigma(data.range_m, data.amplitude, sigma);
  std::vector<double> amplitude(data.amplitude.begin(), data.amplitude.end());
  c.tercile_edges[0] = order_statistic(amplitude, n / 3);
  c.tercile_edges[1] = order_statistic(amplitude, 2 * n / 3);
  std::array<std::size_t, 3> inside{}, count{};
  std::size_t total = 0;
  double sigma_sum = 0;
  for (std::size_t k = 0; k < n; ++k) {
    const std::size_t t = data.amplitude[k] < c.tercile_edges[0]   ? 0
                          : data.amplitude[k] < c.tercile_edges[1] ? 1
                                                                   : 2;
    const bool ok = std::abs(data.residual_m[k]) <= 2.0 * sigma[k];
    ++count[t];
    inside[t] += ok ? 1 : 0;
    total += ok ? 1 : 0;
    sigma_sum += sigma[k];
  }
  c.within_2sigma = static_cast<double>(total) / static_cast<double>(n);
  for (std::size_t t = 0; t < 3; ++t) {
    c.within_2sigma_by_tercile[t] =
        count[t] ? static_cast<double>(inside[t]) / static_cast<double>(count[t]) : 0.0;
  }
  c.mean_sigma_m = sigma_sum / static_cast<double>(n);
  return c;
}

}  // namespace tofkit::calib
