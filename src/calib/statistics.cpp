#include "tofkit/calib/statistics.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <map>
#include <stdexcept>

namespace tofkit::calib {
namespace {

double quantile_sorted(const std::vector<double>& sorted, double q) {
  if (sorted.empty()) return ranging::kNaN;
  const double position = q * static_cast<double>(sorted.size() - 1);
  const auto below = static_cast<std::size_t>(std::floor(position));
  const std::size_t above = std::min(below + 1, sorted.size() - 1);
  const double fraction = position - static_cast<double>(below);
  return sorted[below] + fraction * (sorted[above] - sorted[below]);
}

GroupEvaluation evaluate_rows(const EvaluationColumns& c, const std::vector<std::size_t>& rows,
                              const TercileEdges& terciles) {
  GroupEvaluation g;
  g.rows = rows.size();
  std::vector<double> corrected, raw, sigma, amplitude;
  for (std::size_t i : rows) {
    if (!std::isfinite(c.distance_m[i])) {
      ++g.rows_without_range;
      continue;
    }
    corrected.push_back(c.truth_m[i] - c.distance_m[i]);
    raw.push_back(c.truth_m[i] - c.distance_raw_m[i]);
    sigma.push_back(c.sigma_m[i]);
    amplitude.push_back(c.amplitude[i]);
  }
  g.corrected = error_stats(corrected);
  g.raw = error_stats(raw);
  g.rms_improvement_pct = improvement_pct(g.raw.rms_m, g.corrected.rms_m);
  g.bias_improvement_pct = improvement_pct(g.raw.abs_bias_m, g.corrected.abs_bias_m);
  g.within_1_sigma = coverage(corrected, sigma, amplitude, 1.0, terciles);
  g.within_2_sigma = coverage(corrected, sigma, amplitude, 2.0, terciles);
  return g;
}

std::string mm(double metres) {
  char buffer[32];
  std::snprintf(buffer, sizeof buffer, "%9.3f", metres * 1e3);
  return buffer;
}

std::string pct(double value) {
  char buffer[32];
  std::snprintf(buffer, sizeof buffer, "%6.1f", value);
  return buffer;
}

}  // namespace

void require_magnitude(double v, const char* column, std::size_t index) {
  if (std::isfinite(v) && std::fabs(v) > kMaxMagnitude) {
    char buffer[160];
    std::snprintf(
        buffer, sizeof buffer,
        "%s = %.6g in data row %zu is too large (|value| must be below %.0e: a corrupt cell)",
        column, v, index + 1, kMaxMagnitude);
    throw std::invalid_argument(buffer);
  }
  // The columns with a physical range: a value outside it is impossible, and
  // fitted it had cost a fit minutes (one distance_true_m = -1 made a walk
  // chain's bootstrap take 143 s) or its sense (a 4.3e9 ns pulse width, NaN
  // BICs with exit 0).
  struct PhysicalRange {
    const char* column;
    double min, max;
    const char* why;
  };
  static constexpr PhysicalRange kRanges[] = {
      {"distance_true_m", 0.0, 1e6, "a true distance is in [0, 1e6] m"},
      {"pulse_width_ns", 0.0, 1e6, "an echo's width is in [0, 1e6] ns"},
      {"amplitude", 0.0, kMaxMagnitude, "an echo's amplitude is >= 0"},
      {"temperature_c", -273.15, 1e4, "a temperature is in [-273.15, 1e4] C"},
  };
  for (const auto& range : kRanges) {
    if (std::strcmp(range.column, column) != 0 || !std::isfinite(v)) continue;
    if (v < range.min || v > range.max) {
      char buffer[200];
      std::snprintf(buffer, sizeof buffer, "%s = %.6g in data row %zu is impossible (%s)", column,
                    v, index + 1, range.why);
      throw std::invalid_argument(buffer);
    }
  }
}

ErrorStats error_stats(std::span<const double> error_m) {
  ErrorStats s;
  double sum = 0, max_abs = 0;
  for (double e : error_m) {
    if (!std::isfinite(e)) continue;
    ++s.rows;
    sum += e;
    max_abs = std::max(max_abs, std::fabs(e));
  }
  if (s.rows == 0) return s;
  const double n = static_cast<double>(s.rows);
  s.bias_m = sum / n;  // Eq. 4.1
  double squares = 0;
  for (double e : error_m) {
    if (std::isfinite(e)) squares += (e - s.bias_m) * (e - s.bias_m);
  }
  s.abs_bias_m = std::fabs(s.bias_m);
  s.variance_m2 = squares / n;                               // Eq. 4.2
  s.rms_m = std::sqrt(s.bias_m * s.bias_m + s.variance_m2);  // Eq. 4.3
  s.max_abs_m = max_abs;
  return s;
}

double improvement_pct(double before, double after) {
  if (!std::isfinite(before) || !std::isfinite(after) || before == 0) return ranging::kNaN;
  return 100.0 * (before - after) / before;  // Eqs. 4.10-4.11
}

std::size_t fold_of(std::size_t group, std::size_t folds) {
  // SplitMix64's finalizer (Steele, Lea & Flood 2014): consecutive group
  // numbers map to well-mixed 64-bit values.
  std::uint64_t z = static_cast<std::uint64_t>(group) + 0x9E3779B97F4A7C15ull;
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
  z ^= z >> 31;
  return folds > 0 ? static_cast<std::size_t>(z % folds) : 0;
}

TercileEdges amplitude_terciles(std::span<const double> amplitude) {
  std::vector<double> sorted;
  for (double a : amplitude) {
    if (std::isfinite(a)) sorted.push_back(a);
  }
  std::sort(sorted.begin(), sorted.end());
  return {quantile_sorted(sorted, 1.0 / 3.0), quantile_sorted(sorted, 2.0 / 3.0)};
}

Coverage coverage(std::span<const double> error_m, std::span<const double> sigma_m,
                  std::span<const double> amplitude, double k_sigma, const TercileEdges& terciles) {
  if (error_m.size() != sigma_m.size() || error_m.size() != amplitude.size()) {
    throw std::invalid_argument("coverage: error, sigma and amplitude sizes differ");
  }
  Coverage c;
  c.k_sigma = k_sigma;
  std::size_t inside = 0;
  std::array<std::size_t, 3> tercile_inside{};
  for (std::size_t i = 0; i < error_m.size(); ++i) {
    if (!std::isfinite(error_m[i]) || !std::isfinite(sigma_m[i])) continue;
    const bool covered = std::fabs(error_m[i]) <= k_sigma * sigma_m[i];
    ++c.rows;
    inside += covered ? 1 : 0;
    if (std::isfinite(amplitude[i]) && std::isfinite(terciles.lower)) {
      const auto t = static_cast<std::size_t>(terciles.tercile(amplitude[i]));
      ++c.tercile_rows[t];
      tercile_inside[t] += covered ? 1 : 0;
    }
  }
  if (c.rows > 0) c.share = static_cast<double>(inside) / static_cast<double>(c.rows);
  for (std::size_t t = 0; t < 3; ++t) {
    if (c.tercile_rows[t] > 0) {
      c.tercile_share[t] =
          static_cast<double>(tercile_inside[t]) / static_cast<double>(c.tercile_rows[t]);
    }
  }
  return c;
}

Evaluation evaluate(const EvaluationColumns& c) {
  const std::size_t n = c.truth_m.size();
  if (c.distance_m.size() != n || c.distance_raw_m.size() != n || c.sigma_m.size() != n ||
      c.amplitude.size() != n || (!c.key.empty() && c.key.size() != n)) {
    throw std::invalid_argument("evaluate: columns differ in length");
  }
  Evaluation out;
  out.terciles = amplitude_terciles(c.amplitude);
  std::vector<std::size_t> all(n);
  for (std::size_t i = 0; i < n; ++i) all[i] = i;
  out.overall = evaluate_rows(c, all, out.terciles);
  if (!c.key.empty()) {
    // Equal keys form a group; NaN keys form no group (they still count overall).
    std::map<double, std::vector<std::size_t>> groups;
    for (std::size_t i = 0; i < n; ++i) {
      if (!std::isnan(c.key[i])) groups[c.key[i]].push_back(i);
    }
    for (const auto& [key, rows] : groups) {
      GroupEvaluation g = evaluate_rows(c, rows, out.terciles);
      g.key = key;
      out.groups.push_back(std::move(g));
    }
  }
  return out;
}

std::string Evaluation::summary() const {
  std::string s =
      "        key   rows  bias_mm   rms_mm  raw_rms_mm  improv_%  max_mm  in_1s_%  in_2s_%\n";
  const auto line = [&](const GroupEvaluation& g, const std::string& label) {
    char buffer[256];
    std::snprintf(buffer, sizeof buffer, "%11s %6zu %s %s %s  %s %s  %s  %s\n", label.c_str(),
                  g.rows, mm(g.corrected.bias_m).c_str(), mm(g.corrected.rms_m).c_str(),
                  mm(g.raw.rms_m).c_str(), pct(g.rms_improvement_pct).c_str(),
                  mm(g.corrected.max_abs_m).c_str(), pct(100 * g.within_1_sigma.share).c_str(),
                  pct(100 * g.within_2_sigma.share).c_str());
    s += buffer;
  };
  for (const GroupEvaluation& g : groups) {
    char key[32];
    std::snprintf(key, sizeof key, "%.6g", g.key);
    line(g, key);
  }
  line(overall, "all");
  return s;
}

}  // namespace tofkit::calib
