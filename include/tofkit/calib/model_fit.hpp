#pragma once
/// \file One fit of a whole ranging model, shared by `tofkit fit` and the
/// Python fitters: the paper's chain, a correction surface on its residual
/// (or alone), and a confidence model fitted on residuals the correction
/// never saw (out-of-fold over whole truth groups, or a held-out share of
/// the groups).

#include <cstddef>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "tofkit/calib/chain_fit.hpp"
#include "tofkit/calib/confidence_model.hpp"
#include "tofkit/calib/statistics.hpp"
#include "tofkit/calib/surface_fit.hpp"
#include "tofkit/ranging/pipeline.hpp"
#include "tofkit/ranging/raw_measurement.hpp"
#include "tofkit/ranging/uncertainty_budget.hpp"

namespace tofkit::calib {

enum class SurfaceKind { none, polynomial, bspline };

struct SurfaceSpec {
  SurfaceKind kind = SurfaceKind::none;
  int order = 0;  ///< polynomial: total degree (1..12)
};

/// "poly:N" (N = 1..12) or "bspline". Throws std::invalid_argument
/// ("expected poly:N (N = 1..12) or bspline"); the caller names the option.
[[nodiscard]] SurfaceSpec parse_surface_spec(std::string_view spec);
[[nodiscard]] std::string to_string(const SurfaceSpec& spec);

/// calibrated: fitted on out-of-fold residuals, coverage calibrated per band;
/// thesis: the thesis's cubic; noise_systematic: noise of one row from the
/// repeats' scatter plus the correction's systematic error from the targets'
/// mean residuals, each times its pointwise optimism (1 + h) / (1 - h) from
/// the target's leverage h (one refit per target; above 500 targets one
/// optimism (G + p) / (G - p) for all), on the correction's own intensity
/// axis (fit_noise_systematic_confidence).
enum class ConfidenceKind { none, calibrated, thesis, noise_systematic };

/// A B-spline surface's intensity axis: the amplitude (log scale), the pulse
/// width, or (choose) the one with the lower grouped cross-validated RMS.
enum class SurfaceIntensity { choose, amplitude, pulse_width };

/// "auto", "amplitude" or "pulse-width"; throws std::invalid_argument otherwise.
[[nodiscard]] SurfaceIntensity parse_surface_intensity(std::string_view text);

/// "none", "calibrated", "thesis" or "noise-systematic"; throws std::invalid_argument otherwise.
[[nodiscard]] ConfidenceKind parse_confidence_kind(std::string_view kind);
[[nodiscard]] std::string to_string(ConfidenceKind kind);

/// B-spline options with knots and smoothing chosen by cross-validation.
[[nodiscard]] inline BSplineFitOptions auto_bspline_options() {
  BSplineFitOptions b;
  b.choose_intervals_by_gcv = true;
  b.choose_smoothing_by_gcv = true;
  return b;
}

/// The extrapolation refits: refit k = 1..kExtrapolationRefits leaves out
/// the truth groups whose mean ln amplitude lies below the weakest group's
/// plus kExtrapolationSpan k / kExtrapolationRefits e-folds.
inline constexpr double kExtrapolationSpan = 1.0;
inline constexpr std::size_t kExtrapolationRefits = 4;

struct ModelFitOptions {
  ranging::TimeToDistance time_to_distance;
  /// The chain's steps; nullopt: no chain.
  std::optional<ChainSteps> chain;
  /// Chain fit settings (steps and time_to_distance are set from the fields above).
  ChainFitOptions chain_options;
  /// After the chain, refine its grayvalue step by a dense penalized
  /// piecewise-linear correction in pulse width: nodes at quantiles of the
  /// pulse widths, a second-difference penalty, the node count and the
  /// smoothing chosen by 5-fold cross-validation over whole truth groups (no
  /// refinement when it does not lower the cross-validated error). The
  /// hinge's few knots cannot follow a walk curve that bends everywhere.
  bool refine_walk = false;
  /// > 0: the TDC's coarse clock period (1e3 / tdc.coarse_clock_mhz). With the
  /// laser fired on the clock, the interpolator's residual nonlinearity leaves
  /// an error periodic in each stop's time; a periodic step at both stops
  /// (Fourier series modulo the period, 0-16 harmonics chosen by grouped
  /// cross-validation, correcting tof_ns and pulse_width_ns) is fitted in
  /// front of the chain / surface by backfitting, on the rows that kept 98 %
  /// of the most shots any row kept.
  /// Needs targets whose stops cover the period's phases (a rail). 0: none.
  double tdc_period_ns = 0;
  /// Start from this already fitted pipeline instead of fitting a chain (the
  /// surface then fits its residual); exclusive with `chain`. It stays fixed
  /// in every cross-fitting fold.
  std::optional<ranging::Pipeline> base;
  SurfaceSpec surface;
  bool surface_temperature = false;  ///< the surface gets a temperature axis
  /// B-spline only (a polynomial surface reads the amplitude).
  SurfaceIntensity surface_intensity = SurfaceIntensity::choose;
  PolynomialFitOptions polynomial;  ///< order and use_temperature are set from above
  /// B-spline settings; by default knots and smoothing are chosen by
  /// cross-validation over whole truth groups. use_temperature is set from above.
  BSplineFitOptions bspline = auto_bspline_options();
  ConfidenceKind confidence = ConfidenceKind::calibrated;
  CalibratedConfidenceOptions calibrated_confidence;  ///< settings of the calibrated kind
  /// false: when cross-fitting is impossible (too few truth groups) the model
  /// gets no confidence model (sigma = residual RMS) and the report says why;
  /// true: that is an error.
  bool confidence_required = false;
  int confidence_folds = 5;  ///< cross-fitting folds of whole truth groups (at most one per group)
  /// > 0: instead of cross-fitting, every round(1 / fraction)-th truth group
  /// is held out of the correction fit and used for the confidence fit.
  double confidence_hold_out_fraction = 0;
  /// With cross-fitting: refits without the weakest truth groups
  /// (kExtrapolationSpan, kExtrapolationRefits), whose errors on them are how
  /// this correction errs where it extrapolates below its data
  /// (ModelFitResult::extrapolation; the uncertainty budget's extrapolation
  /// term is sized from them). They run beside the folds.
  bool extrapolation_refit = false;

