#include "tofkit/calib/walk_fit.hpp"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <stdexcept>
#include <vector>

namespace tofkit::calib {
namespace {

constexpr std::size_t kMinWalkRows = 6;
/// Bounds of the log-parameters: times 0.005-200 ns, within a factor 30 of each other.
constexpr double kMinLogTime = -5.3, kMaxLogTime = 5.3, kMaxLogRatio = 3.4;

/// Parameters: [constant, ln sigma, ln tau] or, with clipping,
/// [constant, ln sigma, ln tau, ln a_sat, ln tau_r].
ranging::WalkShape shape_of(const Eigen::VectorXd& p) {
  ranging::WalkShape s;
  s.pulse_sigma_ns = std::exp(p(1));
  s.pole_time_constant_ns = std::exp(p(2));
  if (p.size() > 3) {
    s.saturation_log_overdrive = p(3);
    s.recovery_ns_per_neper = std::exp(p(4));
  }
  return s;
}

/// min_log_saturation: the clipping onset is not below the strongest unclipped
/// echo seen (less a margin for the shape's change).
void clamp_parameters(Eigen::VectorXd& p, double min_log_saturation) {
  p(1) = std::clamp(p(1), kMinLogTime, kMaxLogTime);
  p(2) = std::clamp(p(2), std::max(kMinLogTime, p(1) - kMaxLogRatio),
                    std::min(kMaxLogTime, p(1) + kMaxLogRatio));
  if (p.size() > 3) {
    p(3) = std::clamp(p(3), std::max(0.01, min_log_saturation), ranging::kMaxLogOverdrive - 0.5);
    p(4) = std::clamp(p(4), -7.0, 5.0);
  }
}

struct Problem {
  std::span<const double> w, e;
  std::vector<std::size_t> rows;  ///< rows in this stage
  double reference = 0, metres_per_ns = 0;
  double min_log_saturation = 0;

