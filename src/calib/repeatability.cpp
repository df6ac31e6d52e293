#include "tofkit/calib/repeatability.hpp"

#include <algorithm>
#include <cmath>
#include <map>
#include <stdexcept>
#include <vector>

#include "tofkit/calib/statistics.hpp"

namespace tofkit::calib {

RepeatabilitySplit split_noise_systematic(std::span<const double> error_m,
                                          std::span<const std::size_t> group_id) {
  if (error_m.size() != group_id.size())
    throw std::invalid_argument("split_noise_systematic: error and group spans differ in length");
  struct Sum {
    std::size_t n = 0;
    double sum = 0, sum_sq = 0;
  };
  std::map<std::size_t, Sum> groups;
  for (std::size_t i = 0; i < error_m.size(); ++i) {
    if (!std::isfinite(error_m[i])) continue;
    auto& g = groups[group_id[i]];
    ++g.n;
    g.sum += error_m[i];
  }
  RepeatabilitySplit out;
  if (groups.empty()) return out;
  // Second pass about each group's mean (two-pass sums: no cancellation).
  for (std::size_t i = 0; i < error_m.size(); ++i) {
    if (!std::isfinite(error_m[i])) continue;
    auto& g = groups[group_id[i]];
    const double d = error_m[i] - g.sum / static_cast<double>(g.n);
    g.sum_sq += d * d;
  }
  double within = 0;
  std::size_t dof = 0;
  std::vector<double> means;
  means.reserve(groups.size());
  for (const auto& [id, g] : groups) {
    means.push_back(g.sum / static_cast<double>(g.n));
    within += g.sum_sq;
    dof += g.n - 1;
    out.rows += g.n;
  }
  out.groups = groups.size();
  const auto ng = static_cast<double>(out.groups);
  const ErrorStats of_means = error_stats(means);
  out.systematic_mean_m = of_means.bias_m;
  out.systematic_max_abs_m = of_means.max_abs_m;
  if (dof == 0) return out;
  out.noise_m = std::sqrt(within / static_cast<double>(dof));
  // Each group mean carries noise^2 / n_g of variance: remove its average.
  double mean_noise_var = 0;
  for (const auto& [id, g] : groups)
    mean_noise_var += out.noise_m * out.noise_m / static_cast<double>(g.n);
  mean_noise_var /= ng;
  out.noise_of_mean_m = std::sqrt(mean_noise_var);
  out.systematic_rms_m = std::sqrt(std::max(0.0, of_means.rms_m * of_means.rms_m - mean_noise_var));
  return out;
}

}  // namespace tofkit::calib
