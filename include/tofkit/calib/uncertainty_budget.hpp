#pragma once
/// \file Fitting an uncertainty budget (ranging/uncertainty_budget.hpp) from
/// the steps of a calibration protocol (calib/calibration_plan.hpp): each
/// component from the step that observes it (type A), or, where no step
/// did, from a stated specification (type B, GUM 4.3) with the cause named
/// as unobserved.
///
/// - repeatability (type A): the scatter of each target's repeats, pooled in
///   bins of echo amplitude (its noise falls as the echo grows);
/// - periodic residual (type A): the part of the targets' cross-validated mean
///   residuals periodic in the time of flight with the TDC's coarse period
///   (harmonics 1-3, less the fit's own noise), when the targets' distances
///   span a period; else type B from tdc_inl_ps;
/// - correction residual (type A): the targets' cross-validated mean
///   residual at the reference temperature, less the periodic part and the
///   noise of a mean, per amplitude bin, each surface (reflectance, angle)
///   weighted alike;
/// - extrapolation below the calibrated amplitudes (type A size, type B
///   form): 0 at and above the weakest target's amplitude; below it a walk
///   ~ 1 / peak departing from its tangent, C (e^delta - 1 - delta), delta
///   e-folds below, C measured by refits without the weakest targets (their
///   errors on them), or else the weakest targets' raw curvature (looser;
///   apply_budget counts it and the pipeline's out-of-domain growth as one
///   cause);
/// - temperature model residual (type A): the temperature run's in-sample
///   mean residuals against the same target at the reference temperature, plus
///   the optimism of the temperature step's fit (additive in the noise), as a function of the row's
///   temperature reading (none at the calibration's); else type B from
///   delay_tempco_ps_per_c (u = tempco x |T - T_ref|);
/// - drift since calibration (type A): the structure function of a stability
///   record (a static target over time), D(tau) = E[(y(t + tau) - y(t))^2]
///   less its rows' noise and a row's repeatability (drift_structure_function):
///   the variance a row tau after the calibration adds; else type B from
///   drift_ps;
/// - power-on reproducibility (type A): the mean residual of repeats on other
///   power-ons; else type B from power_on_ps.

#include <span>
#include <string>
#include <vector>

#include "tofkit/calib/model_fit.hpp"
#include "tofkit/ranging/pipeline.hpp"
#include "tofkit/ranging/raw_measurement.hpp"
#include "tofkit/ranging/uncertainty_budget.hpp"

