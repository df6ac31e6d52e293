#include "tofkit/device/receiver_echo.hpp"

#include <array>
#include <limits>
#include <map>
#include <mutex>

#include "random_draws.hpp"

namespace tofkit::device {

using detail::footprint_nodes;

std::size_t first_peak_index(const std::vector<double>& c, std::size_t begin) {
  const std::size_t n = c.size();
  double best[4] = {c[begin], c[begin], c[begin], c[begin]};
  bool nan = false;
  std::size_t i = begin;
  for (; i + 4 <= n; i += 4) {
    for (std::size_t k = 0; k < 4; ++k) {
      const double v = c[i + k];
      best[k] = best[k] > v ? best[k] : v;
      nan |= v != v;
    }
  }
  for (; i < n; ++i) {
    best[0] = best[0] > c[i] ? best[0] : c[i];
    nan |= c[i] != c[i];
  }
  if (nan)
    return static_cast<std::size_t>(
        std::max_element(c.begin() + static_cast<std::ptrdiff_t>(begin), c.end()) - c.begin());
  const double peak = std::max(std::max(best[0], best[1]), std::max(best[2], best[3]));
  i = begin;
  while (c[i] != peak) ++i;
  return i;
}

void StrideSearch::build(const std::vector<double>& c) {
  const std::size_t n = c.size();
  const std::size_t blocks = (n + kBlock - 1) / kBlock;
  minima_.assign(blocks * kStride, std::numeric_limits<double>::infinity());
  bool nan = false;
  for (std::size_t b = 0; b < blocks; ++b) {
    double* low = &minima_[b * kStride];
    const std::size_t begin = b * kBlock, end = std::min(n, begin + kBlock);
    std::size_t p = begin;
    for (; p + kStride <= end; p += kStride) {  // a row of kStride residues: vectorized
      for (std::size_t r = 0; r < kStride; ++r) {
        low[r] = c[p + r] < low[r] ? c[p + r] : low[r];
        nan |= c[p + r] != c[p + r];
      }
    }
    for (; p < end; ++p) {
      low[p % kStride] = c[p] < low[p % kStride] ? c[p] : low[p % kStride];
      nan |= c[p] != c[p];
    }
  }
  has_nan_ = nan;
}

std::size_t StrideSearch::fall_index(const std::vector<double>& c, std::size_t i0,
                                     double level) const {
  const std::size_t n = c.size();
  std::size_t i = i0;
  if (has_nan_) {
    while (i + kStride < n && c[i + kStride] >= level) i += kStride;
  } else {
    // The first p = i0 + m kStride (m >= 1) at or past the end or below the level.
    std::size_t p = i0 + kStride;
    const std::size_t block_end = std::min(n, (p / kBlock + 1) * kBlock);
    while (p < block_end && c[p] >= level) p += kStride;
    if (p >= block_end && p < n) {
      while (p < n && minima_[(p / kBlock) * kStride + p % kStride] >= level) p += kBlock;
      while (p < n && c[p] >= level) p += kStride;
    }
    if (p >= n) p = i0 + kStride * ((n - i0 + kStride - 1) / kStride);
    i = p - kStride;
  }
  while (i < n && c[i] >= level) ++i;
  return i;
}

double sampled_crossing_times(const std::vector<double>& c, double begin_ns, double step_ns,
                              double peak_time_ns, double level_lo_v, double level_step_v,
                              bool gated, std::size_t i_gate, double gate_ns,
                              std::vector<double>& rise_ns, std::vector<double>& fall_ns) {
  const std::size_t n = c.size(), levels = rise_ns.size();
  double level_top_v = 0;
  auto time_at = [&](std::size_t i, double frac) {
    return begin_ns + (static_cast<double>(i) + frac) * step_ns;
  };
  if (gated) {
    // Blanked: the first upcrossing after the blanking (NaN: none; a level
    // already exceeded when the comparator is released is not a crossing),
    // and the first downcrossing after it (or after the blanking).
    // No level's upcrossing comes before the first sample at or above the
    // lowest level after the gate: every search starts there.
    std::size_t i_first = std::max<std::size_t>(i_gate, 1);
    while (i_first < n && c[i_first] < level_lo_v) ++i_first;
    for (std::size_t j = 0; j < levels; ++j) {
      const double level = level_lo_v + static_cast<double>(j) * level_step_v;
      double rise = std::numeric_limits<double>::quiet_NaN(), fall = peak_time_ns;
      std::size_t i = i_first;
      for (; i < n; ++i) {
        const double a = c[i - 1], b = c[i];
        if (a < level && b >= level) {
          const double t = time_at(i - 1, (level - a) / (b - a));
          if (t >= gate_ns) {
            rise = t;
            break;
          }
        }
      }
      std::size_t k = i < n ? i : std::max<std::size_t>(i_gate, 1);
      for (; k < n; ++k) {
        const double a = c[k - 1], b = c[k];
        if (a >= level && b < level) {
          fall = time_at(k - 1, (a - level) / (a - b));
          break;
        }
      }
      if (!std::isnan(rise)) {
        level_top_v = level;
        fall = std::max(fall, rise);
      }
      rise_ns[j] = rise;
      fall_ns[j] = fall;
    }
  } else {
    // The first upcrossing index never decreases with the level: one forward pointer.
    // The downcrossing after it is found with a coarse stride (echo features span
    // hundreds of grid steps), then refined step by step (StrideSearch).
    thread_local StrideSearch falls;
    falls.build(c);
    std::size_t i_rise = 1;
    for (std::size_t j = 0; j < levels; ++j) {
      const double level = level_lo_v + static_cast<double>(j) * level_step_v;
      double rise = peak_time_ns, fall = peak_time_ns;
      while (i_rise < n && c[i_rise] < level) ++i_rise;
      if (i_rise < n) {
        level_top_v = level;
        const double a = c[i_rise - 1], b = c[i_rise];
        rise = time_at(i_rise - 1, (level - a) / (b - a));
        const std::size_t i = falls.fall_index(c, i_rise, level);
        if (i < n) {
          const double c0 = c[i - 1], d = c[i];
          fall = time_at(i - 1, (c0 - level) / (c0 - d));
        }
      }
      rise_ns[j] = rise;
      fall_ns[j] = std::max(fall, rise);
    }
  }
  return level_top_v;
}

SpreadEchoTable::SpreadEchoTable(const physics::PulseTemplate& pulse) {
  const auto& nodes = footprint_nodes();
  // Spread step: a small fraction of the echo's half-maximum width.
  step_ns_ = pulse.width_at_level_ns(0.5) / 64.0;
  inv_step_ = 1.0 / step_ns_;
  const double sqrt_half = std::sqrt(0.5);
  high_scale_ = static_cast<double>(kHigh - 1) / sqrt_half;
  std::vector<double> g;
  std::vector<double> levels(kLow + kHigh);
  for (std::size_t j = 0; j < kLow; ++j) levels[j] = low_level(j);
  for (std::size_t j = 0; j < kHigh; ++j) {
    const double s = sqrt_half * (1.0 - static_cast<double>(j) / static_cast<double>(kHigh - 1));
    levels[kLow + j] = j + 1 == kHigh ? 1.0 : 1.0 - s * s;
  }
  double evaluations = 0;  // build cost: long templates get fewer rows
  for (std::size_t r = 0; r < kMaxRows && evaluations < kMaxEvaluations; ++r) {
    const double h = static_cast<double>(r) * step_ns_;
    const double t0 = pulse.begin_ns() - h - kSampleNs;
    const auto n = static_cast<std::size_t>((pulse.end_ns() + h + kSampleNs - t0) / kSampleNs) + 2;
    g.assign(n, 0.0);
    evaluations += static_cast<double>(n * nodes.u.size());
    for (std::size_t i = 0; i < n; ++i) {
      const double t = t0 + static_cast<double>(i) * kSampleNs;
      double v = 0;
      for (std::size_t k = 0; k < nodes.u.size(); ++k)
        v += nodes.w[k] * pulse(t - (r == 0 ? 0.0 : nodes.u[k] * h));
      g[i] = v;
    }
    const auto peak_i = static_cast<std::size_t>(std::max_element(g.begin(), g.end()) - g.begin());
    // One peak: non-decreasing before it, non-increasing after.
    bool single = peak_i > 0 && peak_i + 1 < n;
    for (std::size_t i = 1; single && i <= peak_i; ++i) single = g[i] >= g[i - 1];
    for (std::size_t i = peak_i + 1; single && i < n; ++i) single = g[i] <= g[i - 1];
    if (!single) break;
    // Peak between samples: the parabola through the three around the largest.
    const double a = g[peak_i - 1], b = g[peak_i], c = g[peak_i + 1];
    const double den = a - 2.0 * b + c;
    const double off = den < 0 ? std::clamp(0.5 * (a - c) / den, -0.5, 0.5) : 0.0;
    const double peak = b - 0.25 * (a - c) * off;
    const double peak_t = t0 + (static_cast<double>(peak_i) + off) * kSampleNs;
    peaks_.push_back(peak);
    peak_times_.push_back(peak_t);
    const std::size_t base = times_.size();
    times_.resize(base + kRowSize);
    double* rise = &times_[base];
    double* fall = rise + (kLow + kHigh);
    std::size_t i_rise = 1, i_fall = n - 2;
    for (std::size_t j = 0; j < kLow + kHigh; ++j) {
      const double level = levels[j] * peak;
      if (levels[j] >= 1.0) {
        rise[j] = fall[j] = peak_t;
        continue;
      }
      while (i_rise < peak_i && g[i_rise] < level) ++i_rise;
      const double ra = g[i_rise - 1], rb = g[i_rise];
      rise[j] = rb > ra
                    ? t0 + (static_cast<double>(i_rise - 1) + (level - ra) / (rb - ra)) * kSampleNs
                    : t0 + static_cast<double>(i_rise) * kSampleNs;
      while (i_fall > peak_i && g[i_fall] < level) --i_fall;
      const double fa = g[i_fall], fb = g[i_fall + 1];
      fall[j] = fa > fb ? t0 + (static_cast<double>(i_fall) + (fa - level) / (fa - fb)) * kSampleNs
                        : t0 + static_cast<double>(i_fall) * kSampleNs;
      rise[j] = std::min(rise[j], peak_t);
      fall[j] = std::max(fall[j], peak_t);
    }
  }
  max_spread_ns_ = static_cast<double>(peaks_.size() - 1) * step_ns_;
}

std::shared_ptr<const SpreadEchoTable> spread_table(const physics::PulseTemplate& pulse,
                                                    double fwhm_ns, double bandwidth_mhz,
                                                    double onset_ns) {
  static std::mutex mutex;
  static std::map<std::array<double, 3>, std::shared_ptr<const SpreadEchoTable>> cache;
  const std::lock_guard lock(mutex);
  const std::array key{fwhm_ns, bandwidth_mhz, onset_ns};
  if (const auto it = cache.find(key); it != cache.end()) return it->second;
  if (cache.size() >= 8) cache.clear();  // devices keep their own reference
  auto table = std::make_shared<const SpreadEchoTable>(pulse);
  cache.emplace(key, table);
  return table;
}

}  // namespace tofkit::device
