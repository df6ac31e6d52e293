#include "tofkit/experiments/thesis_line_scan.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <stdexcept>

#include "tofkit/experiments/scan_sequence.hpp"
#include "tofkit/scan/footprint.hpp"
#include "tofkit/scan/pattern.hpp"
#include "tofkit/scan/ray_caster.hpp"

namespace tofkit::experiments {
namespace {

// Salts of the independent random streams.
constexpr std::uint64_t kTrainingSalt = 1, kConfidenceSalt = 2, kTestSalt = 3, kTestRepeatSalt = 4,
                        kCheckerSalt = 5, kCheckerRepeatSalt = 6, kRandomConfidenceSalt = 7;

/// A chart in the y-z plane at x = distance, with the grey of every cell.
struct Chart {
  scan::Scene scene;
  int columns = 0, lines = 0;
  std::vector<double> y_m, z_m;    ///< wanted columns (descending) and lines
  std::vector<double> pixel_grey;  ///< row-major, lines x columns
};

std::vector<double> centred(int count, double pitch) {
  std::vector<double> v(static_cast<std::size_t>(count));
  for (int i = 0; i < count; ++i) v[static_cast<std::size_t>(i)] = (0.5 * (count - 1) - i) * pitch;
  return v;  // descending
}

/// The six-level stripe chart, one margin stripe of the edge greys on each side
/// (so the line's first and last samples see no extra edge).
Chart stripe_chart(const LineScanOptions& o, double distance_m) {
  Chart c;
  const int stripes = static_cast<int>(o.grey_levels.size());
  const double w = o.stripe_width_m;
  scan::Primitive p;
  p.kind = scan::PrimitiveKind::kPlane;
  p.name = "stripe chart";
  p.center_m = {distance_m, 0, 0};
  p.normal = {-1, 0, 0};
  p.size_m = {(stripes + 2) * w, o.lines * o.line_spacing_m + 0.02};
  p.reflectance.kind = scan::Reflectance::Kind::kStripes;
  p.reflectance.cell_m = w;
  // u runs along -y from the corner at y = +(stripes + 2) w / 2.
  p.reflectance.values.push_back(grey_reflectance(o.grey_levels.front()));
  for (const int g : o.grey_levels) p.reflectance.values.push_back(grey_reflectance(g));
  p.reflectance.values.push_back(grey_reflectance(o.grey_levels.back()));
  c.scene.primitives.push_back(p);
  c.columns = stripes * o.columns_per_stripe;
  c.lines = o.lines;
  c.y_m = centred(c.columns, w / o.columns_per_stripe);
  c.z_m = centred(c.lines, o.line_spacing_m);
  for (int l = 0; l < c.lines; ++l) {
    for (int col = 0; col < c.columns; ++col) {
      c.pixel_grey.push_back(o.grey_levels[static_cast<std::size_t>(col / o.columns_per_stripe)]);
    }
  }
  return c;
}

/// Random greys on square cells (each cell one of the chart's levels, drawn
/// counter-based from chart_seed), one cell of margin around the scanned ones,
/// at distance_m.
Chart checker_chart(const LineScanOptions& o, double distance_m, std::uint64_t chart_seed) {
  Chart c;
  const int n = o.checker_cells, m = n + 2;
  const double cell = o.checker_cell_m;
  std::vector<int> grey(static_cast<std::size_t>(m * m));
  for (int i = 0; i < m * m; ++i) {
    const auto pick = derive_seed(chart_seed, static_cast<std::uint64_t>(i)) % o.grey_levels.size();
    grey[static_cast<std::size_t>(i)] = o.grey_levels[static_cast<std::size_t>(pick)];
  }
  // Cell (i, j): i along -y (columns), j along -z (lines), margin at 0 and m - 1.
  for (int j = 0; j < m; ++j) {
    for (int i = 0; i < m; ++i) {
      scan::Primitive p;
      p.kind = scan::PrimitiveKind::kPlane;
      p.name = "checker cell";
      p.center_m = {distance_m, (0.5 * (m - 1) - i) * cell, (0.5 * (m - 1) - j) * cell};
      p.normal = {-1, 0, 0};
      p.size_m = {cell, cell};
      p.reflectance.value = grey_reflectance(grey[static_cast<std::size_t>(j * m + i)]);
      c.scene.primitives.push_back(p);
    }
  }
  c.columns = n * o.columns_per_stripe;
  c.lines = o.checker_lines;
  c.y_m = centred(c.columns, cell / o.columns_per_stripe);
  c.z_m = centred(c.lines, n * cell / o.checker_lines);
  for (int l = 0; l < c.lines; ++l) {
    const int j =
        1 +
        std::clamp(static_cast<int>((0.5 * n * cell - c.z_m[static_cast<std::size_t>(l)]) / cell),
                   0, n - 1);
    for (int col = 0; col < c.columns; ++col) {
      const int i = 1 + col / o.columns_per_stripe;
      c.pixel_grey.push_back(grey[static_cast<std::size_t>(j * m + i)]);
    }
  }
  return c;
}

struct ChartScan {
  scan::ScanImages images;
  std::vector<int> samples_per_line;
  std::vector<ranging::Record> records;
};

/// A scan's outputs as raw records with the true range of each beam axis.
std::vector<ranging::Record> records_of(const scan::ScanResult& result, double ambient_c) {
  std::vector<ranging::Record> out;
  out.reserve(result.beams.size());
  for (const auto& b : result.beams) {
    out.push_back({{b.true_range_m, ranging::kNaN, 0.0, ambient_c}, b.raw});
  }
  return out;
}

ChartScan scan_chart(const device::VirtualRangefinder& device, const LineScanOptions& o,
                     const Chart& chart, std::uint64_t seed) {
  const scan::RayCaster caster(chart.scene);
  const scan::Footprint footprint(device.config());
  const double period_s = o.shots_per_sample / device.config().link.laser.repetition_hz;
  scan::LineOptions lo;
  lo.y_m = chart.y_m;
  lo.z_m = chart.z_m;
  lo.stage_speed_m_per_s = o.stage_speed_m_per_s;
  lo.turnaround_s = o.turnaround_s;
  const auto pattern = scan::line_pattern(lo, period_s);
  SequenceScanOptions so;
  so.seed = seed;
  so.shots = o.shots_per_sample;
  so.conditions.ambient_c = o.ambient_c;
  so.window_points = o.window_points;
  const auto s = run_sequence_scan(caster, footprint, device, pattern, so);
  ChartScan out;
  out.images = scan::make_images(s.result);
  out.records = records_of(s.result, o.ambient_c);
  out.samples_per_line.assign(static_cast<std::size_t>(pattern.rows), 0);
  for (const auto& b : pattern.beams) ++out.samples_per_line[static_cast<std::size_t>(b.row)];
  return out;
}

/// Pixels with an echo: the columns of the fit.
struct Pixels {
  std::vector<std::size_t> index;  // into the image
  std::vector<double> range_m, amplitude, truth_m, error_m, grey;
  [[nodiscard]] calib::SurfaceInputs inputs() const { return {range_m, amplitude, {}}; }
  void append(const scan::ScanImages& im, const std::vector<double>& pixel_grey) {
    for (std::size_t i = 0; i < im.range.values.size(); ++i) {
      const double r = im.range.values[i], a = im.intensity.values[i], t = im.truth.values[i];
      if (!std::isfinite(r) || !std::isfinite(a) || !std::isfinite(t)) continue;
      index.push_back(i);
      range_m.push_back(r);
      amplitude.push_back(a);
      truth_m.push_back(t);
      error_m.push_back(t - r);
      grey.push_back(pixel_grey[i]);
    }
  }
};

std::vector<double> residuals(const calib::CorrectionSurface& surface, const Pixels& p,
                              std::size_t* out_of_domain = nullptr) {
  std::vector<double> correction(p.range_m.size());
  std::vector<std::uint8_t> outside(p.range_m.size());
  surface.evaluate(p.inputs(), correction, outside);
  std::vector<double> r(correction.size());
  for (std::size_t i = 0; i < r.size(); ++i) r[i] = p.error_m[i] - correction[i];
  if (out_of_domain)
    *out_of_domain = static_cast<std::size_t>(std::count(outside.begin(), outside.end(), 1));
  return r;
}

/// RMS a perfect systematic correction leaves: the noise of a pixel, from two
/// independent scans of the same chart: var(a - b) = 2 var(noise).
double noise_limit_m(const scan::ScanImages& a, const scan::ScanImages& b) {
  double sum = 0;
  std::size_t n = 0;
  for (std::size_t i = 0; i < a.range.values.size(); ++i) {
    const double d = double(a.range.values[i]) - double(b.range.values[i]);
    if (!std::isfinite(d)) continue;
    sum += d * d;
    ++n;
  }
  return n > 0 ? std::sqrt(sum / (2.0 * static_cast<double>(n))) : ranging::kNaN;
}

/// Where a grey's raw error comes from (Fig. 4.24's rows): the error's mean and
/// spread, and the pixel noise from two scans, at the stripe's inner columns (two
/// or more from either edge) and at its first and last columns.
void locate_grey_errors(const scan::ScanImages& a, const scan::ScanImages& b,
                        const std::vector<double>& pixel_grey, int columns_per_stripe, int grey,
                        LineGreyRow& row) {
  std::vector<double> centre, edge;
  double centre_d2 = 0, edge_d2 = 0;
  const int columns = a.range.columns;
  for (std::size_t i = 0; i < a.range.values.size(); ++i) {
    if (pixel_grey[i] != grey) continue;
    const double r = a.range.values[i], t = a.truth.values[i];
    if (!std::isfinite(r) || !std::isfinite(t)) continue;
    const int position =
        static_cast<int>(i % static_cast<std::size_t>(columns)) % columns_per_stripe;
    const bool at_edge = position == 0 || position == columns_per_stripe - 1;
    if (!at_edge && (position < 2 || position > columns_per_stripe - 3)) continue;
    (at_edge ? edge : centre).push_back(t - r);
    const double d = r - double(b.range.values[i]);
    if (std::isfinite(d)) (at_edge ? edge_d2 : centre_d2) += d * d;
  }
  const auto c = calib::error_stats(centre), e = calib::error_stats(edge);
  row.centre_mean_m = c.bias_m;
  row.centre_sd_m = std::sqrt(c.variance_m2);
  row.edge_mean_m = e.bias_m;
  row.edge_sd_m = std::sqrt(e.variance_m2);
  // var(a - b) = 2 var(noise)
  if (!centre.empty()) row.centre_noise_m = std::sqrt(centre_d2 / (2.0 * double(centre.size())));
  if (!edge.empty()) row.edge_noise_m = std::sqrt(edge_d2 / (2.0 * double(edge.size())));
}

struct Fitted {
  std::string model;
  std::shared_ptr<const calib::CorrectionSurface> surface;
};

LineTable table_of(const std::vector<Fitted>& models, const Pixels& test, double noise_m) {
  LineTable t;
  t.noise_limit_m = noise_m;
  const auto raw = calib::error_stats(test.error_m);
  auto excess = [&](double rms) { return 100.0 * (rms - noise_m) / (raw.rms_m - noise_m); };
  t.rows.push_back({"raw", raw, ranging::kNaN, ranging::kNaN, 100.0, 0});
  for (const auto& m : models) {
    LineModelRow row;
    row.model = m.model;
    row.test = calib::error_stats(residuals(*m.surface, test, &row.out_of_domain));
    row.bias_improvement_pct = calib::improvement_pct(raw.abs_bias_m, row.test.abs_bias_m);
    row.rms_improvement_pct = calib::improvement_pct(raw.rms_m, row.test.rms_m);
    row.excess_over_noise_pct = excess(row.test.rms_m);
    t.rows.push_back(row);
  }
  return t;
}

/// The image of a scan corrected by the surface, its sigma, and coverage.
ChartImages chart_images(const scan::ScanImages& im, const std::vector<double>& pixel_grey,
                         const calib::CorrectionSurface& surface,
                         const calib::ConfidenceModel& confidence) {
  ChartImages out;
  out.raw = im.range;
  out.truth = im.truth;
  out.intensity = im.intensity;
  out.pixel_grey = pixel_grey;
  out.corrected = im.range;
  out.sigma = im.range;
  std::fill(out.sigma.values.begin(), out.sigma.values.end(), std::nanf(""));
  Pixels p;
  p.append(im, pixel_grey);
  const auto resid = residuals(surface, p);
  std::vector<double> sigma(p.range_m.size());
  confidence.sigma(p.range_m, p.amplitude, sigma);
  for (std::size_t k = 0; k < p.index.size(); ++k) {
    out.corrected.values[p.index[k]] = static_cast<float>(p.truth_m[k] - resid[k]);
    out.sigma.values[p.index[k]] = static_cast<float>(sigma[k]);
  }
  const auto terciles = calib::amplitude_terciles(p.amplitude);
  out.within_1_sigma = calib::coverage(resid, sigma, p.amplitude, 1.0, terciles);
  out.within_2_sigma = calib::coverage(resid, sigma, p.amplitude, 2.0, terciles);
  if (!sigma.empty()) {
    out.sigma_min_m = *std::min_element(sigma.begin(), sigma.end());
    out.sigma_max_m = *std::max_element(sigma.begin(), sigma.end());
  }
  return out;
}

}  // namespace

calib::BSplineFitOptions LineScanOptions::line_bspline_options() {
  calib::BSplineFitOptions o;
  o.intervals_range = 3;
  o.intervals_amplitude = 8;
  o.smoothing = 1e-2;
  o.log_amplitude = true;
  o.choose_smoothing_by_gcv = false;
  return o;
}

void LineScanOptions::validate() const {
  auto fail = [](const std::string& field, const std::string& why) {
    throw std::invalid_argument("line scan: " + field + " " + why);
  };
  if (training_distances_m.size() < 2) fail("training_distances_m", "needs two or more");
  for (const double d : training_distances_m)
    if (!(d > 0)) fail("training_distances_m", "must be positive");
  if (confidence_distances_m.empty()) fail("confidence_distances_m", "needs one or more");
  if (!(test_distance_m > 0)) fail("test_distance_m", "must be positive");
  if (!(checker_distance_m > 0)) fail("checker_distance_m", "must be positive");
  if (grey_levels.size() < 2) fail("grey_levels", "needs two or more");
  for (const int g : grey_levels)
    if (g < 0 || g > 255) fail("grey_levels", "must be in 0..255");
  if (!(stripe_width_m > 0)) fail("stripe_width_m", "must be positive");
  if (columns_per_stripe < 1) fail("columns_per_stripe", "must be >= 1");
  if (lines < 1 || checker_lines < 1) fail("lines", "must be >= 1");
  if (!(line_spacing_m > 0)) fail("line_spacing_m", "must be positive");
  if (checker_cells < 1) fail("checker_cells", "must be >= 1");
  if (!(checker_cell_m > 0)) fail("checker_cell_m", "must be positive");
  if (shots_per_sample < 1) fail("shots_per_sample", "must be >= 1");
  if (!(stage_speed_m_per_s > 0)) fail("stage_speed_m_per_s", "must be positive");
  if (!(turnaround_s >= 0)) fail("turnaround_s", "must be >= 0");
  if (window_points < 1 || window_points > 64) fail("window_points", "must be in 1..64");
  if (polynomial_orders.empty()) fail("polynomial_orders", "needs one or more");
  if (!(thesis_floor_in2 > 0)) fail("thesis_floor_in2", "must be positive");
  if (!(intensity_full_scale_counts > 0)) fail("intensity_full_scale_counts", "must be positive");
  if (!std::isfinite(thesis_floor_intensity_counts))
    fail("thesis_floor_intensity_counts", "must be finite");
  bspline.validate();
  confidence.validate();
}

const LineModelRow& LineTable::row(const std::string& model) const {
  for (const auto& r : rows)
    if (r.model == model) return r;
  throw std::out_of_range("line scan: no model row '" + model + "'");
}

const LineModelRow& LineTable::best() const {
  const LineModelRow* best = nullptr;
  for (const auto& r : rows) {
    if (r.model == "raw") continue;
    if (!best || r.test.rms_m < best->test.rms_m) best = &r;
  }
  if (!best) throw std::out_of_range("line scan: no model rows");
  return *best;
}

LineScanResult run_line_scan(const device::VirtualRangefinder& device,
                             const LineScanOptions& options, std::uint64_t seed) {
  options.validate();
  LineScanResult result;
  result.options = options;

  Pixels train, conf, test, checker;
  std::uint64_t k = 0;
  for (const double d : options.training_distances_m) {
    const auto chart = stripe_chart(options, d);
    train.append(
        scan_chart(device, options, chart, derive_seed(seed, kTrainingSalt * 100 + k++)).images,
        chart.pixel_grey);
  }
  k = 0;
  for (const double d : options.confidence_distances_m) {
    const auto chart = stripe_chart(options, d);
    conf.append(
        scan_chart(device, options, chart, derive_seed(seed, kConfidenceSalt * 100 + k++)).images,
        chart.pixel_grey);
  }
  const auto test_chart = stripe_chart(options, options.test_distance_m);
  const auto test_scan = scan_chart(device, options, test_chart, derive_seed(seed, kTestSalt));
  const auto test_repeat =
      scan_chart(device, options, test_chart, derive_seed(seed, kTestRepeatSalt));
  test.append(test_scan.images, test_chart.pixel_grey);
  result.samples_per_line = test_scan.samples_per_line;
  result.records = test_scan.records;
  result.line_test_records = result.records.size();
  const auto checker_board =
      checker_chart(options, options.checker_distance_m, options.checker_seed);
  const auto checker_scan =
      scan_chart(device, options, checker_board, derive_seed(seed, kCheckerSalt));
  const auto checker_repeat =
      scan_chart(device, options, checker_board, derive_seed(seed, kCheckerRepeatSalt));
  checker.append(checker_scan.images, checker_board.pixel_grey);
  result.records.insert(result.records.end(), checker_scan.records.begin(),
                        checker_scan.records.end());
  if (train.index.size() < 50 || conf.index.size() < 30 || test.index.size() < 30 ||
      checker.index.size() < 30) {
    throw std::runtime_error("line scan: too few pixels with an echo (training " +
                             std::to_string(train.index.size()) + ", test " +
                             std::to_string(test.index.size()) + ", checkerboard " +
                             std::to_string(checker.index.size()) + ")");
  }

  // Fig. 4.23: polynomial orders and the B-spline, trained on the line scans.
  const calib::SurfaceFitData data{train.inputs(), train.error_m};
  std::vector<Fitted> models;
  for (const int order : options.polynomial_orders) {
    calib::PolynomialFitOptions po;
    po.order = order;
    po.rcond = options.rcond;
    models.push_back(
        {"poly" + std::to_string(order), calib::fit_polynomial_surface(data, po).surface});
  }
  models.push_back({"bspline", calib::fit_bspline_surface(data, options.bspline).surface});
  result.line = table_of(models, test, noise_limit_m(test_scan.images, test_repeat.images));
  result.checker =
      table_of(models, checker, noise_limit_m(checker_scan.images, checker_repeat.images));
  result.best_model = result.line.best().model;
  for (const auto& m : models)
    if (m.model == result.best_model) result.best_surface = m.surface;

  // Fig. 4.24: RMS per grey before and after the best model.
  const auto best_resid = residuals(*result.best_surface, test);
  for (const int g : options.grey_levels) {
    std::vector<double> raw, best;
    for (std::size_t i = 0; i < test.grey.size(); ++i) {
      if (test.grey[i] != g) continue;
      raw.push_back(test.error_m[i]);
      best.push_back(best_resid[i]);
    }
    LineGreyRow row{g, calib::error_stats(raw).rms_m, calib::error_stats(best).rms_m};
    locate_grey_errors(test_scan.images, test_repeat.images, test_chart.pixel_grey,
                       options.columns_per_stripe, g, row);
    result.per_grey.push_back(row);
  }

  // Confidence (Section 4.8), judged on the test images (Figs. 4.32-4.33).
  // tofkit's is fitted on the residuals of line scans of random-grey charts at
  // the confidence distances (other charts than the test's checkerboard): in a
  // line scan a pixel's error depends on the greys just scanned (the coupling's
  // memory: white after black reads up to 1.9 in long), and the stripes, whose
  // neighbours differ by one step, show only the smallest transitions.
  Pixels random_conf;
  k = 0;
  for (const double d : options.confidence_distances_m) {
    const auto chart = checker_chart(options, d, derive_seed(options.checker_seed, 1000 + k));
    random_conf.append(
        scan_chart(device, options, chart, derive_seed(seed, kRandomConfidenceSalt * 100 + k++))
            .images,
        chart.pixel_grey);
  }
  const auto random_conf_resid = residuals(*result.best_surface, random_conf);
  result.confidence = calib::fit_calibrated_confidence(
      {random_conf.range_m, random_conf.amplitude, random_conf_resid}, options.confidence);
  result.stripe_images = chart_images(test_scan.images, test_chart.pixel_grey, *result.best_surface,
                                      *result.confidence);
  result.checker_images = chart_images(checker_scan.images, checker_board.pixel_grey,
                                       *result.best_surface, *result.confidence);

  // The same images the thesis's way: its best polynomial and its metric.
  const LineModelRow* best_poly = nullptr;
  for (const auto& row : result.line.rows)
    if (row.model.starts_with("poly") && (!best_poly || row.test.rms_m < best_poly->test.rms_m))
      best_poly = &row;
  if (best_poly) {
    result.best_polynomial_model = best_poly->model;
    std::shared_ptr<const calib::CorrectionSurface> poly;
    for (const auto& m : models)
      if (m.model == best_poly->model) poly = m.surface;
    // The thesis's metric on the stripe scans at the confidence distances.
    const auto poly_conf_resid = residuals(*poly, conf);
    calib::ThesisConfidenceOptions thesis_options = options.thesis_confidence;
    thesis_options.floor_m2 = options.thesis_floor_in2 * kMetersPerInch * kMetersPerInch;
    thesis_options.floor_above_amplitude = options.thesis_floor_intensity_counts > 0
                                               ? options.thesis_floor_intensity_counts /
                                                     options.intensity_full_scale_counts *
                                                     device.config().link.receiver.amplitude_clip_v
                                               : 0.0;
    result.thesis_confidence = calib::fit_thesis_confidence(
        {conf.range_m, conf.amplitude, poly_conf_resid}, thesis_options);
    result.stripe_images_thesis =
        chart_images(test_scan.images, test_chart.pixel_grey, *poly, *result.thesis_confidence);
    result.checker_images_thesis = chart_images(checker_scan.images, checker_board.pixel_grey,
                                                *poly, *result.thesis_confidence);
  }
  return result;
}

std::vector<Finding> LineScanResult::findings() const {
  std::vector<Finding> f;
  for (const auto& [name, table] : {std::pair{"line", &line}, std::pair{"checker", &checker}}) {
    for (const auto& r : table->rows) {
      f.push_back({std::string(name) + "_" + r.model + "_rms_in", m_to_inches(r.test.rms_m), "in"});
      if (r.model == "raw")
        f.push_back({std::string(name) + "_raw_bias_in", m_to_inches(r.test.bias_m), "in"});
      else
        f.push_back({std::string(name) + "_" + r.model + "_rms_improvement_pct",
                     r.rms_improvement_pct, "%"});
    }
    f.push_back({std::string(name) + "_noise_limit_in", m_to_inches(table->noise_limit_m), "in"});
  }
  f.push_back({"stripe_within_1_sigma", stripe_images.within_1_sigma.share, ""});
  f.push_back({"stripe_within_2_sigma", stripe_images.within_2_sigma.share, ""});
  f.push_back({"checker_within_1_sigma", checker_images.within_1_sigma.share, ""});
  f.push_back({"checker_within_2_sigma", checker_images.within_2_sigma.share, ""});
  return f;
}

std::vector<ResultTable> LineScanResult::tables() const {
  std::vector<ResultTable> out;
  for (const auto& [name, table] :
       {std::pair{"line_models", &line}, std::pair{"checker_models", &checker}}) {
    ResultTable t{name,
                  {"bias_m", "variance_m2", "rms_m", "bias_improvement_pct", "rms_improvement_pct",
                   "excess_over_noise_pct", "out_of_domain"},
                  {}};
    for (const auto& r : table->rows) {
      t.rows.push_back({r.test.bias_m, r.test.variance_m2, r.test.rms_m, r.bias_improvement_pct,
                        r.rms_improvement_pct, r.excess_over_noise_pct, double(r.out_of_domain)});
    }
    out.push_back(t);
  }
  ResultTable grey{"per_grey",
                   {"grey", "raw_rms_m", "best_rms_m", "centre_mean_m", "centre_sd_m",
                    "centre_noise_m", "edge_mean_m", "edge_sd_m", "edge_noise_m"},
                   {}};
  for (const auto& g : per_grey) {
    grey.rows.push_back({double(g.grey), g.raw_rms_m, g.best_rms_m, g.centre_mean_m, g.centre_sd_m,
                         g.centre_noise_m, g.edge_mean_m, g.edge_sd_m, g.edge_noise_m});
  }
  out.push_back(grey);
  ResultTable cov{
      "coverage", {"within_1_sigma", "within_2_sigma", "sigma_min_m", "sigma_max_m"}, {}};
  for (const auto* im : {&stripe_images, &checker_images}) {
    cov.rows.push_back(
        {im->within_1_sigma.share, im->within_2_sigma.share, im->sigma_min_m, im->sigma_max_m});
  }
  out.push_back(cov);
  return out;
}

std::string LineScanResult::summary() const {
  std::string out;
  char line_text[256];
  int lo = 1 << 30, hi = 0;
  for (const int s : samples_per_line) {
    lo = std::min(lo, s);
    hi = std::max(hi, s);
  }
  std::snprintf(line_text, sizeof line_text,
                "line-by-line scans: %d-%d samples per line resampled to %d columns; best "
                "model %s\n",
                lo, hi, static_cast<int>(options.grey_levels.size()) * options.columns_per_stripe,
                best_model.c_str());
  out += line_text;
  const double in2 = kMetersPerInch * kMetersPerInch;
  for (const auto& [name, table] :
       {std::pair{"stripe chart at the test distance (Fig. 4.23)", &line},
        std::pair{"checkerboard (Fig. 4.27)", &checker}}) {
    out += std::string("  ") + name +
           ":\n    model     bias [in]  variance [in^2]  RMS [in]  "
           "RMS impr. [%]  excess over noise [%]\n";
    for (const auto& r : table->rows) {
      std::snprintf(line_text, sizeof line_text, "    %-8s %10.4f %16.5f %9.4f %14.1f %22.1f\n",
                    r.model.c_str(), m_to_inches(r.test.bias_m), r.test.variance_m2 / in2,
                    m_to_inches(r.test.rms_m), r.model == "raw" ? 0.0 : r.rms_improvement_pct,
                    r.excess_over_noise_pct);
      out += line_text;
    }
    std::snprintf(line_text, sizeof line_text, "    noise limit: %.4f in RMS\n",
                  m_to_inches(table->noise_limit_m));
    out += line_text;
  }
  out +=
      "  raw error per grey (Fig. 4.24): inner columns (2+ from an edge), edge columns; noise\n"
      "  from a repeated scan:\n"
      "    grey  inner mean [in]  sd [in]  noise [in]  edge mean [in]  sd [in]  noise [in]\n";
  for (const auto& g : per_grey) {
    std::snprintf(line_text, sizeof line_text, "    %4d %16.3f %8.3f %11.3f %15.3f %8.3f %11.3f\n",
                  g.grey, m_to_inches(g.centre_mean_m), m_to_inches(g.centre_sd_m),
                  m_to_inches(g.centre_noise_m), m_to_inches(g.edge_mean_m),
                  m_to_inches(g.edge_sd_m), m_to_inches(g.edge_noise_m));
    out += line_text;
  }
  for (const auto& [name, im] :
       {std::pair{"stripe chart", &stripe_images}, std::pair{"checkerboard", &checker_images}}) {
    std::snprintf(line_text, sizeof line_text,
                  "  confidence image, %s: sigma %.3f-%.3f in, within 1 sigma %.1f %%, within 2 "
                  "sigma %.1f %%\n",
                  name, m_to_inches(im->sigma_min_m), m_to_inches(im->sigma_max_m),
                  100 * im->within_1_sigma.share, 100 * im->within_2_sigma.share);
    out += line_text;
  }
  return out;
}

}  // namespace tofkit::experiments
