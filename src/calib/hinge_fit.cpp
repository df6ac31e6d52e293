#include "tofkit/calib/hinge_fit.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <numeric>
#include <stdexcept>
#include <utility>

#include "tofkit/calib/statistics.hpp"

namespace tofkit::calib {
namespace {

constexpr std::size_t kMinRows = 5;
constexpr double kInf = std::numeric_limits<double>::infinity();
/// Largest number of knot combinations searched exhaustively; above it knots
/// are inserted greedily into the best (k-1)-knot solution.
constexpr double kMaxExhaustiveCombinations = 2000;
constexpr double kMadToSigma = 1.4826;  // MAD -> sigma for Gaussian residuals

/// The median of v, reordering v (no copy: the IRLS loops take two a step).
double median_in_place(std::span<double> v) {
  if (v.empty()) return ranging::kNaN;
  const auto mid = v.begin() + static_cast<std::ptrdiff_t>(v.size() / 2);
  std::nth_element(v.begin(), mid, v.end());
  double m = *mid;
  if (v.size() % 2 == 0) m = 0.5 * (m + *std::max_element(v.begin(), mid));
  return m;
}

double median_of(std::vector<double> v) {
  return median_in_place(v);
}

/// Robust sigma: 1.4826 median |r - median r|.
double mad_scale(const Eigen::VectorXd& r) {
  std::vector<double> v(r.data(), r.data() + r.size());
  const double m = median_in_place(v);
  for (double& e : v) e = std::fabs(e - m);
  return kMadToSigma * median_in_place(v);
}

/// Smallest scale the robust weights may use: residuals of an exact fit are
/// rounding noise, which must not be mistaken for a tiny noise level.
double scale_floor(const Eigen::VectorXd& y) {
  const double spread = y.size() > 0 ? (y.maxCoeff() - y.minCoeff()) : 0.0;
  return std::max(1e-9 * spread, 1e-300);
}

double weight_of(double u, RobustLoss loss, const RobustOptions& o) {
  const double a = std::fabs(u);
  switch (loss) {
    case RobustLoss::kNone:
      return 1.0;
    case RobustLoss::kHuber:
      return a <= o.huber_k ? 1.0 : o.huber_k / a;
    case RobustLoss::kBisquare: {
      if (a >= o.bisquare_c) return 0.0;
      const double t = 1.0 - (u / o.bisquare_c) * (u / o.bisquare_c);
      return t * t;
    }
  }
  return 1.0;
}

/// rho(u), normalised so rho(u) ~ u^2 / 2 for small u (the BIC deviance term).
double rho_of(double u, RobustLoss loss, const RobustOptions& o) {
  const double a = std::fabs(u);
  switch (loss) {
    case RobustLoss::kNone:
      return 0.5 * u * u;
    case RobustLoss::kHuber:
      return a <= o.huber_k ? 0.5 * u * u : o.huber_k * a - 0.5 * o.huber_k * o.huber_k;
    case RobustLoss::kBisquare: {
      const double c2 = o.bisquare_c * o.bisquare_c;
      if (a >= o.bisquare_c) return c2 / 6.0;
      const double t = 1.0 - u * u / c2;
      return c2 / 6.0 * (1.0 - t * t * t);
    }
  }
  return 0.5 * u * u;
}

/// Loss used in IRLS iteration `it` (bisquare starts with Huber iterations).
RobustLoss loss_at(int it, const RobustOptions& o) {
  if (o.loss == RobustLoss::kBisquare && it < o.huber_start_iterations) return RobustLoss::kHuber;
  return o.loss;
}

/// Design matrix in the scaled variable u: [1, u, (u - kappa_j)+ ...].
Eigen::MatrixXd hinge_design(const std::vector<double>& u, const std::vector<double>& knots) {
  const auto n = static_cast<Eigen::Index>(u.size());
  Eigen::MatrixXd a(n, static_cast<Eigen::Index>(2 + knots.size()));
  for (Eigen::Index i = 0; i < n; ++i) {
    const double ui = u[static_cast<std::size_t>(i)];
    a(i, 0) = 1.0;
    a(i, 1) = ui;
    for (std::size_t j = 0; j < knots.size(); ++j) {
      a(i, static_cast<Eigen::Index>(2 + j)) = std::max(0.0, ui - knots[j]);
    }
  }
  return a;
}

Eigen::VectorXd weighted_qr_solve(const Eigen::MatrixXd& a, const Eigen::VectorXd& y,
                                  const Eigen::VectorXd& w) {
  const Eigen::VectorXd sw = w.array().sqrt();
  const Eigen::MatrixXd aw = sw.asDiagonal() * a;
  const Eigen::VectorXd yw = sw.cwiseProduct(y);
  return aw.householderQr().solve(yw);
}

/// Profile least squares over knot positions on x-sorted, scaled data: the
/// normal equations of [1, u, (u - kappa_j)+] are assembled from suffix sums
/// of w, w u, w u^2, w y, w u y, so a candidate costs O(k^3 + k log n).
class ProfileSolver {
 public:
  ProfileSolver(std::vector<double> u, std::vector<double> y, std::size_t min_segment_rows)
      : u_(std::move(u)), y_(std::move(y)), min_rows_(min_segment_rows) {
    set_weights(std::vector<double>(u_.size(), 1.0));
  }

