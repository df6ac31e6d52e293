#pragma once
/// \file A physical model of range walk: the crossing times of a parameterized
/// echo shape through a fixed comparator threshold (time over threshold,
/// DESIGN.md "Discriminator").
///
/// An echo A p(t) (p: peak 1) crosses the threshold V where p = V / A, at
/// t_rise(a) and t_fall(a) with a = A / V > 1. The comparator's time over
/// threshold (the echo pulse width the device reports) is
///
///   w(a) = t_fall(a) - t_rise(a) + tau_r ln(a / a_sat)   (the last term when a > a_sat)
///
/// where an amplifier overdriven above a_sat stays clipped about tau_r per
/// e-fold of overdrive longer (charge storage); the rising crossing is unchanged
/// by the clipping. The range walk is the late arrival of the rising crossing,
/// so the correction (true - measured) is -(c_air / 2) (t_rise(a) - t_rise(a_ref)).
///
/// p is a Gaussian laser pulse (standard deviation sigma) through a receiver of
/// two equal real poles (time constant tau each): smooth, asymmetric (fast
/// rise, exponential tail), two numbers. Because w(a) is monotone in a, the
/// walk is tabulated once as a function of w over a wide range of a (to
/// a = e^kMaxLogOverdrive), so a measured width maps to its walk without
/// knowing A: the walk then holds for echoes weaker and stronger than those the
/// parameters were fitted on.

#include <cstddef>
#include <limits>
#include <memory>
#include <span>
#include <string>
#include <vector>

namespace tofkit::ranging {

/// The fitted numbers of the echo shape (all times in ns).
struct WalkShape {
  double pulse_sigma_ns = 0.5;         ///< Gaussian laser pulse's standard deviation
  double pole_time_constant_ns = 1.0;  ///< each of the receiver's two equal poles
  /// ln(a_sat) = ln(V_sat / V): overdrive at which the amplifier clips;
  /// +infinity when the calibration saw no clipped echo (no recovery term).
  double saturation_log_overdrive = std::numeric_limits<double>::infinity();
  double recovery_ns_per_neper = 0;  ///< extra clipped time per e-fold above a_sat

  /// Throws std::invalid_argument naming the bad field.
  void validate() const;
};

/// Crossing times of the shape, parametric in ln a (ascending).
struct WalkCurve {
  std::vector<double> log_overdrive;  ///< ln a, ascending
  std::vector<double> width_ns;       ///< w(a), strictly ascending
  std::vector<double> rise_ns;        ///< t_rise(a) (descending: stronger echoes cross earlier)
};

/// Largest ln a tabulated (a = 1.6e5: far beyond any unclipped echo).
inline constexpr double kMaxLogOverdrive = 12.0;

/// The shape's crossings for ln a in (0, kMaxLogOverdrive]. Throws
/// std::invalid_argument for an invalid shape.
[[nodiscard]] WalkCurve walk_curve(const WalkShape& shape, std::size_t levels = 1500);

/// A column of the curve (rise_ns, log_overdrive) at a measured width, by
/// linear interpolation (beyond its first and last widths: the end segments
/// continued).
[[nodiscard]] double curve_at_width(const WalkCurve& curve, const std::vector<double>& column,
                                    double width_ns);

/// Rising-crossing time at a measured width: curve_at_width of rise_ns, but
/// below the first width its first rise.
[[nodiscard]] inline double rise_at_width(const WalkCurve& curve, double width_ns) {
  return width_ns <= curve.width_ns.front() ? curve.rise_ns.front()
                                            : curve_at_width(curve, curve.rise_ns, width_ns);
}

/// The shape's parameters as the fit estimates them (all free of sign
/// constraints): ln pulse_sigma_ns, ln pole_time_constant_ns and, with clipping,
/// ln recovery_ns_per_neper and saturation_log_overdrive (already a log).
[[nodiscard]] std::vector<double> walk_parameters(const WalkShape& shape);
/// The inverse of walk_parameters (2 or 4 values).
[[nodiscard]] WalkShape walk_shape_of(std::span<const double> parameters);

/// Most replicates a walk step holds (each is a tabulated walk of its own).
inline constexpr std::size_t kMaxWalkReplicates = 1024;

/// Replicates standing for a parameter covariance (row-major k x k over
/// walk_parameters(shape), as older model files hold it): the 2k points
/// q +- sqrt(k lambda_a) v_a along its principal axes, whose mean squared
/// deviation is the covariance itself (an axis whose full step leaves the
/// shapes the walk can tabulate is taken at the largest half, quarter, ...
/// step that stays inside). Throws std::invalid_argument naming the problem
/// (wrong size, not finite, not symmetric, not positive semi-definite).
[[nodiscard]] std::vector<WalkShape> walk_sigma_points(const WalkShape& shape,
                                                       std::span<const double> covariance);

/// The walk tabulated on a uniform grid in pulse width, ready to apply.
class WalkModel {
 public:
  /// `reference_pulse_width_ns`: the width at which the walk correction is zero
  /// (the constant lives in the offset step). `replicates`: optional, shapes
  /// fitted on resampled data (calib::fit_walk's bootstrap), whose scatter
  /// about `shape` makes the walk's own uncertainty at any width known
  /// (relative_rise_variance_ns2). Throws std::invalid_argument naming the bad
  /// field (an invalid shape or replicate, more than kMaxWalkReplicates).
  WalkModel(WalkShape shape, double reference_pulse_width_ns,
            std::vector<WalkShape> replicates = {});

  [[nodiscard]] const WalkShape& shape() const { return shape_; }
  [[nodiscard]] double reference_pulse_width_ns() const { return reference_ns_; }
  /// Largest width the table holds from the curve (beyond: last slope).
  [[nodiscard]] double table_max_width_ns() const { return width_max_ns_; }

  /// t_rise(w) - t_rise(w_ref) in ns (multiply by -c_air / 2 for the correction).
  [[nodiscard]] double relative_rise_ns(double width_ns) const;
  /// rise_ns[i] = relative_rise_ns(width_ns[i]); NaN in, NaN out.
  void relative_rise_ns(const double* width_ns, double* rise_ns, std::size_t n) const;

  [[nodiscard]] const std::vector<WalkShape>& replicates() const { return replicates_; }
  [[nodiscard]] bool has_replicates() const { return !replicates_.empty(); }
  /// Variance (ns^2) of relative_rise_ns(width): the mean squared difference
  /// of the replicates' walks from this one's, (1/R) sum_r (rise_r(w) -
  /// rise(w))^2. It follows the fit's real scatter where the shape's
  /// parameters trade off along a curved valley (clipping onset against
  /// recovery), where a linearized (Gauss-Newton) covariance overstates the
  /// extrapolation's spread many times. 0 without replicates.
  [[nodiscard]] double relative_rise_variance_ns2(double width_ns) const;

  /// One line: the shape's numbers.
  [[nodiscard]] std::string summary() const;

 private:
  WalkShape shape_;
  double reference_ns_ = 0;
  double width_max_ns_ = 0;
  double inv_step_ = 0;
  double step_ = 0;
  double slope_above_ = 0;    ///< d rise / d w beyond the last node
  std::vector<double> rise_;  ///< relative rise at width k * step_
  std::vector<WalkShape> replicates_;
  std::vector<std::shared_ptr<const WalkModel>> replicate_models_;
};

}  // namespace tofkit::ranging
