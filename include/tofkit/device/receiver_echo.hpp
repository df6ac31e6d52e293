#pragma once
/// \file The receiver stage's echo of one surface: the pulse template (the
/// emitted pulse through the receiver's response, physics/pulse_template.hpp)
/// summed over a tilted footprint, tabulated once per pulse shape with its
/// peak and its threshold-crossing times for every level (SpreadEchoTable);
/// and the searches on a sampled composite echo (first_peak_index,
/// StrideSearch) and the crossing tables of a sampled composite echo
/// (sampled_crossing_times), the exact path's.

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <vector>

#include "tofkit/physics/pulse_template.hpp"

namespace tofkit::device {

/// Where std::max_element puts a sampled echo's peak over [begin, size): the
/// first of the largest samples. Four running maxima (independent chains
/// instead of one compare-and-branch per sample), then the first sample equal
/// to their largest; with a NaN in the echo, std::max_element itself.
std::size_t first_peak_index(const std::vector<double>& c, std::size_t begin);

/// The downcrossing search of the exact path's crossing tables: from the
/// rise's index i0, strides of kStride while the sample kStride ahead is at or
/// above the level, then step by step. A saturated echo stays above the
/// comparator's levels for thousands of grid steps, and each of the 129 levels
/// strode over them. The smallest sample of each residue class (mod kStride)
/// in aligned blocks of kBlock samples lets the search skip a block whose
/// samples on its stride all stay at or above the level: the index the plain
/// stride reaches, after far fewer reads.
class StrideSearch {
 public:
  static constexpr std::size_t kStride = 8, kBlock = 128;

  void build(const std::vector<double>& c);

  /// The index where `while (i + kStride < n && c[i + kStride] >= level) i += kStride;
  /// while (i < n && c[i] >= level) ++i;` from i = i0 stops.
  [[nodiscard]] std::size_t fall_index(const std::vector<double>& c, std::size_t i0,
                                       double level) const;

 private:
  std::vector<double> minima_;  // [block * kStride + residue]
  bool has_nan_ = false;
};

/// The crossing tables of a sampled echo c (sample i at begin_ns + i step_ns,
/// linear between samples): for each comparator level
/// L_j = level_lo_v + j level_step_v (j < rise_ns.size(), fall_ns the same
/// size), the first upcrossing and the following downcrossing (in ns; both at
/// peak_time_ns for a level the echo never reaches; the fall never before the
/// rise). The upcrossings' sample never decreases with the level (one forward
/// pointer), and the downcrossings are found with StrideSearch.
/// `gated`: the comparator is blanked before gate_ns and released at sample
/// i_gate >= 1: an upcrossing counts only at or after gate_ns (NaN: none; a
/// level already exceeded at the release is not crossed), the downcrossing is
/// the first after it (or after the release). Returns the highest level
/// crossed (0: none).
[[nodiscard]] double sampled_crossing_times(const std::vector<double>& c, double begin_ns,
                                            double step_ns, double peak_time_ns, double level_lo_v,
                                            double level_step_v, bool gated, std::size_t i_gate,
                                            double gate_ns, std::vector<double>& rise_ns,
                                            std::vector<double>& fall_ns);

/// The echo of one surface, tabulated once per pulse shape in normalized form.
/// A surface at delay d, amplitude A and footprint spread h (ns of round trip
/// over the half depth) gives the echo A g_h(t - d) with
/// g_h(t) = sum_k w_k p(t - u_k h), p the pulse template. Its crossings of a
/// level L are d + rise_h(L / A) and d + fall_h(L / A). Rows hold g_h for
/// h = 0, dh, 2 dh, ... as long as g_h has a single peak (then the first
/// upcrossing and the next downcrossing are the two branches of its inverse);
/// each row holds the peak P_h, its time and both branches over the level
/// y = x / P_h: log-spaced below 1/2 (pseudo-log2 of the double's bits, 32
/// per octave, down to 2^-32) and uniform in sqrt(1 - y) above (the peak is
/// parabolic there). Between rows the times are interpolated linearly in h.
class SpreadEchoTable {
 public:
  static constexpr int kLowestExponent = -32;  // y below 2^-32: the first entry
  static constexpr int kOctaves = 31;
  static constexpr int kPerOctave = 32;
  static constexpr std::size_t kLow = kOctaves * kPerOctave + 1;  // y in [2^-32, 1/2]
  static constexpr std::size_t kHigh = 257;                       // y in [1/2, 1]
  static constexpr std::size_t kRowSize = 2 * (kLow + kHigh);
  static constexpr std::size_t kMaxRows = 256;
  static constexpr double kSampleNs = 0.005;      // the template's own step
  static constexpr double kMaxEvaluations = 3e7;  // pulse evaluations to build the rows

  explicit SpreadEchoTable(const physics::PulseTemplate& pulse);

  /// Largest spread covered (ns); beyond it the echo may have several peaks.
  [[nodiscard]] double max_spread_ns() const { return max_spread_ns_; }

