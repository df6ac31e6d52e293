#include "tofkit/calib/model_fit.hpp"

#include <tbb/parallel_for.h>

#include <Eigen/Dense>
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <exception>
#include <functional>
#include <limits>
#include <numbers>
#include <numeric>
#include <optional>
#include <set>
#include <stdexcept>
#include <string>
#include <tuple>
#include <unordered_map>
#include <utility>
#include <vector>

namespace tofkit::calib {
namespace {

using GroupKey = std::tuple<double, double, double, double>;

/// Identical truth (distance_true_m, reflectance, angle_deg, ambient_c); NaN
/// compares unequal to itself, so it maps to a sentinel and groups.
GroupKey key_of(const ranging::GroundTruth& t) {
  const auto v = [](double x) { return std::isnan(x) ? -1e300 : x; };
  return {v(t.distance_m), v(t.reflectance), v(t.angle_deg), v(t.ambient_c)};
}

/// Group of every record, numbered in order of first appearance.
struct GroupKeyHash {
  std::size_t operator()(const GroupKey& k) const {
    std::size_t h = 0;
    for (double v : {std::get<0>(k), std::get<1>(k), std::get<2>(k), std::get<3>(k)}) {
      h ^= std::hash<double>{}(v) + 0x9E3779B97F4A7C15ull + (h << 6) + (h >> 2);
    }
    return h;
  }
};

std::vector<std::size_t> truth_groups(std::span<const ranging::Record> records,
                                      std::size_t& groups) {
  std::unordered_map<GroupKey, std::size_t, GroupKeyHash> group_of;
  group_of.reserve(records.size());
  std::vector<std::size_t> group;
  group.reserve(records.size());
  for (const ranging::Record& r : records) {
    group.push_back(group_of.emplace(key_of(r.truth), group_of.size()).first->second);
  }
  groups = group_of.size();
  return group;
}

/// Folds of whole truth groups, stratified along the echo's intensity: the
/// groups ranked by their mean pulse width (the walk's axis; groups without an
/// echo last), group of rank r in fold r mod K. A held-out group then has
/// training groups on both sides of its width (but at the ends), so its
/// residual is the error of interpolating the correction, as a new target's
/// is; random folds held out neighbouring plates together, and a fold with
/// two of the three plates that clip fitted the clipping onset and recovery
/// from one width (held-out RMS 2.6 mm against 0.4 mm of error).
std::vector<std::size_t> intensity_stratified_folds(std::span<const ranging::Record> records,
                                                    std::span<const std::size_t> group,
                                                    std::size_t groups, std::size_t folds) {
  std::vector<double> sum(groups, 0.0);
  std::vector<std::size_t> count(groups, 0);
  for (std::size_t i = 0; i < records.size(); ++i) {
    const double w = records[i].raw.pulse_width_ns;
    if (!std::isfinite(w)) continue;
    sum[group[i]] += w;
    ++count[group[i]];
  }
  std::vector<std::size_t> rank(groups);
  std::iota(rank.begin(), rank.end(), std::size_t{0});
  const auto mean = [&](std::size_t g) {
    return count[g] > 0 ? sum[g] / static_cast<double>(count[g])
                        : std::numeric_limits<double>::infinity();
  };
  std::stable_sort(rank.begin(), rank.end(),
                   [&](std::size_t a, std::size_t b) { return mean(a) < mean(b); });
  std::vector<std::size_t> fold(groups);
  for (std::size_t r = 0; r < groups; ++r) fold[rank[r]] = r % folds;
  return fold;
}

std::string format(const char* fmt, auto... args) {
  char buffer[512];
  std::snprintf(buffer, sizeof buffer, fmt, args...);
  return buffer;
}

/// The extrapolation refits' groups: refit k leaves out the groups with an
/// echo whose mean ln amplitude lies below the weakest group's plus
/// kExtrapolationSpan k / kExtrapolationRefits (distinct sets only).
struct EdgeGroups {
  std::vector<double> mean_log_amplitude;  ///< per group (NaN: no echo)
  std::vector<double> below;               ///< refit k leaves out the groups below below[k]
  std::string why;                         ///< below empty: why there is no refit
};

EdgeGroups weakest_groups(std::span<const ranging::Record> records,
                          std::span<const std::size_t> group, std::size_t groups) {
  std::vector<double> sum(groups, 0.0);
  std::vector<std::size_t> count(groups, 0);
  for (std::size_t i = 0; i < records.size(); ++i) {
    const double a = records[i].raw.amplitude;
    if (!records[i].raw.has_echo() || !(a > 0) || !std::isfinite(a)) continue;
    sum[group[i]] += std::log(a);
    ++count[group[i]];
  }
  EdgeGroups out;
  out.mean_log_amplitude.assign(groups, ranging::kNaN);
  std::vector<double> mean;
  for (std::size_t g = 0; g < groups; ++g) {
    if (count[g] == 0) continue;
    out.mean_log_amplitude[g] = sum[g] / static_cast<double>(count[g]);
    mean.push_back(out.mean_log_amplitude[g]);
  }
  std::sort(mean.begin(), mean.end());
  // Refit k leaves out the groups below x0 + span k / K (x0 the weakest's
  // mean), each keeping at least half of the groups and 3: it measures the
  // correction's extrapolation, not a fit on a remnant. Thresholds by
  // amplitude, not by count: a sweep's many weak positions a few mm apart
  // would otherwise be left out one by one and extrapolate nowhere.
  for (std::size_t k = 1; k <= kExtrapolationRefits && !mean.empty(); ++k) {
    const double below =
        mean.front() + kExtrapolationSpan * static_cast<double>(k) / kExtrapolationRefits;
    const auto first_kept =
        static_cast<std::size_t>(std::lower_bound(mean.begin(), mean.end(), below) - mean.begin());
    const std::size_t kept = mean.size() - first_kept;
    if (2 * kept < mean.size() || kept < 3) break;
    // The same groups as the previous refit's: nothing new to learn.
    if (!out.below.empty() && mean[first_kept] == out.below.back()) continue;
    out.below.push_back(mean[first_kept]);  // the refit's weakest kept group
  }
  if (out.below.empty())
    out.why = mean.size() < 4 ? "fewer than 4 truth groups with an echo"
                              : "the weakest group is alone within the span, or most groups are";
  return out;
}

/// A surface over range needs calibration plates at two or more true distances.
void require_two_distances(std::span<const ranging::Record> records) {
  double first = ranging::kNaN;
  for (const auto& r : records) {
    if (!std::isfinite(r.truth.distance_m)) continue;
    if (std::isnan(first)) first = r.truth.distance_m;
    if (r.truth.distance_m != first) return;
  }
  throw std::invalid_argument(
      format("surface bspline: range axis undetermined: every row has distance_true_m = %g m (one "
             "distinct distance); measure plates at two or more distances, or fit a chain only",
             first));
}

/// Rows a surface can be fitted on: corrected distance, truth, amplitude (and temperature).
struct SurfaceRows {
  std::vector<double> range, amplitude, temperature, error;
  std::vector<std::uint32_t> group;  ///< truth group (cross-validation over whole targets)
};

/// The pipeline's ranges for `records`, their raw columns read in place.
std::vector<ranging::Range> corrected_ranges(const ranging::Pipeline& pipeline,
                                             std::span<const ranging::Record> records) {
  std::vector<ranging::Range> out(records.size());
  if (!records.empty()) pipeline.apply(ranging::RawColumns::of(records), out);
  return out;
}

SurfaceRows surface_rows(const ranging::Pipeline& pipeline,
                         std::span<const ranging::Record> records, bool use_temperature,
                         bool pulse_width) {
  const std::vector<ranging::Range> before = corrected_ranges(pipeline, records);
  SurfaceRows rows;
  std::size_t groups = 0;
  const std::vector<std::size_t> group = truth_groups(records, groups);
  for (std::size_t i = 0; i < records.size(); ++i) {
    const double d = before[i].distance_m;
    const double truth = records[i].truth.distance_m;
    const double a = pulse_width ? records[i].raw.pulse_width_ns : records[i].raw.amplitude;
    const double t = records[i].raw.temperature_c;
    if (!std::isfinite(d) || !std::isfinite(truth) || !std::isfinite(a) ||
        (use_temperature && !std::isfinite(t))) {
      continue;
    }
    rows.range.push_back(d);
    rows.amplitude.push_back(a);
    rows.temperature.push_back(t);
    rows.error.push_back(truth - d);  // C = true - measured (thesis Section 4.6)
    rows.group.push_back(static_cast<std::uint32_t>(group[i]));
  }
  return rows;
}

/// A piecewise-linear function through nodes (u_j, y_j), slope `left` before
/// the first and `right` after the last.
ranging::PiecewiseLinear from_nodes(const std::vector<double>& u, const std::vector<double>& y,
                                    double left, double right) {
  ranging::PiecewiseLinear f;
  f.x0 = u.front();
  f.intercept = y.front();
  f.slope0 = left;
  double previous = left;
  for (std::size_t j = 0; j < u.size(); ++j) {
    const double next = j + 1 < u.size() ? (y[j + 1] - y[j]) / (u[j + 1] - u[j]) : right;
    f.knots.push_back(u[j]);
    f.slopes.push_back(next - previous);
    previous = next;
  }
  return f;
}

/// Hat-function design: row i interpolates the node values at x_i.
void hat_row(const std::vector<double>& t, double x, std::size_t& j, double& w) {
  const auto it = std::upper_bound(t.begin(), t.end(), x);
  j = std::clamp<std::size_t>(static_cast<std::size_t>(it - t.begin()), 1, t.size() - 1) - 1;
  w = (x - t[j]) / (t[j + 1] - t[j]);  // weight of node j + 1 (linear beyond the ends)
}

/// Normal equations of the hat-function design (rows with use[i]).
struct NormalEquations {
  Eigen::MatrixXd normal;
  Eigen::VectorXd rhs;
};

struct Hat {
  std::size_t j = 0;  ///< left node
  double w = 0;       ///< weight of node j + 1
};

NormalEquations accumulate(std::size_t nodes, const std::vector<Hat>& hats,
                           const std::vector<double>& r, const std::vector<char>& use) {
  const auto k = static_cast<Eigen::Index>(nodes);
  NormalEquations eq{Eigen::MatrixXd::Zero(k, k), Eigen::VectorXd::Zero(k)};
  for (std::size_t i = 0; i < hats.size(); ++i) {
    if (!use[i]) continue;
    const double w = hats[i].w;
    const auto a = static_cast<Eigen::Index>(hats[i].j), b = a + 1;
    eq.normal(a, a) += (1 - w) * (1 - w);
    eq.normal(a, b) += (1 - w) * w;
    eq.normal(b, a) += (1 - w) * w;
    eq.normal(b, b) += w * w;
    eq.rhs(a) += (1 - w) * r[i];
    eq.rhs(b) += w * r[i];
  }
  return eq;
}

/// A^T A + lambda s D2^T D2 (+ a tiny ridge), s = trace(A^T A) / nodes, D2 the
/// nodes' second differences.
Eigen::MatrixXd penalized_normal(const NormalEquations& eq, double lambda_rel) {
  Eigen::MatrixXd normal = eq.normal;
  const Eigen::Index k = normal.rows();
  const double scale = normal.trace() / static_cast<double>(k);
  for (Eigen::Index j = 0; j + 2 < k; ++j) {
    const double d[3] = {1, -2, 1};
    for (int p = 0; p < 3; ++p)
      for (int q = 0; q < 3; ++q) normal(j + p, j + q) += lambda_rel * scale * d[p] * d[q];
  }
  normal.diagonal().array() += 1e-12 * scale;
  return normal;
}

/// Penalized node values: min |A v - r|^2 + lambda s |D2 v|^2.
Eigen::VectorXd solve_nodes(const NormalEquations& eq, double lambda_rel) {
  return penalized_normal(eq, lambda_rel).ldlt().solve(eq.rhs);
}

std::vector<Hat> hats_of(const std::vector<double>& t, const std::vector<double>& x) {
  std::vector<Hat> hats(x.size());
  for (std::size_t i = 0; i < x.size(); ++i) hat_row(t, x[i], hats[i].j, hats[i].w);
  return hats;
}

double hat_value(const Hat& h, const Eigen::VectorXd& v) {
  return (1 - h.w) * v(static_cast<Eigen::Index>(h.j)) +
         h.w * v(static_cast<Eigen::Index>(h.j + 1));
}

double node_value(const std::vector<double>& t, const Eigen::VectorXd& v, double x) {
  std::size_t j = 0;
  double w = 0;
  hat_row(t, x, j, w);
  return (1 - w) * v(static_cast<Eigen::Index>(j)) + w * v(static_cast<Eigen::Index>(j + 1));
}

/// refine_walk: the chain's grayvalue step plus a dense penalized correction
/// in pulse width, fitted on the chain's residual (see ModelFitOptions).
ranging::Pipeline refine_walk(const ranging::Pipeline& chain, std::span<const ranging::Record> rows,
                              std::size_t search_rows, ModelFitSummary::WalkRefinement* info) {
  std::size_t grayvalue = chain.steps().size();
  for (std::size_t s = 0; s < chain.steps().size(); ++s) {
    if (chain.steps()[s].kind == ranging::StepKind::kGrayvalue) grayvalue = s;
  }
  if (grayvalue == chain.steps().size()) return chain;
  const std::vector<ranging::Range> corrected = corrected_ranges(chain, rows);
  std::size_t groups = 0;
  const std::vector<std::size_t> group_of = truth_groups(rows, groups);
  std::vector<double> x, r;
  std::vector<std::size_t> group;
  for (std::size_t i = 0; i < rows.size(); ++i) {
    const double e = rows[i].truth.distance_m - corrected[i].distance_m;
    if (!std::isfinite(e) || !std::isfinite(rows[i].raw.pulse_width_ns) ||
        (corrected[i].correction_flags & ranging::kCorrOutOfDomain) != 0) {
      continue;
    }
    x.push_back(rows[i].raw.pulse_width_ns);
    r.push_back(e);
    group.push_back(group_of[i]);
  }
  constexpr std::size_t kFolds = 5;
  if (groups < kFolds || x.size() < 20) return chain;
  std::vector<double> sorted = x;
  std::sort(sorted.begin(), sorted.end());
  sorted.erase(std::unique(sorted.begin(), sorted.end()), sorted.end());
  const auto nodes_at = [&](int count) {
    std::vector<double> t;
    for (int j = 0; j < count; ++j) {
      const double q =
          static_cast<double>(j) / (count - 1) * static_cast<double>(sorted.size() - 1);
      const double v = sorted[static_cast<std::size_t>(std::lround(q))];
      if (t.empty() || v > t.back()) t.push_back(v);
    }
    return t;
  };
  // The cross-validation runs on at most search_rows rows (every k-th), as the
  // chain's knot search does; the chosen correction is then fitted on all.
  const std::size_t cap = std::max<std::size_t>(search_rows, 1);
  const std::size_t stride = (x.size() + cap - 1) / cap;
  std::vector<double> cx, cr;
  std::vector<std::size_t> cgroup;
  for (std::size_t i = 0; i < x.size(); i += stride) {
    cx.push_back(x[i]);
    cr.push_back(r[i]);
    cgroup.push_back(group[i]);
  }
  double without = 0;
  for (double e : cr) without += e * e;
  without = std::sqrt(without / static_cast<double>(cr.size()));
  double best = without, best_lambda = 0;
  int best_nodes = 0;
  for (int count : {6, 10, 16, 24, 32, 48, 64, 96, 128}) {
    if (static_cast<std::size_t>(count) * 3 > sorted.size()) break;
    const std::vector<double> t = nodes_at(count);
    if (t.size() < 3) continue;
    // The normal equations of each fold do not depend on the smoothing.
    const std::vector<Hat> hats = hats_of(t, cx);
    std::vector<NormalEquations> fold_eq;
    std::vector<char> use(cx.size());
    for (std::size_t fold = 0; fold < kFolds; ++fold) {
      for (std::size_t i = 0; i < cx.size(); ++i) use[i] = fold_of(cgroup[i], kFolds) != fold;
      fold_eq.push_back(accumulate(t.size(), hats, cr, use));
    }
    for (int decade_half = -10; decade_half <= 6; ++decade_half) {
      const double lambda = std::pow(10.0, 0.5 * decade_half);
      double sse = 0;
      for (std::size_t fold = 0; fold < kFolds; ++fold) {
        const Eigen::VectorXd v = solve_nodes(fold_eq[fold], lambda);
        for (std::size_t i = 0; i < cx.size(); ++i) {
          if (fold_of(cgroup[i], kFolds) != fold) continue;
          const double e = cr[i] - hat_value(hats[i], v);
          sse += e * e;
        }
      }
      const double cv = std::sqrt(sse / static_cast<double>(cx.size()));
      if (cv < best) {
        best = cv;
        best_lambda = lambda;
        best_nodes = count;
      }
    }
  }
  if (info) *info = {0, 0, best, without};
  if (best_nodes == 0) return chain;
  const std::vector<double> t = nodes_at(best_nodes);
  const NormalEquations all =
      accumulate(t.size(), hats_of(t, x), r, std::vector<char>(x.size(), 1));
  const Eigen::LDLT<Eigen::MatrixXd> factor = penalized_normal(all, best_lambda).ldlt();
  const Eigen::VectorXd v = factor.solve(all.rhs);
  if (info) {
    // Effective parameters: trace of the hat matrix A (A'A + lambda s P)^-1 A'
    // = trace((A'A + lambda s P)^-1 A'A), P the second-difference penalty.
    const double edf = factor.solve(all.normal).trace();
    *info = {static_cast<int>(t.size()), best_lambda, best, without, edf};
  }
  // g + d as one piecewise-linear function: nodes at the union of both knot sets.
  const ranging::Step& old = chain.steps()[grayvalue];
  std::vector<double> u = t;
  for (double k : old.function.knots) u.push_back(k);
  std::sort(u.begin(), u.end());
  u.erase(std::unique(u.begin(), u.end()), u.end());
  std::vector<double> y;
  for (double p : u) y.push_back(old.function(p) + node_value(t, v, p));
  const auto k = static_cast<Eigen::Index>(t.size());
  const double d_left = (v(1) - v(0)) / (t[1] - t[0]);
  const double d_right = (v(k - 1) - v(k - 2)) / (t[t.size() - 1] - t[t.size() - 2]);
  const ranging::PiecewiseLinear g =
      from_nodes(u, y, old.function.slope_at(u.front() - 1e-9) + d_left,
                 old.function.slope_at(u.back()) + d_right);
  ranging::Pipeline refined(chain.time_to_distance());
  for (std::size_t s = 0; s < chain.steps().size(); ++s) {
    ranging::Step step = chain.steps()[s];
    if (s == grayvalue) {
      ranging::Step walk = ranging::make_grayvalue_step(g, step.domain);
      walk.fit = step.fit;
      step = walk;
    }
    refined.add_step(std::move(step));
  }
  const std::vector<ranging::Range> after = corrected_ranges(refined, rows);
  double sse = 0;
  std::size_t n = 0;
  for (std::size_t i = 0; i < rows.size(); ++i) {
    const double e = rows[i].truth.distance_m - after[i].distance_m;
    if (!std::isfinite(e)) continue;
    sse += e * e;
    ++n;
  }
  refined.set_residual_rms_m(n ? std::sqrt(sse / static_cast<double>(n)) : chain.residual_rms_m());
  return refined;
}

/// The correction (base or chain, then the surface on its residual) fitted on
/// `rows`; the summary and report only when given (the model that is kept).
ranging::Pipeline fit_main_correction(std::span<const ranging::Record> rows,
                                      const ModelFitOptions& o, ModelFitSummary* summary,
                                      std::string* report) {
  ranging::Pipeline pipeline = o.base ? *o.base : ranging::Pipeline(o.time_to_distance);
  if (o.chain) {
    ChainFitOptions chain_options = o.chain_options;
    chain_options.steps = *o.chain;
    chain_options.time_to_distance = o.time_to_distance;
    ChainFitResult chain = fit_chain(rows, chain_options);
    pipeline = chain.pipeline;
    if (report) *report += chain.summary();
    if (o.refine_walk) {
      ModelFitSummary::WalkRefinement walk;
      pipeline = refine_walk(pipeline, rows, chain_options.knot_search_rows, &walk);
      if (report) {
        *report += format(
            "walk refinement: %d nodes in pulse width, smoothing %g, cross-validated RMS %.3f mm "
            "(chain alone %.3f mm)\n",
            walk.nodes, walk.smoothing, walk.cv_rms_m * 1e3, walk.cv_rms_without_m * 1e3);
      }
      if (summary) summary->walk = walk;
    }
    if (summary) {
      summary->chain_steps = to_string(*o.chain);
      summary->chain = std::move(chain);
    }
  }
  if (o.surface.kind != SurfaceKind::none) {
    const auto fit_on = [&](bool pulse_width, SurfaceRows& input) {
      input = surface_rows(pipeline, rows, o.surface_temperature, pulse_width);
      const SurfaceFitData data{{input.range, input.amplitude,
                                 o.surface_temperature ? std::span<const double>(input.temperature)
                                                       : std::span<const double>()},
                                input.error,
                                input.group};
      if (o.surface.kind == SurfaceKind::polynomial) {
        PolynomialFitOptions poly = o.polynomial;
        poly.order = o.surface.order;
        poly.use_temperature = o.surface_temperature;
        return fit_polynomial_surface(data, poly);
      }
      require_two_distances(rows);
      BSplineFitOptions bspline = o.bspline;
      bspline.use_temperature = o.surface_temperature;
      // On a chain's residual the prior is no correction: where the rows
      // leave a corner of range x intensity empty (far and weak), the surface
      // decays to zero instead of extrapolating a twist fitted elsewhere.
      if (o.chain && bspline.shrink_to_zero == 0) bspline.shrink_to_zero = 1.0;
      if (pulse_width) {
        bspline.log_amplitude = false;
        bspline.intensity = ranging::IntensityInput::pulse_width;
      }
      return fit_bspline_surface(data, bspline);
    };
    const bool bspline = o.surface.kind == SurfaceKind::bspline;
    // On a chain's residual, an amplitude reading that clips (its peak
    // detector's ceiling: several rows read exactly the largest amplitude,
    // whatever their overdrive) cannot index the saturated echoes' residual,
    // which the rows' cross-validation does not see (few such targets, each
    // predicted from its clipped neighbours): the automatic axis is then the
    // pulse width. Measured on a held-out device: saturated field echoes
    // 7.8 mm off on the amplitude axis, 3.4 mm worst row on the pulse width.
    std::size_t echoes = 0, at_ceiling = 0;
    double ceiling = 0;
    bool widths = true;
    for (const auto& r : rows)
      if (r.raw.has_echo() && std::isfinite(r.raw.amplitude)) {
        ++echoes;
        ceiling = std::max(ceiling, r.raw.amplitude);
        widths = widths && std::isfinite(r.raw.pulse_width_ns);
      }
    for (const auto& r : rows)
      if (r.raw.has_echo() && r.raw.amplitude == ceiling) ++at_ceiling;
    const bool amplitude_clips = o.chain && widths && at_ceiling >= 3 && 50 * at_ceiling >= echoes;
    const bool try_amplitude =
        !bspline || o.surface_intensity == SurfaceIntensity::amplitude ||
        (o.surface_intensity != SurfaceIntensity::pulse_width && !amplitude_clips);
    const bool try_pulse_width = bspline && o.surface_intensity != SurfaceIntensity::amplitude;
    SurfaceRows input, other_input;
    SurfaceFitResult surface;
    bool pulse_width = false;
    double other_cv = 0;
    if (try_amplitude) surface = fit_on(false, input);
    if (try_pulse_width) {
      if (!try_amplitude) {
        surface = fit_on(true, input);
        pulse_width = true;
      } else {
        // choose: the axis with the lower grouped cross-validated RMS; an axis
        // the data cannot carry (no pulse widths, no spread) is not a candidate.
        try {
          SurfaceFitResult by_width = fit_on(true, other_input);
          if (by_width.cv_rms_m > 0 && by_width.cv_rms_m < surface.cv_rms_m) {
            other_cv = surface.cv_rms_m;
            std::swap(surface, by_width);
            std::swap(input, other_input);
            pulse_width = true;
          } else {
            other_cv = by_width.cv_rms_m;
          }
        } catch (const std::invalid_argument&) {
        }
      }
    }
    ranging::Step step = ranging::make_surface_step(surface.surface);
    step.fit.rows = surface.rows;
    step.fit.residual_rms_m = surface.residual_rms_m;
    pipeline.add_step(std::move(step));
    pipeline.set_residual_rms_m(surface.residual_rms_m);
    if (report) {
      *report += surface.summary() + (pulse_width ? ", intensity axis: pulse width" : "");
      if (amplitude_clips && o.surface_intensity == SurfaceIntensity::choose)
        *report += format(" (the amplitude reading clips: %zu rows at %g)", at_ceiling, ceiling);
      if (other_cv > 0) {
        *report += format(" (%s axis: cross-validated RMS %.3f mm)",
                          pulse_width ? "amplitude" : "pulse-width", other_cv * 1e3);
      }
      *report += "\n";
    }
    if (summary) {
      summary->surface_spec = to_string(o.surface);
      summary->surface_temperature = o.surface_temperature;
      summary->surface_intensity = pulse_width ? "pulse_width_ns" : "amplitude";
      summary->surface_cv_rms_other_m = other_cv;
      summary->surface_error_before = error_stats(input.error);
      summary->surface = std::move(surface);
    }
  }
  return pipeline;
}

/// How much a row's corrected range moves per metre of pulse width (the
/// width's change as a distance, c_air/2 x ns): the main correction's
/// sensitivity to the falling edge's stop (0 without a finite width, or for a
/// correction that does not read the width). Central difference over
/// +-kWidthStep_ns.
std::vector<double> width_sensitivity(const ranging::Pipeline& main,
                                      std::span<const ranging::Record> rows) {
  constexpr double kWidthStep_ns = 0.005;
  std::vector<ranging::Record> up(rows.begin(), rows.end()), down(rows.begin(), rows.end());
  for (std::size_t i = 0; i < rows.size(); ++i) {
    up[i].raw.pulse_width_ns += kWidthStep_ns;
    down[i].raw.pulse_width_ns -= kWidthStep_ns;
  }
  const std::vector<ranging::Range> a = corrected_ranges(main, up),
                                    b = corrected_ranges(main, down);
  const double metres_per_ns = ranging::metres_per_ns(main.time_to_distance());
  std::vector<double> g(rows.size(), 0.0);
  for (std::size_t i = 0; i < rows.size(); ++i) {
    const double d = (a[i].distance_m - b[i].distance_m) / (2 * kWidthStep_ns * metres_per_ns);
    if (std::isfinite(d)) g[i] = d;
  }
  return g;
}

/// The periodic step on the residual of `main` (rows outside its domain or
/// without a finite tof left out): the TDC's error at a stop, a Fourier
/// series E in the stop's time modulo the period, its harmonic count
/// (0 .. kMaxHarmonics) chosen by grouped 5-fold cross-validation. A row's
/// time of flight is its rising edge's stop; its pulse width, which the walk,
/// gray-value or width-axis surface reads, is the falling edge's stop less
/// the rising one's, so a row's corrected range carries (1 - g) E(rise) +
/// g E(fall) with g the main correction's width sensitivity (the same
/// function at both stops: linear in E's coefficients). Fitted to the rising
/// stop alone, the falling stop's share (half the INL where the walk's slope
/// is -1/2) would sit at a phase that moves with the echo's width, which no
/// series in the time of flight can follow: on held-out case 0 it left
/// 0.35 mm of a 1.15 mm effect even fitted to the field rows themselves,
/// both stops 0.11 mm (8 harmonics) and 0.04 mm (16).
/// Where the rows span temperatures (a temperature run over the period's
/// phases), the cross-validation also chooses whether each coefficient moves
/// linearly with the temperature reading about the rows' median reading: the
/// fine bins' width follows the timing board's temperature, so a bin-width
/// error, a sawtooth over the period, grows with the board's departure from
/// where the codes were fitted. Its mean over the period is the temperature
/// step's (a column fitted, not kept). Held-out case 0 (power-ons 9-16,
/// the planner's protocol): the field's rows at 37 C read 0.38 mm long
/// against 17 C on average over 0.7-4.9 m (phases 0.30-0.41 m of the 0.75 m
/// period), 0.03 mm with the slopes; the systematic residual at 0 min fell
/// from 0.41 to 0.36 mm (one row's noise 0.31 mm).
/// Returns the step, at both stops (empty harmonics: none chosen).
constexpr int kMaxHarmonics = 16;

ranging::Step fit_periodic(const ranging::Pipeline& main, std::span<const ranging::Record> rows,
                           double period_ns, ModelFitSummary::Periodic* info) {
  const std::vector<ranging::Range> corrected = corrected_ranges(main, rows);
  const std::vector<double> sensitivity = width_sensitivity(main, rows);
  std::size_t groups = 0;
  const std::vector<std::size_t> group_of = truth_groups(rows, groups);
  std::vector<double> rise, fall, g, e, temperature;
  std::vector<std::size_t> fold;
  constexpr std::size_t kFolds = 5;
  const auto phase = [&](double tof_ns) {
    return 2.0 * std::numbers::pi * std::fmod(tof_ns, period_ns) / period_ns;
  };
  // Rows that lost more than 2 % of the shots (false stops kept within the
  // firmware's gate pull them short, weak echoes miss the threshold) carry
  // errors the TDC does not make, at the few phases of their plates: left out
  // (held-out case 1, in sunlight: the chain's field rows 96.9 -> 98.8 %
  // within 2 sigma, bright tercile 93.6 -> 97.6 %, systematic 1.44 -> 1.37
  // mm).
  std::uint32_t shots = 0;
  for (const auto& r : rows) shots = std::max(shots, r.raw.shots_valid);
  for (std::size_t i = 0; i < rows.size(); ++i) {
    const double r = rows[i].truth.distance_m - corrected[i].distance_m;
    if (!std::isfinite(r) || !std::isfinite(rows[i].raw.tof_ns) ||
        (corrected[i].correction_flags & ranging::kCorrOutOfDomain) != 0 ||
        50 * static_cast<std::uint64_t>(rows[i].raw.shots_valid) <
            49 * static_cast<std::uint64_t>(shots)) {
      continue;
    }
    const double width = rows[i].raw.pulse_width_ns;
    rise.push_back(phase(rows[i].raw.tof_ns));
    fall.push_back(std::isfinite(width) ? phase(rows[i].raw.tof_ns + width) : 0.0);
    g.push_back(std::isfinite(width) ? sensitivity[i] : 0.0);
    e.push_back(r);
    temperature.push_back(rows[i].raw.temperature_c);
    fold.push_back(fold_of(group_of[i], kFolds));
  }
  const auto n = static_cast<Eigen::Index>(e.size());
  ranging::Step out = ranging::make_periodic_step(period_ns, {}, true);
  // The slope's anchor: the median reading (where the plates and the rail
  // stand); rows without a reading get none of the slope.
  std::vector<double> readings;
  for (double t : temperature)
    if (std::isfinite(t)) readings.push_back(t);
  double t_lo = 0, t_hi = 0;
  if (!readings.empty()) {
    std::sort(readings.begin(), readings.end());
    out.reference_temperature_c = readings[readings.size() / 2];
    t_lo = readings.front();
    t_hi = readings.back();
  }
  // Columns: a constant (the main correction's business; fitted, not kept),
  // then cos and sin of each harmonic at both stops, weighted by their share;
  // then the same times the reading's departure (the slopes).
  constexpr Eigen::Index kCols = 1 + 2 * kMaxHarmonics;
  Eigen::MatrixXd x(n, 2 * kCols);
  for (Eigen::Index i = 0; i < n; ++i) {
    const auto k = static_cast<std::size_t>(i);
    x(i, 0) = 1.0;
    for (int h = 1; h <= kMaxHarmonics; ++h) {
      x(i, 2 * h - 1) = (1 - g[k]) * std::cos(h * rise[k]) + g[k] * std::cos(h * fall[k]);
      x(i, 2 * h) = (1 - g[k]) * std::sin(h * rise[k]) + g[k] * std::sin(h * fall[k]);
    }
    const double dt =
        std::isfinite(temperature[k]) ? temperature[k] - out.reference_temperature_c : 0.0;
    x.row(i).segment(kCols, kCols) = dt * x.row(i).head(kCols);
  }
  // A slope needs a spread of readings to be seen (a temperature run's), and
  // its harmonics phases that resolve them: the rows away from the reference
  // stand at a few phases only (a run's plates), where more harmonics than
  // a third of their phases (in 64ths of the period) would alias, fitting
  // them and swinging between them, and a grouped fold holds out a target,
  // not its phase, so the cross-validation would not see it.
  constexpr double kMinSpanC = 5;
  constexpr int kPhaseBins = 64;
  std::vector<bool> seen(kPhaseBins, false);
  for (std::size_t k = 0; k < temperature.size(); ++k)
    if (std::abs(temperature[k] - out.reference_temperature_c) >= kMinSpanC / 2)
      seen[std::min(kPhaseBins - 1,
                    static_cast<int>(rise[k] / (2 * std::numbers::pi) * kPhaseBins))] = true;
  const int slope_harmonics = static_cast<int>(std::count(seen.begin(), seen.end(), true)) / 3;
  const bool slope_seen = t_hi - t_lo >= kMinSpanC && slope_harmonics >= 1;
  const auto columns = [&](int h, bool slope) {
    std::vector<Eigen::Index> c;
    for (Eigen::Index j = 0; j <= 2 * h; ++j) c.push_back(j);
    if (slope)
      for (Eigen::Index j = 0; j <= 2 * std::min(h, slope_harmonics); ++j) c.push_back(kCols + j);
    return c;
  };
  const Eigen::Map<const Eigen::VectorXd> y(e.data(), n);
  double best = y.squaredNorm(), without = -1;
  int best_h = 0;
  bool best_slope = false;
  if (groups >= kFolds && n >= 40) {
    // Each fold's normal equations over every column, formed once; a
    // candidate solves its columns' block of them (a tiny ridge, as the walk
    // refinement's, for a block its training rows cannot carry).
    std::array<std::vector<Eigen::Index>, kFolds> test;
    std::array<NormalEquations, kFolds> train;
    for (Eigen::Index i = 0; i < n; ++i) test[fold[static_cast<std::size_t>(i)]].push_back(i);
    for (std::size_t f = 0; f < kFolds; ++f) {
      std::vector<Eigen::Index> rows_in;
      for (Eigen::Index i = 0; i < n; ++i)
        if (fold[static_cast<std::size_t>(i)] != f) rows_in.push_back(i);
      const Eigen::MatrixXd a = x(rows_in, Eigen::all);
      train[f] = {a.transpose() * a, a.transpose() * y(rows_in)};
    }
    for (int slope = 0; slope <= (slope_seen ? 1 : 0); ++slope) {
      for (int h = slope; h <= kMaxHarmonics; ++h) {
        const std::vector<Eigen::Index> cols = columns(h, slope != 0);
        double sse = 0;
        for (std::size_t f = 0; f < kFolds; ++f) {
          const std::size_t train_rows = static_cast<std::size_t>(n) - test[f].size();
          if (test[f].empty() || train_rows < 3 * cols.size()) continue;
          Eigen::MatrixXd normal = train[f].normal(cols, cols);
          normal.diagonal().array() += 1e-12 * normal.trace() / static_cast<double>(cols.size());
          const Eigen::VectorXd c = normal.ldlt().solve(train[f].rhs(cols).eval());
          sse += (y(test[f]) - x(test[f], cols) * c).squaredNorm();
        }
        if (h == 0 && slope == 0) {
          without = sse;
          best = sse;
        } else if (sse < best) {
          best = sse;
          best_h = h;
          best_slope = slope != 0;
        }
      }
    }
  }
  if (info && without >= 0) {
    info->harmonics = best_h;
    info->temperature_slope = best_slope;
    info->cv_rms_m = std::sqrt(best / static_cast<double>(n));
    info->cv_rms_without_m = std::sqrt(without / static_cast<double>(n));
  }
  if (best_h == 0) return out;
  const std::vector<Eigen::Index> cols = columns(best_h, best_slope);
  const Eigen::VectorXd c = x(Eigen::all, cols).colPivHouseholderQr().solve(y);
  const auto terms = static_cast<Eigen::Index>(2 * best_h);
  out.harmonics_m.assign(c.data() + 1, c.data() + 1 + terms);
  if (best_slope) {  // the harmonics beyond the slope's own hold still
    out.harmonics_per_c_m.assign(static_cast<std::size_t>(terms), 0.0);
    const Eigen::Index slope_terms = 2 * std::min(best_h, slope_harmonics);
    std::copy(c.data() + 2 + terms, c.data() + 2 + terms + slope_terms,
              out.harmonics_per_c_m.begin());
  }
  return out;
}

/// The correction: the main one (chain and/or surface), and with
/// o.tdc_period_ns a periodic step at both stops in front of it, fitted by
/// backfitting: the periodic part on the main correction's residual, the main
/// correction again on rows whose stops the periodic part has corrected,
/// twice.
ranging::Pipeline fit_correction(std::span<const ranging::Record> rows, const ModelFitOptions& o,
                                 ModelFitSummary* summary, std::string* report) {
  if (!(o.tdc_period_ns > 0)) return fit_main_correction(rows, o, summary, report);
  std::vector<ranging::Record> adjusted(rows.begin(), rows.end());
  ranging::Step step;  // the periodic one
  // The rows as the step hands them on: its corrected tof and width.
  const auto adjust = [&] {
    const double metres_per_ns = ranging::metres_per_ns(o.time_to_distance);
    for (std::size_t i = 0; i < rows.size(); ++i) {
      const double tof = rows[i].raw.tof_ns, width = rows[i].raw.pulse_width_ns;
      const double reading = rows[i].raw.temperature_c;
      const double c_rise = ranging::periodic_correction(step, tof, reading);
      adjusted[i].raw.tof_ns = tof + c_rise / metres_per_ns;
      adjusted[i].raw.distance_raw_m = rows[i].raw.distance_raw_m + c_rise;
      if (std::isfinite(width) && std::isfinite(tof)) {
        const double c_fall = ranging::periodic_correction(step, tof + width, reading);
        adjusted[i].raw.pulse_width_ns = width + (c_fall - c_rise) / metres_per_ns;
      }
    }
  };
  ranging::Pipeline main = fit_main_correction(rows, o, nullptr, nullptr);
  ModelFitSummary::Periodic info;
  constexpr int kRounds = 2;
  for (int round = 0; round <= kRounds; ++round) {
    step = fit_periodic(main, rows, o.tdc_period_ns, &info);
    if (step.harmonics_m.empty() || round == kRounds) break;
    adjust();
    const bool last = round + 1 == kRounds;
    main = fit_main_correction(adjusted, o, last ? summary : nullptr, last ? report : nullptr);
  }
  if (step.harmonics_m.empty()) {
    // Not chosen: the main correction alone, fitted (and summarised) on the rows as they are.
    main = fit_main_correction(rows, o, summary, report);
    if (summary) summary->periodic = info;
    if (report) {
      *report +=
          format("periodic (TDC clock period %.4g ns): none chosen (cross-validated RMS %.3f mm)\n",
                 o.tdc_period_ns, info.cv_rms_without_m * 1e3);
    }
    return main;
  }
  ranging::Pipeline pipeline(main.time_to_distance());
  step.fit.rows = rows.size();
  step.fit.residual_rms_m = main.residual_rms_m();  // of the whole fit, periodic part included
  pipeline.add_step(step);
  for (const ranging::Step& s : main.steps()) pipeline.add_step(s);
  pipeline.set_residual_rms_m(main.residual_rms_m());
  if (summary) summary->periodic = info;
  if (report) {
    const auto rms = [](const std::vector<double>& c) {
      double amplitude2 = 0;
      for (double v : c) amplitude2 += v * v;
      return std::sqrt(0.5 * amplitude2);
    };
    const std::string slope =
        step.harmonics_per_c_m.empty()
            ? std::string()
            : format(", its rms moving %.4f mm/C about %.1f C", rms(step.harmonics_per_c_m) * 1e3,
                     step.reference_temperature_c);
    *report += format(
        "periodic (TDC clock period %.4g ns, at both stops): %d harmonic(s), rms %.3f mm%s, "
        "cross-validated RMS %.3f mm (without %.3f mm)\n",
        o.tdc_period_ns, info.harmonics, rms(step.harmonics_m) * 1e3, slope.c_str(),
        info.cv_rms_m * 1e3, info.cv_rms_without_m * 1e3);
  }
  return pipeline;
}

/// Residuals of a model on rows it was not fitted on.
struct Residuals {
  std::vector<double> range, amplitude, residual;