  void set_weights(const std::vector<double>& w) {
    const std::size_t n = u_.size();
    for (auto* s : {&s0_, &s1_, &s2_, &sy_, &suy_}) s->assign(n + 1, 0.0L);
    syy_ = 0;
    // Suffix sums: index i holds the sum over rows i..n-1.
    for (std::size_t i = n; i-- > 0;) {
      const long double wi = w[i], ui = u_[i], yi = y_[i];
      s0_[i] = s0_[i + 1] + wi;
      s1_[i] = s1_[i + 1] + wi * ui;
      s2_[i] = s2_[i + 1] + wi * ui * ui;
      sy_[i] = sy_[i + 1] + wi * yi;
      suy_[i] = suy_[i + 1] + wi * ui * yi;
      syy_ += wi * yi * yi;
    }
  }

  std::size_t rows() const { return u_.size(); }
  const std::vector<double>& u() const { return u_; }
  const std::vector<double>& y() const { return y_; }

  /// First row strictly right of kappa (rows at a knot belong to the left segment).
  std::size_t first_above(double kappa) const {
    return static_cast<std::size_t>(std::upper_bound(u_.begin(), u_.end(), kappa) - u_.begin());
  }

  /// Every segment holds at least min_rows rows.
  bool supported(const std::vector<double>& knots) const {
    std::size_t previous = 0;
    for (double kappa : knots) {
      const std::size_t a = first_above(kappa);
      if (a < previous + min_rows_) return false;
      previous = a;
    }
    return u_.size() >= previous + min_rows_;
  }

  /// Weighted residual sum of squares for ascending knots (inf if infeasible).
  double rss(const std::vector<double>& knots, Eigen::VectorXd* beta = nullptr) const {
    const std::size_t k = knots.size();
    const std::size_t p = 2 + k;
    long double g[8][8];
    long double b[8];
    std::size_t a[6];
    // supported(), with each knot's first row kept for the sums below.
    for (std::size_t j = 0; j < k; ++j) {
      a[j] = first_above(knots[j]);
      if (a[j] < (j > 0 ? a[j - 1] : 0) + min_rows_) return kInf;
    }
    if (u_.size() < (k > 0 ? a[k - 1] : 0) + min_rows_) return kInf;
    g[0][0] = s0_[0];
    g[0][1] = s1_[0];
    g[1][1] = s2_[0];
    b[0] = sy_[0];
    b[1] = suy_[0];
    for (std::size_t j = 0; j < k; ++j) {
      const long double kj = knots[j];
      const std::size_t aj = a[j];
      g[0][2 + j] = s1_[aj] - kj * s0_[aj];
      g[1][2 + j] = s2_[aj] - kj * s1_[aj];
      b[2 + j] = suy_[aj] - kj * sy_[aj];
      for (std::size_t l = j; l < k; ++l) {
        const long double kl = knots[l];
        const std::size_t al = a[l];  // knots ascending: rows right of both are right of kl
        g[2 + j][2 + l] = s2_[al] - (kj + kl) * s1_[al] + kj * kl * s0_[al];
      }
    }
    // Cholesky of the symmetric normal matrix (upper triangle filled above).
    long double l[8][8] = {};
    for (std::size_t i = 0; i < p; ++i) {
      for (std::size_t j = 0; j <= i; ++j) {
        long double sum = g[j][i];
        for (std::size_t m = 0; m < j; ++m) sum -= l[i][m] * l[j][m];
        if (i == j) {
          if (!(sum > 1e-14L * g[i][i])) return kInf;  // (near-)singular: collinear columns
          l[i][i] = std::sqrt(sum);
        } else {
          l[i][j] = sum / l[j][j];
        }
      }
    }
    long double z[8];
    long double explained = 0;
    for (std::size_t i = 0; i < p; ++i) {
      long double sum = b[i];
      for (std::size_t m = 0; m < i; ++m) sum -= l[i][m] * z[m];
      z[i] = sum / l[i][i];
      explained += z[i] * z[i];
    }
    if (beta != nullptr) {
      beta->resize(static_cast<Eigen::Index>(p));
      long double x[8];
      for (std::size_t i = p; i-- > 0;) {
        long double sum = z[i];
        for (std::size_t m = i + 1; m < p; ++m) sum -= l[m][i] * x[m];
        x[i] = sum / l[i][i];
        (*beta)(static_cast<Eigen::Index>(i)) = static_cast<double>(x[i]);
      }
    }
    return static_cast<double>(std::max(0.0L, syy_ - explained));
  }

