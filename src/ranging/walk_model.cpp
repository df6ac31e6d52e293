#include "tofkit/ranging/walk_model.hpp"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <stdexcept>
#include <string>

namespace tofkit::ranging {
namespace {

/// Samples per shortest time constant of the shape: crossing times are
/// interpolated linearly between samples (error ~ step^2, far below a ps).
constexpr double kSamplesPerTimeConstant = 120.0;
/// Nodes of the uniform width table applied to measurements.
constexpr std::size_t kTableNodes = 4096;

/// The echo shape sampled at t0 + i dt: a Gaussian pulse through two equal
/// poles, each an exact first-order recursion (the impulse response
/// exp(-t / tau) / tau integrated over one step). A common delay of the samples
/// shifts both crossings alike and cancels in widths and relative walks.
std::vector<double> sample_shape(const WalkShape& s, double& t0, double& dt) {
  dt = std::min(s.pulse_sigma_ns, s.pole_time_constant_ns) / kSamplesPerTimeConstant;
  t0 = -8.0 * s.pulse_sigma_ns;
  // The two-pole tail (t / tau) exp(-t / tau) falls below e^-kMaxLogOverdrive
  // well within 8 sigma + 22 tau.
  const double t1 = 8.0 * s.pulse_sigma_ns + 22.0 * s.pole_time_constant_ns;
  const auto n = static_cast<std::size_t>((t1 - t0) / dt) + 2;
  std::vector<double> p(n);
  const double alpha = -std::expm1(-dt / s.pole_time_constant_ns);
  double y1 = 0, y2 = 0;
  for (std::size_t i = 0; i < n; ++i) {
    const double t = t0 + static_cast<double>(i) * dt;
    const double x = std::exp(-0.5 * (t / s.pulse_sigma_ns) * (t / s.pulse_sigma_ns));
    y1 += alpha * (x - y1);
    y2 += alpha * (y1 - y2);
    p[i] = y2;
  }
  return p;
}

}  // namespace

void WalkShape::validate() const {
  const auto positive = [](double v, const char* name) {
    if (!(std::isfinite(v) && v > 0)) {
      throw std::invalid_argument(std::string("walk shape: ") + name +
                                  " must be finite and > 0, is " + std::to_string(v));
    }
  };
  positive(pulse_sigma_ns, "pulse_sigma_ns");
  positive(pole_time_constant_ns, "pole_time_constant_ns");
  if (pulse_sigma_ns / pole_time_constant_ns > 1e3 ||
      pole_time_constant_ns / pulse_sigma_ns > 1e3 || pulse_sigma_ns > 1e3 ||
      pole_time_constant_ns > 1e3) {
    throw std::invalid_argument(
        "walk shape: pulse_sigma_ns and pole_time_constant_ns must be within a factor 1000 of "
        "each other and at most 1000 ns");
  }
  if (std::isnan(saturation_log_overdrive) || saturation_log_overdrive <= 0) {
    throw std::invalid_argument(
        "walk shape: saturation_log_overdrive must be > 0 (or infinite: no clipping)");
  }
  if (!(std::isfinite(recovery_ns_per_neper) && recovery_ns_per_neper >= 0)) {
    throw std::invalid_argument("walk shape: recovery_ns_per_neper must be finite and >= 0");
  }
}

WalkCurve walk_curve(const WalkShape& shape, std::size_t levels) {
  shape.validate();
  double t0 = 0, dt = 0;
  std::vector<double> p = sample_shape(shape, t0, dt);
  const auto peak_it = std::max_element(p.begin(), p.end());
  const double peak = *peak_it;
  for (double& v : p) v /= peak;
  const auto ip = static_cast<std::size_t>(peak_it - p.begin());
  const auto time = [&](std::size_t i, double f) { return t0 + (static_cast<double>(i) + f) * dt; };

  WalkCurve c;
  std::size_t rise = ip, fall = ip;
  for (std::size_t j = 1; j <= levels; ++j) {
    // Denser near a = 1, where the width grows like sqrt(ln a).
    const double u = static_cast<double>(j) / static_cast<double>(levels);
    const double log_a = kMaxLogOverdrive * u * u;
    const double level = std::exp(-log_a);
    while (rise > 0 && p[rise] > level) --rise;
    while (fall + 1 < p.size() && p[fall] > level) ++fall;
    if (p[rise] > level || p[fall] > level) break;  // the samples do not reach the level
    // Linear interpolation between the samples around each crossing.
    const double t_rise = time(rise, (level - p[rise]) / (p[rise + 1] - p[rise]));
    const double t_fall = time(fall - 1, (p[fall - 1] - level) / (p[fall - 1] - p[fall]));
    double width = t_fall - t_rise;
    if (log_a > shape.saturation_log_overdrive) {
      // Clipped: the amplifier stays saturated tau_r per e-fold of overdrive longer.
      width += shape.recovery_ns_per_neper * (log_a - shape.saturation_log_overdrive);
    }
    if (!c.width_ns.empty() && !(width > c.width_ns.back())) continue;  // keep w strictly ascending
    c.log_overdrive.push_back(log_a);
    c.width_ns.push_back(width);
    c.rise_ns.push_back(t_rise);
  }
  if (c.width_ns.size() < 2) throw std::invalid_argument("walk shape: no crossings tabulated");
  return c;
}

double curve_at_width(const WalkCurve& c, const std::vector<double>& column, double width_ns) {
  const std::vector<double>& w = c.width_ns;
  const auto k = static_cast<std::size_t>(
      std::clamp<std::ptrdiff_t>(std::upper_bound(w.begin(), w.end(), width_ns) - w.begin(), 1,
                                 static_cast<std::ptrdiff_t>(w.size()) - 1));
  const double f = (width_ns - w[k - 1]) / (w[k] - w[k - 1]);
  return column[k - 1] + f * (column[k] - column[k - 1]);
}

std::vector<double> walk_parameters(const WalkShape& shape) {
  std::vector<double> q{std::log(shape.pulse_sigma_ns), std::log(shape.pole_time_constant_ns)};
  if (std::isfinite(shape.saturation_log_overdrive)) {
    q.push_back(std::log(shape.recovery_ns_per_neper));
    q.push_back(shape.saturation_log_overdrive);
  }
  return q;
}

WalkShape walk_shape_of(std::span<const double> q) {
  if (q.size() != 2 && q.size() != 4) {
    throw std::invalid_argument("walk shape: 2 or 4 parameters expected");
  }
  WalkShape s;
  s.pulse_sigma_ns = std::exp(q[0]);
  s.pole_time_constant_ns = std::exp(q[1]);
  if (q.size() == 4) {
    s.recovery_ns_per_neper = std::exp(q[2]);
    s.saturation_log_overdrive = q[3];
  }
  return s;
}

std::vector<WalkShape> walk_sigma_points(const WalkShape& shape,
                                         std::span<const double> covariance) {
  const std::vector<double> q = walk_parameters(shape);
  const auto k = static_cast<Eigen::Index>(q.size());
  if (covariance.size() != q.size() * q.size()) {
    throw std::invalid_argument("walk step: shape_covariance must be " + std::to_string(k) + " x " +
                                std::to_string(k) + " (the shape's " + std::to_string(k) +
                                " parameters), has " + std::to_string(covariance.size()) +
                                " values");
  }
  const Eigen::Map<const Eigen::MatrixXd> c(covariance.data(), k, k);
  if (!c.allFinite()) throw std::invalid_argument("walk step: shape_covariance is not finite");
  const double norm = c.cwiseAbs().maxCoeff();
  if (!((c - c.transpose()).cwiseAbs().maxCoeff() <= 1e-9 * norm)) {
    throw std::invalid_argument("walk step: shape_covariance is not symmetric");
  }
  const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eigen(0.5 * (c + c.transpose()));
  if (!(eigen.eigenvalues().minCoeff() >= -1e-9 * norm)) {
    throw std::invalid_argument("walk step: shape_covariance is not positive semi-definite");
  }
  std::vector<WalkShape> points;
  for (Eigen::Index a = 0; a < k; ++a) {
    const double variance = eigen.eigenvalues()(a);
    if (!(variance > 0)) continue;
    const Eigen::VectorXd step =
        std::sqrt(static_cast<double>(k) * variance) * eigen.eigenvectors().col(a);
    for (double fraction = 1.0; fraction >= 1.0 / 64; fraction *= 0.5) {
      std::vector<double> plus = q, minus = q;
      for (Eigen::Index j = 0; j < k; ++j) {
        plus[static_cast<std::size_t>(j)] += fraction * step(j);
        minus[static_cast<std::size_t>(j)] -= fraction * step(j);
      }
      try {
        const WalkShape p = walk_shape_of(plus), m = walk_shape_of(minus);
        p.validate();
        m.validate();
        points.push_back(p);
        points.push_back(m);
        break;
      } catch (const std::invalid_argument&) {
      }
    }
  }
  return points;
}

WalkModel::WalkModel(WalkShape shape, double reference_pulse_width_ns,
                     std::vector<WalkShape> replicates)
    : shape_(shape), reference_ns_(reference_pulse_width_ns), replicates_(std::move(replicates)) {
  if (!std::isfinite(reference_pulse_width_ns)) {
    throw std::invalid_argument("walk step: reference_pulse_width_ns must be finite");
  }
  const WalkCurve curve = walk_curve(shape_);
  width_max_ns_ = curve.width_ns.back();
  step_ = width_max_ns_ / static_cast<double>(kTableNodes - 1);
  inv_step_ = 1.0 / step_;
  const double reference = rise_at_width(curve, reference_ns_);
  rise_.resize(kTableNodes);
  for (std::size_t k = 0; k < kTableNodes; ++k) {
    rise_[k] = rise_at_width(curve, static_cast<double>(k) * step_) - reference;
  }
  const std::size_t m = curve.width_ns.size();
  slope_above_ = (curve.rise_ns[m - 1] - curve.rise_ns[m - 2]) /
                 (curve.width_ns[m - 1] - curve.width_ns[m - 2]);
  if (replicates_.size() > kMaxWalkReplicates) {
    throw std::invalid_argument("walk step: at most " + std::to_string(kMaxWalkReplicates) +
                                " shape_replicates, has " + std::to_string(replicates_.size()));
  }
  replicate_models_.reserve(replicates_.size());
  for (std::size_t r = 0; r < replicates_.size(); ++r) {
    try {
      replicate_models_.push_back(std::make_shared<const WalkModel>(replicates_[r], reference_ns_));
    } catch (const std::invalid_argument& e) {
      throw std::invalid_argument("walk step: shape_replicates[" + std::to_string(r) +
                                  "]: " + e.what());
    }
  }
}

double WalkModel::relative_rise_variance_ns2(double width_ns) const {
  if (replicate_models_.empty()) return 0.0;
  const double rise = relative_rise_ns(width_ns);
  double sum = 0;
  for (const auto& r : replicate_models_) {
    const double d = r->relative_rise_ns(width_ns) - rise;
    sum += d * d;
  }
  return sum / static_cast<double>(replicate_models_.size());
}

double WalkModel::relative_rise_ns(double width_ns) const {
  double out = 0;
  relative_rise_ns(&width_ns, &out, 1);
  return out;
}

void WalkModel::relative_rise_ns(const double* width_ns, double* rise_ns, std::size_t n) const {
  const double last = static_cast<double>(kTableNodes - 1);
  for (std::size_t i = 0; i < n; ++i) {
    const double w = width_ns[i];
    if (std::isnan(w)) {
      rise_ns[i] = w;
      continue;
    }
    const double x = std::max(0.0, w * inv_step_);
    if (x >= last) {
      rise_ns[i] = rise_.back() + slope_above_ * (w - width_max_ns_);
      continue;
    }
    const auto k = static_cast<std::size_t>(x);
    const double f = x - static_cast<double>(k);
    rise_ns[i] = rise_[k] + f * (rise_[k + 1] - rise_[k]);
  }
}

std::string WalkModel::summary() const {
  char buffer[256];
  std::snprintf(buffer, sizeof buffer,
                "pulse sigma %.4g ns, pole time constant %.4g ns, clipping at ln(A/V) %.4g, "
                "recovery %.4g ns/neper, reference width %.4g ns",
                shape_.pulse_sigma_ns, shape_.pole_time_constant_ns,
                shape_.saturation_log_overdrive, shape_.recovery_ns_per_neper, reference_ns_);
  return buffer;
}

}  // namespace tofkit::ranging