  /// Throws std::invalid_argument naming the bad field.
  void validate() const;
};

/// What the fit did, for the model file's "fit" object (io::fit_summary_json).
struct ModelFitSummary {
  std::size_t rows = 0;      ///< records given
  std::size_t rows_fit = 0;  ///< records the correction was fitted on
  std::optional<ChainFitResult> chain;
  std::string chain_steps;  ///< to_string of the steps (when a chain was fitted)
  /// refine_walk: the nodes chosen (0: no refinement), the smoothing, and the
  /// cross-validated RMS with and without it.
  struct WalkRefinement {
    int nodes = 0;
    double smoothing = 0;
    double cv_rms_m = 0;
    double cv_rms_without_m = 0;
    double effective_parameters = 0;  ///< trace of the refinement's hat matrix
  };
  std::optional<WalkRefinement> walk;
  /// tdc_period_ns: harmonics chosen (0: none) and the cross-validated RMS
  /// with them and without a periodic step.
  struct Periodic {
    int harmonics = 0;
    bool temperature_slope = false;  ///< the coefficients move with the temperature reading
    double cv_rms_m = 0;
    double cv_rms_without_m = 0;
  };
  std::optional<Periodic> periodic;
  std::optional<SurfaceFitResult> surface;
  std::string surface_spec;
  bool surface_temperature = false;
  std::string surface_intensity;      ///< "amplitude" or "pulse_width_ns": what the surface reads
  double surface_cv_rms_other_m = 0;  ///< choose: the other axis's cross-validated RMS (0: none)
  ErrorStats surface_error_before;    ///< of the error the surface was fitted to
  struct Confidence {
    ConfidenceKind kind = ConfidenceKind::none;
    std::size_t rows = 0;      ///< residuals the confidence was fitted on
    std::size_t groups = 0;    ///< truth groups of the data
    int folds = 0;             ///< cross-fitting folds (0: hold-out)
    long every_kth_group = 0;  ///< hold-out: every k-th group (0: cross-fitting)
    ErrorStats held_out;       ///< of the out-of-fold / held-out residuals
    /// noise_systematic: the correction's effective parameters p, the sum of
    /// the targets' leverages h (measured by refits; about p; 0: not measured,
    /// more than 500 targets), and the mean
    /// and largest pointwise optimism (1 + h) / (1 - h) applied to the targets'
    /// systematic errors.
    double effective_parameters = 0;
    double leverage_sum = 0;
    double optimism = 0;
    double optimism_max = 0;
  };
  std::optional<Confidence> confidence;
  double residual_rms_m = 0;
  /// Distances the calibration rows' truths stand at (calib::distinct_distances).
  /// One: neither the correction nor its sigma can see errors that change with
  /// range (the report says so).
  int distances = 0;
};

struct ModelFitResult {
  ranging::Pipeline pipeline;
  ModelFitSummary summary;
  std::string report;  ///< the fitters' summaries and the confidence line
  /// Per record, its cross-validated residual (true - corrected by a fit
  /// without its fold; NaN where the fold's correction extrapolates or no
  /// echo); empty without cross-fitting. The uncertainty budget's input.
  std::vector<double> out_of_fold_m;
  /// ModelFitOptions::extrapolation_refit: the refits without the weakest
  /// truth groups (kExtrapolationSpan, kExtrapolationRefits); empty when not
  /// asked for or impossible (the report says why).
  struct ExtrapolationRefit {
    /// Per record: true - corrected by the refit, for the rows of the groups
    /// it left out (NaN elsewhere and without an echo).
    std::vector<double> residual_m;
    /// The refit's weakest group's mean ln amplitude: the edge it extrapolated from.
    double edge_log_amplitude = ranging::kNaN;
    std::size_t groups_left_out = 0;
  };
  std::vector<ExtrapolationRefit> extrapolation;
  /// The uncertainty budget (calib::fit_model_budget), where the caller fitted
  /// one (experiments::factory_calibration does); empty from fit_model.
  ranging::UncertaintyBudget budget;
};

/// Fits the model. Throws std::invalid_argument naming the problem (too few
/// rows or groups, an axis without spread, a bad option).
[[nodiscard]] ModelFitResult fit_model(std::span<const ranging::Record> records,
                                       const ModelFitOptions& options);

}  // namespace tofkit::calib
