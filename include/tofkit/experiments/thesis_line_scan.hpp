#pragma once
/// \file The thesis's line-by-line results (reference/characterization_thesis.md,
/// Sections 4.7-4.8) on a virtual rangefinder with memory: the six-level
/// stripe chart scanned line by line (the stage moving while the device samples
/// at its own rate; samples per line vary and are resampled onto the wanted
/// columns by weighted averaging) at 15, 17, 20 and 22 in for training and at
/// 19 in for testing; correction surfaces over (pixel range, pixel intensity)
/// for polynomial orders 4-6 and a B-spline (Fig. 4.23, per grey Fig. 4.24);
/// a random-grey checkerboard at 18 in corrected with the line model (Fig.
/// 4.27); expected-error (confidence) images of both (Figs. 4.32-4.33) with the
/// share of pixels within 1 and 2 sigma; and the noise limit (what a perfect
/// systematic correction would leave, from a repeated test scan).

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "tofkit/calib/confidence_model.hpp"
#include "tofkit/calib/correction_surface.hpp"
#include "tofkit/calib/statistics.hpp"
#include "tofkit/calib/surface_fit.hpp"
#include "tofkit/device/virtual_rangefinder.hpp"
#include "tofkit/experiments/characterization_common.hpp"
#include "tofkit/experiments/thesis_grey_chart.hpp"
#include "tofkit/scan/scanner.hpp"

