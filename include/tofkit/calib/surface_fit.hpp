#pragma once
/// \file Least-squares fits of correction surfaces.

#include <array>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "tofkit/calib/correction_surface.hpp"

namespace tofkit::calib {

/// Training data: inputs and the error to model, error_m = true - measured.
struct SurfaceFitData {
  SurfaceInputs inputs;
  std::span<const double> error_m;
  /// Optional: the target (group of repeats) of every row. With groups, the
  /// B-spline's knots and smoothing are chosen by 5-fold cross-validation over
  /// whole groups instead of GCV (repeats of one target are not independent);
  /// each fold is scored on its rows inside the bounding box of the other
  /// folds' rows (the surface is not applied outside its domain).
  std::span<const std::uint32_t> group = {};
};

/// The thesis's cutoff (Section 4.6) as an rcond on the scaled design A: it
/// decomposes A^T A, divides S's diagonal by its first entry and zeroes the
/// entries below 1e-2. A^T A's singular values are A's squared, so that drops
/// the directions with s_k / s_0 < sqrt(1e-2) = 0.1: the same pseudo-inverse.
inline constexpr double kThesisRcond = 0.1;

struct PolynomialFitOptions {
  int order = 4;  ///< total degree N: terms of (1 + r + i [+ t])^N
  /// Relative cutoff on the singular values of the scaled design A: those below
  /// rcond * s_max are dropped; 0 keeps all. The thesis applied 1e-2 to the
  /// spectrum of A^T A (the squares), which is rcond = 0.1 here.
  double rcond = 1e-2;
  bool use_temperature = false;
  /// Throws std::invalid_argument naming the bad field.
  void validate() const;
};

/// Where a B-spline axis's knots go.
enum class KnotPlacement {
  uniform,   ///< equal intervals over the data's span
  quantile,  ///< at quantiles of the data's distinct axis coordinates
};
[[nodiscard]] const char* to_string(KnotPlacement placement);

struct BSplineFitOptions {
  int intervals_range = 6;      ///< knot intervals along range (cubic: intervals + 3 coefficients)
  int intervals_amplitude = 8;  ///< along amplitude
  int intervals_temperature = 3;  ///< along temperature (when used)
  double smoothing = 1e-3;        ///< second-difference penalty weight, relative to the data term
  bool use_temperature = false;
  bool log_amplitude = true;  ///< place amplitude knots on a log scale (intensity spans decades)
  /// The column the data's amplitude span holds (stored with the surface, so
  /// that the pipeline feeds the same column); pulse width: use log_amplitude = false.
  ranging::IntensityInput intensity = ranging::IntensityInput::amplitude;
  /// Pick `smoothing` by generalized cross-validation over decades 1e-7 .. 1e1
  /// (Craven & Wahba 1979), or k-fold over groups when the data carry them,
  /// instead of using the value above; then each axis's penalty weight
  /// relative to it (decades 1e-3 .. 1e3, one pass per axis) by the same score.
  bool choose_smoothing_by_gcv = false;
  /// Knot placement of each axis (range, amplitude, temperature) when the
  /// intervals are given (below: chosen). Quantile knots are capped at the
  /// axis's distinct values minus one intervals.
  std::array<KnotPlacement, 3> knot_placement = {KnotPlacement::uniform, KnotPlacement::uniform,
                                                 KnotPlacement::uniform};
  /// Choose the knots of each axis too, by the same generalized
  /// cross-validation: the count from a ladder (3, 5, 8, 12 per axis; 2, 3, 5
  /// for temperature) capped by the data's distinct values on that axis, and
  /// the placement (uniform or quantile) per axis; the intervals_* and
  /// knot_placement above are then ignored. Implies choose_smoothing_by_gcv
  /// unless keep_smoothing. Grids with more coefficients than
  /// kMaxBSplineCoefficientsPerRow per data row, or than
  /// bspline_coefficient_limit(true), are not tried: the search is bounded
  /// in time by construction.
  bool choose_intervals_by_gcv = false;
  /// With choose_intervals_by_gcv: keep `smoothing` as given (the knots are
  /// chosen for it) instead of choosing it too.
  bool keep_smoothing = false;
  /// When nothing is chosen by cross-validation: each axis's penalty weight
  /// relative to `smoothing` (range, amplitude, temperature). With a result's
  /// intervals, smoothing, placement and axis_weight the options refit its
  /// surface with the same choices (a refit that is linear in the data).
  double axis_weight[3] = {1, 1, 1};
  /// A ridge toward a zero surface, relative to the penalty (its weight per
  /// coefficient is this times the mean diagonal of the second-difference
  /// penalty, times the smoothing). 0: none. For a surface on a chain's
  /// residual, whose prior is no correction: where the data leave a corner of
  /// the grid empty (far and weak), the second-difference penalty alone
  /// extrapolates its null space (a bilinear twist fitted elsewhere) into it;
  /// with the ridge the surface decays to zero there within a knot or two.
  double shrink_to_zero = 0;
  /// Throws std::invalid_argument naming the bad field.
  void validate() const;
};

/// The largest smoothing weight (relative to the data term) a fit takes.
constexpr double kMaxBSplineSmoothing = 1e6;

/// Coefficients per data row the automatic knot search tries at most (the
/// penalty fixes what the data leave free; a finer grid than this the data
/// cannot choose).
constexpr double kMaxBSplineCoefficientsPerRow = 1.0;

/// The most coefficients a B-spline fit solves for: each penalized solve costs
/// p^3 / 3, and choosing the smoothing by cross-validation takes ~27 weights x
/// (folds + 1) of them (400: a few seconds; fixed smoothing, 1500: one solve,
/// its hat-matrix trace and condition number). fit_bspline_surface refuses a
/// grid beyond it naming the intervals.
[[nodiscard]] constexpr std::size_t bspline_coefficient_limit(bool choose_smoothing) {
  return choose_smoothing ? 400 : 1500;
}

struct SurfaceFitResult {
  std::shared_ptr<const CorrectionSurface> surface;
  std::size_t rows = 0;
  std::size_t parameters = 0;
  std::size_t rank = 0;         ///< effective rank after the rcond cutoff (polynomial)
  double residual_rms_m = 0;    ///< on the training data
  double condition_number = 0;  ///< of the (scaled) design matrix
  double smoothing = 0;         ///< B-spline: the smoothing weight used (GCV's pick when chosen)
  double effective_parameters = 0;  ///< B-spline: trace of the hat matrix; polynomial: rank
  double cv_rms_m = 0;  ///< B-spline: cross-validated RMS, sqrt(GCV score); 0 when not computed
  int intervals[3] = {0, 0, 0};  ///< B-spline: knot intervals (range, amplitude, temperature)
  /// B-spline: each axis's placement and breakpoints (input units: the
  /// amplitude axis's exponentiated when on a log scale); empty for a
  /// polynomial or an unused axis.
  KnotPlacement placement[3] = {KnotPlacement::uniform, KnotPlacement::uniform,
                                KnotPlacement::uniform};
  std::vector<double> knots[3];
  /// B-spline: each axis's penalty weight relative to `smoothing` (chosen by
  /// cross-validation with the smoothing).
  double axis_weight[3] = {1, 1, 1};
  [[nodiscard]] std::string summary() const;
};

/// Total-degree polynomial surface by SVD with a relative singular-value cutoff,
/// inputs scaled to [-1, 1] for conditioning. Throws std::invalid_argument on
/// degenerate data (too few rows, no spread in an input) naming the problem.
[[nodiscard]] SurfaceFitResult fit_polynomial_surface(const SurfaceFitData& data,
                                                      const PolynomialFitOptions& options);

/// Tensor-product cubic B-spline surface with a second-difference smoothing
/// penalty (P-spline), which stays sane at and beyond the data's edge. The
/// penalty makes the fit well posed with fewer rows than coefficients; it
/// refuses only data with no spread on an axis (naming the axis).
[[nodiscard]] SurfaceFitResult fit_bspline_surface(const SurfaceFitData& data,
                                                   const BSplineFitOptions& options);

}  // namespace tofkit::calib
