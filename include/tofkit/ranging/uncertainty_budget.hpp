#pragma once
/// \file An uncertainty budget (GUM, JCGM 100:2008): the standard
/// uncertainties of a corrected range, one per cause, each estimated from the
/// calibration step that observed it (type A) or from a stated specification
/// where no step did (type B), and their combination, Eq. (10) with
/// uncorrelated inputs: u_c^2 = sum_k u_k^2. Fitted by
/// calib::fit_uncertainty_budget; evaluated here, per row, at the row's
/// amplitude and time since calibration.

#include <cstddef>
#include <span>
#include <string>
#include <vector>

#include "tofkit/ranging/pipeline.hpp"
#include "tofkit/ranging/raw_measurement.hpp"

namespace tofkit::ranging {

/// Which rows a component applies to.
enum class BudgetScope {
  always,          ///< every row
  same_power_on,   ///< rows on the calibration's power-on (their time since calibration known)
  other_power_on,  ///< rows whose power-on (or time since calibration) is not the calibration's
};

/// One cause's standard uncertainty. Its value is a piecewise-linear curve of
/// u^2 over one axis (constant beyond the first and last node; one node: a
/// constant): ln(amplitude) for causes that follow the echo's strength, the
/// time since calibration (s) for drift, the row's temperature reading
/// (temperature_c, C) for the temperature model's residual, the share of the
/// row's shots the device lost (1 - shots_valid / shots) for echoes missed at
/// the threshold, the row's false-stop rate per metre of range
/// (false_stop_rate_per_m) for false stops before the echo, none for the rest.
struct BudgetComponent {
  enum class Axis {
    none,
    log_amplitude,
    time_since_calibration_s,
    temperature_c,
    lost_shot_share,
    false_stop_rate_per_m
  };
  std::string name;  ///< "repeatability", "correction residual", ...
  std::string step;  ///< the calibration step that gave it, or the specification key (type B)
  bool type_b = false;
  bool default_specification = false;  ///< type B from a default, not a value the user stated
  BudgetScope scope = BudgetScope::always;
  Axis axis = Axis::none;
  std::vector<double> node;         ///< ascending axis values (size 1 for Axis::none)
  std::vector<double> variance_m2;  ///< u^2 at each node (>= 0)

  /// u (m) at an axis value.
  [[nodiscard]] double u_m(double axis_value) const;
};

struct UncertaintyBudget {
  std::vector<BudgetComponent> components;
  /// Causes the calibration rows did not observe (their type B terms stand in).
  std::vector<std::string> unobserved;
  /// When the calibration rows were taken, s after power-on (the median of
  /// their raw CSV's time_s; NaN: unknown): a row's time_s less it is its time
  /// since calibration, on the calibration's power-on.
  double calibration_time_s = kNaN;
  /// Shots per measurement (the calibration rows' largest shots_valid; NaN:
  /// unknown): a row's lost share is 1 - shots_valid / shots. Needed by a
  /// lost_shot_share or false_stop_rate_per_m component only.
  double shots = kNaN;

  /// Throws std::invalid_argument naming the bad component and field.
  void validate() const;
  [[nodiscard]] bool empty() const { return components.empty(); }
  /// u of component k for a row (amplitude in the row's units; since_s NaN: the
  /// time since calibration is unknown, i.e. another power-on; temperature_c
  /// NaN: unknown, the temperature components' largest value; lost_share NaN:
  /// unknown, the lost-shot components' largest value; distance_m: the row's
  /// range, for its false-stop rate, NaN: unknown, that component's largest).
  [[nodiscard]] double component_u_m(std::size_t k, double amplitude, double since_s,
                                     double temperature_c = kNaN, double lost_share = kNaN,
                                     double distance_m = kNaN) const;
  /// Combined standard uncertainty of each row (GUM Eq. 10): since_s either
  /// one value for every row or one per row; NaN: unknown; temperature_c
  /// (the rows' temperature readings) empty or one per row; lost_share (1 -
  /// shots_valid / shots) and distance_m (the rows' ranges) each empty or one
  /// per row.
  void combined(std::span<const double> amplitude, std::span<const double> since_s,
                std::span<double> u_m, std::span<const double> temperature_c = {},
                std::span<const double> lost_share = {},
                std::span<const double> distance_m = {}) const;
  /// The budget as a table: component, value at each point, step, type, share
  /// of the combined variance at each point (amplitude, since_s, temperature_c;
  /// temperature_c empty: unknown) given.
  [[nodiscard]] std::string table(std::span<const double> amplitude,
                                  std::span<const double> since_s,
                                  std::span<const double> temperature_c = {}) const;
};

/// A row's share of lost shots, 1 - shots_valid / shots, within [0, 1]; NaN
/// when shots per measurement is unknown (not > 0).
[[nodiscard]] double lost_shot_share(double shots_valid, double shots);

/// False stops per metre of range of a row that lost lost_share of its shots
/// at distance_m: noise crossings arrive at a steady rate between the shot and
/// the echo (a Poisson process over the 2 d / c before it), so a shot escapes
/// them with probability exp(-rate d) and rate = -ln(1 - lost_share) / d. The
/// share lost grows with the range at one rate; the false stops the range
/// gate keeps just before the echo, and the bias they give, follow the rate
/// (0 when none was lost, at any d; NaN when either is unknown or d <= 0;
/// +inf when every shot was lost).
[[nodiscard]] double false_stop_rate_per_m(double lost_share, double distance_m);

/// Name of the component for rows below the calibrated amplitudes (the
/// correction extrapolated there); apply_budget counts it and the pipeline's
/// out-of-domain growth as one cause.
inline constexpr const char* kExtrapolationComponent =
    "extrapolation below the calibrated amplitudes";

/// Replaces each corrected range's sigma_m by the budget's combined standard
/// uncertainty at the row's amplitude, temperature reading, lost share of
/// shots (with budget.shots) and time since calibration (since_s: one
/// value for every row or one per row; NaN: unknown, another power-on), plus
/// the variance the pipeline adds where a row lies outside a step's domain
/// (its sigma^2 there less its in-domain sigma^2; where the budget has an
/// extrapolation term, only what exceeds that term's u^2). Rows without an echo keep NaN.
void apply_budget(const UncertaintyBudget& budget, const Pipeline& pipeline, const RawColumns& in,
                  std::span<const double> since_s, std::span<Range> out);

}  // namespace tofkit::ranging
