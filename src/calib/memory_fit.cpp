#include "tofkit/calib/memory_fit.hpp"

#include <array>
#include <cmath>
#include <stdexcept>
#include <vector>

namespace tofkit::calib {
namespace {

/// Least squares of y on three columns via the normal equations (Cholesky-free
/// Gaussian elimination on a 3x3 system, well conditioned after centring).
bool solve3(const std::vector<std::array<double, 3>>& a, const std::vector<double>& y,
            std::array<double, 3>& coef, double& sse) {
  std::array<std::array<double, 4>, 3> m{};
  for (std::size_t i = 0; i < y.size(); ++i) {
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 3; ++c) m[r][c] += a[i][r] * a[i][c];
      m[r][3] += a[i][r] * y[i];
    }
  }
  for (int p = 0; p < 3; ++p) {
    int best = p;
    for (int r = p + 1; r < 3; ++r)
      if (std::abs(m[r][p]) > std::abs(m[best][p])) best = r;
    std::swap(m[p], m[best]);
    if (!(std::abs(m[p][p]) > 1e-300)) return false;
    for (int r = 0; r < 3; ++r) {
      if (r == p) continue;
      const double f = m[r][p] / m[p][p];
      for (int c = p; c < 4; ++c) m[r][c] -= f * m[p][c];
    }
  }
  for (int r = 0; r < 3; ++r) coef[r] = m[r][3] / m[r][r];
  sse = 0;
  for (std::size_t i = 0; i < y.size(); ++i) {
    const double e = y[i] - (coef[0] * a[i][0] + coef[1] * a[i][1] + coef[2] * a[i][2]);
    sse += e * e;
  }
  return true;
}

}  // namespace

void MemoryFitOptions::validate() const {
  if (!(time_constant_min_s > 0))
    throw std::invalid_argument("memory fit: time_constant_min_s must be positive");
  if (!(time_constant_max_s > time_constant_min_s))
    throw std::invalid_argument("memory fit: time_constant_max_s must exceed time_constant_min_s");
  if (candidates < 2) throw std::invalid_argument("memory fit: candidates must be >= 2");
}

MemoryFitResult fit_memory_correction(std::span<const double> time_s,
                                      std::span<const ranging::RawMeasurement> raw,
                                      std::span<const double> truth_m,
                                      const MemoryFitOptions& options) {
  options.validate();
  if (time_s.size() != raw.size() || truth_m.size() != raw.size())
    throw std::invalid_argument("memory fit: time, raw and truth differ in size");
  std::vector<double> lag(raw.size());
  MemoryFitResult best;
  double best_sse = INFINITY;
  for (int k = 0; k < options.candidates; ++k) {
    const double tau = options.time_constant_min_s *
                       std::pow(options.time_constant_max_s / options.time_constant_min_s,
                                static_cast<double>(k) / (options.candidates - 1));
    ranging::memory_lag(tau, 30.0, time_s, raw, lag);
    std::vector<std::array<double, 3>> a;
    std::vector<double> y;
    double x_mean = 0;
    for (std::size_t i = 0; i < raw.size(); ++i) {
      const double x = ranging::echo_strength_neper(raw[i]);
      if (!std::isfinite(lag[i]) || !std::isfinite(truth_m[i]) || !std::isfinite(x)) continue;
      a.push_back({1.0, x, lag[i]});
      y.push_back(truth_m[i] - raw[i].distance_raw_m);
      x_mean += x;
    }
    if (y.size() < 10)
      throw std::invalid_argument("memory fit: fewer than 10 outputs with an echo and a truth");
    x_mean /= static_cast<double>(y.size());
    for (auto& row : a) row[1] -= x_mean;
    std::array<double, 3> coef{};
    double sse = 0;
    if (!solve3(a, y, coef, sse)) continue;
    if (sse < best_sse) {
      best_sse = sse;
      best.correction.time_constant_s = tau;
      best.correction.gain_m_per_neper = coef[2];
      best.rows = y.size();
      best.residual_rms_m = std::sqrt(sse / static_cast<double>(y.size()));
      double mean = 0, var = 0;
      for (const double v : y) mean += v;
      mean /= static_cast<double>(y.size());
      for (const double v : y) var += (v - mean) * (v - mean);
      best.error_rms_m = std::sqrt(var / static_cast<double>(y.size()));
    }
  }
  if (!std::isfinite(best_sse))
    throw std::invalid_argument("memory fit: the regression is singular (no step in the scan?)");
  return best;
}

}  // namespace tofkit::calib