  /// residual_i = model_i - e_i; false when the shape cannot be tabulated.
  bool residuals(const Eigen::VectorXd& p, Eigen::VectorXd& r) const {
    ranging::WalkCurve curve;
    try {
      curve = ranging::walk_curve(shape_of(p), 600);
    } catch (const std::invalid_argument&) {
      return false;
    }
    const double rise_ref = ranging::rise_at_width(curve, reference);
    r.resize(static_cast<Eigen::Index>(rows.size()));
    for (std::size_t k = 0; k < rows.size(); ++k) {
      const std::size_t i = rows[k];
      const double model = p(0) - metres_per_ns * (ranging::rise_at_width(curve, w[i]) - rise_ref);
      r(static_cast<Eigen::Index>(k)) = model - e[i];
    }
    return r.allFinite();
  }
};

struct LmResult {
  Eigen::VectorXd p;
  double sse = std::numeric_limits<double>::infinity();
  int iterations = 0;
  bool converged = false;
};

/// Levenberg-Marquardt with Marquardt's diagonal scaling and a forward-difference Jacobian.
LmResult levenberg_marquardt(const Problem& problem, Eigen::VectorXd p, int max_iterations) {
  LmResult out;
  clamp_parameters(p, problem.min_log_saturation);
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
      clamp_parameters(q, problem.min_log_saturation);
      if (problem.residuals(q, r_step) && r_step.squaredNorm() < sse) {
        const double gain = sse - r_step.squaredNorm();
        const double step_size = (q - p).cwiseAbs().maxCoeff();
        p = q;
        r = r_step;
        sse = r.squaredNorm();
        lambda = std::max(lambda * 0.3, 1e-9);
        improved = true;
        if (gain < 1e-10 * std::max(sse, 1e-18) || step_size < 1e-9) out.converged = true;
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
  out.iterations = it + 1;
  return out;
}

}  // namespace

WalkFitResult fit_walk(std::span<const double> pulse_width_ns, std::span<const double> error_m,
                       std::span<const std::uint8_t> saturated, double reference_pulse_width_ns,
                       double metres_per_ns, const WalkFitOptions& options) {
  const std::size_t n = pulse_width_ns.size();
  if (error_m.size() != n || (!saturated.empty() && saturated.size() != n)) {
    throw std::invalid_argument(
        "walk fit: pulse widths, errors and saturation flags differ in size");
  }
  if (n < kMinWalkRows) {
    throw std::invalid_argument("walk fit: " + std::to_string(n) + " rows (needs at least " +
                                std::to_string(kMinWalkRows) + ")");
  }
  if (!(std::isfinite(reference_pulse_width_ns) && metres_per_ns > 0)) {
    throw std::invalid_argument("walk fit: reference width and c_air / 2 must be finite");
  }
  WalkFitResult result;
  result.rows = n;
  result.reference_pulse_width_ns = reference_pulse_width_ns;
  Problem problem{pulse_width_ns, error_m, {}, reference_pulse_width_ns, metres_per_ns};
  std::vector<std::size_t> clear, clipped;
  for (std::size_t i = 0; i < n; ++i) {
    if (!std::isfinite(pulse_width_ns[i]) || !std::isfinite(error_m[i])) {
      throw std::invalid_argument("walk fit: row " + std::to_string(i + 1) +
                                  " has a non-finite pulse width or error");
    }
    (!saturated.empty() && saturated[i] != 0 ? clipped : clear).push_back(i);
  }
  result.saturated_rows = clipped.size();
  const auto [lo, hi] = std::minmax_element(pulse_width_ns.begin(), pulse_width_ns.end());
  result.width_min_ns = *lo;
  result.width_max_ns = *hi;
  if (!(*hi > *lo)) throw std::invalid_argument("walk fit: no spread in pulse_width_ns");
  const bool fit_clipping =
      clipped.size() >= options.min_saturated_rows && clear.size() >= kMinWalkRows;
  // Without enough clipped rows to fit the recovery, every row (clipped or
  // not) is fitted by the shape alone.
  problem.rows = fit_clipping ? clear : std::vector<std::size_t>(n);
  if (!fit_clipping) {
    for (std::size_t i = 0; i < n; ++i) problem.rows[i] = i;
  }
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
  if (!options.initial || options.multistart) {
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
  LmResult best;
  for (const Eigen::VectorXd& start : starts) {
    LmResult lm = levenberg_marquardt(problem, start, options.max_iterations);
    if (lm.sse < best.sse) best = lm;
  }
  if (!std::isfinite(best.sse)) throw std::invalid_argument("walk fit: no shape fits the rows");
  int iterations = best.iterations;

  if (fit_clipping) {
    // Stage 2: clipping onset at the strongest unclipped echo seen, then all
    // parameters on all rows.
    const ranging::WalkCurve curve = ranging::walk_curve(shape_of(best.p));
    double widest_clear = 0;
    for (std::size_t i : clear) widest_clear = std::max(widest_clear, pulse_width_ns[i]);
    std::size_t k = 0;
    while (k + 1 < curve.width_ns.size() && curve.width_ns[k] < widest_clear) ++k;
    const double onset = curve.log_overdrive[k];
    problem.min_log_saturation = onset - 0.3;
    problem.rows.resize(n);
    for (std::size_t i = 0; i < n; ++i) problem.rows[i] = i;
    std::vector<Eigen::VectorXd> clipped_starts;
    for (double above : {0.0, 0.7, 1.5}) {
      for (double recovery_ns : {0.5, 2.0}) {
        Eigen::VectorXd p(5);
        p << best.p(0), best.p(1), best.p(2), onset + above, std::log(recovery_ns);
        clipped_starts.push_back(p);
      }
    }
    if (options.initial && std::isfinite(options.initial->saturation_log_overdrive)) {
      Eigen::VectorXd p(5);
      p << best.p(0), best.p(1), best.p(2), options.initial->saturation_log_overdrive,
          std::log(std::max(options.initial->recovery_ns_per_neper, 1e-3));
      if (options.multistart) {
        clipped_starts.push_back(p);
      } else {
        clipped_starts.assign(1, p);
      }
    }
    LmResult clipped_best;
    for (const Eigen::VectorXd& start : clipped_starts) {
      LmResult lm = levenberg_marquardt(problem, start, options.max_iterations);
      iterations += lm.iterations;
      if (lm.sse < clipped_best.sse) clipped_best = lm;
    }
    if (!std::isfinite(clipped_best.sse)) {
      throw std::invalid_argument("walk fit: clipping did not fit");
    }
    best = clipped_best;
  }
  result.shape = shape_of(best.p);
  result.constant_m = best.p(0);
  result.rms_m = std::sqrt(best.sse / static_cast<double>(problem.rows.size()));
  result.iterations = iterations;
  result.converged = best.converged;
  return result;
}

std::string WalkFitResult::summary() const {
  char buffer[320];
  std::snprintf(buffer, sizeof buffer,
                "walk shape: pulse sigma %.4f ns, pole time constant %.4f ns, clipping %s, "
                "recovery %.3f ns/neper; %zu rows (%zu clipped), widths [%.3f, %.3f] ns, "
                "RMS %.3f mm, %d LM iterations%s",
                shape.pulse_sigma_ns, shape.pole_time_constant_ns,
                std::isfinite(shape.saturation_log_overdrive)
                    ? ("at ln(A/V) " + std::to_string(shape.saturation_log_overdrive)).c_str()
                    : "not observed",
                shape.recovery_ns_per_neper, rows, saturated_rows, width_min_ns, width_max_ns,
                rms_m * 1e3, iterations, converged ? "" : " (not converged)");
  return buffer;
}

}  // namespace tofkit::calib
