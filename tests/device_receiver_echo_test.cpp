// The receiver stage's echo of one surface, alone (device/receiver_echo.hpp).
// Oracles: the tabulated crossing times against a direct root-find on the
// pulse template summed over the footprint's nodes (Gauss-Chebyshev of the
// second kind, written out here), the tabulated peak against a dense scan of
// that sum; the sampled-echo searches against the plain loops they replace.
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <random>
#include <vector>

#include "tofkit/device/device_config.hpp"
#include "tofkit/device/receiver_echo.hpp"
#include "tofkit/physics/pulse_template.hpp"

using namespace tofkit;

namespace {

constexpr double kPi = 3.14159265358979323846;

/// The paper preset's echo template (pulse through the receiver's two poles).
physics::PulseTemplate paper_pulse() {
  const auto cfg = device::preset("paper");
  return physics::PulseTemplate(cfg.link.laser.pulse_width_ns, cfg.link.receiver.bandwidth_mhz, 5.0,
                                cfg.link.laser.lasing_onset_ns);
}

/// The echo of a tilted footprint, normalized: sum_k w_k p(t - u_k h) with the
/// five Gauss-Chebyshev (second kind) nodes u_k = cos(k pi / 6), weights
/// sin^2(k pi / 6), normalized: a uniform disk's depth profile.
double footprint_echo(const physics::PulseTemplate& p, double spread_ns, double t) {
  double sum = 0, weights = 0;
  for (int k = 1; k <= 5; ++k) {
    const double x = k * kPi / 6.0;
    const double w = std::sin(x) * std::sin(x);
    sum += w * p(t - std::cos(x) * spread_ns);
    weights += w;
  }
  return sum / weights;
}

struct Reference {
  double peak = 0, peak_t = 0;
};

/// Peak of the footprint echo by a dense scan refined by golden section.
Reference reference_peak(const physics::PulseTemplate& p, double h) {
  Reference r;
  for (double t = p.begin_ns() - h; t < p.end_ns() + h; t += 1e-3) {
    const double v = footprint_echo(p, h, t);
    if (v > r.peak) {
      r.peak = v;
      r.peak_t = t;
    }
  }
  double a = r.peak_t - 1e-3, b = r.peak_t + 1e-3;
  const double g = 0.5 * (std::sqrt(5.0) - 1.0);
  for (int i = 0; i < 60; ++i) {
    const double c = b - g * (b - a), d = a + g * (b - a);
    if (footprint_echo(p, h, c) > footprint_echo(p, h, d))
      b = d;
    else
      a = c;
  }
  r.peak_t = 0.5 * (a + b);
  r.peak = std::max(r.peak, footprint_echo(p, h, r.peak_t));
  return r;
}

/// Bisection for f(t) = level between a (below) and b (above) or the reverse.
double bisect(const physics::PulseTemplate& p, double h, double level, double a, double b) {
  const bool rising = footprint_echo(p, h, a) < level;
  for (int i = 0; i < 80; ++i) {
    const double m = 0.5 * (a + b);
    ((footprint_echo(p, h, m) < level) == rising ? a : b) = m;
  }
  return 0.5 * (a + b);
}

}  // namespace

TEST(ReceiverEcho, CrossingTimesMatchARootFindOnThePulseTemplate) {
  const auto p = paper_pulse();
  const device::SpreadEchoTable table(p);
  ASSERT_GT(table.max_spread_ns(), 0.5);  // a 45 degree footprint at a few m
  // Row spreads (exact rows) and spreads between rows (interpolated in h).
  for (const double h : {0.0, 0.2, 0.37, table.max_spread_ns() * 0.8}) {
    SCOPED_TRACE("spread " + std::to_string(h) + " ns");
    const auto ref = reference_peak(p, h);
    const auto at = table.at(h);
    EXPECT_NEAR(table.peak(at), ref.peak, 1e-4 * ref.peak);
    EXPECT_NEAR(table.peak_time_ns(at), ref.peak_t, 0.02);
    // The level over the peak for each row the lookup mixes.
    const double p0 = table.row_peak(at.row);
    const double p1 = at.w > 0 ? table.row_peak(at.row + 1) : p0;
    for (const double y : {1e-3, 0.02, 0.1, 0.3, 0.5, 0.7, 0.9, 0.99}) {
      const double level = y * ref.peak;
      const double rise_ref = bisect(p, h, level, p.begin_ns() - h - 1.0, ref.peak_t);
      const double fall_ref = bisect(p, h, level, ref.peak_t, p.end_ns() + h + 1.0);
      double rise = 0, fall = 0;
      table.rise_fall_ns(at, level / p0, level / p1, rise, fall);
      // 1 ps (a tenth of the finest TDC's LSB; the template's own step is 5 ps)
      // up to 0.9 of the peak. Nearer the peak the time is ill-conditioned (the
      // slope goes to 0): there the echo at the table's times must be the level,
      // to 0.2 % of the peak (between rows, which are a 64th of the half-maximum
      // width apart, the times are interpolated linearly in the spread).
      if (y <= 0.9) {
        EXPECT_NEAR(rise, rise_ref, 1e-3) << "y " << y;
        EXPECT_NEAR(fall, fall_ref, 1e-3) << "y " << y;
      }
      EXPECT_NEAR(footprint_echo(p, h, rise), level, 2e-3 * ref.peak) << "y " << y;
      EXPECT_NEAR(footprint_echo(p, h, fall), level, 2e-3 * ref.peak) << "y " << y;
      EXPECT_EQ(rise, table.rise_ns(at, level / p0, level / p1));
      EXPECT_EQ(fall, table.fall_ns(at, level / p0, level / p1));
    }
    // At or above the peak both crossings read the peak's time.
    double rise = 0, fall = 0;
    table.rise_fall_ns(at, 1.5, 1.5, rise, fall);
    EXPECT_EQ(rise, table.peak_time_ns(at));
    EXPECT_EQ(fall, table.peak_time_ns(at));
  }
}

