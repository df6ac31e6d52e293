#pragma once
/// \file Accuracy statistics of ranges against the truth (thesis Eqs. 4.1-4.3,
/// 4.10-4.11) and coverage of the expected error sigma.
///
/// With errors e_i = true_i - measured_i (i = 1..n):
///   bias      = (1/n) sum e_i                           (Eq. 4.1; |bias| also reported)
///   variance  = (1/n) sum (e_i - bias)^2                (Eq. 4.2, population form)
///   RMS       = sqrt((1/n) sum e_i^2), so RMS^2 = bias^2 + variance   (Eq. 4.3)
///   improvement % = 100 (before - after) / before       (Eqs. 4.10-4.11, for RMS and |bias|)
/// Coverage at k sigma = share of rows with |e_i| <= k sigma_i.

#include <array>
#include <cstddef>
#include <span>
#include <string>
#include <vector>

#include "tofkit/ranging/raw_measurement.hpp"

namespace tofkit::calib {

using ranging::kMaxMagnitude;

/// Throws std::invalid_argument naming the column and the data row (`index`
/// 0-based, printed 1-based) when a finite value exceeds kMaxMagnitude, or is
/// outside its column's physical range (distance_true_m and pulse_width_ns
/// in [0, 1e6], amplitude >= 0, temperature_c in [-273.15, 1e4]): checked
/// before any fit, so an impossible cell is named, not fitted.
void require_magnitude(double v, const char* column, std::size_t index);

struct ErrorStats {
  std::size_t rows = 0;                ///< finite errors counted
  double bias_m = ranging::kNaN;       ///< mean of true - measured
  double abs_bias_m = ranging::kNaN;   ///< |bias|
  double variance_m2 = ranging::kNaN;  ///< population variance
  double rms_m = ranging::kNaN;        ///< sqrt(bias^2 + variance)
  double max_abs_m = ranging::kNaN;    ///< largest |error|
};

/// Statistics of the finite entries of error_m (NaN fields when there are none).
[[nodiscard]] ErrorStats error_stats(std::span<const double> error_m);

/// 100 (before - after) / before; NaN when before is 0 or either is NaN.
[[nodiscard]] double improvement_pct(double before, double after);

/// Cross-validation fold (0 .. folds - 1) of truth group `group`: a fixed
/// hash of the group's number, not group % folds, so that folds do not follow
/// the structure of a measurement plan (groups numbered distance-major over a
/// grid would otherwise put whole diagonals of the grid into one fold).
/// Deterministic: the same group always lands in the same fold.
[[nodiscard]] std::size_t fold_of(std::size_t group, std::size_t folds);

/// Amplitude terciles: rows with amplitude < lower are tercile 0, >= upper tercile 2.
struct TercileEdges {
  double lower = ranging::kNaN;  ///< 1/3 quantile
  double upper = ranging::kNaN;  ///< 2/3 quantile
  [[nodiscard]] int tercile(double amplitude) const {
    return amplitude < lower ? 0 : (amplitude < upper ? 1 : 2);
  }
};

/// Edges at the 1/3 and 2/3 quantiles (linear interpolation) of the finite values.
[[nodiscard]] TercileEdges amplitude_terciles(std::span<const double> amplitude);

/// Share of |error| <= k sigma, overall and per amplitude tercile.
struct Coverage {
  double k_sigma = 1;
  std::size_t rows = 0;                       ///< rows with finite error and sigma
  double share = ranging::kNaN;               ///< in [0, 1]
  std::array<std::size_t, 3> tercile_rows{};  ///< low, middle, high amplitude
  std::array<double, 3> tercile_share{ranging::kNaN, ranging::kNaN, ranging::kNaN};
};

/// Rows with a non-finite error, sigma or amplitude are skipped (amplitude
/// only for the tercile shares). All spans the same length.
[[nodiscard]] Coverage coverage(std::span<const double> error_m, std::span<const double> sigma_m,
                                std::span<const double> amplitude, double k_sigma,
                                const TercileEdges& terciles);

/// Columns of a corrected table (all the same length; `key` may be empty).
struct EvaluationColumns {
  std::span<const double> truth_m;
  std::span<const double> distance_m;      ///< corrected
  std::span<const double> distance_raw_m;  ///< before correction
  std::span<const double> sigma_m;
  std::span<const double> amplitude;
  std::span<const double> key;  ///< group rows by equal values; empty: overall only
};

struct GroupEvaluation {
  double key = ranging::kNaN;          ///< NaN for the overall group
  std::size_t rows = 0;                ///< rows in the group
  std::size_t rows_without_range = 0;  ///< rows with a NaN corrected distance (not counted below)
  ErrorStats corrected;                ///< true - distance_m
  ErrorStats raw;                      ///< true - distance_raw_m, on the same rows
  double rms_improvement_pct = ranging::kNaN;
  double bias_improvement_pct = ranging::kNaN;  ///< of |bias|
  Coverage within_1_sigma;
  Coverage within_2_sigma;
};

struct Evaluation {
  TercileEdges terciles;  ///< amplitude terciles of all rows
  GroupEvaluation overall;
  std::vector<GroupEvaluation> groups;  ///< ascending key (empty without a key)
  [[nodiscard]] std::string summary() const;
};

/// Throws std::invalid_argument when the columns differ in length.
[[nodiscard]] Evaluation evaluate(const EvaluationColumns& columns);

}  // namespace tofkit::calib
