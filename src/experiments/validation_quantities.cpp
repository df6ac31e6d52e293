// The quantities a validation matrix row may name, each computed by the
// experiment code that reproduces the document's figure.

#include "validation_quantities.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>

#include "tofkit/experiments/characterization_angle.hpp"
#include "tofkit/experiments/characterization_reflectance.hpp"
#include "tofkit/experiments/characterization_sampling.hpp"
#include "tofkit/experiments/characterization_temperature.hpp"
#include "tofkit/experiments/characterization_warmup.hpp"
#include "tofkit/experiments/paper_method.hpp"
#include "tofkit/experiments/paper_reference.hpp"
#include "tofkit/experiments/paper_study.hpp"
#include "tofkit/experiments/scan_memory.hpp"
#include "tofkit/experiments/thesis_line_scan.hpp"
#include "tofkit/experiments/thesis_protocol.hpp"
#include "tofkit/physics/link_budget.hpp"

namespace tofkit::experiments::validation_detail {

/// Every experiment a quantity may need, run on first use.
struct QuantityContext::Runs {
  device::DeviceConfig config;
  std::uint64_t seed;
  std::optional<device::VirtualRangefinder> device_;
  std::optional<PaperStudyResult> paper_study_;
  std::optional<PaperMethodResult> paper_method_;
  std::optional<ThesisProtocolResult> thesis_;
  std::optional<LineScanResult> line_scan_;
  std::optional<SamplingResult> sampling_;
  std::optional<ReflectanceResult> reflectance_;
  std::optional<WarmupResult> warmup_;
  std::optional<TemperatureResult> temperature_;
  std::optional<AngleResult> angle_;
  std::optional<MemoryScanResult> memory_;

  // Salts: the experiments of one validation run never share random streams.
  enum Salt : std::uint64_t {
    kThesis = 11,
    kLine,
    kSampling,
    kReflectance,
    kWarmup,
    kTemperature,
    kAngle,
    kMemory
  };

  /// Experiments that threw, by name: their rows get the same message without a rerun.
  std::map<std::string, std::string> failed;

  /// Runs `compute` into `slot` once; a failure is remembered and rethrown.
  template <typename T, typename F>
  const T& once(std::optional<T>& slot, const char* name, F&& compute) {
    if (slot) return *slot;
    if (const auto it = failed.find(name); it != failed.end()) throw std::runtime_error(it->second);
    try {
      slot.emplace(compute());
    } catch (const std::exception& e) {
      const std::string what = e.what();
      failed[name] = what.starts_with(name) ? what : std::string(name) + ": " + what;
      throw std::runtime_error(failed[name]);
    }
    return *slot;
  }