TEST(ReceiverEcho, SharedTablesAreKeyedByThePulse) {
  const auto p = paper_pulse();
  const auto cfg = device::preset("paper");
  const double fwhm = cfg.link.laser.pulse_width_ns, bw = cfg.link.receiver.bandwidth_mhz,
               onset = cfg.link.laser.lasing_onset_ns;
  const auto a = device::spread_table(p, fwhm, bw, onset);
  EXPECT_EQ(a, device::spread_table(p, fwhm, bw, onset));
  const physics::PulseTemplate wide(2.0 * fwhm, bw, 5.0, onset);
  const auto b = device::spread_table(wide, 2.0 * fwhm, bw, onset);
  EXPECT_NE(a, b);
  // A wider pulse crosses half its peak farther apart.
  double r0 = 0, f0 = 0, r1 = 0, f1 = 0;
  a->rise_fall_ns(a->at(0), 0.5 / a->row_peak(0), 0.5 / a->row_peak(0), r0, f0);
  b->rise_fall_ns(b->at(0), 0.5 / b->row_peak(0), 0.5 / b->row_peak(0), r1, f1);
  EXPECT_NEAR(f0 - r0, p.width_at_level_ns(0.5), 0.01);
  EXPECT_NEAR(f1 - r1, wide.width_at_level_ns(0.5), 0.01);
}

TEST(ReceiverEcho, FirstPeakIndexIsMaxElementsPlace) {
  std::mt19937 gen(5);
  std::uniform_int_distribution<int> small(0, 6);
  for (int trial = 0; trial < 200; ++trial) {
    std::vector<double> c(static_cast<std::size_t>(1 + trial % 37));
    for (auto& v : c) v = small(gen);  // ties: the first of the largest
    if (trial % 17 == 3) c[c.size() / 2] = std::numeric_limits<double>::quiet_NaN();
    const std::size_t begin = static_cast<std::size_t>(trial) % c.size();
    const auto expected = static_cast<std::size_t>(
        std::max_element(c.begin() + static_cast<std::ptrdiff_t>(begin), c.end()) - c.begin());
    EXPECT_EQ(device::first_peak_index(c, begin), expected) << "trial " << trial;
  }
}

TEST(ReceiverEcho, StrideSearchStopsWhereThePlainStrideStops) {
  // A clipped echo: long plateau above every level, noise on the edges.
  std::mt19937 gen(11);
  std::normal_distribution<double> noise(0.0, 0.02);
  for (int trial = 0; trial < 40; ++trial) {
    const std::size_t n = 300 + static_cast<std::size_t>(trial) * 97;
    std::vector<double> c(n);
    const double top = n * 0.7;
    for (std::size_t i = 0; i < n; ++i) {
      const double x = static_cast<double>(i);
      c[i] = std::clamp(std::min(x / 50.0, (top - x) / 80.0), 0.0, 1.0) + noise(gen);
    }
    if (trial % 9 == 4) c[n / 3] = std::numeric_limits<double>::quiet_NaN();
    device::StrideSearch search;
    search.build(c);
    for (const double level : {0.05, 0.3, 0.6, 0.95, 1.2}) {
      for (const std::size_t i0 : {std::size_t{1}, n / 10, n / 2, n - 2}) {
        constexpr std::size_t k = device::StrideSearch::kStride;
        std::size_t i = i0;
        while (i + k < n && c[i + k] >= level) i += k;
        while (i < n && c[i] >= level) ++i;
        EXPECT_EQ(search.fall_index(c, i0, level), i)
            << "trial " << trial << " level " << level << " from " << i0;
      }
    }
  }
}

