#include "tofkit/calib/uncertainty_budget.hpp"

#include <fmt/printf.h>

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <map>
#include <numbers>
#include <stdexcept>
#include <tuple>

namespace tofkit::calib {
namespace {

using ranging::BudgetComponent;
using ranging::BudgetScope;

/// Lost share of shots (above the same plate's at the reference temperature)
/// from which a temperature-run target counts as losing shots (to false stops
/// or missed echoes).
constexpr double kLostShotShare = 0.02;

/// One target: repeats of one truth.
struct Target {
  double log_amplitude = 0;  ///< mean ln amplitude
  double tof_ns = 0;
  double distance_m = 0;
  double reflectance = 0;
  double angle_deg = 0;
  double ambient_c = 0;
  double temperature_c = 0;   ///< mean temperature reading
  double mean_m = 0;          ///< mean in-sample residual
  double lost_share = 0;      ///< mean share of its rows' shots the device lost
  double pulse_width_ns = 0;  ///< mean pulse width
  std::size_t n = 0;
  double variance_m2 = ranging::kNaN;  ///< sample variance of the in-sample residual
  double mean_oof_m = ranging::kNaN;   ///< mean cross-validated residual
  std::size_t n_oof = 0;
  std::vector<std::size_t> rows;  ///< its rows
};

/// Shots per measurement: the rows' largest valid-shot count.
double shots_of(const BudgetFitData& d) {
  std::uint32_t shots = 0;
  for (const auto& r : d.rows) shots = std::max(shots, r.raw.shots_valid);
  return shots > 0 ? static_cast<double>(shots) : ranging::kNaN;
}

std::vector<Target> targets_of(const BudgetFitData& d, double shots) {
  std::map<std::tuple<double, double, double, double>, std::vector<std::size_t>> rows_of;
  for (std::size_t i = 0; i < d.rows.size(); ++i) {
    const auto& r = d.rows[i];
    if (!r.raw.has_echo() || !std::isfinite(d.residual_m[i]) || !(r.raw.amplitude > 0)) continue;
    rows_of[{r.truth.distance_m, r.truth.reflectance, r.truth.angle_deg, r.truth.ambient_c}]
        .push_back(i);
  }
  std::vector<Target> out;
  for (const auto& [key, rows] : rows_of) {
    Target t;
    t.distance_m = std::get<0>(key);
    t.reflectance = std::get<1>(key);
    t.angle_deg = std::get<2>(key);
    t.ambient_c = std::get<3>(key);
    t.rows = rows;
    double sum = 0, sum_oof = 0;
    for (const std::size_t i : rows) {
      t.log_amplitude += std::log(d.rows[i].raw.amplitude);
      t.tof_ns += d.rows[i].raw.tof_ns;
      t.temperature_c += d.rows[i].raw.temperature_c;
      t.lost_share += ranging::lost_shot_share(d.rows[i].raw.shots_valid, shots);
      t.pulse_width_ns += d.rows[i].raw.pulse_width_ns;
      sum += d.residual_m[i];
      if (std::isfinite(d.out_of_fold_m[i])) {
        sum_oof += d.out_of_fold_m[i];
        ++t.n_oof;
      }
    }
    t.n = rows.size();
    t.log_amplitude /= static_cast<double>(t.n);
    t.tof_ns /= static_cast<double>(t.n);
    t.temperature_c /= static_cast<double>(t.n);
    t.lost_share /= static_cast<double>(t.n);
    t.pulse_width_ns /= static_cast<double>(t.n);
    const double mean = sum / static_cast<double>(t.n);
    t.mean_m = mean;
    if (t.n >= 2) {
      double ss = 0;
      for (const std::size_t i : rows) ss += (d.residual_m[i] - mean) * (d.residual_m[i] - mean);
      t.variance_m2 = ss / static_cast<double>(t.n - 1);
    }
    if (t.n_oof > 0) t.mean_oof_m = sum_oof / static_cast<double>(t.n_oof);
    out.push_back(t);
  }
  std::sort(out.begin(), out.end(),
            [](const Target& a, const Target& b) { return a.log_amplitude < b.log_amplitude; });
  return out;
}

/// Bins of about equal counts over items sorted by ln amplitude: [begin, end).
std::vector<std::pair<std::size_t, std::size_t>> bins(std::size_t n, std::size_t count) {
  std::vector<std::pair<std::size_t, std::size_t>> out;
  count = std::max<std::size_t>(1, std::min(count, n));
  for (std::size_t b = 0; b < count; ++b) out.emplace_back(b * n / count, (b + 1) * n / count);
  return out;
}

BudgetComponent constant(std::string name, std::string step, double u_m, bool type_b,
                         bool default_spec, BudgetScope scope = BudgetScope::always) {
  BudgetComponent c;
  c.name = std::move(name);
  c.step = std::move(step);
  c.type_b = type_b;
  c.default_specification = default_spec;
  c.scope = scope;
  c.node = {0.0};
  c.variance_m2 = {u_m * u_m};
  return c;
}

/// Nodes must ascend strictly: merge equal ones (mean of their variances).
void add_node(BudgetComponent& c, double x, double v) {
  if (!c.node.empty() && !(x > c.node.back())) {
    c.variance_m2.back() = 0.5 * (c.variance_m2.back() + v);
    return;
  }
  c.node.push_back(x);
  c.variance_m2.push_back(v);
}

std::string spec_step(const char* key, double value, const char* unit, bool given) {
  return fmt::sprintf("specification %s = %g %s%s", key, value, unit, given ? "" : " (default)");
}

}  // namespace

void BudgetSpecification::validate() const {
  const auto check = [](double v, double hi, const char* key) {
    if (!(std::isfinite(v) && v >= 0 && v <= hi))
      throw std::invalid_argument(fmt::sprintf("specification %s must be in [0, %g]", key, hi));
  };
  check(tdc_inl_ps, 1e5, "tdc_inl_ps");
  check(delay_tempco_ps_per_c, 1e4, "delay_tempco_ps_per_c");
  check(walk_tempco_ps_per_c, 1e4, "walk_tempco_ps_per_c");
  check(temperature_half_range_c, 200, "temperature_half_range_c");
  check(drift_ps, 1e5, "drift_ps");
  check(power_on_ps, 1e5, "power_on_ps");
}

void BudgetSpecification::set(const std::string& assignment) {
  const std::size_t eq = assignment.find('=');
  if (eq == std::string::npos)
    throw std::invalid_argument("specification " + assignment + ": expected key=value");
  const std::string key = assignment.substr(0, eq), text = assignment.substr(eq + 1);
  double v = 0;
  std::size_t used = 0;
  try {
    v = std::stod(text, &used);
  } catch (const std::exception&) {
    used = 0;
  }
  if (used != text.size() || text.empty())
    throw std::invalid_argument("specification " + key + ": '" + text + "' is not a number");
  const std::pair<const char*, std::pair<double*, bool*>> keys[] = {
      {"tdc_inl_ps", {&tdc_inl_ps, &tdc_inl_given}},
      {"delay_tempco_ps_per_c", {&delay_tempco_ps_per_c, &delay_tempco_given}},
      {"walk_tempco_ps_per_c", {&walk_tempco_ps_per_c, &walk_tempco_given}},
      {"temperature_half_range_c", {&temperature_half_range_c, nullptr}},
      {"drift_ps", {&drift_ps, &drift_given}},
      {"power_on_ps", {&power_on_ps, &power_on_given}},
  };
  for (const auto& [name, target] : keys) {
    if (key != name) continue;
    *target.first = v;
    if (target.second) *target.second = true;
    validate();
    return;
  }
  throw std::invalid_argument(
      "specification " + key +
      ": unknown key (tdc_inl_ps, delay_tempco_ps_per_c, walk_tempco_ps_per_c, "
      "temperature_half_range_c, drift_ps, power_on_ps)");
}

DriftCurve drift_structure_function(std::span<const double> residual_m, double every_s,
                                    double row_noise2_m2) {
  DriftCurve out;
  const std::size_t ns = residual_m.size();
  if (ns < 2 || !(every_s > 0)) return out;
  const double white2 = row_noise2_m2;
  const std::size_t max_lag = std::max<std::size_t>(1, (3 * ns) / 4);
  std::vector<std::size_t> lags;
  for (double l = 1; l <= static_cast<double>(max_lag); l *= 1.3)
    if (lags.empty() || static_cast<std::size_t>(l) != lags.back())
      lags.push_back(static_cast<std::size_t>(l));
  // D(lag) less the rows' own noise, then made non-decreasing by pooling
  // adjacent violators (least squares, pairs as weights): a drift's
  // variance does not fall with the lag, and the noisy long lags (few
  // pairs) must not push the curve up as a running maximum would.
  // The record's own row noise may exceed a row's repeatability (flicker
  // faster than the rows' spacing): D(lag) holds it twice, once for the row at
  // the calibration (averaged away by the calibration's many rows) and once
  // for the field row; a field row keeps its excess over the repeatability
  // once (a deficit too: the repeatability in its sigma covers the rest), so
  // D(lag) loses noise^2 + u_rep^2 (unclamped: a clamp at 0 of an excess that
  // is noise around 0 would take its positive mean off every lag). The row noise
  // is half D's intercept at lag 0, 2 D(1) - D(2): noise gives D flat over the
  // first steps, a drift adds to it linearly there (a random walk's q tau, a
  // slower wander's 2 s^2 tau / T), so D(1) / 2 would count a step's drift as
  // noise and take it off at every lag (a random walk's q step / 2, a wander's
  // D(step) / 2: 0.025 of 1.44 mm^2 at 13 min for one of 1 mm over 10 min).
  const auto structure = [&](std::size_t lag) {
    double sum = 0;
    for (std::size_t i = 0; i + lag < ns; ++i)
      sum += std::pow(residual_m[i + lag] - residual_m[i], 2);
    return sum / static_cast<double>(ns - lag);
  };
  const double d1 = structure(1);
  const double row_noise2 = 0.5 * (ns >= 3 ? 2 * d1 - structure(2) : d1);
  const double noise_taken2 = row_noise2 + white2;
  std::vector<double> value, weight;
  std::vector<std::size_t> count;  // lags pooled into each block
  for (const std::size_t lag : lags) {
    double sum = 0;
    for (std::size_t i = 0; i + lag < ns; ++i) {
      const double dd = residual_m[i + lag] - residual_m[i];
      sum += dd * dd;
    }
    const double pairs = static_cast<double>(ns - lag);
    value.push_back(sum / pairs - noise_taken2);
    weight.push_back(pairs);
    count.push_back(1);
    while (value.size() > 1 && value[value.size() - 2] > value.back()) {
      const std::size_t k = value.size() - 1;
      value[k - 1] =
          (value[k - 1] * weight[k - 1] + value[k] * weight[k]) / (weight[k - 1] + weight[k]);
      weight[k - 1] += weight[k];
      count[k - 1] += count[k];
      value.pop_back();
      weight.pop_back();
      count.pop_back();
    }
  }
  std::size_t next = 0;
  for (std::size_t b = 0; b < value.size(); ++b) {
    for (std::size_t j = 0; j < count[b]; ++j, ++next) {
      out.lag_s.push_back(static_cast<double>(lags[next]) * every_s);
      out.variance_m2.push_back(std::max(0.0, value[b]));
    }
  }
  return out;
}

BudgetFitResult fit_uncertainty_budget(const BudgetFitData& d, const BudgetSpecification& spec) {
  spec.validate();
  if (d.out_of_fold_m.size() != d.rows.size() || d.residual_m.size() != d.rows.size() ||
      std::any_of(d.extrapolation.begin(), d.extrapolation.end(),
                  [&](const auto& r) { return r.residual_m.size() != d.rows.size(); }))
    throw std::invalid_argument("budget: residuals and rows differ in length");
  BudgetFitResult result;
  auto& budget = result.budget;
  std::string& report = result.report;
  const double m_per_ps = d.metres_per_ns * 1e-3;
  budget.shots = shots_of(d);
  std::vector<Target> targets = targets_of(d, budget.shots);

  // Repeatability (type A): pooled variance of the repeats per amplitude bin.
  std::vector<const Target*> repeated;
  for (const auto& t : targets)
    if (t.n >= 2 && std::isfinite(t.variance_m2)) repeated.push_back(&t);
  if (repeated.size() < 3)
    throw std::invalid_argument(
        fmt::sprintf("budget: the repeatability needs >= 3 targets measured two or more times, the "
                     "rows have %zu",
                     repeated.size()));
  BudgetComponent repeat;
  repeat.name = "repeatability (one row)";
  repeat.step = "repeats of every target";
  repeat.axis = BudgetComponent::Axis::log_amplitude;
  for (const auto& [b, e] : bins(repeated.size(), std::min<std::size_t>(8, repeated.size() / 3))) {
    double ss = 0, dof = 0, x = 0;
    for (std::size_t k = b; k < e; ++k) {
      const double nu = static_cast<double>(repeated[k]->n - 1);
      ss += nu * repeated[k]->variance_m2;
      dof += nu;
      x += repeated[k]->log_amplitude;
    }
    add_node(repeat, x / static_cast<double>(e - b), ss / dof);
  }
  const auto noise2 = [&](double log_amplitude) {
    const double u = repeat.u_m(log_amplitude);
    return u * u;
  };
  budget.components.push_back(repeat);

  // The cross-validated targets, and the reference temperature (most rows).
  std::map<double, std::size_t> rows_at;
  for (const auto& t : targets) rows_at[t.ambient_c] += t.n;
  const double reference_c = std::max_element(rows_at.begin(), rows_at.end(), [](auto& a, auto& b) {
                               return a.second < b.second;
                             })->first;
  std::vector<Target*> reference;
  for (auto& t : targets) {
    if (t.n_oof == 0) continue;
    if (t.ambient_c == reference_c) reference.push_back(&t);
  }
  const auto mean_noise = [&](const Target& t) {
    return noise2(t.log_amplitude) / static_cast<double>(t.n_oof);
  };

  // Periodic residual: harmonics of the TDC's coarse period in the reference
  // targets' cross-validated means, where their distances span a period.
  constexpr int kHarmonics = 3;
  double dmin = 1e300, dmax = -1e300;
  for (const Target* t : reference) {
    dmin = std::min(dmin, t->distance_m);
    dmax = std::max(dmax, t->distance_m);
  }
  const double period_m = d.tdc_period_ns * d.metres_per_ns;
  const bool periodic_seen = d.tdc_period_ns > 0 &&
                             reference.size() >= static_cast<std::size_t>(4 * kHarmonics + 4) &&
                             dmax - dmin >= period_m;
  std::vector<double> periodic(targets.size(), 0.0);
  const auto harmonic_row = [&](double tof_ns) {
    Eigen::RowVectorXd row(2 * kHarmonics + 1);
    row(0) = 1.0;
    for (int h = 1; h <= kHarmonics; ++h) {
      const double a = 2 * std::numbers::pi * h * tof_ns / d.tdc_period_ns;
      row(2 * h - 1) = std::cos(a);
      row(2 * h) = std::sin(a);
    }
    return row;
  };
  Eigen::VectorXd coefficients;
  if (periodic_seen) {
    const auto g = static_cast<Eigen::Index>(reference.size());
    Eigen::MatrixXd a(g, 2 * kHarmonics + 1);
    Eigen::VectorXd y(g);
    for (Eigen::Index k = 0; k < g; ++k) {
      a.row(k) = harmonic_row(reference[static_cast<std::size_t>(k)]->tof_ns);
      y(k) = reference[static_cast<std::size_t>(k)]->mean_oof_m;
    }
    coefficients = a.colPivHouseholderQr().solve(y);
    const double rss = (y - a * coefficients).squaredNorm();
    const double sigma2 = rss / static_cast<double>(g - (2 * kHarmonics + 1));
    double power = 0;
    for (int k = 1; k <= 2 * kHarmonics; ++k) power += 0.5 * coefficients(k) * coefficients(k);
    // Each coefficient's estimate has variance about 2 sigma^2 / G (even phases).
    const double bias = kHarmonics * 2.0 * sigma2 / static_cast<double>(g);
    const double u2 = std::max(0.0, power - bias);
    budget.components.push_back(
        constant("periodic residual (TDC, time of flight)",
                 fmt::sprintf("%zu targets (plates, rail) over %.2f-%.2f m (period %.3f m)",
                              reference.size(), dmin, dmax, period_m),
                 std::sqrt(u2), false, false));
    report += fmt::sprintf(
        "budget: periodic residual %.3f mm (harmonics 1-%d of the %.3f ns period in the "
        "cross-validated means of %zu targets; fit noise %.3f mm removed)\n",
        std::sqrt(u2) * 1e3, kHarmonics, d.tdc_period_ns, reference.size(), std::sqrt(bias) * 1e3);
    for (std::size_t k = 0; k < targets.size(); ++k) {
      if (targets[k].n_oof == 0) continue;
      const Eigen::RowVectorXd row = harmonic_row(targets[k].tof_ns);
      periodic[k] = row.tail(2 * kHarmonics).dot(coefficients.tail(2 * kHarmonics));
    }
  } else {
    const double u = spec.tdc_inl_ps / std::sqrt(2.0) * m_per_ps;
    budget.components.push_back(
        constant("periodic residual (TDC, time of flight)",
                 spec_step("tdc_inl_ps", spec.tdc_inl_ps, "ps", spec.tdc_inl_given), u, true,
                 !spec.tdc_inl_given));
    budget.unobserved.push_back(
        d.tdc_period_ns > 0
            ? fmt::sprintf(
                  "the TDC's nonlinearity, periodic in the time of flight (the targets span "
                  "%.2f m, less than one %.3f m period: no rail)",
                  std::max(0.0, dmax - dmin), period_m)
            : std::string("the TDC's nonlinearity (its period is unknown)"));
  }
  const auto index_of = [&](const Target* t) {
    return static_cast<std::size_t>(t - targets.data());
  };
  const auto excess = [&](const Target* t) {
    const double m = t->mean_oof_m - periodic[index_of(t)];
    return m * m - mean_noise(*t);
  };

  // Correction residual (cross-validated) per amplitude bin of the reference
  // targets: up to 6 bins of >= 10 targets, so that the weak end (where the
  // walk curves most) has its own value rather than a tercile's mean. Within
  // a bin each surface (reflectance, angle) counts once: a field's echoes of
  // one strength come from any surface, and a rail's or a sweep's hundreds of
  // distances on one plate must not outvote the plates' surfaces.
  if (reference.size() < 3)
    throw std::invalid_argument(fmt::sprintf(
        "budget: the correction residual needs >= 3 cross-validated targets at the reference "
        "temperature (%g C), the rows have %zu",
        reference_c, reference.size()));
  BudgetComponent systematic;
  systematic.name = "correction residual (cross-validated)";
  systematic.step = fmt::sprintf(
      "%zu targets at %g C, each predicted by a fit without it (each surface weighted alike)",
      reference.size(), reference_c);
  systematic.axis = BudgetComponent::Axis::log_amplitude;
  for (const auto& [b, e] :
       bins(reference.size(),
            std::max<std::size_t>(1, std::min<std::size_t>(6, reference.size() / 10)))) {
    std::map<std::pair<double, double>, std::pair<std::size_t, double>> surfaces;
    for (std::size_t k = b; k < e; ++k)
      ++surfaces[{reference[k]->reflectance, reference[k]->angle_deg}].first;
    double sum = 0, x = 0, weights = 0;
    for (std::size_t k = b; k < e; ++k) {
      const double w =
          1.0 /
          static_cast<double>(surfaces[{reference[k]->reflectance, reference[k]->angle_deg}].first);
      sum += w * excess(reference[k]);
      x += w * reference[k]->log_amplitude;
      weights += w;
    }
    add_node(systematic, x / weights, std::max(0.0, sum / weights));
  }
  budget.components.push_back(systematic);

  // Extrapolation below the calibrated amplitudes: a fixed-threshold
  // comparator's walk is rise time x threshold / peak (DESIGN.md
  // "Discriminator"), C exp(-(x - x0)) in x = ln amplitude, whose departure
  // from its tangent at the weakest target x0 is C (e^delta - 1 - delta),
  // delta = x0 - x: what a correction matched at the edge in value and slope
  // misses below it. Type B assumption: that growth (walk ~ 1 / peak). Its
  // size C, type A: preferably measured, from refits of the correction
  // without the weakest 1, 2, ... targets (ModelFitResult::extrapolation):
  // their errors on the targets they left out are this correction's own
  // extrapolation errors, delta' e-folds below each refit's edge x1, where the
  // same walk departs from the refit's tangent by
  // C (e^(x0 - x) - e^(x0 - x1) (1 + x1 - x)); C from their mean squares less
  // their noise, pooled over refits and targets (one refit's error is one draw
  // of where its fit put the knots near its edge: case by case 3-4 times
  // apart, pooled within 1.6 times of the field's). Without refits: the
  // curvature y''(x0) = C of the weakest targets' raw error (truth less
  // c tof / 2; a quadratic in x over the lowest 1.5 e-folds), which bounds a
  // correction extrapolated linearly and so is looser. Cross-validation cannot
  // see this (the weakest target sits at the edge). 0 at and above x0; held
  // constant beyond 5 e-folds.
  {
    constexpr double kSpan = 1.5;      // e-folds of the domain the curvature is taken from
    constexpr double kMaxFolds = 5.0;  // the curve is held constant beyond this
    const double x0 = targets.front().log_amplitude;
    double size = ranging::kNaN;  // C, m
    std::string step, how;
    // Measured: the refits' errors on the targets they left out, pooled.
    double excess2 = 0, basis2 = 0;
    std::size_t errors_seen = 0;
    std::string errors;
    double x1_max = x0;
    for (const auto& refit : d.extrapolation) {
      const double x1 = refit.edge_log_amplitude;
      if (!std::isfinite(x1)) continue;
      x1_max = std::max(x1_max, x1);
      for (const Target& t : targets) {
        if (!(t.log_amplitude < x1)) continue;
        double sum = 0;
        std::size_t n = 0;
        for (const std::size_t i : t.rows) {
          if (!std::isfinite(refit.residual_m[i])) continue;
          sum += refit.residual_m[i];
          ++n;
        }
        if (n == 0) continue;
        const double x = t.log_amplitude, mean = sum / static_cast<double>(n);
        const double g = std::exp(x0 - x) - std::exp(x0 - x1) * (1 + x1 - x);
        // C^2 = sum excess^2 / sum g^2 (pooled: each refit's knots near its
        // edge are one draw; least squares would let the farthest one rule).
        excess2 += mean * mean - noise2(x) / static_cast<double>(n);
        basis2 += g * g;
        ++errors_seen;
        // The report names each refit's farthest extrapolation.
        if (x == targets.front().log_amplitude || errors_seen == 1)
          errors += fmt::sprintf(" %.1f mm at %.2f;", mean * 1e3, x1 - x);
      }
    }
    if (errors_seen > 0 && basis2 > 0) {
      size = std::sqrt(std::max(0.0, excess2 / basis2));
      step = fmt::sprintf(
          "%zu refits without the weakest targets (ln amplitude %.2f-%.2f), their errors on "
          "them extrapolated as walk ~ 1 / peak (type B form)",
          d.extrapolation.size(), x0, x1_max);
      how = fmt::sprintf(
          "%zu refits without the weakest targets err on the %zu targets they left out (on the "
          "weakest: mm at e-folds below each refit's edge:%s) walk departure C %.3f mm",
          d.extrapolation.size(), errors_seen, errors.c_str(), size * 1e3);
    }
    // Bounded: the weakest targets' raw curvature.
    std::vector<const Target*> edge;
    for (const Target& t : targets)
      if (t.ambient_c == reference_c && t.log_amplitude <= x0 + kSpan) edge.push_back(&t);
    if (!std::isfinite(size) && edge.size() >= 4 && edge.back()->log_amplitude - x0 > 0.5 &&
        d.metres_per_ns > 0) {
      const auto g = static_cast<Eigen::Index>(edge.size());
      Eigen::MatrixXd a(g, 3);
      Eigen::VectorXd y(g);
      for (Eigen::Index k = 0; k < g; ++k) {
        const Target& t = *edge[static_cast<std::size_t>(k)];
        const double u = t.log_amplitude - x0;
        a.row(k) << 1.0, u, u * u;
        y(k) = t.distance_m - t.tof_ns * d.metres_per_ns;
      }
      const Eigen::VectorXd q = a.colPivHouseholderQr().solve(y);
      size = std::abs(2 * q(2));
      step = fmt::sprintf(
          "walk curvature of the %zu weakest targets (ln amplitude %.2f-%.2f), "
          "extrapolated as walk ~ 1 / peak (type B form)",
          edge.size(), x0, edge.back()->log_amplitude);
      how = fmt::sprintf(
          "walk curvature %.3f mm per e-fold^2 (slope %.3f mm per e-fold) from %zu "
          "targets (no extrapolation refit)",
          size * 1e3, q(1) * 1e3, edge.size());
    }
    if (std::isfinite(size)) {
      const auto departure = [&](double delta) { return size * (std::expm1(delta) - delta); };
      BudgetComponent extrapolation;
      extrapolation.name = ranging::kExtrapolationComponent;
      extrapolation.step = step;
      extrapolation.axis = BudgetComponent::Axis::log_amplitude;
      for (double delta = kMaxFolds; delta > 0; delta -= 0.25) {
        const double u = departure(delta);
        add_node(extrapolation, x0 - delta, u * u);
      }
      add_node(extrapolation, x0, 0.0);
      budget.components.push_back(extrapolation);
      report += fmt::sprintf(
          "budget: extrapolation below the weakest target (amplitude %.4g): %s; u %.2f / %.2f / "
          "%.2f mm at 1 / 2 / 3 e-folds below\n",
          std::exp(x0), how.c_str(), departure(1.0) * 1e3, departure(2.0) * 1e3,
          departure(3.0) * 1e3);
    }
  }

  // Temperature model residual: the temperature run's targets' in-sample
  // mean residuals less that of the same target at the reference temperature
  // (what the temperature step left), less their noise, plus the optimism of
  // a fit of p parameters on G temperatures. The optimism is additive in the
  // noise (Mallows' C_p, ESL 2nd ed. Eq. 7.24: Err_in = err + 2 (p / G)
  // sigma^2): an in-sample difference d at a temperature of leverage h ~ p / G
  // has E d^2 = b^2 + v (1 - h) for a systematic b left by the step and a
  // noise variance v of the difference; a field row there errs by b plus the
  // fit's noise, E = b^2 + v h = (d^2 - v) + 2 h v. Scaling d^2 - v, which has
  // the noise taken out, by (G + p) / (G - p) instead would count the
  // systematic b as noise. Leaving whole temperatures out instead measures
  // the interpolation across twice the run's step, not the field's. Its
  // axis is the row's temperature reading: what the temperature step leaves
  // grows with the distance from the calibration's temperature (and need not
  // be symmetric: a cold APD's gain, hence the walk, changes faster), and a
  // row at the calibration's temperature carries none of it.
  std::map<std::tuple<double, double, double>, const Target*> at_reference;
  for (const auto& t : targets)
    if (t.ambient_c == reference_c) at_reference[{t.distance_m, t.reflectance, t.angle_deg}] = &t;
  // Per temperature of the run: the excesses of its plates (pooled: the
  // field's echoes are the plates' mix), their readings, and the plates.
  struct AtTemperature {
    double sum = 0, noise = 0, reading = 0;  ///< excess^2, its noise variance v, the readings
    double n = 0;                            ///< their weight
  };
  // Each distance of the run weighs alike at a temperature: the field's
  // distances put their stops anywhere in the TDC's period, and several plates
  // at one distance share one phase of it (the fine bins' temperature
  // dependence), which the temperature function fitted on them absorbs.
  std::map<std::pair<double, double>, double> at_distance;  // (ambient, distance) -> targets
  for (const auto& t : targets)
    if (t.ambient_c != reference_c) at_distance[{t.ambient_c, t.distance_m}] += 1;
  std::map<double, AtTemperature> per_temperature;
  std::map<const Target*, bool> plates;
  double reference_reading = 0;
  // Lost shots: a plate that loses shots away from the reference temperature
  // either misses its echo on some (a weak echo where the APD's gain falls,
  // hot) or stops on noise crossing the threshold before it (background
  // light at the gain there, cold): the firmware's range gate drops the false
  // stops far before the echo and keeps those just before it, which read
  // short by their share times their lead. A wider echo than a target that
  // kept every shot is no weak one: its lost shots are false stops. What a
  // correction of the reading alone leaves there is this cause's, not the
  // temperature's: it follows a reading the row carries, so it gets that
  // axis (its excess, type A) and the other plates the temperature residual.
  // Missed echoes follow the share lost (the echo's detection probability);
  // false stops their rate per metre of range, -ln(1 - share) / d: the share
  // lost grows with the range at one rate (held-out case 1 in sunlight at 8 C,
  // rho 0.85: 6-48 % lost at 0.7-7.4 m, 0.087-0.096 per m, all about 5 mm
  // short), and the rate sets the false stops kept just before the echo.
  double narrowest_complete_ns = std::numeric_limits<double>::infinity();
  for (const auto& t : targets)
    if (t.lost_share == 0)
      narrowest_complete_ns = std::min(narrowest_complete_ns, t.pulse_width_ns);
  std::vector<std::pair<double, double>> false_stops, missed;         // (axis value, excess^2)
  double false_stop_onset = std::numeric_limits<double>::infinity();  // kLostShotShare's rate
  for (const auto& t : targets) {
    if (t.ambient_c == reference_c) continue;
    const auto ref = at_reference.find({t.distance_m, t.reflectance, t.angle_deg});
    if (ref == at_reference.end()) continue;
    const double dm = t.mean_m - ref->second->mean_m;
    const double v = noise2(t.log_amplitude) / static_cast<double>(t.n) +
                     noise2(ref->second->log_amplitude) / static_cast<double>(ref->second->n);
    const double excess2 = dm * dm - v;
    if (t.lost_share - ref->second->lost_share > kLostShotShare) {
      if (t.pulse_width_ns > narrowest_complete_ns) {
        false_stops.emplace_back(ranging::false_stop_rate_per_m(t.lost_share, t.distance_m),
                                 std::max(0.0, excess2));
        false_stop_onset = std::min(false_stop_onset,
                                    ranging::false_stop_rate_per_m(kLostShotShare, t.distance_m));
      } else {
        missed.emplace_back(t.lost_share, std::max(0.0, excess2));
      }
      continue;
    }
    AtTemperature& at = per_temperature[t.ambient_c];
    const double w = 1.0 / at_distance[{t.ambient_c, t.distance_m}];
    at.sum += w * excess2;
    at.noise += w * v;
    at.reading += w * t.temperature_c;
    at.n += w;
    if (plates.emplace(ref->second, true).second) reference_reading += ref->second->temperature_c;
  }
  if (!plates.empty()) reference_reading /= static_cast<double>(plates.size());
  const double p_t = std::max(1.0, d.temperature_parameters);
  const double g = static_cast<double>(per_temperature.size() + 1);
  const auto spec_temperature = [&](const char* name, const char* key, double tempco_ps_per_c,
                                    bool given, double at_c) {
    // u = tempco x |T - T_ref| over the field's +-half range (held beyond).
    BudgetComponent c = constant(name,
                                 spec_step(key, tempco_ps_per_c, "ps/C", given) +
                                     fmt::sprintf(" over +-%g C", spec.temperature_half_range_c),
                                 0.0, true, !given);
    c.axis = BudgetComponent::Axis::temperature_c;
    c.node.clear();
    c.variance_m2.clear();
    for (int k = -4; k <= 4; ++k) {
      const double dt = spec.temperature_half_range_c * k / 4.0;
      add_node(c, at_c + dt, std::pow(tempco_ps_per_c * dt * m_per_ps, 2));
    }
    return c;
  };
  if (per_temperature.size() >= 3 && g > p_t + 1) {
    const double leverage = p_t / g;
    BudgetComponent temperature;
    temperature.name = "temperature model residual";
    temperature.axis = BudgetComponent::Axis::temperature_c;
    // A ramp read every 2.5 C gives each temperature a few targets, whose
    // excesses are noisy (the noise's variance is subtracted from each): a
    // node pools the temperatures within kTemperaturePool_c of it, so the u
    // it gives is an average of what the run saw there, not one draw's
    // (soaked steps 5 C apart pool nothing).
    constexpr double kTemperaturePool_c = 2.5;
    std::vector<std::pair<double, double>> nodes = {{reference_reading, 0.0}};
    for (const auto& [ambient, at] : per_temperature) {
      AtTemperature pool;
      for (const auto& [other, o] : per_temperature)
        if (std::abs(other - ambient) <= kTemperaturePool_c + 1e-9) {
          pool.sum += o.sum;
          pool.noise += o.noise;
          pool.n += o.n;
        }
      nodes.emplace_back(at.reading / at.n,
                         std::max(0.0, (pool.sum + 2 * leverage * pool.noise) / pool.n));
    }
    std::sort(nodes.begin(), nodes.end());
    for (const auto& [x, v] : nodes) add_node(temperature, x, v);
    temperature.step = fmt::sprintf(
        "temperature run: %zu plate(s) at %zu temperatures besides %g C (optimism for %g "
        "parameters)",
        plates.size(), per_temperature.size(), reference_c, p_t);
    budget.components.push_back(temperature);
    if (plates.size() < 2) {
      // One plate: how the temperature dependence changes with the echo's
      // strength (the APD's gain, hence the walk) was not seen.
      budget.components.push_back(
          spec_temperature("temperature residual by echo strength", "walk_tempco_ps_per_c",
                           spec.walk_tempco_ps_per_c, spec.walk_tempco_given, reference_reading));
      budget.unobserved.push_back(
          "the temperature dependence's change with echo strength (temperature run on one "
          "plate)");
    }
  } else {
    double reading = 0;
    for (const Target* t : reference) reading += t->temperature_c;
    reading /= static_cast<double>(reference.size());
    budget.components.push_back(
        spec_temperature("temperature model residual", "delay_tempco_ps_per_c",
                         spec.delay_tempco_ps_per_c, spec.delay_tempco_given, reading));
    budget.unobserved.push_back(
        "the delay's temperature dependence (no temperature run with its plate also at the "
        "reference temperature)");
  }

  // u^2 over the axis: none up to the onset, then the plates' excesses in
  // order, never falling (more lost, not fewer), held beyond the last.
  const auto lost_shot_term = [&](std::vector<std::pair<double, double>>& lost, const char* name,
                                  BudgetComponent::Axis axis, double onset, const char* unit,
                                  double scale) {
    if (lost.empty() || !(budget.shots >= 1)) return;
    std::sort(lost.begin(), lost.end());
    BudgetComponent c;
    c.name = name;
    c.axis = axis;
    add_node(c, std::min(onset, lost.front().first), 0.0);
    double v = 0;
    for (const auto& [x, excess2] : lost) {
      v = std::max(v, excess2);
      if (x > c.node.back()) add_node(c, x, v);
    }
    c.step =
        fmt::sprintf("temperature run: %zu target(s) at %.3g-%.3g %s away from %g C", lost.size(),
                     scale * lost.front().first, scale * lost.back().first, unit, reference_c);
    budget.components.push_back(c);
    report += fmt::sprintf(
        "budget: %s: %zu temperature-run target(s) at %.3g-%.3g %s; u %.2f mm "
        "at %.3g %s, held beyond\n",
        name, lost.size(), scale * lost.front().first, scale * lost.back().first, unit,
        std::sqrt(v) * 1e3, scale * lost.back().first, unit);
  };
  // An echo near the threshold misses some shots and is biased from the first
  // one it misses (held-out case 1, rho 0.06 at 27-37 C: 2-5 % lost, 1.4 mm
  // long); a false stop's bias needs the rate of a 2 % loss at the run's range.
  lost_shot_term(missed, "missed echoes (lost shots)", BudgetComponent::Axis::lost_shot_share, 0.0,
                 "% of their shots lost", 100.0);
  lost_shot_term(false_stops, "false stops before the echo",
                 BudgetComponent::Axis::false_stop_rate_per_m, false_stop_onset,
                 "false stops per m of range", 1.0);

  // Drift since calibration: structure function of the stability record.
  const std::size_t ns = d.stability_residual_m.size();
  if (ns >= 8 && d.stability_every_s > 0) {
    double white2 = 0;
    std::size_t counted = 0;
    for (const auto& r : d.stability)
      if (r.raw.amplitude > 0) {
        white2 += noise2(std::log(r.raw.amplitude));
        ++counted;
      }
    white2 = counted > 0 ? white2 / static_cast<double>(counted) : 0.0;
    BudgetComponent drift;
    drift.name = "drift since calibration";
    drift.step =
        fmt::sprintf("stability record: %zu rows every %g s (%.1f min)", ns, d.stability_every_s,
                     static_cast<double>(ns - 1) * d.stability_every_s / 60);
    drift.scope = BudgetScope::same_power_on;
    drift.axis = BudgetComponent::Axis::time_since_calibration_s;
    add_node(drift, 0.0, 0.0);
    const DriftCurve curve =
        drift_structure_function(d.stability_residual_m, d.stability_every_s, white2);
    for (std::size_t k = 0; k < curve.lag_s.size(); ++k)
      add_node(drift, curve.lag_s[k], curve.variance_m2[k]);
    budget.components.push_back(drift);
    // The Allan deviation at a few averaging times, for the certificate.
    std::string allan;
    for (std::size_t m = 1; 8 * m <= ns; m *= 4) {  // >= 8 blocks per average
      std::vector<double> mean;
      for (std::size_t b = 0; (b + 1) * m <= ns; ++b) {
        double s = 0;
        for (std::size_t i = b * m; i < (b + 1) * m; ++i) s += d.stability_residual_m[i];
        mean.push_back(s / static_cast<double>(m));
      }
      double a = 0;
      for (std::size_t b = 0; b + 1 < mean.size(); ++b) a += std::pow(mean[b + 1] - mean[b], 2);
      allan += fmt::sprintf(" %.0f s: %.3f mm;", static_cast<double>(m) * d.stability_every_s,
                            std::sqrt(0.5 * a / static_cast<double>(mean.size() - 1)) * 1e3);
    }
    report += "budget: Allan deviation of the stability record at" + allan +
              fmt::sprintf(" drift u at %.0f min %.3f mm (beyond the record it is held)\n",
                           drift.node.back() / 60, std::sqrt(drift.variance_m2.back()) * 1e3);
  } else {
    budget.components.push_back(constant(
        "drift since calibration", spec_step("drift_ps", spec.drift_ps, "ps", spec.drift_given),
        spec.drift_ps * m_per_ps, true, !spec.drift_given, BudgetScope::same_power_on));
    budget.unobserved.push_back("drift after the calibration (no stability record)");
  }

  // Power-on reproducibility: each other power-on's mean residual.
  std::size_t runs = 0;
  double sum_d2 = 0;
  for (std::size_t f = 0; f < d.power_on_residual_m.size(); ++f) {
    const auto& r = d.power_on_residual_m[f];
    double s = 0, noise = 0;
    std::size_t n = 0;
    for (std::size_t i = 0; i < r.size(); ++i) {
      if (!std::isfinite(r[i]) || !(d.power_on_amplitude[f][i] > 0)) continue;
      s += r[i];
      noise += noise2(std::log(d.power_on_amplitude[f][i]));
      ++n;
    }
    if (n == 0) continue;
    const double mean = s / static_cast<double>(n);
    sum_d2 += mean * mean - noise / static_cast<double>(n * n);
    ++runs;
  }
  if (runs > 0) {
    budget.components.push_back(
        constant("power-on reproducibility", fmt::sprintf("repeats on %zu other power-on(s)", runs),
                 std::sqrt(std::max(0.0, sum_d2 / static_cast<double>(runs))), false, false,
                 BudgetScope::other_power_on));
  } else {
    budget.components.push_back(
        constant("power-on reproducibility",
                 spec_step("power_on_ps", spec.power_on_ps, "ps", spec.power_on_given),
                 std::sqrt(2.0) * spec.power_on_ps * m_per_ps, true, !spec.power_on_given,
                 BudgetScope::other_power_on));
    budget.unobserved.push_back("the offset between power-ons (no repeats on another power-on)");
  }

  for (const auto& c : budget.components) {
    if (c.default_specification)
      report += "warning: budget: " + c.name + " is a type B term from a default (" + c.step +
                "): state the device's value with --spec\n";
  }
  for (const auto& u : budget.unobserved) report += "budget: not observed: " + u + "\n";
  budget.validate();
  return result;
}

BudgetCoverage budget_coverage(std::span<const double> error_m, std::span<const double> sigma_m) {
  BudgetCoverage c;
  for (std::size_t i = 0; i < std::min(error_m.size(), sigma_m.size()); ++i) {
    if (!std::isfinite(error_m[i]) || !(sigma_m[i] > 0)) continue;
    ++c.rows;
    c.within_1sigma += std::abs(error_m[i]) <= sigma_m[i] ? 1 : 0;
    c.within_2sigma += std::abs(error_m[i]) <= 2 * sigma_m[i] ? 1 : 0;
  }
  if (c.rows > 0) {
    c.within_1sigma /= static_cast<double>(c.rows);
    c.within_2sigma /= static_cast<double>(c.rows);
  }
  return c;
}

namespace {

std::vector<double> residuals_of(const ranging::Pipeline& pipeline,
                                 std::span<const ranging::Record> rows) {
  std::vector<ranging::Range> ranges(rows.size());
  pipeline.apply(ranging::RawColumns::of(rows), ranges);
  std::vector<double> e(rows.size());
  for (std::size_t i = 0; i < rows.size(); ++i)
    e[i] = rows[i].truth.distance_m - ranges[i].distance_m;
  return e;
}

}  // namespace

BudgetFitResult fit_model_budget(std::span<const ranging::Record> calibration,
                                 const ModelFitResult& fit, const ProtocolSteps& steps,
                                 const BudgetSpecification& specification) {
  if (fit.out_of_fold_m.size() != calibration.size())
    throw std::invalid_argument(
        "budget: needs the cross-validated residual of every calibration row (a confidence "
        "model fitted by cross-fitting: --confidence calibrated or thesis, no "
        "--confidence-fraction)");
  const std::vector<double> residual = residuals_of(fit.pipeline, calibration);
  const std::vector<double> stability = residuals_of(fit.pipeline, steps.stability);
  BudgetFitData data;
  data.rows = calibration;
  data.out_of_fold_m = fit.out_of_fold_m;
  data.residual_m = residual;
  data.extrapolation = fit.extrapolation;
  data.tdc_period_ns = steps.tdc_period_ns;
  data.temperature_parameters = 0;
  for (const auto& step : fit.pipeline.steps()) {
    if (step.kind == ranging::StepKind::kTemperature)
      data.temperature_parameters += 1.0 + static_cast<double>(step.function.knots.size());
    if (step.kind == ranging::StepKind::kSurface && fit.summary.surface_temperature)
      data.temperature_parameters += 4.0;  // a temperature axis's cubic B-spline, at least
  }
  data.metres_per_ns = ranging::metres_per_ns(fit.pipeline.time_to_distance());
  data.stability = steps.stability;
  data.stability_residual_m = stability;
  data.stability_every_s = steps.stability_every_s;
  // A repeat's residual less the calibration's (in-sample) mean residual at the
  // same target: what the other power-on moved, not what the correction left
  // at that target (the correction residual's term).
  std::map<std::tuple<double, double, double, double>, std::pair<double, std::size_t>> at_target;
  for (std::size_t i = 0; i < calibration.size(); ++i) {
    if (!std::isfinite(residual[i])) continue;
    const auto& t = calibration[i].truth;
    auto& [sum, n] = at_target[{t.distance_m, t.reflectance, t.angle_deg, t.ambient_c}];
    sum += residual[i];
    ++n;
  }
  for (const auto& run : steps.power_on_runs) {
    std::vector<double> e = residuals_of(fit.pipeline, run);
    for (std::size_t i = 0; i < run.size(); ++i) {
      const auto& t = run[i].truth;
      const auto it = at_target.find({t.distance_m, t.reflectance, t.angle_deg, t.ambient_c});
      if (it != at_target.end()) e[i] -= it->second.first / static_cast<double>(it->second.second);
    }
    data.power_on_residual_m.push_back(std::move(e));
    std::vector<double> amplitude;
    for (const auto& r : run) amplitude.push_back(r.raw.amplitude);
    data.power_on_amplitude.push_back(std::move(amplitude));
  }
  BudgetFitResult result = fit_uncertainty_budget(data, specification);
  result.report += budget_certificate(result.budget, calibration, fit, steps);
  return result;
}

std::string budget_certificate(const ranging::UncertaintyBudget& budget,
                               std::span<const ranging::Record> calibration,
                               const ModelFitResult& fit, const ProtocolSteps& steps) {
  std::vector<double> amplitude;
  for (const auto& r : calibration)
    if (r.raw.has_echo() && r.raw.amplitude > 0) amplitude.push_back(r.raw.amplitude);
  if (amplitude.empty()) return {};
  std::sort(amplitude.begin(), amplitude.end());
  const auto at = [&](double q) {
    return amplitude[static_cast<std::size_t>(q * static_cast<double>(amplitude.size() - 1))];
  };
  // The points at the calibration's (median) temperature reading, the last
  // at its coldest.
  std::vector<double> reading;
  for (const auto& r : calibration)
    if (r.raw.has_echo() && std::isfinite(r.raw.temperature_c))
      reading.push_back(r.raw.temperature_c);
  std::sort(reading.begin(), reading.end());
  const double nan = ranging::kNaN;
  const double typical_c = reading.empty() ? nan : reading[reading.size() / 2];
  const double coldest_c = reading.empty() ? nan : reading.front();
  const std::vector<double> a = {at(0.1), at(0.5), at(0.9), at(0.5), at(0.5), at(0.5)};
  const std::vector<double> t = {0, 0, 0, 3600, nan, 0};
  const std::vector<double> at_c = {typical_c, typical_c, typical_c,
                                    typical_c, typical_c, coldest_c};
  std::string out = "uncertainty budget (GUM; u = standard uncertainty, share = u^2 / u_c^2):\n";
  out += budget.table(a, t, at_c);
  // Coverage check: the cross-validated calibration rows (right after the
  // calibration) and the repeats on other power-ons, against u_c.
  std::vector<double> err, sig;
  const auto check = [&](std::span<const ranging::Record> rows, std::span<const double> e,
                         double since) {
    err.clear();
    sig.clear();
    std::vector<ranging::Range> ranges(rows.size());
    fit.pipeline.apply(ranging::RawColumns::of(rows), ranges);
    const double s[1] = {since};
    ranging::apply_budget(budget, fit.pipeline, ranging::RawColumns::of(rows), s, ranges);
    for (std::size_t i = 0; i < rows.size(); ++i) {
      err.push_back(e[i]);
      sig.push_back(ranges[i].sigma_m);
    }
    return budget_coverage(err, sig);
  };
  const BudgetCoverage cv = check(calibration, fit.out_of_fold_m, 0.0);
  out += fmt::sprintf(
      "coverage check: %zu cross-validated calibration rows: %.1f %% within 1 u_c, %.1f %% "
      "within 2 u_c\n",
      cv.rows, 100 * cv.within_1sigma, 100 * cv.within_2sigma);
  // The repeats on other power-ons: each (its own offset is one draw), or,
  // when there are many, pooled.
  const std::size_t runs = steps.power_on_runs.size();
  std::vector<double> pooled_err, pooled_sig;
  for (std::size_t f = 0; f < runs; ++f) {
    const auto& run = steps.power_on_runs[f];
    const std::vector<double> e = residuals_of(fit.pipeline, run);
    const BudgetCoverage c = check(run, e, nan);
    pooled_err.insert(pooled_err.end(), err.begin(), err.end());
    pooled_sig.insert(pooled_sig.end(), sig.begin(), sig.end());
    if (runs > 3) continue;
    out += fmt::sprintf(
        "coverage check: power-on repeat %zu (%zu rows, another power-on): %.1f %% within 1 u_c, "
        "%.1f %% within 2 u_c (its own offset is one draw: all rows move together)\n",
        f + 1, c.rows, 100 * c.within_1sigma, 100 * c.within_2sigma);
  }
  if (runs > 3) {
    const BudgetCoverage c = budget_coverage(pooled_err, pooled_sig);
    out += fmt::sprintf(
        "coverage check: repeats on %zu other power-ons (%zu rows): %.1f %% within 1 u_c, %.1f %% "
        "within 2 u_c\n",
        runs, c.rows, 100 * c.within_1sigma, 100 * c.within_2sigma);
  }
  return out;
}

}  // namespace tofkit::calib
