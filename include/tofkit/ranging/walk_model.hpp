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

/// Rising-crossing time at a measured width, by linear interpolation of the
/// curve (below its first width: its first rise; above its last: continued with
/// the last segment's slope).
[[nodiscard]] double rise_at_width(const WalkCurve& curve, double width_ns);

/// The shape's parameters as the fit estimates them (all free of sign
/// constraints): ln pulse_sigma_ns, ln pole_time_constant_ns and, with clipping,
/// ln recovery_ns_per_neper and saturation_log_overdrive (already a log).
[[nodiscard]] std::vector<double> walk_parameters(const WalkShape& shape);
/// The inverse of walk_parameters (2 or 4 values).
[[nodiscard]] WalkShape walk_shape_of(std::span<const double> parameters);

/// The walk tabulated on a uniform grid in pulse width, ready to apply.
class WalkModel {
 public:
  /// `reference_pulse_width_ns`: the width at which the walk correction is zero
  /// (the constant lives in the offset step). `covariance`: optional,
  /// row-major k x k over walk_parameters(shape) (k = 2, or 4 with clipping):
  /// the fit's parameter covariance, which makes the walk's own uncertainty at
  /// any width known (relative_rise_variance_ns2). Throws
  /// std::invalid_argument naming the bad field (wrong size, not finite, not
  /// symmetric, not positive semi-definite).
  WalkModel(WalkShape shape, double reference_pulse_width_ns, std::vector<double> covariance = {});

  [[nodiscard]] const WalkShape& shape() const { return shape_; }
  [[nodiscard]] double reference_pulse_width_ns() const { return reference_ns_; }
  /// Largest width the table holds from the curve (beyond: last slope).
  [[nodiscard]] double table_max_width_ns() const { return width_max_ns_; }

  /// t_rise(w) - t_rise(w_ref) in ns (multiply by -c_air / 2 for the correction).
  [[nodiscard]] double relative_rise_ns(double width_ns) const;
  /// rise_ns[i] = relative_rise_ns(width_ns[i]); NaN in, NaN out.
  void relative_rise_ns(const double* width_ns, double* rise_ns, std::size_t n) const;

  [[nodiscard]] const std::vector<double>& covariance() const { return covariance_; }
  [[nodiscard]] bool has_covariance() const { return !covariance_.empty(); }
  /// Variance (ns^2) of relative_rise_ns(width) from the parameters'
  /// covariance, propagated to first order (delta method) along the
  /// covariance's principal axes by central differences of the tabulated
  /// walk: sum_k ((rise_k+(w) - rise_k-(w)) / 2)^2, the shapes at +-1 standard
  /// deviation along axis k. 0 without a covariance.
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
  std::vector<double> covariance_;
  /// Per principal axis with a non-zero variance: the walks at +-1 standard
  /// deviation along it, and 1 / the fraction of it they were taken at (a
  /// full step may leave the shape's valid range).
  struct Axis {
    std::shared_ptr<const WalkModel> plus, minus;
    double scale = 1;
  };
  std::vector<Axis> axes_;
};

}  // namespace tofkit::ranging
