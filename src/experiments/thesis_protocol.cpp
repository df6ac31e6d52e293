#include "tofkit/experiments/thesis_protocol.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <stdexcept>

#include "tofkit/physics/constants.hpp"

namespace tofkit::experiments {
namespace {

// Salts of the independent random streams of the protocol.
constexpr std::uint64_t kTrainingSalt = 1, kConfidenceSalt = 2, kTestSalt = 3;
constexpr std::uint64_t kChartSalt = 1000;           // per-point chart deviations
constexpr std::uint64_t kTemperatureSalt = 2000;     // warmer repeats of the test scan
constexpr std::uint64_t kTemperatureRunSalt = 3000;  // the temperature term's run

/// A standard normal fixed by (seed, index, k): counter-based, so a chart point's
/// deviations do not depend on how many points came before it.
double point_normal(std::uint64_t seed, std::uint64_t index, std::uint64_t k) {
  const std::uint64_t a = derive_seed(derive_seed(seed, index), 2 * k);
  const std::uint64_t b = derive_seed(derive_seed(seed, index), 2 * k + 1);
  const double u1 = (static_cast<double>(a >> 11) + 0.5) * 0x1.0p-53;
  const double u2 = (static_cast<double>(b >> 11) + 0.5) * 0x1.0p-53;
  return std::sqrt(-2.0 * std::log(u1)) * std::cos(2.0 * physics::kPi * u2);  // Box-Muller
}

struct Scan {
  std::vector<ranging::Record> records;
  std::vector<int> grey;
};

/// The chart scanned point by point at each distance: every point averages
/// samples_per_point N-shot samples (one measurement of samples x N shots, the
/// same valid-shot mean), on a point whose reflectance and distance deviate a
/// little from the nominal ones the experimenter knows (the record's truth).
Scan scan_chart(const device::VirtualRangefinder& device, const ThesisProtocolOptions& o,
                const std::vector<double>& distances, int points_per_grey, std::uint64_t seed,
                double ambient_offset_c = 0.0) {
  const int shots = resolve_shots(device, o.shots) * o.samples_per_point;
  const std::uint64_t chart_seed = derive_seed(seed, kChartSalt);
  Scan scan;
  std::vector<PlannedMeasurement> plan;
  device::Conditions c;
  c.ambient_c = o.ambient_c + ambient_offset_c;
  std::uint64_t index = 0;
  for (const double d : distances) {
    for (const int g : o.grey_levels) {
      const double rho = grey_reflectance(g);
      for (int p = 0; p < points_per_grey; ++p, ++index) {
        const double rho_point = std::clamp(
            rho * (1.0 + o.reflectance_variation_rel * point_normal(chart_seed, index, 0)),
            0.05 * rho, 1.0);
        const double d_point =
            d + o.point_distance_sd_mm * 1e-3 * point_normal(chart_seed, index, 1);
        // Points are taken point_period_s apart (move, settle, sample), and the
        // laser is switched on at each point (thesis: laser on -> N samples ->
        // averaged -> move), so every point's samples fall in its turn-on transient.
        c.session_time_s = static_cast<double>(index) * o.point_period_s;
        c.ms_since_laser_on = 0.0;
        // The truth is the chart's: the stripe's nominal distance and grey.
        plan.push_back(
            {{device::Target::plate(d_point, rho_point), c, shots}, {d, rho, 0.0, c.ambient_c}});
        scan.grey.push_back(g);
      }
    }
  }
  scan.records = run(device, plan, seed);
  return scan;
}

/// Columns of the rows with an echo.
struct Columns {
  std::vector<std::size_t> index;                            // into the scan
  std::vector<double> range_m, amplitude, truth_m, error_m;  // error = true - measured
  std::vector<double> temperature_c;                         // the unit's sensor
  [[nodiscard]] calib::SurfaceInputs inputs() const { return {range_m, amplitude, {}}; }
};

Columns columns_of(const std::vector<ranging::Record>& records) {
  Columns c;
  for (std::size_t i = 0; i < records.size(); ++i) {
    const auto& r = records[i];
    if (!r.raw.has_echo() || !std::isfinite(r.raw.amplitude)) continue;
    c.index.push_back(i);
    c.range_m.push_back(r.raw.distance_raw_m);
    c.amplitude.push_back(r.raw.amplitude);
    c.truth_m.push_back(r.truth.distance_m);
    c.error_m.push_back(r.truth.distance_m - r.raw.distance_raw_m);
    c.temperature_c.push_back(r.raw.temperature_c);
  }
  return c;
}

/// The columns as the training's temperature would have read them: the
/// temperature term's correction added to each measured range (and so taken
/// from its error). The drift is a delay of the timing board, so it moves the
/// measured range before the surface sees it; a surface over (measured range,
/// intensity) must be evaluated where the range would have been, not only
/// offset afterwards (its range dependence, steep near the chart's darkest
/// grey, would otherwise read the drift as distance).
Columns at_training_temperature(const Columns& c, const TemperatureTerm& t) {
  Columns out = c;
  for (std::size_t i = 0; i < out.range_m.size(); ++i) {
    const double correction = t.correction_m(c.temperature_c[i]);
    out.range_m[i] += correction;
    out.error_m[i] -= correction;
  }
  return out;
}

/// Residuals true - (measured + correction); counts rows clamped to the domain.
std::vector<double> residuals(const calib::CorrectionSurface& surface, const Columns& c,
                              std::size_t* out_of_domain = nullptr) {
  std::vector<double> correction(c.range_m.size());
  std::vector<std::uint8_t> outside(c.range_m.size());
  surface.evaluate(c.inputs(), correction, outside);
  std::vector<double> r(c.range_m.size());
  for (std::size_t i = 0; i < r.size(); ++i) r[i] = c.error_m[i] - correction[i];
  if (out_of_domain) {
    *out_of_domain = static_cast<std::size_t>(std::count(outside.begin(), outside.end(), 1));
  }
  return r;
}

double rms_of(const std::vector<double>& v) {
  return calib::error_stats(v).rms_m;
}

}  // namespace

calib::BSplineFitOptions default_bspline_options() {
  calib::BSplineFitOptions o;
  o.intervals_range = 3;
  o.intervals_amplitude = 10;
  o.smoothing = 1e-2;
  o.log_amplitude = true;
  o.choose_smoothing_by_gcv = false;
  return o;
}

calib::CalibratedConfidenceOptions default_calibrated_confidence_options() {
  calib::CalibratedConfidenceOptions o;
  o.target_coverage_2sigma = 0.955;
  return o;
}

void ThesisProtocolOptions::validate() const {
  auto fail = [](const std::string& what) {
    throw std::invalid_argument("thesis protocol: " + what);
  };
  if (training_distances_m.size() < 2) fail("training_distances_m needs at least two distances");
  for (const double d : training_distances_m) {
    if (!(d > 0)) fail("training_distances_m must be > 0");
  }
  if (!(test_distance_m > 0)) fail("test_distance_m must be > 0");
  if (confidence_distances_m.empty()) fail("confidence_distances_m is empty");
  for (const double d : confidence_distances_m) {
    if (!(d > 0)) fail("confidence_distances_m must be > 0");
  }
  if (grey_levels.size() < 2) fail("grey_levels needs at least two levels");
  for (const int g : grey_levels) {
    if (g < 0 || g > 255) fail("grey_levels must be in 0..255");
  }
  if (training_points_per_grey < 1) fail("training_points_per_grey must be >= 1");
  if (confidence_points_per_grey < 1) fail("confidence_points_per_grey must be >= 1");
  if (test_points_per_grey < 1) fail("test_points_per_grey must be >= 1");
  if (samples_per_point < 1) fail("samples_per_point must be >= 1");
  if (shots < 0) fail("shots must be >= 0");
  if (!(reflectance_variation_rel >= 0 && reflectance_variation_rel < 0.5))
    fail("reflectance_variation_rel must be in [0, 0.5)");
  if (!(point_distance_sd_mm >= 0)) fail("point_distance_sd_mm must be >= 0");
  if (!(point_period_s >= 0 && point_period_s <= 3600)) fail("point_period_s must be in [0, 3600]");
  if (!(std::abs(test_ambient_offset_c) <= 60.0))
    fail("test_ambient_offset_c must be within +-60 C");
  if (polynomial_orders.empty()) fail("polynomial_orders is empty");
  for (const double t : test_temperature_offsets_c) {
    if (!(std::abs(t) <= 60.0)) fail("test_temperature_offsets_c must be within +-60 C");
  }
  for (const int order : polynomial_orders) {
    if (order < 1 || order > 12) fail("polynomial_orders must be in 1..12");
  }
  if (!(rcond >= 0 && rcond < 1)) fail("rcond must be in [0, 1)");
  temperature_term.validate();
  bspline.validate();
  calibrated_confidence.validate();
  if (grid_range_nodes < 2 || grid_amplitude_nodes < 2) fail("grid nodes must be >= 2");
}

ThesisProtocolResult run_thesis_protocol(const device::VirtualRangefinder& device,
                                         const ThesisProtocolOptions& options, std::uint64_t seed) {
  options.validate();
  ThesisProtocolResult result;
  result.options = options;

  // Three independent scans of the chart.
  auto training = scan_chart(device, options, options.training_distances_m,
                             options.training_points_per_grey, derive_seed(seed, kTrainingSalt));
  auto confidence =
      scan_chart(device, options, options.confidence_distances_m,
                 options.confidence_points_per_grey, derive_seed(seed, kConfidenceSalt));
  auto test = scan_chart(device, options, {options.test_distance_m}, options.test_points_per_grey,
                         derive_seed(seed, kTestSalt), options.test_ambient_offset_c);
  result.training = std::move(training.records);
  result.training_grey = std::move(training.grey);
  result.confidence = std::move(confidence.records);
  result.confidence_grey = std::move(confidence.grey);
  result.test = std::move(test.records);
  result.test_grey = std::move(test.grey);

  const Columns train = columns_of(result.training);
  const Columns conf = columns_of(result.confidence);
  const Columns held = columns_of(result.test);
  result.test_rows_without_echo = result.test.size() - held.index.size();
  if (train.index.size() < 50 || conf.index.size() < 30 || held.index.size() < 30) {
    throw std::runtime_error(
        "thesis protocol: too few echoes (training " + std::to_string(train.index.size()) +
        ", confidence " + std::to_string(conf.index.size()) + ", test " +
        std::to_string(held.index.size()) + "); is the device able to see the chart?");
  }
  const calib::SurfaceFitData train_data{train.inputs(), train.error_m};

  // Fig. 4.18: raw, then each polynomial order, then the B-spline, on the test scan.
  const auto raw_stats = calib::error_stats(held.error_m);
  ThesisModelRow raw_row;
  raw_row.model = "raw";
  raw_row.test = raw_stats;
  raw_row.training_rms_m = rms_of(train.error_m);
  result.rows.push_back(raw_row);
  auto add_row = [&](ThesisModelRow row, const calib::SurfaceFitResult& fit,
                     const std::vector<double>& residual) {
    row.test = calib::error_stats(residual);
    row.bias_improvement_pct = calib::improvement_pct(raw_stats.abs_bias_m, row.test.abs_bias_m);
    row.rms_improvement_pct = calib::improvement_pct(raw_stats.rms_m, row.test.rms_m);
    row.training_rms_m = fit.residual_rms_m;
    row.parameters = fit.parameters;
    row.rank = fit.rank;
    result.rows.push_back(std::move(row));
  };
  std::vector<double> best_poly_residual;
  double best_poly_rms = 1e300;
  for (const int order : options.polynomial_orders) {
    calib::PolynomialFitOptions po;
    po.order = order;
    po.rcond = options.rcond;
    const auto fit = calib::fit_polynomial_surface(train_data, po);
    ThesisModelRow row;
    row.model = "poly" + std::to_string(order);
    row.order = order;
    const auto r = residuals(*fit.surface, held, &row.test_rows_out_of_domain);
    add_row(row, fit, r);
    if (result.rows.back().test.rms_m < best_poly_rms) {
      best_poly_rms = result.rows.back().test.rms_m;
      result.best_polynomial_order = order;
      result.best_polynomial = fit.surface;
      best_poly_residual = r;
    }
  }
  result.bspline_fit = calib::fit_bspline_surface(train_data, options.bspline);
  result.bspline = result.bspline_fit.surface;
  ThesisModelRow bspline_row;
  bspline_row.model = "bspline";
  const auto bspline_residual =
      residuals(*result.bspline, held, &bspline_row.test_rows_out_of_domain);
  add_row(bspline_row, result.bspline_fit, bspline_residual);
  // Beyond the thesis: the sensor's temperature term on the B-spline, its slope
  // measured on the device in a session of its own (or the thesis's stated one).
  result.temperature_term =
      make_temperature_term(device, options.temperature_term, options.training_distances_m,
                            train.temperature_c, derive_seed(seed, kTemperatureRunSalt));
  const TemperatureTerm& temp = result.temperature_term;
  const bool with_temperature = temp.active();
  const Columns held_t = at_training_temperature(held, temp);
  std::size_t temperature_out_of_domain = 0;
  const auto temperature_residual = residuals(*result.bspline, held_t, &temperature_out_of_domain);
  if (with_temperature) {
    ThesisModelRow row;
    row.model = "bspline_temp";
    row.test_rows_out_of_domain = temperature_out_of_domain;
    add_row(row, result.bspline_fit, temperature_residual);
  }

  // Section 4.8 (relative error roughly constant in range), in-sample like the thesis.
  {
    const auto train_residual = residuals(*result.bspline, train);
    for (const double d : options.training_distances_m) {
      std::vector<double> at;
      for (std::size_t i = 0; i < train_residual.size(); ++i) {
        if (std::abs(train.truth_m[i] - d) < 1e-12) at.push_back(train_residual[i]);
      }
      result.relative_error_by_training_distance.push_back(rms_of(at) / d);
    }
    // The same with the best polynomial: the thesis's own correction.
    const auto poly_residual = residuals(*result.best_polynomial, train);
    for (const double d : options.training_distances_m) {
      std::vector<double> at;
      for (std::size_t i = 0; i < poly_residual.size(); ++i) {
        if (std::abs(train.truth_m[i] - d) < 1e-12) at.push_back(poly_residual[i]);
      }
      result.relative_error_by_training_distance_polynomial.push_back(rms_of(at) / d);
    }
  }

  // Confidence: both metrics fitted on the confidence scan's B-spline residuals.
  const auto conf_residual = residuals(*result.bspline, conf);
  const calib::ConfidenceFitData conf_data{conf.range_m, conf.amplitude, conf_residual};
  result.thesis_confidence = calib::fit_thesis_confidence(conf_data, options.thesis_confidence);
  result.calibrated_confidence =
      calib::fit_calibrated_confidence(conf_data, options.calibrated_confidence);
  const auto terciles = calib::amplitude_terciles(held.amplitude);
  std::vector<double> sigma_thesis(held.range_m.size()), sigma_calibrated(held.range_m.size());
  result.thesis_confidence->sigma(held.range_m, held.amplitude, sigma_thesis);
  result.calibrated_confidence->sigma(held.range_m, held.amplitude, sigma_calibrated);
  for (const auto& [name, sigma] :
       {std::pair{"thesis", &sigma_thesis}, std::pair{"calibrated", &sigma_calibrated}}) {
    ThesisCoverageRow row;
    row.model = name;
    row.within_1_sigma = calib::coverage(bspline_residual, *sigma, held.amplitude, 1.0, terciles);
    row.within_2_sigma = calib::coverage(bspline_residual, *sigma, held.amplitude, 2.0, terciles);
    row.mean_sigma_m = sample_stats(*sigma).mean;
    result.coverage.push_back(row);
  }
  if (with_temperature) {
    // The calibrated sigma saw one session's temperature; the slope's own
    // uncertainty over the test's departure from it adds in quadrature (GUM:
    // independent inputs).
    std::vector<double> sigma(held.range_m.size());
    result.calibrated_confidence->sigma(held_t.range_m, held_t.amplitude, sigma);
    for (std::size_t i = 0; i < sigma.size(); ++i) {
      sigma[i] = std::hypot(sigma[i], temp.u_m(held.temperature_c[i]));
    }
    ThesisCoverageRow row;
    row.model = "calibrated_temp";
    row.within_1_sigma =
        calib::coverage(temperature_residual, sigma, held.amplitude, 1.0, terciles);
    row.within_2_sigma =
        calib::coverage(temperature_residual, sigma, held.amplitude, 2.0, terciles);
    row.mean_sigma_m = sample_stats(sigma).mean;
    result.coverage.push_back(row);
  }

  // Per-row data for the plots, and Fig. 4.19 per grey level.
  for (std::size_t k = 0; k < held.index.size(); ++k) {
    ThesisTestRow row;
    row.grey = result.test_grey[held.index[k]];
    row.truth_m = held.truth_m[k];
    row.measured_m = held.range_m[k];
    row.amplitude = held.amplitude[k];
    row.raw_error_m = held.error_m[k];
    row.best_polynomial_error_m = best_poly_residual[k];
    row.bspline_error_m = bspline_residual[k];
    row.sigma_thesis_m = sigma_thesis[k];
    row.sigma_calibrated_m = sigma_calibrated[k];
    result.test_rows.push_back(row);
  }
  for (const int g : options.grey_levels) {
    std::vector<double> raw, poly, spline, amplitude;
    for (const auto& r : result.test_rows) {
      if (r.grey != g) continue;
      raw.push_back(r.raw_error_m);
      poly.push_back(r.best_polynomial_error_m);
      spline.push_back(r.bspline_error_m);
      amplitude.push_back(r.amplitude);
    }
    const auto raw_stats_g = calib::error_stats(raw);
    result.per_grey.push_back({g, grey_reflectance(g), sample_stats(amplitude).mean, rms_of(raw),
                               rms_of(poly), rms_of(spline), raw_stats_g.bias_m,
                               std::sqrt(raw_stats_g.variance_m2)});
  }

  // Section 4.4's explanation of the thesis's residual: the test scan repeated
  // warmer than the training, corrected with the same surfaces.
  for (std::size_t k = 0; k < options.test_temperature_offsets_c.size(); ++k) {
    const double offset = options.test_temperature_offsets_c[k];
    const auto warm =
        scan_chart(device, options, {options.test_distance_m}, options.test_points_per_grey,
                   derive_seed(seed, kTemperatureSalt + k), offset);
    const Columns w = columns_of(warm.records);
    if (w.index.empty()) continue;
    ThesisTemperatureRow row;
    row.offset_c = offset;
    row.raw = calib::error_stats(w.error_m);
    row.best_polynomial = calib::error_stats(residuals(*result.best_polynomial, w));
    const auto w_residual = residuals(*result.bspline, w);
    row.bspline = calib::error_stats(w_residual);
    row.bspline_temperature =
        calib::error_stats(residuals(*result.bspline, at_training_temperature(w, temp)));
    result.temperature.push_back(row);
  }

  // Fig. 4.15: both surfaces over the training domain (intensity log-spaced).
  {
    const auto& dom = result.bspline->domain();
    auto& grid = result.surface_grid;
    const auto nr = static_cast<std::size_t>(options.grid_range_nodes);
    const auto na = static_cast<std::size_t>(options.grid_amplitude_nodes);
    for (std::size_t i = 0; i < nr; ++i) {
      grid.range_m.push_back(dom.range_min_m + (dom.range_max_m - dom.range_min_m) *
                                                   static_cast<double>(i) / double(nr - 1));
    }
    const double log_lo = std::log(std::max(dom.amplitude_min, 1e-12));
    const double log_hi = std::log(std::max(dom.amplitude_max, dom.amplitude_min * 1.0001));
    for (std::size_t j = 0; j < na; ++j) {
      grid.amplitude.push_back(
          std::exp(log_lo + (log_hi - log_lo) * static_cast<double>(j) / double(na - 1)));
    }
    std::vector<double> r, a;
    for (std::size_t i = 0; i < nr; ++i) {
      for (std::size_t j = 0; j < na; ++j) {
        r.push_back(grid.range_m[i]);
        a.push_back(grid.amplitude[j]);
      }
    }
    grid.bspline_m.resize(r.size());
    grid.best_polynomial_m.resize(r.size());
    std::vector<std::uint8_t> outside(r.size());
    result.bspline->evaluate({r, a, {}}, grid.bspline_m, outside);
    result.best_polynomial->evaluate({r, a, {}}, grid.best_polynomial_m, outside);
  }
  return result;
}

const ThesisModelRow& ThesisProtocolResult::row(const std::string& model) const {
  for (const auto& r : rows) {
    if (r.model == model) return r;
  }
  throw std::out_of_range("thesis protocol: no model row '" + model + "'");
}

const ThesisCoverageRow& ThesisProtocolResult::coverage_of(const std::string& model) const {
  for (const auto& c : coverage) {
    if (c.model == model) return c;
  }
  throw std::out_of_range("thesis protocol: no coverage row '" + model + "'");
}

std::vector<ranging::Record> ThesisProtocolResult::all_records() const {
  std::vector<ranging::Record> all(training);
  all.insert(all.end(), confidence.begin(), confidence.end());
  all.insert(all.end(), test.begin(), test.end());
  return all;
}

std::vector<Finding> ThesisProtocolResult::findings() const {
  std::vector<Finding> f;
  for (const auto& r : rows) {
    f.push_back({r.model + "_rms_in", m_to_inches(r.test.rms_m), "in"});
    if (r.model != "raw")
      f.push_back({r.model + "_rms_improvement_pct", r.rms_improvement_pct, "%"});
  }
  f.push_back({"best_polynomial_order", double(best_polynomial_order), ""});
  if (temperature_term.active()) {
    f.push_back({"temperature_slope_mm_per_c", 1e3 * temperature_term.slope_m_per_c, "mm/C"});
    f.push_back({"temperature_slope_u_mm_per_c", 1e3 * temperature_term.u_slope_m_per_c, "mm/C"});
  }
  for (const auto& c : coverage) {
    f.push_back({c.model + "_within_1_sigma", c.within_1_sigma.share, ""});
    f.push_back({c.model + "_within_2_sigma", c.within_2_sigma.share, ""});
    for (int t = 0; t < 3; ++t) {
      f.push_back({c.model + "_within_2_sigma_tercile_" + std::to_string(t),
                   c.within_2_sigma.tercile_share[static_cast<std::size_t>(t)], ""});
    }
  }
  return f;
}

std::vector<ResultTable> ThesisProtocolResult::tables() const {
  std::vector<ResultTable> out;
  ResultTable models{
      "models",
      {"order", "bias_m", "variance_m2", "rms_m", "bias_improvement_pct", "rms_improvement_pct",
       "training_rms_m", "parameters", "rank", "test_rows_out_of_domain"},
      {}};
  for (const auto& r : rows) {
    models.rows.push_back({double(r.order), r.test.bias_m, r.test.variance_m2, r.test.rms_m,
                           r.bias_improvement_pct, r.rms_improvement_pct, r.training_rms_m,
                           double(r.parameters), double(r.rank),
                           double(r.test_rows_out_of_domain)});
  }
  out.push_back(models);
  ResultTable cov{"coverage",
                  {"within_1_sigma", "within_2_sigma", "within_2_sigma_low",
                   "within_2_sigma_middle", "within_2_sigma_high", "mean_sigma_m"},
                  {}};
  for (const auto& c : coverage) {
    const auto& t = c.within_2_sigma.tercile_share;
    cov.rows.push_back(
        {c.within_1_sigma.share, c.within_2_sigma.share, t[0], t[1], t[2], c.mean_sigma_m});
  }
  out.push_back(cov);
  ResultTable grey{"per_grey",
                   {"grey", "reflectance", "mean_amplitude", "raw_rms_m", "best_polynomial_rms_m",
                    "bspline_rms_m", "raw_mean_m", "raw_sd_m"},
                   {}};
  for (const auto& g : per_grey) {
    grey.rows.push_back({double(g.grey), g.reflectance, g.mean_amplitude, g.raw_rms_m,
                         g.best_polynomial_rms_m, g.bspline_rms_m, g.raw_mean_m, g.raw_sd_m});
  }
  out.push_back(grey);
  ResultTable test_table{
      "test_rows",
      {"grey", "truth_m", "measured_m", "amplitude", "raw_error_m", "best_polynomial_error_m",
       "bspline_error_m", "sigma_thesis_m", "sigma_calibrated_m"},
      {}};
  for (const auto& r : test_rows) {
    test_table.rows.push_back({double(r.grey), r.truth_m, r.measured_m, r.amplitude, r.raw_error_m,
                               r.best_polynomial_error_m, r.bspline_error_m, r.sigma_thesis_m,
                               r.sigma_calibrated_m});
  }
  out.push_back(test_table);
  ResultTable grid{"surface_grid", {"range_m", "amplitude", "bspline_m", "best_polynomial_m"}, {}};
  const auto na = surface_grid.amplitude.size();
  for (std::size_t i = 0; i < surface_grid.range_m.size(); ++i) {
    for (std::size_t j = 0; j < na; ++j) {
      grid.rows.push_back({surface_grid.range_m[i], surface_grid.amplitude[j],
                           surface_grid.bspline_m[i * na + j],
                           surface_grid.best_polynomial_m[i * na + j]});
    }
  }
  out.push_back(grid);
  return out;
}

std::string ThesisProtocolResult::summary() const {
  // The thesis's Fig. 4.18 (point-by-point, reference/fig4_18_point_fit.csv), in inches.
  struct ThesisFigure {
    const char* model;
    double bias_in, variance_in2, rms_in, rms_improvement_pct;
  };
  static constexpr ThesisFigure kFig418[] = {{"raw", 1.16721, 0.17745, 1.24090, 0},
                                             {"poly3", 0.25710, 0.10289, 0.41109, 66.87},
                                             {"poly4", 0.25932, 0.06376, 0.36195, 70.83},
                                             {"poly5", 0.63784, 0.05426, 0.67905, 45.28},
                                             {"poly6", 0.63795, 0.03587, 0.66548, 46.37}};
  std::string out;
  char line[320];
  std::snprintf(line, sizeof line,
                "thesis protocol: %zu training points (%zu distances), %zu confidence points, "
                "%zu test points at %.1f in (%zu without echo); error = true - corrected\n",
                training.size(), options.training_distances_m.size(), confidence.size(),
                test.size(), m_to_inches(options.test_distance_m), test_rows_without_echo);
  out += line;
  out +=
      "  model         bias [in]  variance [in^2]  RMS [in]  RMS impr. [%]  |  thesis: bias  "
      "variance   RMS   impr.\n";
  for (const auto& r : rows) {
    const double in2 = kMetersPerInch * kMetersPerInch;
    std::snprintf(line, sizeof line, "  %-12s %10.4f %16.5f %9.4f %14.1f", r.model.c_str(),
                  m_to_inches(r.test.bias_m), r.test.variance_m2 / in2, m_to_inches(r.test.rms_m),
                  r.model == "raw" ? 0.0 : r.rms_improvement_pct);
    out += line;
    bool matched = false;
    for (const auto& t : kFig418) {
      if (r.model == t.model) {
        std::snprintf(line, sizeof line, "  |  %12.4f %9.5f %6.4f %6.1f\n", t.bias_in,
                      t.variance_in2, t.rms_in, t.rms_improvement_pct);
        out += line;
        matched = true;
      }
    }
    if (!matched) out += "  |  (thesis: future work)\n";
  }
  std::snprintf(line, sizeof line, "  best polynomial: order %d\n", best_polynomial_order);
  out += line;
  out +=
      "  confidence on the test scan (B-spline correction; thesis and calibrated saw the\n"
      "  training's temperature only, calibrated_temp adds the sensor's term), share\n"
      "  within k sigma:\n"
      "    model            1 sigma  2 sigma  2 sigma by intensity tercile (low mid high)  "
      "mean sigma [in]\n";
  for (const auto& c : coverage) {
    const auto& t = c.within_2_sigma.tercile_share;
    std::snprintf(line, sizeof line,
                  "    %-15s %7.1f%% %7.1f%%   %6.1f%% %6.1f%% %6.1f%%  %24.4f\n", c.model.c_str(),
                  100 * c.within_1_sigma.share, 100 * c.within_2_sigma.share, 100 * t[0],
                  100 * t[1], 100 * t[2], m_to_inches(c.mean_sigma_m));
    out += line;
  }
  out +=
      "  per grey level at the test distance [in] (Fig. 4.19: RMS; raw mean, raw sd):\n"
      "    grey   rho    raw      best poly  bspline   raw mean  raw sd (point to point)\n";
  for (const auto& g : per_grey) {
    std::snprintf(line, sizeof line, "    %4d  %5.3f  %7.4f  %9.4f  %7.4f  %9.4f  %6.4f\n", g.grey,
                  g.reflectance, m_to_inches(g.raw_rms_m), m_to_inches(g.best_polynomial_rms_m),
                  m_to_inches(g.bspline_rms_m), m_to_inches(g.raw_mean_m), m_to_inches(g.raw_sd_m));
    out += line;
  }
  if (!temperature.empty()) {
    out +=
        "  test scan taken warmer than the training (thesis Section 4.4: temperature not\n"
        "  constant between scans, range falls 0.25-0.60 in per 10 C), bias / RMS [in]:\n"
        "    warmer by   raw               best poly         bspline           bspline_temp\n";
    for (const auto& t : temperature) {
      std::snprintf(line, sizeof line,
                    "    %5.1f C   %7.4f / %6.4f  %7.4f / %6.4f  %7.4f / %6.4f  %7.4f / %6.4f\n",
                    t.offset_c, m_to_inches(t.raw.bias_m), m_to_inches(t.raw.rms_m),
                    m_to_inches(t.best_polynomial.bias_m), m_to_inches(t.best_polynomial.rms_m),
                    m_to_inches(t.bspline.bias_m), m_to_inches(t.bspline.rms_m),
                    m_to_inches(t.bspline_temperature.bias_m),
                    m_to_inches(t.bspline_temperature.rms_m));
      out += line;
    }
  }
  const std::string term = temperature_term.summary();  // its lines, indented as the rest
  for (std::size_t a = 0, b = 0; (b = term.find('\n', a)) != std::string::npos; a = b + 1) {
    out += "  " + term.substr(a, b - a + 1);
  }
  out +=
      "  relative error of corrected ranges per training distance (thesis: 0.0117 0.0077 "
      "0.0070 0.0046):";
  for (const double e : relative_error_by_training_distance) {
    std::snprintf(line, sizeof line, " %.4f", e);
    out += line;
  }
  return out + "\n";
}

}  // namespace tofkit::experiments