namespace tofkit::experiments {

struct LineScanOptions {
  std::vector<double> training_distances_m{inches_to_m(15), inches_to_m(17), inches_to_m(20),
                                           inches_to_m(22)};  ///< thesis Section 4.7
  double test_distance_m = inches_to_m(19);
  /// Scans used only to fit the confidence models (between training distances,
  /// like the test): the thesis's metric on the stripe chart there; tofkit's
  /// calibrated sigma on random-grey charts there (other draws than the test's
  /// checkerboard), whose steps of every size show the coupling's memory.
  std::vector<double> confidence_distances_m{inches_to_m(16), inches_to_m(18), inches_to_m(21)};
  double checker_distance_m = inches_to_m(18);  ///< thesis Fig. 4.27
  std::vector<int> grey_levels{kThesisGreyLevels.begin(), kThesisGreyLevels.end()};
  double stripe_width_m = inches_to_m(1.0);  ///< Assumption: one-inch stripes
  int columns_per_stripe = 10;               ///< wanted image columns per stripe
  int lines = 6;                             ///< scan lines per chart
  double line_spacing_m = 0.004;
  int checker_cells = 6;                     ///< cells per side of the checkerboard
  double checker_cell_m = inches_to_m(1.0);  ///< Assumption: one-inch cells, like the stripes
  int checker_lines = 12;
  /// The random greys: each cell one of grey_levels. Assumption: printed with the
  /// stripe chart's six levels, so the line model's domain covers it.
  std::uint64_t checker_seed = 18;
  /// Shots per sample: 2^8 at 312.5 kHz gives 1221 samples/s (thesis Fig. 4.4 setting).
  int shots_per_sample = 256;
  /// With 6 in lines, 0.15 m/s gives about 1250 samples per line (thesis: 1235-1255).
  /// The laser samples while the stage moves (thesis 4.7): unlike the point
  /// scans, which switch it on at every point, a line runs past the laser's
  /// turn-on transient (40 ms of a ~1 s line), so the scans are taken settled.
  double stage_speed_m_per_s = 0.15;
  double turnaround_s = 0.5;
  int window_points = 4;  ///< footprint traces per averaging window (the beam moves)
  double ambient_c = 20.0;
  std::vector<int> polynomial_orders{4, 5, 6};  ///< thesis Fig. 4.23
  double rcond = calib::kThesisRcond;           ///< the thesis's 1e-2 on A^T A's spectrum
  calib::BSplineFitOptions bspline = line_bspline_options();
  calib::CalibratedConfidenceOptions confidence{};
  /// The thesis's own metric (Section 4.8), fitted on its best polynomial's residuals.
  /// Its floor_m2 and floor_above_amplitude are set from the two fields below.
  calib::ThesisConfidenceOptions thesis_confidence{};
  /// Thesis Section 4.8: "above intensity 72 a floor of 0.005 in^2 is used" (the cubic
  /// goes negative there). Assumption: the thesis's intensity is the unit's 8-bit
  /// amplitude (0-255), mapped onto the twin's intensity output as the same share of
  /// its full scale (receiver.amplitude_clip_v): 72 / 255 of 4 V = 1.13 V on the
  /// accurange preset, so greys 0-102 at 15-22 in sit on the floor.
  double thesis_floor_in2 = 0.005;
  double thesis_floor_intensity_counts = 72.0;  ///< <= 0: the floor is only a lower bound
  double intensity_full_scale_counts = 255.0;
  void validate() const;
  /// B-spline over (range, log intensity): 3 intervals along range, 8 along intensity.
  [[nodiscard]] static calib::BSplineFitOptions line_bspline_options();
};

/// One row of Figs. 4.23 / 4.27 (error = true - corrected, over image pixels).
struct LineModelRow {
  std::string model;  ///< "raw", "poly4".."poly6", "bspline"
  calib::ErrorStats test;
  double bias_improvement_pct = ranging::kNaN;
  double rms_improvement_pct = ranging::kNaN;
  /// RMS above the noise limit, as a share of raw's: 0 = a perfect systematic correction.
  double excess_over_noise_pct = ranging::kNaN;
  std::size_t out_of_domain = 0;
};

struct LineGreyRow {  ///< Fig. 4.24, with where each grey's raw error comes from
  int grey = 0;
  double raw_rms_m = ranging::kNaN;
  double best_rms_m = ranging::kNaN;
  /// Raw error (true - measured) at the stripe's inner columns (two or more
  /// columns from either edge: what the stripe's grey does) and at its first
  /// and last columns (where the beam has just crossed, or is about to cross,
  /// an edge: the footprint's mixed pixels and the loop's memory): mean and
  /// standard deviation over the pixels.
  double centre_mean_m = ranging::kNaN, centre_sd_m = ranging::kNaN;
  double edge_mean_m = ranging::kNaN, edge_sd_m = ranging::kNaN;
  /// A pixel's noise from two independent scans of the chart (what no surface
  /// over range and intensity can remove), at the inner and the edge columns.
  double centre_noise_m = ranging::kNaN, edge_noise_m = ranging::kNaN;
};

/// An image of a chart with everything the figures need (row-major, NaN: no echo).
struct ChartImages {
  scan::Image raw, corrected, sigma, truth, intensity;
  std::vector<double> pixel_grey;  ///< reflectance-defining grey of each pixel
  calib::Coverage within_1_sigma, within_2_sigma;
  double sigma_min_m = ranging::kNaN, sigma_max_m = ranging::kNaN;
};

struct LineTable {
  std::vector<LineModelRow> rows;
  double noise_limit_m = ranging::kNaN;  ///< RMS left by a perfect systematic correction
  [[nodiscard]] const LineModelRow& row(const std::string& model) const;
  [[nodiscard]] const LineModelRow& best() const;  ///< lowest RMS other than raw
};

struct LineScanResult {
  LineScanOptions options;
  LineTable line;                     ///< Fig. 4.23, stripe chart at the test distance
  LineTable checker;                  ///< Fig. 4.27, checkerboard corrected with the line model
  std::vector<LineGreyRow> per_grey;  ///< Fig. 4.24
  ChartImages stripe_images, checker_images;  ///< the test images with the best model
  std::vector<int> samples_per_line;          ///< test scan (they vary, thesis 4.7)
  /// Every output of the stripe test scan, then of the checkerboard scan, with
  /// the true range of its beam axis (before resampling).
  std::vector<ranging::Record> records;
  std::size_t line_test_records = 0;  ///< the first this many are the stripe test scan
  std::string best_model;
  std::shared_ptr<const calib::CorrectionSurface> best_surface;
  std::shared_ptr<const calib::ConfidenceModel> confidence;
  /// The thesis's way (Section 4.8): its best polynomial (lowest RMS on the
  /// stripe test scan among orders 4-6) corrects, and E^2 fitted as a
  /// polynomial of intensity on the confidence scans' residuals of that
  /// polynomial gives sigma; the images of both charts with it (Figs. 4.32-4.33).
  std::string best_polynomial_model;
  std::shared_ptr<const calib::ConfidenceModel> thesis_confidence;
  ChartImages stripe_images_thesis, checker_images_thesis;

  [[nodiscard]] std::vector<Finding> findings() const;
  /// "line_models", "checker_models", "per_grey", "coverage".
  [[nodiscard]] std::vector<ResultTable> tables() const;
  [[nodiscard]] std::string summary() const;
};

/// Runs the scans (seeds derived from `seed`), the fits and the evaluation.
/// Throws std::invalid_argument on bad options, std::runtime_error when a scan
/// leaves too few pixels to fit.
[[nodiscard]] LineScanResult run_line_scan(const device::VirtualRangefinder& device,
                                           const LineScanOptions& options, std::uint64_t seed);

}  // namespace tofkit::experiments
