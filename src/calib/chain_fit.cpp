#include "tofkit/calib/chain_fit.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <limits>
#include <memory>
#include <optional>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

namespace tofkit::calib {
namespace {

constexpr std::size_t kMinChainRows = 10;
/// The walk's nonlinear fit settles to about this (its finite-difference
/// Jacobian and tabulated shape): backfitting with a walk step stops when no
/// walk value changes by more than this either (10 um, far below any figure).
constexpr double kWalkTolerance_m = 1e-5;
/// Backfitting passes whose walk fit searches its starts afresh (while the
/// walk still moves by more than 0.1 mm); later passes refine the previous
/// pass's shape. Rows dominated by false stops keep the walk moving pass after
/// pass, and a search on each took minutes.
constexpr int kWalkSearchPasses = 2;

double median_of(std::vector<double> v) {
  const auto mid = v.begin() + static_cast<std::ptrdiff_t>(v.size() / 2);
  std::nth_element(v.begin(), mid, v.end());
  double m = *mid;
  if (v.size() % 2 == 0) m = 0.5 * (m + *std::max_element(v.begin(), mid));
  return m;
}

std::string fixed2(double v) {
  char buffer[32];
  std::snprintf(buffer, sizeof buffer, "%.2f", v);
  return buffer;
}

void require_spread(const std::vector<double>& x, const std::string& column,
                    const std::string& unit, const std::string& hint) {
  const auto [lo, hi] = std::minmax_element(x.begin(), x.end());
  if (!(*hi - *lo > 1e-12 * std::max(1.0, std::max(std::fabs(*lo), std::fabs(*hi))))) {
    throw std::invalid_argument("no spread in " + column + " (all " + fixed2(*lo) + " " + unit +
                                "): " + hint);
  }
}

bool same_target(const ranging::GroundTruth& a, const ranging::GroundTruth& b) {
  return a.distance_m == b.distance_m && a.reflectance == b.reflectance &&
         a.angle_deg == b.angle_deg;
}

/// The target's truth, "distance_true_m 2 m, reflectance 0.3, angle_deg 0 deg".
std::string describe_target(const ranging::GroundTruth& t) {
  char buffer[160];
  std::snprintf(buffer, sizeof buffer, "distance_true_m %g m, reflectance %g, angle_deg %g deg",
                t.distance_m, t.reflectance, t.angle_deg);
  return buffer;
}

std::string span_of(const std::vector<double>& x, const char* unit) {
  const auto [lo, hi] = std::minmax_element(x.begin(), x.end());
  return fixed2(*lo) + "-" + fixed2(*hi) + " " + unit;
}

/// A grayvalue or walk step models the pulse width's change between targets
/// (the echo's strength: reflectance, distance, angle). When every usable row
/// is one target, the widths spread by their noise only and the step would
/// fit noise (12 repeats of one plate gave a walk at its lower bound): refused.
/// Only when the truth says so: with reflectance or angle_deg empty, rows at
/// one distance may be plates of different reflectance (a legitimate
/// calibration), so they are fitted.
void require_targets(std::span<const ranging::Record> records, const std::vector<std::size_t>& used,
                     const std::vector<double>& pulse_width, const ChainSteps& steps) {
  const ranging::GroundTruth& first = records[used.front()].truth;
  for (std::size_t i : used) {
    const ranging::GroundTruth& t = records[i].truth;
    if (std::isnan(t.distance_m) || std::isnan(t.reflectance) || std::isnan(t.angle_deg) ||
        !same_target(t, first))
      return;
  }
  const char* step = steps.walk ? "walk" : "grayvalue";
  const std::string message =
      "no spread in pulse_width_ns between targets (every usable row is one target, " +
      describe_target(first) + ": " + span_of(pulse_width, "ns") + " is noise): the " + step +
      " step needs plates of different reflectance";
  throw ChainStepRefused(message, ChainSteps{false, !steps.walk, false, steps.walk},
                         "pulse_width_ns");
}

/// A temperature step models the reading's change between conditions (the
/// ambient). When every usable row is at one ambient_c, the readings spread
/// by the sensor's noise (and quantization) only: refused. Rows without
/// ambient_c may be at different ones: fitted. Rows taken while warming up
/// exempt the step: the electronics' self-heating moves the reading for a
/// cause at one ambient.
void require_conditions(std::span<const ranging::Record> records,
                        const std::vector<std::size_t>& used,
                        const std::vector<double>& temperature) {
  const ranging::GroundTruth& first = records[used.front()].truth;
  for (std::size_t i : used) {
    const ranging::Record& r = records[i];
    if ((r.raw.flags & ranging::kRawWarmingUp) != 0) return;
    if (std::isnan(r.truth.ambient_c)) return;  // unknown conditions: may differ
    if (r.truth.ambient_c != first.ambient_c) return;
  }
  char buffer[64];
  std::snprintf(buffer, sizeof buffer,
                "every usable row is at one ambient_c, %g C: ", first.ambient_c);
  const std::string message = "no spread in temperature_c between conditions (" +
                              std::string(buffer) + span_of(temperature, "C") +
                              " is noise): the temperature step needs measurements at different "
                              "ambient temperatures";
  throw ChainStepRefused(message, ChainSteps{false, false, true, false}, "temperature_c");
}

/// Columns [x - ref, (x - k_1)+, ...] of one hinge in the joint design.
void add_hinge_columns(Eigen::MatrixXd& a, Eigen::Index first, const std::vector<double>& x,
                       double reference, const std::vector<double>& knots) {
  for (std::size_t i = 0; i < x.size(); ++i) {
    const auto row = static_cast<Eigen::Index>(i);
    a(row, first) = x[i] - reference;
    for (std::size_t k = 0; k < knots.size(); ++k) {
      a(row, first + 1 + static_cast<Eigen::Index>(k)) = std::max(0.0, x[i] - knots[k]);
    }
  }
}

/// The hinge G(x) = b0 (x - ref) + sum s_k (x - k)+ minus G(ref), so g(ref) = 0;
/// returns G(ref), the constant moved to the offset.
double hinge_from_coefficients(const Eigen::VectorXd& beta, Eigen::Index first, double reference,
                               const std::vector<double>& knots, ranging::PiecewiseLinear& g) {
  g = ranging::PiecewiseLinear{};
  g.x0 = reference;
  g.slope0 = beta(first);
  double at_reference = 0;
  for (std::size_t k = 0; k < knots.size(); ++k) {
    const double s = beta(first + 1 + static_cast<Eigen::Index>(k));
    g.knots.push_back(knots[k]);
    g.slopes.push_back(s);
    at_reference += s * std::max(0.0, reference - knots[k]);
  }
  g.intercept = -at_reference;
  return at_reference;
}

/// The joint solve uses the least aggressive loss of the fitted hinges
/// (none < Huber < bisquare), so a hinge fitted by plain least squares (e.g. a
/// temperature sweep beside many plates at one temperature) is not downweighted
/// in the joint solve either.
RobustOptions joint_robust_options(const ChainSteps& steps, const RobustOptions& g,
                                   const RobustOptions& h) {
  if (steps.walk && !steps.temperature) return RobustOptions{.loss = RobustLoss::kNone};
  if (!steps.grayvalue) return h;
  if (!steps.temperature) return g;
  return static_cast<int>(h.loss) < static_cast<int>(g.loss) ? h : g;
}

}  // namespace

ChainSteps parse_chain_steps(std::string_view list) {
  ChainSteps steps{false, false, false};
  bool any = false;
  std::size_t begin = 0;
  while (begin <= list.size()) {
    const std::size_t comma = std::min(list.find(',', begin), list.size());
    std::string_view name = list.substr(begin, comma - begin);
    while (!name.empty() && name.front() == ' ') name.remove_prefix(1);
    while (!name.empty() && name.back() == ' ') name.remove_suffix(1);
    bool* flag = name == "offset"        ? &steps.offset
                 : name == "grayvalue"   ? &steps.grayvalue
                 : name == "temperature" ? &steps.temperature
                 : name == "walk"        ? &steps.walk
                                         : nullptr;
    if (flag == nullptr) {
      throw std::invalid_argument("unknown chain step \"" + std::string(name) +
                                  "\" (expected offset, grayvalue or walk, temperature)");
    }
    if (*flag) throw std::invalid_argument("chain step \"" + std::string(name) + "\" given twice");
    *flag = true;
    any = true;
    begin = comma + 1;
  }
  if (!any) throw std::invalid_argument("empty chain step list");
  if (steps.grayvalue && steps.walk) {
    throw std::invalid_argument(
        "chain steps grayvalue and walk both correct the pulse width: give one of them");
  }
  return steps;
}

std::string to_string(const ChainSteps& steps) {
  std::string s;
  const auto add = [&](bool on, const char* name) {
    if (!on) return;
    if (!s.empty()) s += ",";
    s += name;
  };
  add(steps.offset, "offset");
  add(steps.grayvalue, "grayvalue");
  add(steps.walk, "walk");
  add(steps.temperature, "temperature");
  return s;
}

ChainFitResult fit_chain(std::span<const ranging::Record> records, const ChainFitOptions& options) {
  const ChainSteps& steps = options.steps;
  if (!steps.offset && !steps.grayvalue && !steps.temperature && !steps.walk) {
    throw std::invalid_argument("chain fit: no step selected");
  }
  if (steps.grayvalue && steps.walk) {
    throw std::invalid_argument("chain fit: grayvalue and walk both correct the pulse width");
  }
  const bool width_step = steps.grayvalue || steps.walk;
  ChainFitResult result;
  result.pipeline = ranging::Pipeline(options.time_to_distance);

  // Usable rows and the error to model, e = true - c_air tof / 2.
  std::vector<double> e, pulse_width, temperature, amplitude;
  std::vector<std::uint8_t> saturated;
  std::vector<std::size_t> used;
  for (std::size_t i = 0; i < records.size(); ++i) {
    const ranging::Record& r = records[i];
    const double start = result.pipeline.start_distance_m(r.raw);
    require_magnitude(r.truth.distance_m, "distance_true_m", i);
    require_magnitude(r.raw.tof_ns, "tof_ns", i);
    require_magnitude(start, std::isfinite(r.raw.tof_ns) ? "tof_ns" : "distance_raw_m", i);
    if (width_step) require_magnitude(r.raw.pulse_width_ns, "pulse_width_ns", i);
    if (steps.temperature) require_magnitude(r.raw.temperature_c, "temperature_c", i);
    if (steps.walk)
      require_magnitude(r.raw.amplitude, "amplitude", i);  // its readings pin the shape
    const bool ok = r.raw.has_echo() && std::isfinite(r.truth.distance_m) && std::isfinite(start) &&
                    (!width_step || std::isfinite(r.raw.pulse_width_ns)) &&
                    (!steps.temperature || std::isfinite(r.raw.temperature_c));
    if (!ok) continue;
    used.push_back(i);
    e.push_back(r.truth.distance_m - start);
    pulse_width.push_back(r.raw.pulse_width_ns);
    temperature.push_back(r.raw.temperature_c);
    amplitude.push_back(r.raw.amplitude);
    saturated.push_back(static_cast<std::uint8_t>(
        ((r.raw.flags & ranging::kRawSaturated) != 0 ? kWalkRowClipped : 0) |
        ((r.raw.flags & ranging::kRawPartialEchoes) != 0 ? kWalkRowPartial : 0)));
  }
  // Partial echoes bias a row's mean where the echo itself is missed on some
  // shots (the shots that crossed are those noise lifted): echoes near the
  // threshold. Detection grows with the echo's strength, and its pulse width
  // with it, so a row wider than a row that echoed on every shot lost its
  // shots to something else: false alarms before the echo (background light
  // at a high APD gain, as in sunlight). The firmware's stop gate drops most
  // of them and such a row is fitted like a complete one, unless it lost more
  // than 5 % of its shots: the false stops the gate keeps grow with the rate
  // that lost the others, and pull the row's mean short. On held-out case 1
  // (Table 1 sunlight, bright plate at 2.3 m) rows read about 0.3 mm short per
  // percent lost: 13-20 % lost at 0-10 C, 3-7 mm short; 4-10 % at 12-15 C,
  // 1.5-3 mm; 2-3 % at 17 C, none. Fitted, they bent the walk at the clipped
  // widths, where the field's rows read 1-2 mm long.
  double narrowest_complete_ns = std::numeric_limits<double>::infinity();
  std::uint32_t shots = 0;
  for (std::size_t k = 0; k < e.size(); ++k) {
    if ((saturated[k] & kWalkRowPartial) == 0)
      narrowest_complete_ns = std::min(narrowest_complete_ns, pulse_width[k]);
    shots = std::max(shots, records[used[k]].raw.shots_valid);
  }
  for (std::size_t k = 0; k < e.size(); ++k) {
    const bool few_lost = 20 * static_cast<std::uint64_t>(records[used[k]].raw.shots_valid) >=
                          19 * static_cast<std::uint64_t>(shots);
    if (pulse_width[k] > narrowest_complete_ns && few_lost)
      saturated[k] &= static_cast<std::uint8_t>(~kWalkRowPartial);
  }
  const std::size_t n = e.size();
  result.rows = n;
  result.rows_skipped = records.size() - n;
  const std::size_t min_parameters =
      (steps.offset ? 1 : 0) + (width_step ? 2 : 0) + (steps.temperature ? 2 : 0);
  if (n < std::max(kMinChainRows, min_parameters)) {
    std::string needs = "an echo and finite distance_true_m and tof_ns (or distance_raw_m)";
    if (width_step) needs += ", pulse_width_ns";
    if (steps.temperature) needs += ", temperature_c";
    throw std::invalid_argument("too few rows: " + std::to_string(n) + " usable of " +
                                std::to_string(records.size()) + " (the chain fit needs at least " +
                                std::to_string(std::max(kMinChainRows, min_parameters)) +
                                " rows with " + needs + ")");
  }
  if (width_step) {
    require_spread(pulse_width, "pulse_width_ns", "ns",
                   std::string("the ") + (steps.walk ? "walk" : "grayvalue") +
                       " step needs plates of different reflectance");
  }
  if (steps.temperature) {
    require_spread(temperature, "temperature_c", "C",
                   "the temperature step needs measurements at different temperatures");
  }
  if (width_step) require_targets(records, used, pulse_width, steps);
  if (steps.temperature) require_conditions(records, used, temperature);
  const double ref_g = std::isfinite(options.reference_pulse_width_ns)
                           ? options.reference_pulse_width_ns
                           : median_of(pulse_width);
  const double ref_h = std::isfinite(options.reference_temperature_c)
                           ? options.reference_temperature_c
                           : median_of(temperature);

  HingeFitOptions g_options = options.grayvalue;
  g_options.column = "pulse_width_ns";
  g_options.unit = "ns";
  g_options.x0 = ref_g;
  HingeFitOptions h_options = options.temperature;
  h_options.column = "temperature_c";
  h_options.unit = "C";
  h_options.x0 = ref_h;

  // Knots are searched on at most options.knot_search_rows rows (every k-th
  // usable row, a deterministic subsample), then every coefficient is refitted
  // on all rows with those knots: the knot search costs the same for any row
  // count and the final solve is linear in rows.
  std::vector<std::size_t> search;
  const std::size_t cap = std::max<std::size_t>(options.knot_search_rows, kMinChainRows);
  const std::size_t stride = (n + cap - 1) / cap;
  for (std::size_t i = 0; i < n; i += stride) search.push_back(i);
  const std::size_t ns = search.size();
  result.knot_search_rows = ns;
  std::vector<double> se(ns), spw(ns), st(ns), samp(ns);
  std::vector<std::uint8_t> ssat(ns);
  for (std::size_t j = 0; j < ns; ++j) {
    se[j] = e[search[j]];
    spw[j] = pulse_width[search[j]];
    st[j] = temperature[search[j]];
    samp[j] = amplitude[search[j]];
    ssat[j] = saturated[search[j]];
  }
  const double metres_per_ns = ranging::metres_per_ns(options.time_to_distance);
  // The walk correction at the rows' widths (zero at the reference width).
  std::optional<ranging::WalkModel> walk_model;
  const auto walk_values = [&](const std::vector<double>& pw) {
    Eigen::VectorXd v(static_cast<Eigen::Index>(pw.size()));
    for (std::size_t i = 0; i < pw.size(); ++i) {
      v(static_cast<Eigen::Index>(i)) = -metres_per_ns * walk_model->relative_rise_ns(pw[i]);
    }
    return v;
  };

  // Backfitting over the knots with joint coefficients: each iteration
  // searches the knots of g on e - h and of h on e - g (1-D hinge fits, which
  // never increase the joint residual), then refits every coefficient jointly
  // for those knots, so correlated inputs do not slow the iteration down.
  const Eigen::VectorXd sev =
      Eigen::Map<const Eigen::VectorXd>(se.data(), static_cast<Eigen::Index>(ns));
  const RobustOptions robust = joint_robust_options(steps, g_options.robust, h_options.robust);
  std::vector<double> g_values(ns, 0.0), h_values(ns, 0.0), partial(ns);
  if (steps.walk && steps.temperature) {
    // The walk's nonlinear fit has local minima: its first pass must not see
    // the temperature drift as walk. Start h from the hinge chain (robust,
    // linear in its coefficients) fitted on the same rows.
    ChainFitOptions hinge_options = options;
    hinge_options.steps = ChainSteps{true, true, true, false};
    const ChainFitResult hinge = fit_chain(records, hinge_options);
    for (std::size_t i = 0; i < ns; ++i) h_values[i] = hinge.temperature->function(st[i]);
  }
  std::vector<double> g_knots, h_knots;
  Eigen::VectorXd walk_part = Eigen::VectorXd::Zero(static_cast<Eigen::Index>(ns));
  double last_walk_change = std::numeric_limits<double>::infinity();
  Eigen::Index g_first = 1, h_first = 1;
  RobustLinearFit joint;
  const auto joint_design = [&](const std::vector<double>& pw, const std::vector<double>& t) {
    h_first = g_first + (steps.grayvalue ? 1 + static_cast<Eigen::Index>(g_knots.size()) : 0);
    const Eigen::Index columns =
        h_first + (steps.temperature ? 1 + static_cast<Eigen::Index>(h_knots.size()) : 0);
    Eigen::MatrixXd design(static_cast<Eigen::Index>(pw.size()), columns);
    design.col(0).setOnes();
    if (steps.grayvalue) add_hinge_columns(design, g_first, pw, ref_g, g_knots);
    if (steps.temperature) add_hinge_columns(design, h_first, t, ref_h, h_knots);
    return design;
  };
  for (int it = 1; it <= options.max_backfit_iterations; ++it) {
    const std::vector<double> old_g_knots = g_knots, old_h_knots = h_knots;
    if (steps.grayvalue) {
      for (std::size_t i = 0; i < ns; ++i) partial[i] = se[i] - h_values[i];
      result.grayvalue = fit_hinge(spw, partial, g_options);
      g_knots = result.grayvalue->knots;
      for (std::size_t i = 0; i < ns; ++i) g_values[i] = result.grayvalue->function(spw[i]);
    }
    double walk_change = 0;
    if (steps.walk) {
      // The walk's shape by nonlinear least squares on e - h (warm start from
      // the previous pass); the joint linear solve then fits e - walk.
      for (std::size_t i = 0; i < ns; ++i) partial[i] = se[i] - h_values[i];
      WalkFitOptions walk_options;
      if (result.walk) walk_options.initial = result.walk->shape;
      // Searched afresh while the walk still moves by more than 0.1 mm (the
      // first passes see e with a rough h, and may start in a poor valley);
      // then only refined from the previous pass. Given a start, only refined.
      walk_options.multistart =
          !result.walk || (it <= kWalkSearchPasses && last_walk_change > 1e-4);
      if (options.walk_initial) {
        if (!result.walk) walk_options.initial = options.walk_initial;
        walk_options.multistart = false;
      }
      const WalkFitResult walk =
          fit_walk(spw, partial, ssat, samp, ref_g, metres_per_ns, walk_options);
      walk_model.emplace(walk.shape, ref_g);
      const Eigen::VectorXd values = walk_values(spw);
      walk_change = (values - walk_part).cwiseAbs().maxCoeff();
      walk_part = values;
      last_walk_change = walk_change;
      // The temperature hinge's knots are searched on e - walk (the walk carries the constant).
      for (std::size_t i = 0; i < ns; ++i) {
        g_values[i] = walk.constant_m + values(static_cast<Eigen::Index>(i));
      }
      result.walk = walk;
    }
    if (steps.temperature) {
      for (std::size_t i = 0; i < ns; ++i) partial[i] = se[i] - g_values[i];
      result.temperature = fit_hinge(st, partial, h_options);
      h_knots = result.temperature->knots;
    }
    // Joint robust least squares with the knots fixed: [1, g basis, h basis].
    const Eigen::MatrixXd design = joint_design(spw, st);
    const Eigen::Index columns = design.cols();
    joint = robust_linear_fit(design, sev - walk_part, robust);
    // Partial fits for the next iteration: g carries the constant, h its own basis only.
    const Eigen::VectorXd h_part =
        design.rightCols(columns - h_first) * joint.coefficients.tail(columns - h_first);
    double change = 0;
    for (std::size_t i = 0; i < ns; ++i) {
      const double v = h_part(static_cast<Eigen::Index>(i));
      change = std::max(change, std::fabs(v - h_values[i]));
      h_values[i] = v;
    }
    result.backfit_iterations = it;
    const auto same = [](const std::vector<double>& a, const std::vector<double>& b, double tol) {
      if (a.size() != b.size()) return false;
      for (std::size_t k = 0; k < a.size(); ++k) {
        if (std::fabs(a[k] - b[k]) > tol) return false;
      }
      return true;
    };
    // One hinge (or none) is solved in one pass; two when knots and h settle.
    // With a walk step, when the walk and h values settle: the walk's
    // micrometre-level jitter may move a temperature knot without changing the fit.
    const double walk_tolerance = std::max(options.backfit_tolerance_m, kWalkTolerance_m);
    if (!(width_step && steps.temperature) ||
        (it > 1 && steps.walk && change < walk_tolerance && walk_change < walk_tolerance) ||
        (it > 1 && change < options.backfit_tolerance_m && same(g_knots, old_g_knots, 1e-6) &&
         same(h_knots, old_h_knots, 1e-6))) {
      result.converged = true;
      break;
    }
  }
  if (steps.walk && options.walk_replicates > 0) {
    // The final shape's bootstrap replicates, on the final pass's data (e - h).
    for (std::size_t i = 0; i < ns; ++i) partial[i] = se[i] - h_values[i];
    WalkFitOptions walk_options;
    walk_options.initial = result.walk->shape;
    walk_options.multistart = false;
    walk_options.replicates = options.walk_replicates;
    result.walk->shape_replicates =
        fit_walk(spw, partial, ssat, samp, ref_g, metres_per_ns, walk_options).shape_replicates;
  }
  if (ns < n) {
    // All rows, the knots found: one joint robust solve.
    const Eigen::VectorXd ev =
        Eigen::Map<const Eigen::VectorXd>(e.data(), static_cast<Eigen::Index>(n));
    const Eigen::VectorXd target = steps.walk ? Eigen::VectorXd(ev - walk_values(pulse_width)) : ev;
    joint = robust_linear_fit(joint_design(pulse_width, temperature), target, robust);
  }
  result.rows_downweighted = static_cast<std::size_t>((joint.weights.array() < 0.5).count());

  double constant = joint.coefficients(0);
  ranging::PiecewiseLinear g, h;
  if (steps.grayvalue)
    constant += hinge_from_coefficients(joint.coefficients, g_first, ref_g, g_knots, g);
  if (steps.temperature)
    constant += hinge_from_coefficients(joint.coefficients, h_first, ref_h, h_knots, h);
  if (steps.offset) {
    result.offset_m = constant;
  } else if (steps.grayvalue) {
    g.intercept += constant;  // no offset step: the first hinge carries the constant
  } else if (steps.walk) {
    result.offset_m =
        constant;  // no offset step: the walk has no constant, an offset step holds it
  } else {
    h.intercept += constant;
  }

  if (steps.offset || (steps.walk && !steps.offset)) {
    result.pipeline.add_step(ranging::make_offset_step(result.offset_m));
  }
  if (steps.walk) {
    result.pipeline.add_step(ranging::make_walk_step(
        std::make_shared<const ranging::WalkModel>(walk_model->shape(),
                                                   walk_model->reference_pulse_width_ns(),
                                                   result.walk->shape_replicates),
        // The widths the walk was fitted on (full echoes).
        {result.walk->width_min_ns, result.walk->width_max_ns}));
  }
  if (steps.grayvalue) {
    result.grayvalue->function = g;
    result.pipeline.add_step(
        ranging::make_grayvalue_step(g, {result.grayvalue->x_min, result.grayvalue->x_max}));
  }
  if (steps.temperature) {
    result.temperature->function = h;
    result.pipeline.add_step(
        ranging::make_temperature_step(h, {result.temperature->x_min, result.temperature->x_max}));
  }

  // Residual statistics of the fitted chain on the rows it was fitted on.
  std::vector<ranging::RawMeasurement> raw;
  raw.reserve(n);
  for (std::size_t i : used) raw.push_back(records[i].raw);
  std::vector<ranging::Range> corrected(n);
  result.pipeline.apply(raw, corrected);
  std::vector<double> residual(n);
  for (std::size_t i = 0; i < n; ++i) {
    residual[i] = records[used[i]].truth.distance_m - corrected[i].distance_m;
  }
  result.before = error_stats(e);
  result.after = error_stats(residual);
  // Rebuild the steps with their fit statistics (the pipeline's steps are immutable).
  ranging::Pipeline pipeline(options.time_to_distance);
  for (ranging::Step step : result.pipeline.steps()) {
    step.fit.rows = n;
    step.fit.residual_rms_m = result.after.rms_m;
    pipeline.add_step(std::move(step));
  }
  pipeline.set_residual_rms_m(result.after.rms_m);
  result.pipeline = std::move(pipeline);
  return result;
}

std::string ChainFitResult::summary() const {
  char buffer[256];
  std::string s = "chain fit: " + std::to_string(rows) + " rows";
  if (rows_skipped > 0) s += " (" + std::to_string(rows_skipped) + " skipped)";
  if (knot_search_rows < rows) {
    s +=
        ", knots searched on every " +
        std::to_string((rows + knot_search_rows - 1) / std::max<std::size_t>(knot_search_rows, 1)) +
        "-th row (" + std::to_string(knot_search_rows) + ")";
  }
  if (rows_downweighted > 0) s += ", " + std::to_string(rows_downweighted) + " downweighted";
  std::snprintf(buffer, sizeof buffer, ", backfitting %s after %d iteration(s)\n  offset %.3f mm\n",
                converged ? "converged" : "did NOT converge", backfit_iterations, offset_m * 1e3);
  s += buffer;
  if (grayvalue) s += "  grayvalue:   " + grayvalue->summary() + "\n";
  if (walk) s += "  walk:        " + walk->summary() + "\n";
  if (temperature) s += "  temperature: " + temperature->summary() + "\n";
  std::snprintf(buffer, sizeof buffer,
                "  error before: bias %.3f mm, RMS %.3f mm; after: bias %.3f mm, RMS %.3f mm "
                "(%.1f %% better), max |error| %.3f mm\n",
                before.bias_m * 1e3, before.rms_m * 1e3, after.bias_m * 1e3, after.rms_m * 1e3,
                improvement_pct(before.rms_m, after.rms_m), after.max_abs_m * 1e3);
  s += buffer;
  return s;
}

}  // namespace tofkit::calib