namespace tofkit::calib {

/// Type B inputs: specifications the user states from a datasheet; each
/// `*_given` false means the default stands (the fit summary warns).
struct BudgetSpecification {
  double tdc_inl_ps = 20.0;  ///< peak integral nonlinearity of the TDC's interpolator
  bool tdc_inl_given = false;
  double delay_tempco_ps_per_c = 2.0;  ///< residual delay tempco after the temperature step
  bool delay_tempco_given = false;
  /// How much the delay's tempco differs between weak and strong echoes
  /// (the APD's gain, hence the walk, follows temperature): used when the
  /// temperature run had one plate.
  double walk_tempco_ps_per_c = 5.0;
  bool walk_tempco_given = false;
  double temperature_half_range_c = 15.0;  ///< field temperatures' half range around calibration
  double drift_ps = 15.0;                  ///< delay drift within a power-on (1 sigma)
  bool drift_given = false;
  double power_on_ps = 15.0;  ///< delay offset between power-ons (1 sigma)
  bool power_on_given = false;
  /// Throws std::invalid_argument naming the bad field.
  void validate() const;
  /// "key=value" (tdc_inl_ps, delay_tempco_ps_per_c, walk_tempco_ps_per_c,
  /// temperature_half_range_c, drift_ps, power_on_ps); throws std::invalid_argument naming the key.
  void set(const std::string& assignment);
};

struct BudgetFitData {
  std::span<const ranging::Record> rows;  ///< calibration rows (the correction's)
  /// Per row: the cross-validated (out-of-fold) residual, true - corrected
  /// (NaN: none), and the in-sample residual of the final correction.
  std::span<const double> out_of_fold_m;
  std::span<const double> residual_m;
  /// Refits without the weakest targets (ModelFitResult::extrapolation: per
  /// row its residual, NaN for the targets it kept; its edge). Empty: the
  /// extrapolation term is sized from the weakest targets' raw curvature.
  std::span<const ModelFitResult::ExtrapolationRefit> extrapolation;
  double tdc_period_ns = 0;  ///< coarse clock period; 0: unknown (periodic term type B)
  /// Parameters of the correction's temperature dependence (a hinge: its
  /// slopes), for the temperature residual's optimism.
  double temperature_parameters = 2;
  double metres_per_ns = 0.149896229;
  /// Stability record: rows of one static target in time order, every_s apart,
  /// corrected by the final pipeline (empty: none).
  std::span<const ranging::Record> stability;
  std::span<const double> stability_residual_m;
  double stability_every_s = 0;
  /// Repeats on other power-ons: the final pipeline's residuals of each run
  /// (fit_model_budget: less the calibration's mean residual at the same
  /// target, so that only what the power-on moved remains).
  std::vector<std::vector<double>> power_on_residual_m;
  std::vector<std::vector<double>> power_on_amplitude;
};

struct BudgetFitResult {
  ranging::UncertaintyBudget budget;
  std::string report;  ///< how each component was estimated; warnings for default specifications
};

/// The drift term's curve from a stability record (residuals of one static
/// target in time order, every_s apart): at lags from one step to 3/4 of the
/// record (steps x 1.3), the structure function D(tau) = mean (y(t + tau) -
/// y(t))^2 less the record's own row noise (half D's intercept at lag 0,
/// 2 D(step) - D(2 steps)) and a row's repeatability (row_noise2_m2), made
/// non-decreasing by pooling adjacent violators (pairs as weights), floored
/// at 0. Empty with fewer than 2 rows.
struct DriftCurve {
  std::vector<double> lag_s, variance_m2;
};
[[nodiscard]] DriftCurve drift_structure_function(std::span<const double> residual_m,
                                                  double every_s, double row_noise2_m2);

/// Throws std::invalid_argument when the rows have no repeats (>= 3 targets
/// with two or more rows are needed for the repeatability).
[[nodiscard]] BudgetFitResult fit_uncertainty_budget(const BudgetFitData& data,
                                                     const BudgetSpecification& specification);

/// The protocol's other steps, beside the correction's calibration rows.
struct ProtocolSteps {
  std::span<const ranging::Record> stability;  ///< static target, rows every_s apart in order
  double stability_every_s = 0;
  std::vector<std::vector<ranging::Record>> power_on_runs;  ///< repeats on other power-ons
  double tdc_period_ns = 0;  ///< the TDC's coarse period (0: unknown)
};

/// The budget of a fitted model (fit_model's result, with its out-of-fold
/// residuals: the confidence kind must cross-fit) from its calibration rows
/// and the protocol's other steps; the result's report ends with the
/// certificate (budget_certificate).
[[nodiscard]] BudgetFitResult fit_model_budget(std::span<const ranging::Record> calibration,
                                               const ModelFitResult& fit,
                                               const ProtocolSteps& steps,
                                               const BudgetSpecification& specification);

/// The calibration certificate: the budget table at a weak, a middle and a
/// strong echo of the calibration (10th, 50th, 90th percentile amplitude) right
/// after the calibration, the middle one an hour after and on another power-on,
/// then the coverage check on the cross-validated rows and the power-on repeats.
[[nodiscard]] std::string budget_certificate(const ranging::UncertaintyBudget& budget,
                                             std::span<const ranging::Record> calibration,
                                             const ModelFitResult& fit, const ProtocolSteps& steps);

/// The coverage check of a certificate: the share of errors within 1 and 2
/// combined standard uncertainties.
struct BudgetCoverage {
  std::size_t rows = 0;
  double within_1sigma = 0, within_2sigma = 0;
};
[[nodiscard]] BudgetCoverage budget_coverage(std::span<const double> error_m,
                                             std::span<const double> sigma_m);

}  // namespace tofkit::calib