  void add(const ranging::Pipeline& model, std::span<const ranging::Record> rows) {
    const std::vector<ranging::Range> corrected = corrected_ranges(model, rows);
    for (std::size_t i = 0; i < rows.size(); ++i) {
      const double e = rows[i].truth.distance_m - corrected[i].distance_m;
      // Out-of-domain rows would teach the in-domain sigma the extrapolation error.
      if (!std::isfinite(e) || !std::isfinite(rows[i].raw.amplitude) ||
          (corrected[i].correction_flags & ranging::kCorrOutOfDomain) != 0) {
        continue;
      }
      range.push_back(corrected[i].distance_m);
      amplitude.push_back(rows[i].raw.amplitude);
      residual.push_back(e);
    }
  }
};

/// The correction's effective parameter count: the surface's (trace of its
/// hat matrix, or its rank), the chain's offset, its walk refinement's trace
/// or its hinges' parameters (intercept, slope and one per knot), the walk
/// model's shape parameters, and two per
/// harmonic of a periodic step (four when they move with the temperature).
double effective_parameters(const ModelFitSummary& s) {
  double p = 0;
  if (s.surface) p += s.surface->effective_parameters;
  if (s.chain) {
    p += 1;  // offset
    const auto hinge = [](const std::optional<HingeFitResult>& h) {
      return h ? 2.0 + static_cast<double>(h->knots.size()) : 0.0;
    };
    p += s.walk && s.walk->nodes > 0 ? s.walk->effective_parameters : hinge(s.chain->grayvalue);
    p += hinge(s.chain->temperature);
    // The walk model's shape: pulse sigma and pole, plus onset and recovery when clipping was
    // fitted.
    if (s.chain->walk)
      p += std::isfinite(s.chain->walk->shape.saturation_log_overdrive) ? 4.0 : 2.0;
  }
  if (s.periodic) p += (s.periodic->temperature_slope ? 4.0 : 2.0) * s.periodic->harmonics;
  return p;
}

/// Each truth group's leverage on its own mean residual, h_g = d(mean
/// corrected distance of g) / d(truth of g): the correction refitted with the
/// group's truth moved by a small step (the fit is linear in the truth for
/// fixed choices of knots, smoothing and harmonics, and the step is far below
/// the residuals that choose them; a walk step starts from the full fit's
/// shape), against a refit on the rows as they are with the same options.
/// One refit per group: the price of a pointwise optimism. NaN for groups
/// without a usable row.
std::vector<double> group_leverages(std::span<const ranging::Record> records,
                                    const std::vector<std::size_t>& group_of,
                                    const std::vector<char>& wanted, const ModelFitOptions& o,
                                    const ModelFitSummary& summary) {
  const std::size_t groups = wanted.size();
  constexpr double kStepM = 1e-5;  // 10 um: about 1/30 of a row's noise
  ModelFitOptions refit = o;
  refit.confidence = ConfidenceKind::none;
  if (summary.chain && summary.chain->walk && !refit.chain_options.walk_initial) {
    refit.chain_options.walk_initial = summary.chain->walk->shape;
  }
  refit.chain_options.walk_replicates = 0;  // (their sigma is not used)
  // A B-spline surface keeps the fit's choices (intensity axis, knots,
  // smoothing, axis weights): its search by cross-validation is what costs.
  if (summary.surface && o.surface.kind == SurfaceKind::bspline) {
    const SurfaceFitResult& s = *summary.surface;
    refit.surface_intensity = summary.surface_intensity == "pulse_width_ns"
                                  ? SurfaceIntensity::pulse_width
                                  : SurfaceIntensity::amplitude;
    BSplineFitOptions& b = refit.bspline;
    b.choose_intervals_by_gcv = b.choose_smoothing_by_gcv = false;
    b.intervals_range = s.intervals[0];
    b.intervals_amplitude = s.intervals[1];
    if (s.intervals[2] > 0) b.intervals_temperature = s.intervals[2];
    b.smoothing = s.smoothing;
    b.knot_placement = {s.placement[0], s.placement[1], s.placement[2]};
    for (int k = 0; k < 3; ++k) b.axis_weight[k] = s.axis_weight[k];
  }
  std::vector<ranging::Record> rows(records.begin(), records.end());
  const std::vector<ranging::Range> base =
      corrected_ranges(fit_correction(rows, refit, nullptr, nullptr), records);
  std::vector<std::vector<std::size_t>> members(groups);
  for (std::size_t i = 0; i < records.size(); ++i) members[group_of[i]].push_back(i);
  std::vector<double> leverage(groups, ranging::kNaN);
  for (std::size_t g = 0; g < groups; ++g) {
    if (!wanted[g]) continue;
    for (std::size_t i : members[g]) rows[i].truth.distance_m += kStepM;
    const ranging::Pipeline moved = fit_correction(rows, refit, nullptr, nullptr);
    for (std::size_t i : members[g]) rows[i].truth.distance_m = records[i].truth.distance_m;
    double sum = 0;
    std::size_t used = 0;
    for (std::size_t i : members[g]) {
      const double after = moved.apply(records[i].raw).distance_m;
      if (!std::isfinite(after) || !std::isfinite(base[i].distance_m)) continue;
      sum += (after - base[i].distance_m) / kStepM;
      ++used;
    }
    if (used > 0) leverage[g] = sum / static_cast<double>(used);
  }
  return leverage;
}

/// Above this many targets the noise-systematic confidence takes one optimism
/// (G + p) / (G - p) for all instead of a refit per target.
constexpr std::size_t kMaxLeverageRefits = 500;

/// noise_systematic: in-sample residuals of the kept model on every row,
/// grouped by truth; the intensity axis the correction reads; each group's
/// leverage for its pointwise optimism.
void fit_repeats_confidence(std::span<const ranging::Record> records, const ModelFitOptions& o,
                            ModelFitResult& result) {
  bool pulse_width = result.summary.chain.has_value() && (o.chain->grayvalue || o.chain->walk);
  if (result.summary.surface) pulse_width = result.summary.surface_intensity == "pulse_width_ns";
  std::size_t groups = 0;
  const std::vector<std::size_t> group_of = truth_groups(records, groups);
  const std::vector<ranging::Range> corrected = corrected_ranges(result.pipeline, records);
  std::vector<double> range, intensity, residual;
  std::vector<std::uint32_t> group;
  std::vector<char> seen(groups, 0);
  std::size_t used_groups = 0;
  for (std::size_t i = 0; i < records.size(); ++i) {
    const double e = records[i].truth.distance_m - corrected[i].distance_m;
    const double x = pulse_width ? records[i].raw.pulse_width_ns : records[i].raw.amplitude;
    // (The axis is known only now: require_model_magnitudes left it to here.)
    if (records[i].raw.has_echo())
      require_magnitude(x, pulse_width ? "pulse_width_ns" : "amplitude", i);
    if (!std::isfinite(e) || !(x > 0) || !std::isfinite(x) ||
        (corrected[i].correction_flags & ranging::kCorrOutOfDomain) != 0) {
      continue;
    }
    range.push_back(corrected[i].distance_m);
    intensity.push_back(x);
    residual.push_back(e);
    group.push_back(static_cast<std::uint32_t>(group_of[i]));
    if (!seen[group_of[i]]) {
      seen[group_of[i]] = 1;
      ++used_groups;
    }
  }
  const double p = effective_parameters(result.summary);
  const double g = static_cast<double>(used_groups);
  NoiseSystematicOptions options;
  options.intensity =
      pulse_width ? ranging::IntensityInput::pulse_width : ranging::IntensityInput::amplitude;
  std::string why;
  double leverage_sum = 0, optimism_mean = 0, optimism_max = 0;
  const bool pointwise = used_groups <= kMaxLeverageRefits;
  if (!(g > p + 1)) {
    why = format("%zu targets for %.1f effective parameters", used_groups, p);
  } else if (!pointwise) {
    // One refit per target costs too much here: one optimism for all.
    options.optimism = optimism_mean = optimism_max = (g + p) / (g - p);
    try {
      result.pipeline.set_confidence(
          fit_noise_systematic_confidence({range, intensity, residual, group}, options));
    } catch (const std::invalid_argument& e) {
      why = e.what();
    }
  } else {
    try {
      // Pointwise optimism (1 + h) / (1 - h) from each target's leverage h.
      std::vector<double> h = group_leverages(records, group_of, seen, o, result.summary);
      for (std::size_t t = 0; t < groups; ++t) {
        if (!seen[t]) continue;
        if (!std::isfinite(h[t])) throw std::invalid_argument("a target without a leverage");
        leverage_sum += h[t];
        h[t] = std::clamp(h[t], 0.0, kMaxLeverage);
        const double optimism = (1 + h[t]) / (1 - h[t]);
        optimism_mean += optimism;
        optimism_max = std::max(optimism_max, optimism);
      }
      optimism_mean /= g;
      std::vector<double> leverage(group.size());
      for (std::size_t k = 0; k < group.size(); ++k) leverage[k] = h[group[k]];
      result.pipeline.set_confidence(
          fit_noise_systematic_confidence({range, intensity, residual, group, leverage}, options));
    } catch (const std::invalid_argument& e) {
      why = e.what();
    }
  }
  if (!why.empty()) {
    if (o.confidence_required) throw std::invalid_argument("confidence noise-systematic: " + why);
    result.report += "confidence: none (" + why + ")\n";
    return;
  }
  ModelFitSummary::Confidence c;
  c.kind = o.confidence;
  c.rows = residual.size();
  c.groups = used_groups;
  c.held_out = error_stats(residual);
  c.effective_parameters = p;
  c.leverage_sum = leverage_sum;
  c.optimism = optimism_mean;
  c.optimism_max = optimism_max;
  const std::string optimism =
      pointwise
          ? format(
                "optimism (1 + h) / (1 - h) per target from its leverage h: mean %.3f, max "
                "%.3f (leverages sum to %.1f; p = %.1f effective parameters, (G + p) / (G - p) "
                "= %.3f)",
                c.optimism, c.optimism_max, leverage_sum, p, (g + p) / (g - p))
          : format(
                "optimism (G + p) / (G - p) = %.3f with p = %.1f for every target (more than "
                "%zu targets: their leverages are not measured)",
                c.optimism, p, kMaxLeverageRefits);
  result.report += format(
      "confidence: noise-systematic model on %s, fitted on %zu rows of %zu targets (in-sample "
      "RMS %.3f mm); %s\n",
      pulse_width ? "pulse width" : "amplitude", c.rows, used_groups, c.held_out.rms_m * 1e3,
      optimism.c_str());
  result.summary.confidence = c;
}

}  // namespace

SurfaceSpec parse_surface_spec(std::string_view spec) {
  if (spec == "bspline") return {SurfaceKind::bspline, 0};
  if (spec.rfind("poly:", 0) == 0) {
    const std::string n(spec.substr(5));
    std::size_t used = 0;
    int order = -1;
    try {
      order = std::stoi(n, &used);
    } catch (const std::exception&) {
      used = 0;
    }
    if (used == n.size() && order >= 1 && order <= 12) return {SurfaceKind::polynomial, order};
  }
  throw std::invalid_argument("expected poly:N (N = 1..12) or bspline");
}

std::string to_string(const SurfaceSpec& spec) {
  switch (spec.kind) {
    case SurfaceKind::polynomial:
      return "poly:" + std::to_string(spec.order);
    case SurfaceKind::bspline:
      return "bspline";
    case SurfaceKind::none:
      break;
  }
  return "";
}

SurfaceIntensity parse_surface_intensity(std::string_view text) {
  if (text == "auto") return SurfaceIntensity::choose;
  if (text == "amplitude") return SurfaceIntensity::amplitude;
  if (text == "pulse-width") return SurfaceIntensity::pulse_width;
  throw std::invalid_argument("expected auto, amplitude or pulse-width");
}

ConfidenceKind parse_confidence_kind(std::string_view kind) {
  if (kind == "none") return ConfidenceKind::none;
  if (kind == "calibrated") return ConfidenceKind::calibrated;
  if (kind == "thesis") return ConfidenceKind::thesis;
  if (kind == "noise-systematic") return ConfidenceKind::noise_systematic;
  throw std::invalid_argument("confidence " + std::string(kind) +
                              ": expected none, calibrated, thesis or noise-systematic");
}

std::string to_string(ConfidenceKind kind) {
  switch (kind) {
    case ConfidenceKind::calibrated:
      return "calibrated";
    case ConfidenceKind::thesis:
      return "thesis";
    case ConfidenceKind::noise_systematic:
      return "noise-systematic";
    case ConfidenceKind::none:
      break;
  }
  return "none";
}

void ModelFitOptions::validate() const {
  if (!chain && surface.kind == SurfaceKind::none) {
    throw std::invalid_argument("nothing to fit: give chain steps and/or a surface");
  }
  if (chain && base) throw std::invalid_argument("a base pipeline and a chain are exclusive");
  if (!(confidence_hold_out_fraction >= 0 && confidence_hold_out_fraction <= 0.5)) {
    throw std::invalid_argument("confidence_hold_out_fraction must be in (0, 0.5] (0: none)");
  }
  if (confidence_folds < 2) throw std::invalid_argument("confidence_folds must be >= 2");
  if (!(tdc_period_ns >= 0) || !std::isfinite(tdc_period_ns)) {
    throw std::invalid_argument("tdc_period_ns must be finite and >= 0 (0: no periodic step)");
  }
  if (surface.kind == SurfaceKind::polynomial) polynomial.validate();
  if (surface.kind == SurfaceKind::bspline) bspline.validate();
}

namespace {

/// Refuses a corrupt cell in a column the surface or the confidence reads
/// (fit_chain checks its own columns): |value| > kMaxMagnitude names the
/// column and the data row. Rows without an echo are not fitted. The
/// noise-systematic confidence reads the correction's intensity axis, known
/// after the fit: fit_repeats_confidence checks its column.
void require_model_magnitudes(std::span<const ranging::Record> records, const ModelFitOptions& o) {
  const bool surface = o.surface.kind != SurfaceKind::none;
  const bool amplitude =
      (surface && o.surface_intensity != SurfaceIntensity::pulse_width) ||
      (o.confidence != ConfidenceKind::none && o.confidence != ConfidenceKind::noise_systematic);
  const bool pulse_width = surface && o.surface_intensity != SurfaceIntensity::amplitude;
  for (std::size_t i = 0; i < records.size(); ++i) {
    const ranging::Record& r = records[i];
    if (!r.raw.has_echo()) continue;
    require_magnitude(r.truth.distance_m, "distance_true_m", i);
    if (!surface) continue;
    // The surface reads the time of flight, or the raw distance without one.
    require_magnitude(r.raw.tof_ns, "tof_ns", i);
    if (!std::isfinite(r.raw.tof_ns)) require_magnitude(r.raw.distance_raw_m, "distance_raw_m", i);
    if (pulse_width) require_magnitude(r.raw.pulse_width_ns, "pulse_width_ns", i);
    if (o.surface_temperature) require_magnitude(r.raw.temperature_c, "temperature_c", i);
  }
  // Last, so that a corrupt fitted column is named first.
  for (std::size_t i = 0; amplitude && i < records.size(); ++i) {
    if (records[i].raw.has_echo()) require_magnitude(records[i].raw.amplitude, "amplitude", i);
  }
}

}  // namespace

ModelFitResult fit_model(std::span<const ranging::Record> records, const ModelFitOptions& o) {
  o.validate();
  require_model_magnitudes(records, o);
  ModelFitResult result;
  ModelFitSummary& summary = result.summary;
  std::string& report = result.report;
  summary.rows = records.size();

  const bool from_repeats = o.confidence == ConfidenceKind::noise_systematic;
  const bool hold_out =
      o.confidence != ConfidenceKind::none && !from_repeats && o.confidence_hold_out_fraction > 0;
  std::vector<ranging::Record> fit_part, confidence_part;
  std::size_t groups = 0;
  long every_kth = 0;
  if (hold_out) {
    // Deterministic hold-out: every k-th truth group (the k-th, 2k-th, ...)
    // goes to the confidence part, the rest to the correction fit. Whole
    // groups are held out, so the confidence sees targets the correction did not.
    every_kth = std::lround(1.0 / o.confidence_hold_out_fraction);
    const auto k = static_cast<std::size_t>(every_kth);
    const std::vector<std::size_t> group = truth_groups(records, groups);
    for (std::size_t i = 0; i < records.size(); ++i) {
      ((group[i] % k) == k - 1 ? confidence_part : fit_part).push_back(records[i]);
    }
    if (confidence_part.empty() || fit_part.empty()) {
      throw std::invalid_argument(
          format("confidence %s holds out every %ld-th group of identical truth, but the data "
                 "have %zu group(s): it needs at least %ld groups (distances / plates / "
                 "temperatures)",
                 to_string(o.confidence).c_str(), every_kth, groups, every_kth));
    }
  }
  const std::span<const ranging::Record> fit_rows =
      hold_out ? std::span<const ranging::Record>(fit_part) : records;
  summary.rows_fit = fit_rows.size();

  result.pipeline = fit_correction(fit_rows, o, &summary, &report);
  {
    std::vector<double> truth;
    std::size_t partial = 0;
    for (const auto& r : records) {
      if (!r.raw.has_echo()) continue;
      truth.push_back(r.truth.distance_m);
      if ((r.raw.flags & ranging::kRawPartialEchoes) != 0) ++partial;
    }
    // Rows that lost shots are either echoes at the threshold or shots stopped
    // by noise (false alarms: sunlight, a high APD gain); a calibration made
    // mostly of them times noise as much as echoes, and says so.
    if (!truth.empty() && 4 * partial > truth.size()) {
      report += format(
          "note: %zu of %zu rows with an echo lost shots (partial echoes: weak echoes or false "
          "alarms from background light and gain); their means are biased, and a walk step "
          "leaves weak ones out: a calibration made mostly of them may not represent the device\n",
          partial, truth.size());
    }
    summary.distances = distinct_distances(truth);
    if (summary.distances == 1) {
      report += format(
          "note: every calibration row stands at one distance (%.3f m): errors that change with "
          "range (such as the TDC's nonlinearity, periodic in the time of flight) are neither "
          "corrected nor in sigma; plates at a few more distances measure them\n",
          truth.front());
    }
  }

  if (from_repeats) {
    fit_repeats_confidence(records, o, result);
    summary.residual_rms_m = result.pipeline.residual_rms_m();
    return result;
  }

  Residuals residuals;
  bool fit_confidence = o.confidence != ConfidenceKind::none;
  std::string note;
  std::size_t folds = 0;  // cross-fitting folds used
  if (fit_confidence && hold_out) {
    residuals.add(result.pipeline, confidence_part);
    note = format("%zu held-out rows (every %ld-th of %zu truth groups)", residuals.residual.size(),
                  every_kth, groups);
  } else if (fit_confidence) {
    // Cross-fitting: every truth group's residual comes from a correction
    // fitted without it (K folds of whole groups), so the confidence learns
    // the error on targets the correction never saw; the model kept is fitted
    // on all rows.
    const std::vector<std::size_t> group = truth_groups(records, groups);
    // Fewer groups than folds: each group its own fold (leave one group out),
    // still the error on targets the correction never saw.
    folds = std::min(groups, static_cast<std::size_t>(o.confidence_folds));
    const std::vector<std::size_t> fold_of_group =
        intensity_stratified_folds(records, group, groups, folds);
    bool refitting = false;  // the folds' refits have begun
    try {
      if (groups < 2) {
        throw std::invalid_argument(
            "cross-fitting needs at least 2 groups of identical truth (distances / plates / "
            "temperatures), the data have 1");
      }
      refitting = true;
      // A walk step's nonlinear fit starts each fold from the full fit's
      // shape (its multistart search is what costs; the folds' data are most
      // of the full data, so the valley is the same).
      ModelFitOptions fold_options = o;
      if (summary.chain && summary.chain->walk && !fold_options.chain_options.walk_initial) {
        fold_options.chain_options.walk_initial = summary.chain->walk->shape;
      }
      fold_options.chain_options.walk_replicates = 0;  // (their sigma is not used)
      result.out_of_fold_m.assign(records.size(), ranging::kNaN);
      // The folds' refits are independent: fitted on all cores, then taken in
      // fold order (the first failing fold's error, as one after another).
      std::vector<std::optional<ranging::Pipeline>> fold_fits(folds);
      std::vector<std::exception_ptr> fold_errors(folds);
      // The extrapolation refits (tasks beside the folds').
      const EdgeGroups edge =
          o.extrapolation_refit ? weakest_groups(records, group, groups) : EdgeGroups{};
      const std::size_t refits = edge.below.size();
      std::vector<std::optional<ranging::Pipeline>> edge_fits(refits);
      std::vector<std::string> edge_errors(refits);
      const auto left_out = [&](std::size_t r, std::size_t g) {
        return edge.mean_log_amplitude[g] < edge.below[r];  // (NaN: kept)
      };
      tbb::parallel_for(std::size_t{0}, folds + refits, [&](std::size_t k) {
        std::vector<ranging::Record> train;
        for (std::size_t i = 0; i < records.size(); ++i) {
          if (k < folds ? fold_of_group[group[i]] != k : !left_out(k - folds, group[i]))
            train.push_back(records[i]);
        }
        try {
          (k < folds ? fold_fits[k] : edge_fits[k - folds]) =
              fit_correction(train, fold_options, nullptr, nullptr);
        } catch (const std::exception& e) {
          if (k < folds) fold_errors[k] = std::current_exception();
          if (k >= folds) edge_errors[k - folds] = e.what();
        } catch (...) {
          if (k < folds) fold_errors[k] = std::current_exception();
          if (k >= folds) edge_errors[k - folds] = "an unknown error";
        }
      });
      if (o.extrapolation_refit) {
        std::string made;
        for (std::size_t r = 0; r < refits; ++r) {
          if (!edge_fits[r]) {
            report += format("extrapolation refit from ln amplitude %.2f failed: %s\n",
                             edge.below[r], edge_errors[r].c_str());
            continue;
          }
          ModelFitResult::ExtrapolationRefit refit;
          refit.residual_m.assign(records.size(), ranging::kNaN);
          refit.edge_log_amplitude = edge.below[r];
          std::vector<ranging::Record> test;
          std::vector<std::size_t> test_index;
          for (std::size_t i = 0; i < records.size(); ++i) {
            if (!left_out(r, group[i])) continue;
            test_index.push_back(i);
            test.push_back(records[i]);
          }
          std::set<std::size_t> out_groups;
          const std::vector<ranging::Range> corrected = corrected_ranges(*edge_fits[r], test);
          for (std::size_t j = 0; j < test.size(); ++j) {
            refit.residual_m[test_index[j]] = test[j].truth.distance_m - corrected[j].distance_m;
            out_groups.insert(group[test_index[j]]);
          }
          refit.groups_left_out = out_groups.size();
          made += format(" %zu", refit.groups_left_out);
          result.extrapolation.push_back(std::move(refit));
        }
        report += refits == 0 ? "extrapolation refit: none (" + edge.why + ")\n"
                              : format(
                                    "extrapolation refits: without the weakest%s of %zu truth "
                                    "groups (within %.1f e-folds of amplitude of the weakest)\n",
                                    made.c_str(), groups, kExtrapolationSpan);
      }
      for (std::size_t k = 0; k < folds; ++k) {
        if (fold_errors[k]) std::rethrow_exception(fold_errors[k]);
        std::vector<ranging::Record> test;
        std::vector<std::size_t> test_index;
        for (std::size_t i = 0; i < records.size(); ++i) {
          if (fold_of_group[group[i]] != k) continue;
          test_index.push_back(i);
          test.push_back(records[i]);
        }
        const ranging::Pipeline& fold_fit = *fold_fits[k];
        residuals.add(fold_fit, test);
        // Each row's cross-validated residual, for the uncertainty budget
        // (rows the fold's correction extrapolates to are left out, as above).
        const std::vector<ranging::Range> corrected = corrected_ranges(fold_fit, test);
        for (std::size_t j = 0; j < test.size(); ++j) {
          if ((corrected[j].correction_flags & ranging::kCorrOutOfDomain) != 0) continue;
          result.out_of_fold_m[test_index[j]] = test[j].truth.distance_m - corrected[j].distance_m;
        }
      }
    } catch (const std::invalid_argument& e) {
      // The correction itself fitted: what failed is a refit on fewer groups.
      if (o.confidence_required && refitting) {
        throw std::invalid_argument(
            format("confidence %s: cross-fitting refits the correction without each of %zu folds "
                   "of the %zu truth groups, and a refit failed: %s",
                   to_string(o.confidence).c_str(), folds, groups, e.what()));
      }
      if (o.confidence_required) throw;
      // Data too small to cross-fit: sigma stays the residual RMS.
      fit_confidence = false;
      report += std::string("confidence: none (cross-fitting impossible: ") + e.what() + ")\n";
    }
    note = format("%zu out-of-fold rows (%zu folds of %zu truth groups)", residuals.residual.size(),
                  folds, groups);
  }
  if (fit_confidence) {
    const ConfidenceFitData data{residuals.range, residuals.amplitude, residuals.residual};
    try {
      result.pipeline.set_confidence(
          o.confidence == ConfidenceKind::thesis
              ? fit_thesis_confidence(data)
              : fit_calibrated_confidence(data, o.calibrated_confidence));
    } catch (const std::invalid_argument& e) {
      if (o.confidence_required) throw;
      // Too few or too uniform out-of-fold rows for a confidence model: sigma
      // is their RMS, the error on targets the correction did not see (the
      // in-sample residual of a flexible fit on few rows would promise less).
      fit_confidence = false;
      const double held_out_rms_m = error_stats(residuals.residual).rms_m;
      if (std::isfinite(held_out_rms_m) && held_out_rms_m > result.pipeline.residual_rms_m())
        result.pipeline.set_residual_rms_m(held_out_rms_m);
      report += format("confidence: none (%s); sigma = RMS of the %zu %s, %.3f mm\n", e.what(),
                       residuals.residual.size(), hold_out ? "held-out rows" : "out-of-fold rows",
                       result.pipeline.residual_rms_m() * 1e3);
    }
  }
  if (fit_confidence) {
    ModelFitSummary::Confidence c;
    c.kind = o.confidence;
    c.rows = residuals.residual.size();
    c.groups = groups;
    c.folds = static_cast<int>(folds);
    c.every_kth_group = hold_out ? every_kth : 0;
    c.held_out = error_stats(residuals.residual);
    report += format("confidence: %s model fitted on %s; held-out RMS %.3f mm\n",
                     to_string(o.confidence).c_str(), note.c_str(), c.held_out.rms_m * 1e3);
    summary.confidence = c;
  }
  summary.residual_rms_m = result.pipeline.residual_rms_m();
  return result;
}

}  // namespace tofkit::calib