  const device::VirtualRangefinder& device() {
    return once(device_, "device", [&] { return device::VirtualRangefinder(config); });
  }
  const PaperStudyResult& paper_study() {
    return once(paper_study_, "paper study", [&] {
      PaperStudyOptions o;
      o.seed = seed;
      return run_paper_study(config, o, paper::kTable2);
    });
  }
  const PaperMethodResult& paper_method() {
    return once(paper_method_, "paper method", [&] { return run_paper_method(paper_study()); });
  }
  const ThesisProtocolResult& thesis() {
    return once(thesis_, "thesis protocol",
                [&] { return run_thesis_protocol(device(), {}, derive_seed(seed, kThesis)); });
  }
  const LineScanResult& line_scan() {
    return once(line_scan_, "line scan",
                [&] { return run_line_scan(device(), {}, derive_seed(seed, kLine)); });
  }
  const SamplingResult& sampling() {
    return once(sampling_, "sampling",
                [&] { return run_sampling(device(), {}, derive_seed(seed, kSampling)); });
  }
  const ReflectanceResult& reflectance() {
    return once(reflectance_, "reflectance",
                [&] { return run_reflectance(device(), {}, derive_seed(seed, kReflectance)); });
  }
  const WarmupResult& warmup() {
    return once(warmup_, "warm-up",
                [&] { return run_warmup(device(), {}, derive_seed(seed, kWarmup)); });
  }
  const TemperatureResult& temperature() {
    return once(temperature_, "temperature",
                [&] { return run_temperature(device(), {}, derive_seed(seed, kTemperature)); });
  }
  const AngleResult& angle() {
    return once(angle_, "angle",
                [&] { return run_angle(device(), {}, derive_seed(seed, kAngle)); });
  }
  const MemoryScanResult& memory() {
    return once(memory_, "memory scans",
                [&] { return run_memory_scans(device(), {}, derive_seed(seed, kMemory)); });
  }
};

QuantityContext::QuantityContext(device::DeviceConfig config, std::uint64_t seed)
    : runs_(std::make_unique<Runs>(
          Runs{std::move(config), seed, {}, {}, {}, {}, {}, {}, {}, {}, {}, {}, {}, {}})) {}
QuantityContext::~QuantityContext() = default;

namespace {

constexpr double kInch = kMetersPerInch;

double number(const Parameters& p, const std::string& key, double fallback) {
  const auto it = p.find(key);
  if (it == p.end()) return fallback;
  std::size_t used = 0;
  double v = ranging::kNaN;
  try {
    v = std::stod(it->second, &used);
  } catch (const std::exception&) {
    used = 0;
  }
  if (used != it->second.size() || !std::isfinite(v))
    throw std::invalid_argument("condition " + key + "=" + it->second + " is not a number");
  return v;
}

std::string text(const Parameters& p, const std::string& key, const std::string& fallback) {
  const auto it = p.find(key);
  return it == p.end() ? fallback : it->second;
}

/// Throws a ValidationMatrixError on the conditions column of `row`.
[[noreturn]] void refuse(const ValidationRow& row, const std::string& why) {
  throw ValidationMatrixError(row.line, "conditions", "row " + row.id + ": " + why);
}

void check_one_of(const ValidationRow& row, const std::string& key,
                  const std::vector<std::string>& allowed) {
  const auto it = row.parameters.find(key);
  if (it == row.parameters.end()) return;
  if (std::find(allowed.begin(), allowed.end(), it->second) != allowed.end()) return;
  std::string list;
  for (const auto& a : allowed) list += (list.empty() ? "" : ", ") + a;
  refuse(row, key + "=" + it->second + " is not one of " + list);
}

void check_numbers(const ValidationRow& row) {
  for (const auto& [key, value] : row.parameters) {
    if (key == "model" || key == "side" || key == "group" || key == "chart" || key == "table")
      continue;
    try {
      (void)number(row.parameters, key, 0);
    } catch (const std::invalid_argument& e) {
      refuse(row, e.what());
    }
  }
}

/// A model row of a thesis table: raw, polyN (document) or bspline (tofkit).
void check_model(const ValidationRow& row) {
  check_numbers(row);
  const std::string model = text(row.parameters, "model", "");
  const bool poly =
      model.size() == 5 && model.starts_with("poly") && model[4] >= '3' && model[4] <= '6';
  if (model != "raw" && model != "bspline" && !poly)
    refuse(row, "model=" + model + " is not one of raw, poly3 .. poly6, bspline");
  if ((model == "bspline") != (row.method == ValidationMethod::kTofkit)) {
    throw ValidationMatrixError(row.line, "method",
                                "row " + row.id +
                                    ": model=bspline is tofkit's method (method = tofkit), the "
                                    "other models the document's (method = document)");
  }
}

const VerificationRow& table2_row(const std::vector<VerificationRow>& rows, double distance_m) {
  for (const auto& r : rows)
    if (std::abs(r.actual_m - distance_m) < 0.05) return r;
  throw std::invalid_argument("no Table 2 row at " + std::to_string(distance_m) + " m");
}

/// A figure of a test set, NaN when no row of it was measured (not 0).
double rows_or_nan(const AccuracyFigures& f, double AccuracyFigures::*field) {
  return f.rows == 0 ? ranging::kNaN : f.*field;
}

const LineTable& line_table(QuantityContext::Runs& r, const Parameters& p) {
  return text(p, "chart", "stripes") == "checker" ? r.line_scan().checker : r.line_scan().line;
}

/// The model row of a thesis table ("point": Fig. 4.18, "stripes": Fig. 4.23,
/// "checker": Fig. 4.27): {bias, variance, rms, rms improvement}.
struct ModelFigures {
  calib::ErrorStats test;
  double improvement_pct = ranging::kNaN;
};
ModelFigures model_row(QuantityContext::Runs& r, const Parameters& p, bool point) {
  const std::string model = text(p, "model", "raw");
  if (point) {
    const auto& row = r.thesis().row(model);
    return {row.test, row.rms_improvement_pct};
  }
  const auto& row = line_table(r, p).row(model);
  return {row.test, row.rms_improvement_pct};
}

/// Best RMS improvement among the polynomial rows (document) or the B-spline's.
double best_improvement(QuantityContext::Runs& r, const Parameters& p, ValidationMethod m) {
  const std::string table = text(p, "table", "point");
  auto best_of = [&](const auto& rows) {
    double best = ranging::kNaN;
    for (const auto& row : rows) {
      const bool poly = row.model.starts_with("poly");
      if (m == ValidationMethod::kTofkit ? row.model == "bspline" : poly)
        best = std::isnan(best) ? row.rms_improvement_pct : std::max(best, row.rms_improvement_pct);
    }
    return best;
  };
  if (table == "point") return best_of(r.thesis().rows);
  Parameters q{{"chart", table == "checker" ? "checker" : "stripes"}};
  return best_of(line_table(r, q).rows);
}

std::map<std::string, Quantity> build() {
  std::map<std::string, Quantity> q;
  auto add = [&](QuantityInfo info, QuantityFunction f,
                 std::function<void(const ValidationRow&)> check = {}) {
    if (!check) check = check_numbers;
    const std::string id = info.id;
    q.emplace(id, Quantity{std::move(info), std::move(f), std::move(check)});
  };
  using M = ValidationMethod;
  const bool kBoth = true;

  // ------------------------------------------------------------------ paper
  add({"paper.link_budget.snr",
       "",
       "SNR of the Fig. 3 budget (Table 1, sunlit, Eq. 9 as printed) at a distance",
       {"distance_m", "reflectance"},
       {"distance_m"}},
      [](QuantityContext& c, const Parameters& p, M) {
        auto link = c.runs().config.link;
        link.environment.solar_irradiance_w_per_m2_um = physics::kTable1SolarIrradiance_w_per_m2_um;
        link.environment.eq9_as_printed = true;
        return physics::link_budget_at(link, number(p, "distance_m", 10),
                                       number(p, "reflectance", 0.1))
            .snr;
      });
  add({"paper.link_budget.range_at_snr_m",
       "m",
       "distance where the Fig. 3 budget's SNR falls to a value (paper: 10 at about 10 m)",
       {"snr", "reflectance"},
       {}},
      [](QuantityContext& c, const Parameters& p, M) {
        auto link = c.runs().config.link;
        link.environment.solar_irradiance_w_per_m2_um = physics::kTable1SolarIrradiance_w_per_m2_um;
        link.environment.eq9_as_printed = true;
        return physics::range_at_snr(link, number(p, "snr", 10), number(p, "reflectance", 0.1));
      });
  add({"paper.longest_distance_m",
       "m",
       "longest distance with >= 90 % echoes on the black foam plate (rho 0.1), Section 5.3",
       {},
       {}},
      [](QuantityContext& c, const Parameters&, M) { return c.runs().paper_study().max_range_m; });
  add({"paper.grayvalue.knee_ns",
       "ns",
       "the knot of a one-knot hinge fitted to offset vs echo pulse width on the plates at "
       "2.355 m (Fig. 6's inflection)",
       {},
       {}},
      [](QuantityContext& c, const Parameters&, M) {
        const auto& s = c.runs().paper_study();
        std::vector<double> w, e;
        for (const auto& r : s.calibration) {
          if (!r.raw.has_echo() ||
              std::abs(r.truth.distance_m - PaperStudyOptions{}.grayvalue_distance_m) > 1e-9 ||
              std::abs(r.truth.ambient_c - PaperStudyOptions{}.calibration_ambient_c) > 1e-9)
            continue;
          w.push_back(r.raw.pulse_width_ns);
          e.push_back(r.truth.distance_m - s.fit.pipeline.start_distance_m(r.raw));
        }
        calib::HingeFitOptions o;
        o.max_knots = 1;
        o.robust.loss = calib::RobustLoss::kNone;
        const auto fit = calib::fit_hinge(w, e, o);
        return fit.knots.empty() ? ranging::kNaN : fit.knots.front();
      });
  add(
      {"paper.grayvalue.slope_mm_per_ns",
       "mm/ns",
       "slope of the offset (measured - true) vs echo pulse width below or above the 6.5 ns "
       "knee, the paper's piecewise-linear fit at 2.355 m (Fig. 6: -36 and 70)",
       {"side"},
       {"side"}},
      [](QuantityContext& c, const Parameters& p, M) {
        const auto& m = c.runs().paper_method();
        return text(p, "side", "") == "below" ? m.slope_below_knee_mm_per_ns
                                              : m.slope_above_knee_mm_per_ns;
      },
      [](const ValidationRow& row) {
        check_one_of(row, "side", {"below", "above"});
      });
  auto paper_figures = [](QuantityContext& c, M m, bool grayvalue) -> const AccuracyFigures& {
    if (m == M::kTofkit) {
      const auto& s = c.runs().paper_study();
      return grayvalue ? s.grayvalue : s.temperature;
    }
    const auto& pm = c.runs().paper_method();
    return grayvalue ? pm.grayvalue : pm.temperature;
  };
  add({"paper.grayvalue.std_mm",
       "mm",
       "std of the corrected errors of the 54 plates at 2.355 m (Fig. 7); document: the paper's "
       "correction, tofkit: its chain through the fixed-point form",
       {},
       {},
       kBoth},
      [paper_figures](QuantityContext& c, const Parameters&, M m) {
        return rows_or_nan(paper_figures(c, m, true), &AccuracyFigures::std_mm);
      });
  add({"paper.grayvalue.accuracy_mm",
       "mm",
       "largest |corrected error| of the plates at 2.355 m (Fig. 7: within +-9 mm)",
       {},
       {},
       kBoth},
      [paper_figures](QuantityContext& c, const Parameters&, M m) {
        return rows_or_nan(paper_figures(c, m, true), &AccuracyFigures::accuracy_mm);
      });
  add(
      {"paper.temperature.slope_mm_per_c",
       "mm/C",
       "drift of the gray-value-corrected reading (measured - true) per degree of the sensor, "
       "above or below 16 C (Fig. 8: 3.8 above, small below)",
       {"side"},
       {"side"}},
      [](QuantityContext& c, const Parameters& p, M) {
        const auto& m = c.runs().paper_method();
        return text(p, "side", "") == "below" ? m.temperature_slope_below_mm_per_c
                                              : m.temperature_slope_above_mm_per_c;
      },
      [](const ValidationRow& row) {
        check_one_of(row, "side", {"below", "above"});
      });
  add({"paper.temperature.std_mm",
       "mm",
       "std of the corrected errors of the 20 groups at 2.402 m (Fig. 9)",
       {},
       {},
       kBoth},
      [paper_figures](QuantityContext& c, const Parameters&, M m) {
        return rows_or_nan(paper_figures(c, m, false), &AccuracyFigures::std_mm);
      });
  add({"paper.temperature.accuracy_mm",
       "mm",
       "largest |corrected error| of the 20 groups at 2.402 m (Fig. 9: within +-10 mm)",
       {},
       {},
       kBoth},
      [paper_figures](QuantityContext& c, const Parameters&, M m) {
        return rows_or_nan(paper_figures(c, m, false), &AccuracyFigures::accuracy_mm);
      });
  add({"paper.table2.deviation_mm",
       "mm",
       "actual - measured of the corrected mean at a Table 2 distance (black foam, rho 0.1)",
       {"distance_m"},
       {"distance_m"},
       kBoth},
      [](QuantityContext& c, const Parameters& p, M m) {
        const double d = number(p, "distance_m", 0);
        return m == M::kTofkit
                   ? table2_row(c.runs().paper_study().verification_rows, d).deviation_mm
                   : table2_row(c.runs().paper_method().verification_rows, d).deviation_mm;
      });

  // ----------------------------------------------------------------- thesis
  auto sampling_row = [](QuantityContext& c, const Parameters& p) -> const SamplingRow& {
    const int e = static_cast<int>(number(p, "exponent", 0));
    for (const auto& r : c.runs().sampling().rows)
      if (r.exponent == e) return r;
    throw std::invalid_argument("no sampling setting 2^" + std::to_string(e));
  };
  add({"thesis.sampling.resolution_mm",
       "mm",
       "range step of one count at 312,500 / 2^exponent samples/s, 20 in (Fig. 4.4)",
       {"exponent"},
       {"exponent"}},
      [sampling_row](QuantityContext& c, const Parameters& p, M) {
        return 1e3 * sampling_row(c, p).resolution_m;
      });
  add({"thesis.sampling.variance_in2",
       "in^2",
       "variance of the outputs at 312,500 / 2^exponent samples/s, 20 in (Fig. 4.4)",
       {"exponent"},
       {"exponent"}},
      [sampling_row](QuantityContext& c, const Parameters& p, M) {
        const double sd = sampling_row(c, p).sd_range_m / kInch;
        return sd * sd;
      });
  add({"thesis.sampling.mean_in",
       "in",
       "mean range at 312,500 / 2^exponent samples/s, target at 20 in (Fig. 4.4)",
       {"exponent"},
       {"exponent"}},
      [sampling_row](QuantityContext& c, const Parameters& p, M) {
        return sampling_row(c, p).mean_range_m / kInch;
      });
  add(
      {"thesis.reflectance.rms_in",
       "in",
       "RMS error about the truth at 20 in over the greys >= 102 (group=grey102up) or all six "
       "(group=all), Fig. 4.9",
       {"group"},
       {"group"}},
      [](QuantityContext& c, const Parameters& p, M) {
        const auto& r = c.runs().reflectance();
        return (text(p, "group", "") == "grey102up" ? r.rms_unsaturated_m : r.rms_all_m) / kInch;
      },
      [](const ValidationRow& row) {
        check_one_of(row, "group", {"grey102up", "all"});
      });
  add({"thesis.reflectance.slope",
       "",
       "slope of the line measured vs true range over six greys at 10-30 in (r = 0.9804 T - "
       "0.6732 in)",
       {},
       {}},
      [](QuantityContext& c, const Parameters&, M) { return c.runs().reflectance().line.slope; });
  add({"thesis.reflectance.intercept_in", "in", "intercept of that line, inches", {}, {}},
      [](QuantityContext& c, const Parameters&, M) {
        return c.runs().reflectance().line.intercept / kInch;
      });
  add({"thesis.reflectance.offset_in",
       "in",
       "that line's reading minus the truth at a distance (inches)",
       {"distance_in"},
       {"distance_in"}},
      [](QuantityContext& c, const Parameters& p, M) {
        const auto& l = c.runs().reflectance().line;
        const double t = number(p, "distance_in", 20) * kInch;
        return (l.slope * t + l.intercept - t) / kInch;
      });
  add({"thesis.warmup.settle_min",
       "min",
       "minutes from power-on until every later minute mean stays within 0.01 in (Section 4.4)",
       {},
       {}},
      [](QuantityContext& c, const Parameters&, M) { return c.runs().warmup().settle_time_min; });
  add({"thesis.temperature.in_per_10c",
       "in/10C",
       "change of the mean range per 10 C of ambient (Section 4.4: falls 0.25-0.60 in)",
       {},
       {}},
      [](QuantityContext& c, const Parameters&, M) {
        return c.runs().temperature().mean_slope_mm_per_c * 10.0 / 25.4;
      });
  add({"thesis.angle.max_usable_deg",
       "deg",
       "largest incidence angle with echoes on every sample, per grey (Section 4.4)",
       {"grey"},
       {"grey"}},
      [](QuantityContext& c, const Parameters& p, M) {
        const int g = static_cast<int>(number(p, "grey", 0));
        for (const auto& r : c.runs().angle().growth)
          if (r.grey == g) return r.max_usable_angle_deg;
        throw std::invalid_argument("no grey " + std::to_string(g) + " in the angle study");
      });
  for (const auto& [table, figure] :
       {std::pair{"point", "Fig. 4.18"}, std::pair{"line", "Figs. 4.23 / 4.27"}}) {
    const bool point = std::string(table) == "point";
    const std::vector<std::string> keys =
        point ? std::vector<std::string>{"model"} : std::vector<std::string>{"model", "chart"};
    auto checker = [point](const ValidationRow& row) {
      check_model(row);
      if (!point) check_one_of(row, "chart", {"stripes", "checker"});
      const std::string model = text(row.parameters, "model", "");
      if (!point && model == "poly3") refuse(row, "the line scans fit orders 4-6 (thesis)");
    };
    const std::string base = std::string("thesis.") + table + ".";
    const std::string where = point ? "point-by-point test scan at 19 in (Fig. 4.18)"
                                    : "line-by-line scan, chart=stripes (Fig. 4.23) or checker "
                                      "(Fig. 4.27)";
    add(
        {base + "bias_in",
         "in",
         "bias (true - corrected) of a model on the " + where,
         keys,
         {"model"},
         kBoth},
        [point](QuantityContext& c, const Parameters& p, M) {
          return model_row(c.runs(), p, point).test.bias_m / kInch;
        },
        checker);
    add(
        {base + "variance_in2",
         "in^2",
         "error variance of a model on the " + where,
         keys,
         {"model"},
         kBoth},
        [point](QuantityContext& c, const Parameters& p, M) {
          return model_row(c.runs(), p, point).test.variance_m2 / (kInch * kInch);
        },
        checker);
    add(
        {base + "rms_in", "in", "RMS error of a model on the " + where, keys, {"model"}, kBoth},
        [point](QuantityContext& c, const Parameters& p, M) {
          return model_row(c.runs(), p, point).test.rms_m / kInch;
        },
        checker);
    add(
        {base + "rms_improvement_pct",
         "%",
         "RMS improvement over raw of a model on the " + where,
         keys,
         {"model"},
         kBoth},
        [point](QuantityContext& c, const Parameters& p, M) {
          return model_row(c.runs(), p, point).improvement_pct;
        },
        checker);
    (void)figure;
  }
  add(
      {"thesis.best_improvement_pct",
       "%",
       "the best RMS improvement of the thesis's polynomials (document) or of tofkit's B-spline "
       "on a table: point, stripes or checker (thesis: >= 55 %)",
       {"table"},
       {"table"},
       kBoth},
      [](QuantityContext& c, const Parameters& p, M m) { return best_improvement(c.runs(), p, m); },
      [](const ValidationRow& row) {
        check_one_of(row, "table", {"point", "stripes", "checker"});
      });
  add({"thesis.relative_error",
       "",
       "RMS / distance of corrected training ranges at a training distance (Section 4.8); "
       "document: the best polynomial, tofkit: the B-spline",
       {"distance_in"},
       {"distance_in"},
       kBoth},
      [](QuantityContext& c, const Parameters& p, M m) {
        const auto& t = c.runs().thesis();
        const double d = number(p, "distance_in", 0) * kInch;
        const auto& values = m == M::kTofkit ? t.relative_error_by_training_distance
                                             : t.relative_error_by_training_distance_polynomial;
        for (std::size_t k = 0; k < t.options.training_distances_m.size(); ++k)
          if (std::abs(t.options.training_distances_m[k] - d) < 1e-6 && k < values.size())
            return values[k];
        throw std::invalid_argument("no training distance at " + std::to_string(d / kInch) + " in");
      });
  auto sigma_range = [](QuantityContext& c, const Parameters& p, M m, bool max) {
    const bool checker = text(p, "chart", "stripes") == "checker";
    const auto& line = c.runs().line_scan();
    // Document: the thesis's metric on its best polynomial; tofkit: its calibrated sigma on
    // the best model (Figs. 4.32-4.33).
    const auto& im = m == M::kDocument
                         ? (checker ? line.checker_images_thesis : line.stripe_images_thesis)
                         : (checker ? line.checker_images : line.stripe_images);
    return (max ? im.sigma_max_m : im.sigma_min_m) / kInch;
  };
  auto sigma_check = [](const ValidationRow& row) {
    check_one_of(row, "chart", {"stripes", "checker"});
  };
  add(
      {"thesis.confidence.sigma_min_in",
       "in",
       "smallest expected error of a line-scan confidence image (chart=stripes or checker); "
       "document: the thesis's metric on its best polynomial, tofkit: its calibrated sigma on "
       "the best model",
       {"chart"},
       {"chart"},
       kBoth},
      [sigma_range](QuantityContext& c, const Parameters& p, M m) {
        return sigma_range(c, p, m, false);
      },
      sigma_check);
  add(
      {"thesis.confidence.sigma_max_in",
       "in",
       "largest expected error of the confidence image",
       {"chart"},
       {"chart"},
       kBoth},
      [sigma_range](QuantityContext& c, const Parameters& p, M m) {
        return sigma_range(c, p, m, true);
      },
      sigma_check);
  add({"thesis.color_transition.swing_in",
       "in",
       "max - min of the range read on the first half of the black area after a mid-grey to "
       "black transition at 19 in, scanned line by line as Figs. 4.23-4.27 (Fig. 4.28: 15.65 "
       "to 23.91 in)",
       {},
       {}},
      [](QuantityContext& c, const Parameters&, M) {
        return c.runs().memory().transition_line.swing_m / kInch;
      });
  add({"thesis.edge_spike_mm",
       "mm",
       "mean |spike| at the edges of the mirror-swept block profile (Figs. 3.4-3.5), before any "
       "memory correction",
       {},
       {}},
      [](QuantityContext& c, const Parameters&, M) {
        return 1e3 * c.runs().memory().mirror_edges.spike_before_m;
      });
  // What the protocols fix (a row may say so in its conditions).
  const double gd = PaperStudyOptions{}.grayvalue_distance_m;
  const double td = PaperStudyOptions{}.temperature_distance_m;
  const double groups = PaperStudyOptions{}.temperature_groups;
  const double plates = PaperStudyOptions{}.grayvalue_groups;
  const double rho = PaperStudyOptions{}.verification_reflectance;
  auto fix = [&](const std::string& id, std::map<std::string, double> f) {
    q.at(id).info.fixed = f;
  };
  fix("paper.longest_distance_m", {{"reflectance", PaperStudyOptions{}.max_range_reflectance}});
  fix("paper.grayvalue.knee_ns", {{"distance_m", gd}});
  fix("paper.grayvalue.slope_mm_per_ns", {{"distance_m", gd}});
  fix("paper.grayvalue.std_mm", {{"distance_m", gd}, {"plates", plates}});
  fix("paper.grayvalue.accuracy_mm", {{"distance_m", gd}, {"plates", plates}});
  fix("paper.temperature.slope_mm_per_c", {{"distance_m", td}});
  fix("paper.temperature.std_mm", {{"distance_m", td}, {"groups", groups}});
  fix("paper.temperature.accuracy_mm", {{"distance_m", td}, {"groups", groups}});
  fix("paper.table2.deviation_mm", {{"reflectance", rho}});
  const double in20 = m_to_inches(SamplingOptions{}.distance_m);
  for (const char* id :
       {"thesis.sampling.resolution_mm", "thesis.sampling.variance_in2", "thesis.sampling.mean_in"})
    fix(id, {{"distance_in", in20}});
  fix("thesis.reflectance.rms_in",
      {{"distance_in", m_to_inches(ReflectanceOptions{}.rms_distance_m)}});
  fix("thesis.warmup.settle_min", {{"distance_in", m_to_inches(WarmupOptions{}.distance_m)}});
  fix("thesis.color_transition.swing_in",
      {{"distance_in", m_to_inches(MemoryScanOptions{}.transition_distance_m)}});
  for (const char* id : {"thesis.point.bias_in", "thesis.point.variance_in2", "thesis.point.rms_in",
                         "thesis.point.rms_improvement_pct"})
    fix(id, {{"distance_in", m_to_inches(ThesisProtocolOptions{}.test_distance_m)}});
  return q;
}

}  // namespace

const std::map<std::string, Quantity>& quantities() {
  static const std::map<std::string, Quantity> registry = build();
  return registry;
}

}  // namespace tofkit::experiments::validation_detail