  struct At {
    std::size_t row = 0;
    double w = 0;  // weight of row + 1
  };
  [[nodiscard]] At at(double spread_ns) const {
    const double f = spread_ns * inv_step_;
    At a;
    a.row = std::min(static_cast<std::size_t>(f), peaks_.size() - 1);
    a.w = a.row + 1 < peaks_.size() ? f - static_cast<double>(a.row) : 0.0;
    return a;
  }
  [[nodiscard]] double peak(At a) const { return mix(a, peaks_); }
  [[nodiscard]] double peak_time_ns(At a) const { return mix(a, peak_times_); }
  /// Peak of a row (the level y of a row is x / row_peak).
  [[nodiscard]] double row_peak(std::size_t row) const { return peaks_[row]; }
  /// First upcrossing / following downcrossing of the levels y0 = x / P_row and
  /// y1 = x / P_row+1 (x: level over amplitude), interpolated between the rows.
  [[nodiscard]] double rise_ns(At a, double y0, double y1) const { return cross(a, y0, y1, 0); }
  [[nodiscard]] double fall_ns(At a, double y0, double y1) const {
    return cross(a, y0, y1, kLow + kHigh);
  }
  /// Both at the same level: rise_ns and fall_ns, sharing the level's place in the rows.
  void rise_fall_ns(At a, double y0, double y1, double& rise, double& fall) const {
    row_cross_both(a.row, y0, rise, fall);
    if (a.w <= 0) return;
    double rise1 = 0, fall1 = 0;
    row_cross_both(a.row + 1, y1, rise1, fall1);
    rise += a.w * (rise1 - rise);
    fall += a.w * (fall1 - fall);
  }

 private:
  static double low_level(std::size_t j) {
    const double pl = kLowestExponent + static_cast<double>(j) / kPerOctave;
    const double e = std::floor(pl);
    return std::ldexp(1.0 + (pl - e), static_cast<int>(e));
  }
  static double mix(At a, const std::vector<double>& v) {
    return a.w > 0 ? v[a.row] + a.w * (v[a.row + 1] - v[a.row]) : v[a.row];
  }
  /// Where level y falls in a row: entry i and weight w of entry i + 1; false
  /// at the peak (y >= 1).
  [[nodiscard]] bool row_position(double y, std::size_t& i, double& w) const {
    double f = 0;
    if (y >= 0.5) {
      if (y >= 1.0) return false;
      f = static_cast<double>(kLow) + std::sqrt(0.5) * high_scale_ -
          std::sqrt(1.0 - y) * high_scale_;
    } else {
      // (bits(y) - bits(2^-32)) / 2^52 is log2(y) + 32, piecewise linear in y.
      constexpr auto kBase = std::bit_cast<std::int64_t>(0x1p-32);
      const auto bits = std::bit_cast<std::int64_t>(y) - kBase;
      if (bits <= 0) {
        i = 0;
        w = 0;
        return true;
      }
      f = static_cast<double>(bits) * (kPerOctave * 0x1p-52);
    }
    i = std::min(static_cast<std::size_t>(f), kLow + kHigh - 2);
    w = f - static_cast<double>(i);
    return true;
  }
  /// Entry i of t moved w of the way to entry i + 1.
  static double lerp_at(const double* t, std::size_t i, double w) {
    return t[i] + w * (t[i + 1] - t[i]);
  }
  [[nodiscard]] double row_cross(std::size_t row, double y, std::size_t branch) const {
    std::size_t i = 0;
    double w = 0;
    if (!row_position(y, i, w)) return peak_times_[row];
    return lerp_at(&times_[row * kRowSize + branch], i, w);
  }
  /// Both crossings of one row at the same level.
  void row_cross_both(std::size_t row, double y, double& rise, double& fall) const {
    std::size_t i = 0;
    double w = 0;
    if (!row_position(y, i, w)) {
      rise = fall = peak_times_[row];
      return;
    }
    const double* r = &times_[row * kRowSize];
    rise = lerp_at(r, i, w);
    fall = lerp_at(r + (kLow + kHigh), i, w);
  }
  [[nodiscard]] double cross(At a, double y0, double y1, std::size_t branch) const {
    const double t0 = row_cross(a.row, y0, branch);
    if (a.w <= 0) return t0;
    return t0 + a.w * (row_cross(a.row + 1, y1, branch) - t0);
  }

  double step_ns_ = 0, inv_step_ = 0, high_scale_ = 0, max_spread_ns_ = 0;
  std::vector<double> peaks_, peak_times_, times_;
};

/// Tables shared by devices with the same pulse (a few kept; the key is exact).
std::shared_ptr<const SpreadEchoTable> spread_table(const physics::PulseTemplate& pulse,
                                                    double fwhm_ns, double bandwidth_mhz,
                                                    double onset_ns);

}  // namespace tofkit::device
