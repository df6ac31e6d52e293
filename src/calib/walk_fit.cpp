#include "tofkit/calib/walk_fit.hpp"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <random>
#include <stdexcept>
#include <utility>
#include <vector>

namespace tofkit::calib {
namespace {

constexpr std::size_t kMinWalkRows = 6;
/// Distinct unclipped shapes from which the clipped fit starts.
constexpr std::size_t kClippingShapeStarts = 3;
/// A bootstrap replicate's refit stops when a step gains less than this part of its SSE.
constexpr double kReplicateTolerance = 1e-6;
/// Bounds of the log-parameters: times 0.005-200 ns, within a factor 30 of each other.
constexpr double kMinLogTime = -5.3, kMaxLogTime = 5.3, kMaxLogRatio = 3.4;

/// Parameters: [constant, ln sigma, ln tau] or, with clipping,
/// [constant, ln sigma, ln tau, ln tau_r, w_sat]. The clipping onset is
/// fitted as the pulse width w_sat at which echoes start to clip, bounded by
/// the rows' flags to lie between the widest unclipped and the narrowest
/// clipped echo; the unclipped shape turns it into ln a_sat. (An onset free in
/// ln a trades off against the shape's exponential tail, which also widens
/// strong echoes like ln a: the fit could then explain clipped rows as
/// unclipped.)
ranging::WalkShape shape_of(const Eigen::VectorXd& p) {
  ranging::WalkShape s;
  s.pulse_sigma_ns = std::exp(p(1));
  s.pole_time_constant_ns = std::exp(p(2));
  if (p.size() > 3) {
    const ranging::WalkCurve free = ranging::walk_curve(s, 600);
    const std::vector<double>& w = free.width_ns;
    const double saturation_width_ns = p(4);
    const auto it = std::upper_bound(w.begin(), w.end(), saturation_width_ns);
    const auto k = static_cast<std::size_t>(
        std::clamp<std::ptrdiff_t>(it - w.begin(), 1, static_cast<std::ptrdiff_t>(w.size()) - 1));
    const double f = std::clamp((saturation_width_ns - w[k - 1]) / (w[k] - w[k - 1]), 0.0, 1.0);
    s.saturation_log_overdrive =
        free.log_overdrive[k - 1] + f * (free.log_overdrive[k] - free.log_overdrive[k - 1]);
    s.recovery_ns_per_neper = std::exp(p(3));
  }
  return s;
}

void clamp_parameters(Eigen::VectorXd& p, double onset_min_ns, double onset_max_ns) {
  p(1) = std::clamp(p(1), kMinLogTime, kMaxLogTime);
  p(2) = std::clamp(p(2), std::max(kMinLogTime, p(1) - kMaxLogRatio),
                    std::min(kMaxLogTime, p(1) + kMaxLogRatio));
  if (p.size() > 3) {
    p(3) = std::clamp(p(3), -7.0, 5.0);
    p(4) = std::clamp(p(4), onset_min_ns, onset_max_ns);
  }
}

struct Problem {
  std::span<const double> w, e;
  std::vector<std::size_t> rows;  ///< rows in this stage
  double reference = 0, metres_per_ns = 0;
  double onset_min_ns = 0, onset_max_ns = 0;  ///< bounds of w_sat (with clipping)
  /// Amplitude readings (the peak detector, linear in the echo below the
  /// clip level, so ln A = ln a + ln V_th): on the unclipped rows
  /// `amplitude_rows` the shape's ln a at each row's width must follow ln A up
  /// to one constant (profiled out: the block's mean is removed). These
  /// residuals, in nepers, enter times `amplitude_weight` (metres per neper;
  /// 0: the block is not used).
  std::span<const double> amplitude;
  std::vector<std::size_t> amplitude_rows;
  double amplitude_weight = 0;