 private:
  std::vector<double> u_, y_;
  std::size_t min_rows_;
  std::vector<long double> s0_, s1_, s2_, sy_, suy_;
  long double syy_ = 0;
};

double combinations(std::size_t n, std::size_t k) {
  double c = 1;
  for (std::size_t i = 0; i < k; ++i)
    c = c * static_cast<double>(n - i) / static_cast<double>(i + 1);
  return c;
}

/// Coarse search over grid combinations (exhaustive or greedy), best first.
std::pair<std::vector<double>, double> grid_search(const ProfileSolver& solver,
                                                   const std::vector<double>& grid, std::size_t k,
                                                   const std::vector<double>& previous_knots) {
  std::vector<double> best;
  double best_rss = kInf;
  if (k == 0) return {best, solver.rss(best)};
  if (grid.size() < k) return {best, kInf};
  if (combinations(grid.size(), k) <= kMaxExhaustiveCombinations) {
    std::vector<std::size_t> index(k);
    std::iota(index.begin(), index.end(), 0);
    std::vector<double> knots(k);
    while (true) {
      for (std::size_t j = 0; j < k; ++j) knots[j] = grid[index[j]];
      const double r = solver.rss(knots);
      if (r < best_rss) {
        best_rss = r;
        best = knots;
      }
      // Next combination in lexicographic order.
      std::size_t j = k;
      while (j > 0 && index[j - 1] == grid.size() - k + j - 1) --j;
      if (j == 0) break;
      ++index[j - 1];
      for (std::size_t m = j; m < k; ++m) index[m] = index[m - 1] + 1;
    }
    return {best, best_rss};
  }
  // Greedy insertion into the (k-1)-knot solution.
  for (double candidate : grid) {
    if (std::find(previous_knots.begin(), previous_knots.end(), candidate) !=
        previous_knots.end()) {
      continue;
    }
    std::vector<double> knots = previous_knots;
    knots.insert(std::upper_bound(knots.begin(), knots.end(), candidate), candidate);
    const double r = solver.rss(knots);
    if (r < best_rss) {
      best_rss = r;
      best = knots;
    }
  }
  return {best, best_rss};
}

/// Golden-section refinement of one knot at a time, each within the grid
/// cell around it and between its neighbours, until no knot moves.
double refine_knots(const ProfileSolver& solver, const std::vector<double>& grid,
                    std::vector<double>& knots, double rss) {
  constexpr double kGolden = 0.6180339887498949;
  const double u_lo = solver.u().front();
  const double u_hi = solver.u().back();
  for (int cycle = 0; cycle < 20; ++cycle) {
    bool moved = false;
    for (std::size_t j = 0; j < knots.size(); ++j) {
      const double current = knots[j];
      const auto above = std::upper_bound(grid.begin(), grid.end(), current);
      double lo = above == grid.begin() ? u_lo : *std::prev(above);
      if (lo >= current && above != grid.begin() && std::prev(above) != grid.begin()) {
        lo = *std::prev(above, 2);
      }
      double hi = above == grid.end() ? u_hi : *above;
      if (j > 0) lo = std::max(lo, knots[j - 1]);
      if (j + 1 < knots.size()) hi = std::min(hi, knots[j + 1]);
      std::vector<double> trial = knots;  // (one copy per knot, not per evaluation)
      const auto f = [&](double kappa) {
        trial[j] = kappa;
        return solver.rss(trial);
      };
      double a = lo, b = hi;
      double c = b - kGolden * (b - a), d = a + kGolden * (b - a);
      double fc = f(c), fd = f(d);
      for (int it = 0; it < 60 && (b - a) > 1e-10 * (u_hi - u_lo); ++it) {
        if (fc < fd) {
          b = d;
          d = c;
          fd = fc;
          c = b - kGolden * (b - a);
          fc = f(c);
        } else {
          a = c;
          c = d;
          fc = fd;
          d = a + kGolden * (b - a);
          fd = f(d);
        }
      }
      const double candidate = fc < fd ? c : d;
      const double candidate_rss = std::min(fc, fd);
      if (candidate_rss < rss * (1.0 - 1e-12) && std::fabs(candidate - current) > 0) {
        knots[j] = candidate;
        rss = candidate_rss;
        moved = true;
      }
    }
    if (!moved) break;
  }
  return rss;
}

/// Candidate knots, each leaving enough rows on both sides: quantiles of the
/// rows, and quantiles of the distinct values of u. The second set matters when
/// most rows share a few values (a calibration run where all plates sit at one
/// temperature and only a short sweep spreads it): row quantiles would then all
/// fall inside the cluster and never reach the sweep's knee.
std::vector<double> knot_grid(const ProfileSolver& solver, int grid_points) {
  const std::vector<double>& u = solver.u();  // sorted
  std::vector<double> distinct(u.begin(), u.end());
  distinct.erase(std::unique(distinct.begin(), distinct.end()), distinct.end());
  std::vector<double> grid;
  for (const std::vector<double>* values :
       {&u, static_cast<const std::vector<double>*>(&distinct)}) {
    const std::size_t n = values->size();
    for (int i = 1; i <= grid_points; ++i) {
      const double q = static_cast<double>(i) / (grid_points + 1);
      const auto index = static_cast<std::size_t>(std::lround(q * static_cast<double>(n - 1)));
      const double candidate = (*values)[index];
      if (candidate >= u.back()) continue;
      if (solver.supported({candidate})) grid.push_back(candidate);
    }
  }
  std::sort(grid.begin(), grid.end());
  grid.erase(std::unique(grid.begin(), grid.end()), grid.end());
  return grid;
}

/// One knot count: IRLS around the profile knot search.
struct CountFit {
  std::vector<double> knots;  ///< in u
  Eigen::VectorXd beta;       ///< in u
  Eigen::VectorXd weights;
  Eigen::VectorXd residuals;
  double scale = 0;
  int iterations = 0;
  bool feasible = false;
};

Eigen::VectorXd residuals_of(const ProfileSolver& solver, const std::vector<double>& knots,
                             const Eigen::VectorXd& beta) {
  const auto& u = solver.u();
  const auto& y = solver.y();
  Eigen::VectorXd r(static_cast<Eigen::Index>(u.size()));
  for (std::size_t i = 0; i < u.size(); ++i) {
    double f = beta(0) + beta(1) * u[i];
    for (std::size_t j = 0; j < knots.size(); ++j) {
      f += beta(static_cast<Eigen::Index>(2 + j)) * std::max(0.0, u[i] - knots[j]);
    }
    r(static_cast<Eigen::Index>(i)) = y[i] - f;
  }
  return r;
}

CountFit fit_count(ProfileSolver& solver, const std::vector<double>& grid, std::size_t k,
                   const std::vector<double>& previous_knots, const RobustOptions& robust) {
  CountFit fit;
  const std::size_t n = solver.rows();
  std::vector<double> w(n, 1.0);
  solver.set_weights(w);
  auto [knots, rss] = grid_search(solver, grid, k, previous_knots);
  if (!std::isfinite(rss)) return fit;
  rss = refine_knots(solver, grid, knots, rss);
  const int full_search_iterations = robust.huber_start_iterations + 1;
  const double y_floor = scale_floor(
      Eigen::Map<const Eigen::VectorXd>(solver.y().data(), static_cast<Eigen::Index>(n)));
  for (int it = 0;; ++it) {
    Eigen::VectorXd beta;
    if (!std::isfinite(solver.rss(knots, &beta))) return fit;
    fit.knots = knots;
    fit.beta = beta;
    fit.residuals = residuals_of(solver, knots, beta);
    fit.scale = std::max(mad_scale(fit.residuals), y_floor);
    fit.weights = Eigen::Map<const Eigen::VectorXd>(w.data(), static_cast<Eigen::Index>(n));
    fit.iterations = it;
    fit.feasible = true;
    if (robust.loss == RobustLoss::kNone || it >= robust.max_iterations) break;
    const RobustLoss loss = loss_at(it, robust);
    double change = 0;
    for (std::size_t i = 0; i < n; ++i) {
      const double wi =
          weight_of(fit.residuals(static_cast<Eigen::Index>(i)) / fit.scale, loss, robust);
      change = std::max(change, std::fabs(wi - w[i]));
      w[i] = wi;
    }
    if (change < robust.weight_tolerance && loss == robust.loss) break;
    solver.set_weights(w);
    if (it < full_search_iterations) {
      // The first weighted searches may move knots far from the unweighted start.
      auto [searched, searched_rss] = grid_search(solver, grid, k, previous_knots);
      const double warm_rss = solver.rss(knots);
      if (searched_rss < warm_rss) knots = std::move(searched);
    }
    refine_knots(solver, grid, knots, solver.rss(knots));
  }
  return fit;
}

std::string format_value(double v, const std::string& unit) {
  char buffer[64];
  std::snprintf(buffer, sizeof buffer, "%.2f", v);
  return std::string(buffer) + (unit.empty() ? "" : " " + unit);
}

struct Prepared {
  std::vector<double> x, y;  ///< finite rows, sorted by x
  std::size_t skipped = 0;
  double center = 0, scale = 1;
};

Prepared prepare(std::span<const double> x, std::span<const double> y,
                 const HingeFitOptions& options) {
  if (x.size() != y.size()) {
    throw std::invalid_argument("hinge fit of " + options.column + ": " + std::to_string(x.size()) +
                                " x values but " + std::to_string(y.size()) + " y values");
  }
  std::vector<std::size_t> order;
  Prepared p;
  for (std::size_t i = 0; i < x.size(); ++i) {
    if (std::isfinite(x[i]) && std::isfinite(y[i])) {
      if (std::fabs(x[i]) > kMaxMagnitude || std::fabs(y[i]) > kMaxMagnitude) {
        char buffer[200];
        std::snprintf(buffer, sizeof buffer,
                      "hinge fit of %s: row %zu holds x = %.6g, y = %.6g, too large to fit "
                      "(|value| must be below %.0e)",
                      options.column.c_str(), i + 1, x[i], y[i], kMaxMagnitude);
        throw std::invalid_argument(buffer);
      }
      order.push_back(i);
    } else {
      ++p.skipped;
    }
  }
  if (order.size() < kMinRows) {
    throw std::invalid_argument(
        "too few rows for a hinge fit of " + options.column + ": " + std::to_string(order.size()) +
        " rows with finite values (need at least " + std::to_string(kMinRows) + ")");
  }
  std::stable_sort(order.begin(), order.end(),
                   [&](std::size_t a, std::size_t b) { return x[a] < x[b]; });
  for (std::size_t i : order) {
    p.x.push_back(x[i]);
    p.y.push_back(y[i]);
  }
  const double lo = p.x.front(), hi = p.x.back();
  if (!(hi - lo > 1e-12 * std::max(1.0, std::max(std::fabs(lo), std::fabs(hi))))) {
    throw std::invalid_argument("no spread in " + options.column + " (all " +
                                format_value(lo, options.unit) + ")");
  }
  p.center = p.x[p.x.size() / 2];
  p.scale = 0.5 * (hi - lo);
  return p;
}

/// Converts a fit in u = (x - center) / scale to the result's PiecewiseLinear.
ranging::PiecewiseLinear to_function(const std::vector<double>& knots_u,
                                     const Eigen::VectorXd& beta, double center, double scale,
                                     double x0) {
  ranging::PiecewiseLinear f;
  f.x0 = x0;
  f.slope0 = beta(1) / scale;
  f.intercept = beta(0) + beta(1) * (x0 - center) / scale;
  for (std::size_t j = 0; j < knots_u.size(); ++j) {
    f.knots.push_back(center + scale * knots_u[j]);
    f.slopes.push_back(beta(static_cast<Eigen::Index>(2 + j)) / scale);
  }
  return f;
}

/// Final coefficients by QR and the result's statistics.
HingeFitResult finish(const Prepared& p, const std::vector<double>& u,
                      const std::vector<double>& knots_u, const Eigen::VectorXd& weights,
                      const HingeFitOptions& options) {
  const Eigen::MatrixXd a = hinge_design(u, knots_u);
  const Eigen::VectorXd y =
      Eigen::Map<const Eigen::VectorXd>(p.y.data(), static_cast<Eigen::Index>(p.y.size()));
  const Eigen::VectorXd beta = weighted_qr_solve(a, y, weights);
  const Eigen::VectorXd r = y - a * beta;
  HingeFitResult result;
  const double x0 = std::isfinite(options.x0) ? options.x0 : median_of(p.x);
  result.function = to_function(knots_u, beta, p.center, p.scale, x0);
  result.knots = result.function.knots;
  result.x_min = p.x.front();
  result.x_max = p.x.back();
  result.rows = p.x.size();
  result.rows_skipped = p.skipped;
  result.rows_downweighted = static_cast<std::size_t>((weights.array() < 0.5).count());
  result.residual_rms = std::sqrt(r.squaredNorm() / static_cast<double>(r.size()));
  result.robust_scale = mad_scale(r);
  return result;
}

}  // namespace

RobustLinearFit robust_linear_fit(const Eigen::MatrixXd& design, const Eigen::VectorXd& y,
                                  const RobustOptions& options) {
  if (design.rows() != y.size()) {
    throw std::invalid_argument("robust_linear_fit: design has " + std::to_string(design.rows()) +
                                " rows but y has " + std::to_string(y.size()));
  }
  if (design.rows() < design.cols()) {
    throw std::invalid_argument("robust_linear_fit: " + std::to_string(design.rows()) +
                                " rows for " + std::to_string(design.cols()) + " parameters");
  }
  RobustLinearFit fit;
  fit.weights = Eigen::VectorXd::Ones(y.size());
  for (int it = 0;; ++it) {
    fit.coefficients = weighted_qr_solve(design, y, fit.weights);
    const Eigen::VectorXd r = y - design * fit.coefficients;
    fit.scale = std::max(mad_scale(r), scale_floor(y));
    fit.iterations = it;
    if (options.loss == RobustLoss::kNone || it >= options.max_iterations) {
      break;
    }
    const RobustLoss loss = loss_at(it, options);
    double change = 0;
    for (Eigen::Index i = 0; i < r.size(); ++i) {
      const double wi = weight_of(r(i) / fit.scale, loss, options);
      change = std::max(change, std::fabs(wi - fit.weights(i)));
      fit.weights(i) = wi;
    }
    if (change < options.weight_tolerance && loss == options.loss) break;
  }
  return fit;
}

HingeFitResult fit_hinge(std::span<const double> x, std::span<const double> y,
                         const HingeFitOptions& options) {
  if (options.max_knots < 0 || options.max_knots > 6) {
    throw std::invalid_argument("hinge fit: max_knots = " + std::to_string(options.max_knots) +
                                " is out of range [0, 6]");
  }
  if (options.grid_points < 1) throw std::invalid_argument("hinge fit: grid_points must be >= 1");
  const Prepared p = prepare(x, y, options);
  const std::size_t n = p.x.size();
  std::vector<double> u(n);
  for (std::size_t i = 0; i < n; ++i) u[i] = (p.x[i] - p.center) / p.scale;
  const auto min_rows = std::max<std::size_t>(
      std::max<std::size_t>(options.min_segment_rows, 2),
      static_cast<std::size_t>(std::ceil(options.min_segment_fraction * static_cast<double>(n))));
  ProfileSolver solver(u, p.y, min_rows);
  const std::vector<double> grid = knot_grid(solver, options.grid_points);

  std::vector<CountFit> fits;
  std::vector<double> previous;
  for (int k = 0; k <= options.max_knots; ++k) {
    CountFit fit = fit_count(solver, grid, static_cast<std::size_t>(k), previous, options.robust);
    if (!fit.feasible) break;  // more knots cannot be supported either
    previous = fit.knots;
    fits.push_back(std::move(fit));
  }
  if (fits.empty()) {
    throw std::invalid_argument("hinge fit of " + options.column +
                                ": no knot count gives a usable fit (the data are degenerate: "
                                "collinear or not representable)");
  }
  // BIC with a common robust scale (that of the most flexible fit), so that
  // every knot count is judged by the same yardstick:
  //   D_k = 2 s^2 / n sum rho(r_i / s) (= RSS / n without a robust loss),
  //   BIC_k = n log D_k + (2 + 2k) log n.
  const double s = fits.back().scale > 0 ? fits.back().scale : 1.0;
  const double nd = static_cast<double>(n);
  HingeFitResult result;
  std::vector<double> bic(static_cast<std::size_t>(options.max_knots) + 1, ranging::kNaN);
  // Exact fits tie at the rounding level (the penalty then picks the fewest knots).
  const double floor_scale =
      scale_floor(Eigen::Map<const Eigen::VectorXd>(p.y.data(), static_cast<Eigen::Index>(n)));
  const double d_floor = floor_scale * floor_scale;
  std::size_t best = 0;
  for (std::size_t k = 0; k < fits.size(); ++k) {
    double deviance = 0;
    for (Eigen::Index i = 0; i < fits[k].residuals.size(); ++i) {
      deviance += rho_of(fits[k].residuals(i) / s, options.robust.loss, options.robust);
    }
    const double d = std::max(2.0 * s * s * deviance / nd, d_floor);
    bic[k] = nd * std::log(d) + static_cast<double>(2 + 2 * k) * std::log(nd);
    if (bic[k] < bic[best]) best = k;
  }
  result = finish(p, u, fits[best].knots, fits[best].weights, options);
  result.bic = std::move(bic);
  result.irls_iterations = fits[best].iterations;
  return result;
}

HingeFitResult fit_hinge_fixed_knots(std::span<const double> x, std::span<const double> y,
                                     std::span<const double> knots,
                                     const HingeFitOptions& options) {
  const Prepared p = prepare(x, y, options);
  const std::size_t n = p.x.size();
  std::vector<double> u(n), knots_u;
  for (std::size_t i = 0; i < n; ++i) u[i] = (p.x[i] - p.center) / p.scale;
  for (std::size_t j = 0; j < knots.size(); ++j) {
    if (!std::isfinite(knots[j]) || (j > 0 && !(knots[j] > knots[j - 1]))) {
      throw std::invalid_argument("hinge fit of " + options.column +
                                  ": knots must be finite and strictly ascending");
    }
    knots_u.push_back((knots[j] - p.center) / p.scale);
  }
  if (n < 2 + knots.size()) {
    throw std::invalid_argument("too few rows for a hinge fit of " + options.column + ": " +
                                std::to_string(n) + " rows for " +
                                std::to_string(2 + knots.size()) + " parameters");
  }
  const Eigen::VectorXd yv =
      Eigen::Map<const Eigen::VectorXd>(p.y.data(), static_cast<Eigen::Index>(n));
  const RobustLinearFit fit = robust_linear_fit(hinge_design(u, knots_u), yv, options.robust);
  HingeFitResult result = finish(p, u, knots_u, fit.weights, options);
  result.irls_iterations = fit.iterations;
  return result;
}

std::string HingeFitResult::summary() const {
  std::string s = "hinge fit: " + std::to_string(rows) + " rows";
  if (rows_skipped > 0) s += " (" + std::to_string(rows_skipped) + " skipped)";
  char buffer[160];
  std::snprintf(buffer, sizeof buffer, ", domain [%.4g, %.4g], %zu knot(s)", x_min, x_max,
                knots.size());
  s += buffer;
  if (!knots.empty()) {
    s += " at";
    for (double k : knots) {
      std::snprintf(buffer, sizeof buffer, " %.4g", k);
      s += buffer;
    }
  }
  s += ", segment slopes";
  for (double slope : function.segment_slopes()) {
    std::snprintf(buffer, sizeof buffer, " %.4g", slope);
    s += buffer;
  }
  std::snprintf(buffer, sizeof buffer, ", residual RMS %.4g, robust sigma %.4g, %zu downweighted",
                residual_rms, robust_scale, rows_downweighted);
  s += buffer;
  if (!bic.empty()) {
    s += ", BIC";
    for (std::size_t k = 0; k < bic.size(); ++k) {
      std::snprintf(buffer, sizeof buffer, " k=%zu:%.1f", k, bic[k]);
      s += buffer;
    }
  }
  return s;
}

}  // namespace tofkit::calib
