#pragma once
/// \file Fitting the paper's correction chain (Section 5) from measurements of
/// known distance:
///
///   e = truth.distance_m - c_air tof / 2 = offset + g(pulse_width_ns) + h(temperature_c)
///
/// with g and h hinge functions (calib/hinge_fit.hpp) that are zero at
/// reference points (medians of the data unless given), so the constant lives
/// in `offset`. Without an offset step the constant goes to the first hinge.
///
/// Method: backfitting, then one joint solve. The knots of g and h are found
/// by the 1-D hinge fitter (knot search, BIC, robust weights), which needs a
/// 1-D problem: backfitting alternates fitting g on e - h and h on e - g until
/// the fitted values change by less than `backfit_tolerance_m`. Backfitting
/// converges slowly when pulse width and temperature are correlated, so once
/// the knots are known all linear coefficients are refitted together on one
/// design matrix [1, hinge basis of g, hinge basis of h] by robust least
/// squares (QR), which is the exact joint optimum for those knots. Knots are
/// re-searched on the partial residuals of that joint solve until they settle.
/// The joint solve uses the least aggressive robust loss of the hinges fitted
/// (none < Huber < bisquare).

#include <cstddef>
#include <optional>
#include <span>
#include <stdexcept>
#include <string>
#include <string_view>
#include <utility>

#include "tofkit/calib/hinge_fit.hpp"
#include "tofkit/calib/statistics.hpp"
#include "tofkit/calib/walk_fit.hpp"
#include "tofkit/ranging/pipeline.hpp"
#include "tofkit/ranging/raw_measurement.hpp"

namespace tofkit::calib {

/// Which steps of the chain to fit (any non-empty subset).
struct ChainSteps {
  bool offset = true;
  bool grayvalue = true;
  bool temperature = true;
  /// The physical walk model (calib/walk_fit.hpp) in place of the grayvalue
  /// hinge: same input (pulse width), extrapolates beyond the plates' widths.
  bool walk = false;
};

/// "offset,grayvalue,temperature" (any subset, any order; "walk" instead of
/// "grayvalue"). Throws std::invalid_argument naming an unknown or repeated
/// step, both grayvalue and walk, or an empty list.
[[nodiscard]] ChainSteps parse_chain_steps(std::string_view list);
[[nodiscard]] std::string to_string(const ChainSteps& steps);

struct ChainFitOptions {
  ChainSteps steps;
  ranging::TimeToDistance time_to_distance;
  HingeFitOptions grayvalue;                        ///< column / unit are set by fit_chain
  HingeFitOptions temperature;                      ///< column / unit are set by fit_chain
  double reference_pulse_width_ns = ranging::kNaN;  ///< g(ref) = 0; NaN: median pulse width
  double reference_temperature_c = ranging::kNaN;   ///< h(ref) = 0; NaN: median temperature
  int max_backfit_iterations = 30;
  double backfit_tolerance_m = 1e-6;  ///< stop when no fitted value changes more than this
  /// Knots are searched on at most this many rows (every k-th usable row);
  /// the coefficients are then refitted on all rows. Keeps the fit linear in
  /// rows: the knot search (many robust 1-D fits) no longer grows with them.
  std::size_t knot_search_rows = 50000;
  /// Walk step: the shape every backfitting pass's walk fit starts from,
  /// refined from there only (no multistart search). For refits of nearly the
  /// same data (e.g. cross-fitting folds, started from the full fit's shape),
  /// where the search for the right valley is already done. nullopt: searched.
  std::optional<ranging::WalkShape> walk_initial;
  /// Walk step: bootstrap replicates of the final shape (WalkFitOptions::
  /// replicates), which give a flagged row's sigma the walk's own uncertainty
  /// beyond the fitted widths. 0: none (refits whose sigma is not used).
  std::size_t walk_replicates = 32;
};

struct ChainFitResult {
  ranging::Pipeline pipeline;  ///< offset, grayvalue, temperature steps (those selected)
  double offset_m = 0;
  std::optional<HingeFitResult> grayvalue;  ///< knots, BIC, domain from the 1-D fits
  std::optional<HingeFitResult> temperature;
  std::optional<WalkFitResult> walk;  ///< the walk step's shape (steps.walk)
  std::size_t rows = 0;               ///< rows fitted
  std::size_t rows_skipped = 0;       ///< no echo, or a non-finite value the fit needs
  std::size_t rows_downweighted = 0;  ///< final robust weight below 0.5
  std::size_t knot_search_rows = 0;   ///< rows the knots were searched on (<= rows)
  ErrorStats before;                  ///< of e = truth - c_air tof / 2
  ErrorStats after;                   ///< of truth - corrected distance
  int backfit_iterations = 0;
  bool converged = false;
  [[nodiscard]] std::string summary() const;
};

/// Thrown by fit_chain when a step that models a column has rows from one
/// truth target only, so the column spreads by its noise alone and the step
/// would model noise: grayvalue or walk (pulse_width_ns) when every usable row
/// is one (distance_true_m, reflectance, angle_deg) target; temperature
/// (temperature_c) when every usable row is at one ambient_c. A caller that
/// can do without the step refits without it (the demo does).
class ChainStepRefused : public std::invalid_argument {
 public:
  ChainStepRefused(const std::string& message, const ChainSteps& step, std::string column)
      : std::invalid_argument(message), step_(step), column_(std::move(column)) {}
  /// The refused step alone (one flag set).
  [[nodiscard]] const ChainSteps& step() const noexcept { return step_; }
  /// The column the step models: pulse_width_ns or temperature_c.
  [[nodiscard]] const std::string& column() const noexcept { return column_; }

 private:
  ChainSteps step_;
  std::string column_;
};

/// With a walk step, backfitting alternates the walk's nonlinear fit on e - h
/// with the joint linear solve of [1, h basis] on e - walk.
///
/// Rows need an echo, a finite truth.distance_m and start distance, and (for
/// the steps fitted) a finite pulse width / temperature. Throws
/// std::invalid_argument naming the problem and the column: fewer than 10
/// usable rows (or fewer than parameters), no spread in pulse_width_ns for a
/// grayvalue step, no spread in temperature_c for a temperature step. Throws
/// ChainStepRefused (an std::invalid_argument) when the column spreads but
/// only within one truth target: a grayvalue or walk step whose usable rows
/// are all one (distance_true_m, reflectance, angle_deg) target, a temperature
/// step whose usable rows are all at one ambient_c. Only filled-in truth
/// refuses: rows with reflectance, angle_deg or ambient_c empty (field data)
/// may be different plates or conditions and are fitted. Rows flagged
/// warming-up exempt the temperature step: self-heating moves the reading at
/// one ambient.
[[nodiscard]] ChainFitResult fit_chain(std::span<const ranging::Record> records,
                                       const ChainFitOptions& options = {});

}  // namespace tofkit::calib