namespace {

/// First time at or after t0 where f crosses `level` upward (or downward),
/// from a 1 ps scan refined by bisection; NaN when none before t_end.
template <class F>
double first_crossing(const F& f, double level, bool upward, double t0, double t_end) {
  auto past = [&](double t) { return upward ? f(t) >= level : f(t) < level; };
  double previous = t0;
  bool before = past(t0);
  for (double t = t0 + 1e-3; t < t_end; t += 1e-3) {
    const bool now = past(t);
    if (now && !before) {
      double a = previous, b = t;
      for (int i = 0; i < 60; ++i) (past(0.5 * (a + b)) ? b : a) = 0.5 * (a + b);
      return 0.5 * (a + b);
    }
    before = now;
    previous = t;
  }
  return std::numeric_limits<double>::quiet_NaN();
}

}  // namespace

TEST(ReceiverEcho, SampledCrossingTablesMatchTheContinuousEcho) {
  // A mixed pixel: two surfaces 1.5 ns apart (a dip between the echoes).
  const auto p = paper_pulse();
  auto echo = [&](double t) { return 1.0 * p(t - 10.0) + 0.6 * p(t - 11.5); };
  constexpr double kStep = 0.01;
  const double begin = 10.0 + p.begin_ns();
  const auto n = static_cast<std::size_t>((11.5 + p.end_ns() - begin) / kStep) + 2;
  std::vector<double> c(n, 0.0);
  p.add_to(1.0, 10.0, begin, kStep, c.data(), n);
  p.add_to(0.6, 11.5, begin, kStep, c.data(), n);
  const std::size_t i_peak = device::first_peak_index(c, 0);
  const double peak_t = begin + static_cast<double>(i_peak) * kStep;
  const double end = begin + static_cast<double>(n - 1) * kStep;
  constexpr std::size_t kLevels = 40;
  const double lo = 0.02, step = (1.2 * c[i_peak] - lo) / (kLevels - 1);
  std::vector<double> rise(kLevels), fall(kLevels);

  // Ungated: the first upcrossing and the next downcrossing.
  const double top =
      device::sampled_crossing_times(c, begin, kStep, peak_t, lo, step, false, 0, 0.0, rise, fall);
  EXPECT_LE(top, c[i_peak]);
  EXPECT_GT(top, c[i_peak] - step);
  for (std::size_t j = 0; j < kLevels; ++j) {
    const double level = lo + static_cast<double>(j) * step;
    SCOPED_TRACE("level " + std::to_string(level));
    if (level > c[i_peak]) {  // never reached: the peak's time
      EXPECT_EQ(rise[j], peak_t);
      EXPECT_EQ(fall[j], peak_t);
      continue;
    }
    if (level > 0.97 * c[i_peak]) continue;  // flat top: time ill-conditioned
    const double r = first_crossing(echo, level, true, begin, end);
    const double f = first_crossing(echo, level, false, r, end);
    // Linear between 10 ps samples: within 2 ps on the edges.
    EXPECT_NEAR(rise[j], r, 2e-3);
    EXPECT_NEAR(fall[j], f, 2e-3);
  }

  // Gated: the comparator released at 10.3 ns, on the first echo's rise.
  const double gate = 10.3;
  const auto i_gate = static_cast<std::size_t>(std::ceil((gate - begin) / kStep));
  int unreached = 0;  // levels exceeded at the release and never crossed again
  const double gated_top = device::sampled_crossing_times(c, begin, kStep, peak_t, lo, step, true,
                                                          i_gate, gate, rise, fall);
  EXPECT_LE(gated_top, top);
  for (std::size_t j = 0; j < kLevels; ++j) {
    const double level = lo + static_cast<double>(j) * step;
    SCOPED_TRACE("gated level " + std::to_string(level));
    if (level > 0.97 * c[i_peak]) continue;
    const double r = first_crossing(echo, level, true, gate, end);
    if (std::isnan(r)) {
      // Exceeded at the release and never crossed again: no rise; the fall
      // is the first downcrossing after the release.
      EXPECT_TRUE(std::isnan(rise[j]));
      ++unreached;
      EXPECT_NEAR(fall[j], first_crossing(echo, level, false, gate, end), 2e-3);
      continue;
    }
    EXPECT_NEAR(rise[j], r, 2e-3);
    EXPECT_GE(rise[j], gate);
    EXPECT_NEAR(fall[j], first_crossing(echo, level, false, r, end), 2e-3);
  }
  EXPECT_GT(unreached, 0);  // the case is exercised
}
