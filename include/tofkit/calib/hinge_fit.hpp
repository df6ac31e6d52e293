#pragma once
/// \file Continuous piecewise-linear ("hinge") least squares with the knots
/// found from the data. The paper placed its knots by inspection (6.5 ns in
/// echo pulse width, 16 C in temperature; Section 5); tofkit finds them:
///
/// - For a given knot count k the fit is a profile least-squares problem: the
///   coefficients are linear given the knots, so the residual sum of squares
///   is minimised over knot positions only. Knots start from an exhaustive
///   search of a grid of data quantiles (greedy insertion when the grid has
///   too many combinations) and are refined one at a time by golden-section
///   search between their neighbours, until no knot moves. During the search
///   the residual sum of squares of a candidate comes from prefix sums of the
///   x-sorted data (O(k^3 + log n) per candidate); the final coefficients are
///   computed by Householder QR (Eigen) on the scaled design matrix.
/// - Every segment must hold at least max(min_segment_rows,
///   min_segment_fraction n) rows, so a knot never sits in empty data.
/// - The knot count 0..max_knots is chosen by the Bayesian information
///   criterion BIC(k) = n log(RSS_w / n) + p log n, p = 2 + 2k (intercept,
///   slope, and a position and a slope change per knot), with n and RSS_w the
///   weight sum and weighted residual sum of squares of the (robust) fit.
/// - Robustness: iteratively reweighted least squares with Huber or Tukey
///   bisquare weights, scale = 1.4826 MAD of the residuals; the knot search is
///   repeated with the current weights each iteration. Bisquare starts with
///   a few Huber iterations so gross outliers cannot capture the start.

#include <Eigen/Dense>
#include <cstddef>
#include <span>
#include <string>
#include <vector>

#include "tofkit/ranging/piecewise_linear.hpp"
#include "tofkit/ranging/raw_measurement.hpp"

namespace tofkit::calib {

/// Ordered from the least to the most aggressive downweighting.
enum class RobustLoss { kNone, kHuber, kBisquare };

struct RobustOptions {
  RobustLoss loss = RobustLoss::kBisquare;
  double huber_k = 1.345;          ///< Huber tuning constant, in robust sigmas (95 % efficiency)
  double bisquare_c = 4.685;       ///< Tukey bisquare tuning constant (95 % efficiency)
  int huber_start_iterations = 3;  ///< Huber iterations before bisquare (robust start)
  int max_iterations = 30;
  double weight_tolerance = 1e-4;  ///< stop when no weight changes more than this
};

/// Result of a (robust) linear least-squares fit.
struct RobustLinearFit {
  Eigen::VectorXd coefficients;
  Eigen::VectorXd weights;  ///< final robust weights in [0, 1] (all 1 without a robust loss)
  double scale = 0;         ///< 1.4826 MAD of the residuals (robust sigma)
  int iterations = 0;
};

/// IRLS on a fixed design matrix (coefficients by Householder QR of the
/// sqrt(weight)-scaled system). Used by the hinge and chain fits once knots are fixed.
[[nodiscard]] RobustLinearFit robust_linear_fit(const Eigen::MatrixXd& design,
                                                const Eigen::VectorXd& y,
                                                const RobustOptions& options);

struct HingeFitOptions {
  int max_knots = 3;                   ///< knot counts 0..max_knots are tried; BIC picks one
  int grid_points = 40;                ///< knot candidates at data quantiles for the coarse search
  std::size_t min_segment_rows = 5;    ///< rows every segment must hold
  double min_segment_fraction = 0.03;  ///< ... or this share of the rows, if larger
  double x0 = ranging::kNaN;           ///< reference abscissa of the result (NaN: median of x)
  RobustOptions robust;
  std::string column = "x";  ///< names x in error messages ("pulse_width_ns")
  std::string unit;          ///< unit of x in messages ("ns")
};

struct HingeFitResult {
  ranging::PiecewiseLinear function;
  std::vector<double> knots;     ///< = function.knots
  double x_min = ranging::kNaN;  ///< domain of the data fitted
  double x_max = ranging::kNaN;
  std::size_t rows = 0;                 ///< finite (x, y) rows used
  std::size_t rows_skipped = 0;         ///< rows with a non-finite x or y
  std::size_t rows_downweighted = 0;    ///< rows with a final robust weight below 0.5
  double residual_rms = ranging::kNaN;  ///< RMS of y - f(x) over all rows used (outliers included)
  double robust_scale = ranging::kNaN;  ///< 1.4826 MAD of the residuals
  std::vector<double> bic;              ///< BIC per knot count (NaN: count not feasible)
  int irls_iterations = 0;
  [[nodiscard]] std::string summary() const;
};

/// Fits y = f(x). Throws std::invalid_argument naming options.column when
/// there are fewer than 5 finite rows or x has no spread.
[[nodiscard]] HingeFitResult fit_hinge(std::span<const double> x, std::span<const double> y,
                                       const HingeFitOptions& options = {});

/// Same, with the knots given (only the linear coefficients are fitted).
[[nodiscard]] HingeFitResult fit_hinge_fixed_knots(std::span<const double> x,
                                                   std::span<const double> y,
                                                   std::span<const double> knots,
                                                   const HingeFitOptions& options = {});

}  // namespace tofkit::calib