  /// residual_i = constant - (c_air / 2) (t_rise(w_i) - t_rise(w_ref)) - e_i for
  /// `shape`; false when the shape cannot be tabulated.
  bool residuals(const ranging::WalkShape& shape, double constant, Eigen::VectorXd& r) const {
    ranging::WalkCurve curve;
    try {
      curve = ranging::walk_curve(shape, 600);
    } catch (const std::invalid_argument&) {
      return false;
    }
    const double rise_ref = ranging::rise_at_width(curve, reference);
    const std::size_t m = amplitude_weight > 0 ? amplitude_rows.size() : 0;
    r.resize(static_cast<Eigen::Index>(rows.size() + m));
    for (std::size_t k = 0; k < rows.size(); ++k) {
      const std::size_t i = rows[k];
      const double model =
          constant - metres_per_ns * (ranging::rise_at_width(curve, w[i]) - rise_ref);
      r(static_cast<Eigen::Index>(k)) = model - e[i];
    }
    if (m > 0) {
      auto tail = r.tail(static_cast<Eigen::Index>(m));
      for (std::size_t k = 0; k < m; ++k) {
        const std::size_t i = amplitude_rows[k];
        tail(static_cast<Eigen::Index>(k)) =
            ranging::curve_at_width(curve, curve.log_overdrive, w[i]) - std::log(amplitude[i]);
      }
      tail.array() -= tail.mean();
      tail *= amplitude_weight;
    }
    return r.allFinite();
  }
  /// The walk rows' and the amplitude rows' sums of squares (unweighted: m^2
  /// and nepers^2) of a residual vector.
  [[nodiscard]] std::pair<double, double> block_sse(const Eigen::VectorXd& r) const {
    const auto n = static_cast<Eigen::Index>(rows.size());
    const double walk = r.head(n).squaredNorm();
    if (!(amplitude_weight > 0) || r.size() == n) return {walk, 0.0};
    return {walk, r.tail(r.size() - n).squaredNorm() / (amplitude_weight * amplitude_weight)};
  }
  /// The same for the fit's parameter vector p (p(0): the constant).
  bool residuals(const Eigen::VectorXd& p, Eigen::VectorXd& r) const {
    ranging::WalkShape shape;
    try {
      shape = shape_of(p);
    } catch (const std::invalid_argument&) {
      return false;
    }
    return residuals(shape, p(0), r);
  }
};

struct LmResult {
  Eigen::VectorXd p;
  double sse = std::numeric_limits<double>::infinity();       ///< of the (weighted) residuals
  double walk_sse = std::numeric_limits<double>::infinity();  ///< of the walk rows alone
  /// What minima are ranked by: sse, or with amplitude rows the profile
  /// likelihood of the two blocks (each with its own variance; fit_from).
  double score = std::numeric_limits<double>::infinity();
  double amplitude_weight = 0;  ///< the weight the fit ended with
  int iterations = 0;
  bool converged = false;
};

/// Levenberg-Marquardt with Marquardt's diagonal scaling and a forward-difference Jacobian.
/// Converged when a step lowers the SSE by less than `tolerance` of it.
LmResult levenberg_marquardt(const Problem& problem, Eigen::VectorXd p, int max_iterations,
                             double tolerance = 1e-10) {
  LmResult out;
  clamp_parameters(p, problem.onset_min_ns, problem.onset_max_ns);
  Eigen::VectorXd r;
  if (!problem.residuals(p, r)) return out;
  double sse = r.squaredNorm();
  double lambda = 1e-3;
  const Eigen::Index m = p.size();
  Eigen::MatrixXd jacobian(r.size(), m);
  Eigen::VectorXd r_step;
  int it = 0;
  for (; it < max_iterations; ++it) {
    for (Eigen::Index k = 0; k < m; ++k) {
      // Constant: in metres (1e-5 m); log-parameters: 1e-4 relative.
      const double h = k == 0 ? 1e-5 : 1e-4;
      Eigen::VectorXd q = p;
      q(k) += h;
      if (!problem.residuals(q, r_step)) {
        q(k) = p(k) - h;
        if (!problem.residuals(q, r_step)) return out;
        jacobian.col(k) = (r - r_step) / h;
      } else {
        jacobian.col(k) = (r_step - r) / h;
      }
    }
    const Eigen::MatrixXd jtj = jacobian.transpose() * jacobian;
    const Eigen::VectorXd gradient = jacobian.transpose() * r;
    bool improved = false;
    while (lambda < 1e12) {
      Eigen::MatrixXd a = jtj;
      a.diagonal() += lambda * jtj.diagonal().cwiseMax(1e-12 * jtj.diagonal().maxCoeff());
      Eigen::VectorXd q = p - a.ldlt().solve(gradient);
      clamp_parameters(q, problem.onset_min_ns, problem.onset_max_ns);
      if (problem.residuals(q, r_step) && r_step.squaredNorm() < sse) {
        const double gain = sse - r_step.squaredNorm();
        const double step_size = (q - p).cwiseAbs().maxCoeff();
        p = q;
        r = r_step;
        sse = r.squaredNorm();
        lambda = std::max(lambda * 0.3, 1e-9);
        improved = true;
        if (gain < tolerance * std::max(sse, 1e-18) || step_size < 1e-9) out.converged = true;
        break;
      }
      lambda *= 10;
    }
    if (!improved) {
      out.converged = true;  // no step lowers the residual: a minimum (to the step's resolution)
      break;
    }
    if (out.converged) break;
  }
  out.p = p;
  out.sse = sse;
  out.walk_sse = problem.block_sse(r).first;
  out.score = sse;
  out.amplitude_weight = problem.amplitude_weight;
  out.iterations = it + 1;
  return out;
}

/// Amplitude rows a shape is fitted to (fewer: the block is left out).
constexpr std::size_t kMinAmplitudeRows = 3;
/// Smallest RMS of the amplitude rows' ln a residuals a weight is worked out
/// from (nepers; the peak detector's own scatter is about 1 %).
constexpr double kMinAmplitudeRms = 1e-3;

/// levenberg_marquardt, and with amplitude rows a fit of both blocks by their
/// profile likelihood, n_walk ln(SSE_walk / n_walk) + n_amp ln(SSE_amp / n_amp):
/// each block weighted by its own variance, re-estimated from the fit until
/// the weight settles (iteratively reweighted), so neither unit (metres,
/// nepers) nor a noise level is assumed.
LmResult fit_from(const Problem& problem, const Eigen::VectorXd& start, int max_iterations,
                  double tolerance = 1e-10) {
  if (problem.amplitude_rows.size() < kMinAmplitudeRows)
    return levenberg_marquardt(problem, start, max_iterations, tolerance);
  Problem weighted = problem;
  const double n_walk = static_cast<double>(problem.rows.size());
  const double n_amp = static_cast<double>(problem.amplitude_rows.size());
  const auto weight_of = [&](double walk_sse, double amp_sse) {
    const double amp_ms = std::max(amp_sse / n_amp, kMinAmplitudeRms * kMinAmplitudeRms);
    return std::sqrt(std::max(walk_sse / n_walk, 1e-18) / amp_ms);
  };
  Eigen::VectorXd p = start;
  clamp_parameters(p, problem.onset_min_ns, problem.onset_max_ns);
  Eigen::VectorXd r;
  weighted.amplitude_weight = 1.0;
  if (!weighted.residuals(p, r)) return {};
  {
    const auto [walk, amp] = weighted.block_sse(r);
    weighted.amplitude_weight = weight_of(walk, amp);
  }
  LmResult lm;
  int iterations = 0;
  for (int round = 0; round < 6; ++round) {
    lm = levenberg_marquardt(weighted, p, max_iterations, tolerance);
    iterations += lm.iterations;
    if (!std::isfinite(lm.sse) || !weighted.residuals(lm.p, r)) break;
    const auto [walk, amp] = weighted.block_sse(r);
    lm.score = n_walk * std::log(std::max(walk / n_walk, 1e-30)) +
               n_amp * std::log(std::max(amp / n_amp, kMinAmplitudeRms * kMinAmplitudeRms));
    const double next = weight_of(walk, amp);
    p = lm.p;
    if (std::fabs(std::log(next / weighted.amplitude_weight)) < 0.05) break;
    weighted.amplitude_weight = next;
  }
  lm.iterations = iterations;
  return lm;
}

/// Wild-bootstrap replicates of the fit at `best` (WalkFitOptions::replicates):
/// e*_i = model_i - s v_i r_i with v_i = +-1 at random, r the residuals and
/// s = sqrt(n / (n - m)) (the residuals of a fit of m parameters are that much
/// smaller than the errors), each refitted from `best`.
std::vector<ranging::WalkShape> bootstrap_replicates(const Problem& problem,
                                                     const Eigen::VectorXd& best,
                                                     double best_amplitude_weight,
                                                     std::size_t count, int max_iterations) {
  std::vector<ranging::WalkShape> out;
  Eigen::VectorXd r;
  const auto n = static_cast<Eigen::Index>(problem.rows.size());
  // With amplitude rows, at the weight the fit ended with, and the readings
  // resampled the same way (their residuals, in nepers, about the fitted ln a
  // less the profiled constant): the readings hold the shape too, and kept
  // fixed they would leave the replicates only the walk rows' scatter.
  Problem resampled = problem;
  resampled.amplitude_weight = best_amplitude_weight;
  if (count == 0 || n <= best.size() || !resampled.residuals(best, r)) return out;
  const double inflation = std::sqrt(static_cast<double>(n) / static_cast<double>(n - best.size()));
  std::vector<double> e(problem.e.begin(), problem.e.end());
  resampled.e = e;
  const Eigen::Index m = r.size() - n;  // amplitude rows in the residuals
  std::vector<double> amplitude(problem.amplitude.begin(), problem.amplitude.end());
  resampled.amplitude = amplitude;
  // One constant profiled out of the m readings.
  const double amplitude_inflation =
      m > 1 ? std::sqrt(static_cast<double>(m) / static_cast<double>(m - 1)) : 0.0;
  // The standard fixes mt19937_64's sequence: the same rows give the same signs anywhere.
  std::mt19937_64 signs(20261124);
  const auto next_bit = [&signs] { return (signs() & 1U) != 0; };
  for (std::size_t b = 0; b < count; ++b) {
    for (Eigen::Index k = 0; k < n; ++k) {
      const std::size_t i = problem.rows[static_cast<std::size_t>(k)];
      const double model = problem.e[i] + r(k);
      e[i] = model - (next_bit() ? inflation : -inflation) * r(k);
    }
    for (Eigen::Index k = 0; k < m; ++k) {
      // residual = ln a - ln A - constant: ln A* = ln A + residual -+ s residual.
      const std::size_t i = problem.amplitude_rows[static_cast<std::size_t>(k)];
      const double residual = r(n + k) / best_amplitude_weight;
      const double step = (next_bit() ? amplitude_inflation : -amplitude_inflation) * residual;
      amplitude[i] = problem.amplitude[i] * std::exp(residual - step);
    }
    // A replicate needs its walk to a small part of the scatter it stands
    // for, not the last digit of its SSE.
    const LmResult lm = levenberg_marquardt(resampled, best, max_iterations, kReplicateTolerance);
    if (!std::isfinite(lm.sse)) continue;
    try {
      out.push_back(shape_of(lm.p));
    } catch (const std::invalid_argument&) {
    }
  }
  return out;
}

}  // namespace

WalkFitResult fit_walk(std::span<const double> pulse_width_ns, std::span<const double> error_m,
                       std::span<const std::uint8_t> status, std::span<const double> amplitude,
                       double reference_pulse_width_ns, double metres_per_ns,
                       const WalkFitOptions& options) {
  const std::size_t n = pulse_width_ns.size();
  if (error_m.size() != n || (!status.empty() && status.size() != n) ||
      (!amplitude.empty() && amplitude.size() != n)) {
    throw std::invalid_argument(
        "walk fit: pulse widths, errors, saturation flags and amplitudes differ in size");
  }
  if (!(std::isfinite(reference_pulse_width_ns) && metres_per_ns > 0)) {
    throw std::invalid_argument("walk fit: reference width and c_air / 2 must be finite");
  }
  WalkFitResult result;
  result.reference_pulse_width_ns = reference_pulse_width_ns;
  Problem problem;
  problem.w = pulse_width_ns;
  problem.e = error_m;
  problem.reference = reference_pulse_width_ns;
  problem.metres_per_ns = metres_per_ns;
  std::vector<std::size_t> clear, clipped;
  for (std::size_t i = 0; i < n; ++i) {
    if (!std::isfinite(pulse_width_ns[i]) || !std::isfinite(error_m[i])) {
      throw std::invalid_argument("walk fit: row " + std::to_string(i + 1) +
                                  " has a non-finite pulse width or error");
    }
    const std::uint8_t row = status.empty() ? 0 : status[i];
    if ((row & kWalkRowPartial) != 0) {
      ++result.partial_rows;
      continue;
    }
    ((row & kWalkRowClipped) != 0 ? clipped : clear).push_back(i);
  }
  // The amplitude block: unclipped rows with a usable reading (a clipped
  // reading is the clip level, not the echo).
  problem.amplitude = amplitude;
  if (!amplitude.empty()) {
    for (std::size_t i : clear) {
      if (std::isfinite(amplitude[i]) && amplitude[i] > 0) problem.amplitude_rows.push_back(i);
    }
  }
  if (problem.amplitude_rows.size() < kMinAmplitudeRows) problem.amplitude_rows.clear();
  {
    // The amplitude readings pin the shape: readings of one or two values pin
    // nothing (a constant column had sent the search over shapes wandering for
    // minutes), so such a block is dropped as a too-small one is.
    std::vector<double> readings;
    for (std::size_t i : problem.amplitude_rows) readings.push_back(amplitude[i]);
    std::sort(readings.begin(), readings.end());
    readings.erase(std::unique(readings.begin(), readings.end()), readings.end());
    if (readings.size() < 3) problem.amplitude_rows.clear();
  }
  std::vector<std::size_t> fitted = clear;
  fitted.insert(fitted.end(), clipped.begin(), clipped.end());
  std::sort(fitted.begin(), fitted.end());
  result.rows = fitted.size();
  if (fitted.size() < kMinWalkRows) {
    throw std::invalid_argument("walk fit: " + std::to_string(fitted.size()) +
                                " rows with every shot echoed (needs at least " +
                                std::to_string(kMinWalkRows) + ")");
  }
  result.saturated_rows = clipped.size();
  result.width_min_ns = pulse_width_ns[fitted.front()];
  result.width_max_ns = result.width_min_ns;
  for (std::size_t i : fitted) {
    result.width_min_ns = std::min(result.width_min_ns, pulse_width_ns[i]);
    result.width_max_ns = std::max(result.width_max_ns, pulse_width_ns[i]);
  }
  if (!(result.width_max_ns > result.width_min_ns)) {
    throw std::invalid_argument("walk fit: no spread in pulse_width_ns");
  }
  const bool fit_clipping =
      clipped.size() >= options.min_saturated_rows && clear.size() >= kMinWalkRows;
  // Without enough clipped rows to fit the recovery, every row (clipped or
  // not) is fitted by the shape alone.
  problem.rows = fit_clipping ? clear : fitted;
  double mean_e = 0;
  for (std::size_t i : problem.rows) mean_e += error_m[i];
  mean_e /= static_cast<double>(problem.rows.size());

  // Stage 1: the unclipped shape. Starts scaled to the widths seen (a pulse's
  // width over threshold is a few of its time constants), unless given.
  std::vector<Eigen::VectorXd> starts;
  if (options.initial) {
    Eigen::VectorXd p(3);
    p << mean_e, std::log(options.initial->pulse_sigma_ns),
        std::log(options.initial->pole_time_constant_ns);
    starts.push_back(p);
  }
  // A multistart search, or only a refinement of the given shape.
  const bool search = !options.initial || options.multistart;
  if (search) {
    double w_mid = 0;
    for (std::size_t i : problem.rows) w_mid += pulse_width_ns[i];
    w_mid = std::max(w_mid / static_cast<double>(problem.rows.size()), 1e-3);
    for (double sigma_scale : {0.03, 0.1, 0.3}) {
      for (double ratio : {0.3, 1.0, 3.0}) {
        Eigen::VectorXd p(3);
        p << mean_e, std::log(sigma_scale * w_mid), std::log(sigma_scale * w_mid * ratio);
        starts.push_back(p);
      }
    }
  }
  int iterations = 0;
  // The shape alone from every start on `problem.rows`: the minima, best first.
  const auto unclipped_minima = [&] {
    std::vector<LmResult> minima;
    for (const Eigen::VectorXd& start : starts) {
      LmResult lm = fit_from(problem, start, options.max_iterations);
      iterations += lm.iterations;
      if (std::isfinite(lm.sse)) minima.push_back(std::move(lm));
    }
    std::sort(minima.begin(), minima.end(),
              [](const LmResult& a, const LmResult& b) { return a.score < b.score; });
    return minima;
  };
  // Distinct local minima, best first: unclipped echoes over a narrow range of
  // strengths may fit two shapes almost equally, and clipped rows then decide.
  std::vector<Eigen::VectorXd> shapes;
  const auto add_distinct = [&shapes](const std::vector<LmResult>& minima, std::size_t most) {
    std::size_t added = 0;
    for (const LmResult& m : minima) {
      bool distinct = true;
      for (const Eigen::VectorXd& q : shapes) {
        distinct = distinct && (std::fabs(m.p(1) - q(1)) > 0.05 || std::fabs(m.p(2) - q(2)) > 0.05);
      }
      if (distinct && added < most) {
        shapes.push_back(m.p.head(3));
        ++added;
      }
    }
  };
  std::vector<LmResult> minima = unclipped_minima();
  if (minima.empty()) throw std::invalid_argument("walk fit: no shape fits the rows");
  LmResult best = minima.front();
  add_distinct(minima, kClippingShapeStarts);

  if (fit_clipping) {
    // Stage 2: the recovery, with the onset where the flags put it, then all
    // parameters on all rows.
    double widest_clear = -std::numeric_limits<double>::infinity();
    double narrowest_clipped = std::numeric_limits<double>::infinity();
    for (std::size_t i : clear) widest_clear = std::max(widest_clear, pulse_width_ns[i]);
    for (std::size_t i : clipped)
      narrowest_clipped = std::min(narrowest_clipped, pulse_width_ns[i]);
    problem.onset_min_ns = std::min(widest_clear, narrowest_clipped);
    problem.onset_max_ns = std::max(widest_clear, narrowest_clipped);
    const double onset_mid = 0.5 * (widest_clear + narrowest_clipped);
    problem.rows = fitted;
    // Starts from the unclipped shapes `from` on: three recoveries each, and
    // the onset within the shape's tabulated widths (up to kMaxLogOverdrive:
    // beyond them nothing clips, and neither the onset nor the recovery moves
    // the residuals).
    const auto shape_starts = [&](std::size_t from) {
      std::vector<Eigen::VectorXd> out;
      for (std::size_t k = from; k < shapes.size(); ++k) {
        const Eigen::VectorXd& q = shapes[k];
        const double widest_free_ns = ranging::walk_curve(shape_of(q), 600).width_ns.back();
        const double onset_hi = std::min(problem.onset_max_ns, widest_free_ns);
        const double onset_start =
            onset_hi > problem.onset_min_ns ? 0.5 * (problem.onset_min_ns + onset_hi) : onset_mid;
        for (double recovery_ns : {0.3, 1.0, 3.0}) {
          Eigen::VectorXd p(5);
          p << q(0), q(1), q(2), std::log(recovery_ns), onset_start;
          out.push_back(p);
        }
      }
      return out;
    };
    LmResult clipped_best;  // the best clipped fit from the `candidates` so far
    const auto fit_clipped = [&](const std::vector<Eigen::VectorXd>& candidates) {
      for (const Eigen::VectorXd& start : candidates) {
        LmResult lm = fit_from(problem, start, options.max_iterations);
        iterations += lm.iterations;
        if (lm.score < clipped_best.score) clipped_best = lm;
      }
    };
    std::vector<Eigen::VectorXd> clipped_starts;
    if (search) clipped_starts = shape_starts(0);
    if (options.initial && std::isfinite(options.initial->saturation_log_overdrive)) {
      // (Its onset width from its own unclipped curve.)
      ranging::WalkShape free = *options.initial;
      free.saturation_log_overdrive = std::numeric_limits<double>::infinity();
      const ranging::WalkCurve curve = ranging::walk_curve(free, 600);
      const auto at = std::lower_bound(curve.log_overdrive.begin(), curve.log_overdrive.end(),
                                       options.initial->saturation_log_overdrive);
      const double onset_width =
          at == curve.log_overdrive.end()
              ? onset_mid
              : curve.width_ns[static_cast<std::size_t>(at - curve.log_overdrive.begin())];
      Eigen::VectorXd p(5);
      p << best.p(0), std::log(options.initial->pulse_sigma_ns),
          std::log(options.initial->pole_time_constant_ns),
          std::log(std::max(options.initial->recovery_ns_per_neper, 1e-3)), onset_width;
      clipped_starts.push_back(p);
    }
    if (clipped_starts.empty()) {
      Eigen::VectorXd p(5);
      p << best.p(0), best.p(1), best.p(2), 0.0, onset_mid;
      clipped_starts.push_back(p);
    }
    fit_clipped(clipped_starts);
    // The search from the unclipped rows' shapes can miss: a few distinct
    // widths also fit a short-tailed shape whose widths end below the clipped
    // rows', from which no clipped fit leaves (12 rows at 4 reflectances, one
    // of them clipped: 8 mm of RMS against 0.3 mm for the unclipped rows).
    // When the clipped rows fit that much worse (per row, 2 x the RMS), the
    // shape alone is fitted to every row (the clipped shapes include it: an
    // onset beyond the tabulated widths clips nothing), kept if better, and
    // its minima start clipped fits too.
    const double unclipped_ms = best.walk_sse / static_cast<double>(clear.size());
    if (search && !(clipped_best.walk_sse / static_cast<double>(fitted.size()) <=
                    4.0 * unclipped_ms + 1e-18)) {
      const std::vector<LmResult> all_rows = unclipped_minima();
      if (!all_rows.empty() && all_rows.front().score < clipped_best.score)
        clipped_best = all_rows.front();
      const std::size_t from = shapes.size();
      add_distinct(all_rows, kClippingShapeStarts);
      fit_clipped(shape_starts(from));
    }
    if (!std::isfinite(clipped_best.sse)) {
      throw std::invalid_argument("walk fit: clipping did not fit");
    }
    best = clipped_best;
  }
  result.shape = shape_of(best.p);
  result.constant_m = best.p(0);
  result.rms_m = std::sqrt(best.walk_sse / static_cast<double>(problem.rows.size()));
  result.amplitude_rows = problem.amplitude_rows.size();
  result.shape_replicates = bootstrap_replicates(problem, best.p, best.amplitude_weight,
                                                 options.replicates, options.max_iterations);
  result.iterations = iterations;
  result.converged = best.converged;
  return result;
}

std::string WalkFitResult::summary() const {
  char buffer[400];
  std::snprintf(
      buffer, sizeof buffer,
      "walk shape: pulse sigma %.4f ns, pole time constant %.4f ns, clipping %s, "
      "recovery %.3f ns/neper; %zu rows (%zu clipped), widths [%.3f, %.3f] ns, "
      "RMS %.3f mm, %zu amplitude rows, %d LM iterations%s%s",
      shape.pulse_sigma_ns, shape.pole_time_constant_ns,
      std::isfinite(shape.saturation_log_overdrive)
          ? ("at ln(A/V) " + std::to_string(shape.saturation_log_overdrive)).c_str()
          : "not observed",
      shape.recovery_ns_per_neper, rows, saturated_rows, width_min_ns, width_max_ns, rms_m * 1e3,
      amplitude_rows, iterations, converged ? "" : " (not converged)",
      partial_rows > 0
          ? ("; " + std::to_string(partial_rows) + " partial-echo rows not fitted").c_str()
          : "");
  return buffer;
}

}  // namespace tofkit::calib
