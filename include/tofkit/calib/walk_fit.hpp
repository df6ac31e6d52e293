#pragma once
/// \file Fitting the physical walk model (ranging/walk_model.hpp) to range
/// errors over echo pulse width, by nonlinear least squares
/// (Levenberg-Marquardt, finite-difference Jacobian):
///
///   e_i = constant - (c_air / 2) (t_rise(w_i) - t_rise(w_ref))
///
/// over the shape's pulse sigma and pole time constant (log-parameterized, so
/// they stay positive), and, when the rows include clipped echoes (raw flag
/// kRawSaturated), the recovery time per e-fold of overdrive and the clipping
/// onset, fitted as the pulse width where clipping starts, kept by the flags
/// between the widest unclipped and the narrowest clipped echo (and turned into
/// ln(V_sat / V) by the shape). Without
/// clipped rows neither is observable: the shape then has no recovery term. Only the data are used
/// (no device configuration): the shape is what makes the walk of weaker and stronger echoes than
/// the calibration's predictable.
///
/// Widths alone leave sigma and tau trading off (shapes of 2x the device's
/// sigma fit the plates' widths as well, and read echoes much weaker than the
/// plates mm off). With the rows' amplitude readings (the peak detector, linear
/// in the echo below the clip, so ln A = ln a + const on unclipped rows) a
/// second block of residuals asks the shape's ln a at each unclipped row's
/// width to follow ln A up to one profiled-out constant; the two blocks are
/// weighted by their own variances (profile likelihood, iteratively
/// reweighted). The clipping onset stays free between the widths either way.

#include <cstddef>
#include <cstdint>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "tofkit/ranging/walk_model.hpp"

namespace tofkit::calib {

/// Bits of fit_walk's row status.
enum WalkRowStatus : std::uint8_t { kWalkRowClipped = 1, kWalkRowPartial = 2 };

struct WalkFitOptions {
  int max_iterations = 200;
  /// The clipping onset and recovery are fitted only with at least this many
  /// rows flagged saturated (and this many unsaturated ones for the shape).
  std::size_t min_saturated_rows = 3;
  /// Start of the iteration (e.g. the previous backfitting pass); without it
  /// (or with multistart) a few starting shapes scaled to the data's widths
  /// are tried as well and the best kept (the least-squares surface has local
  /// minima).
  std::optional<ranging::WalkShape> initial;
  bool multistart = true;
  /// Bootstrap replicates of the shape (0: none). Each refits the shape, from
  /// the fitted one, to the fitted walk plus the residuals with random signs
  /// (a wild bootstrap: it keeps each row's own scatter and the rows' widths),
  /// so their scatter is the fit's own where the parameters trade off along a
  /// curved valley. Drawn from a fixed seed: the same rows give the same
  /// replicates.
  std::size_t replicates = 0;
};

struct WalkFitResult {
  ranging::WalkShape shape;
  double constant_m = 0;                      ///< e at the reference width
  double reference_pulse_width_ns = 0;        ///< walk correction is zero here
  double width_min_ns = 0, width_max_ns = 0;  ///< widths fitted on (the step's domain)
  std::size_t rows = 0;                       ///< rows fitted (partial-echo rows are not)
  std::size_t partial_rows = 0;               ///< rows left out: kWalkRowPartial
  std::size_t saturated_rows = 0;  ///< rows flagged clipped (clipping fitted when enough)
  /// Unclipped rows whose amplitude reading the shape's ln a was fitted to (0:
  /// no amplitude block).
  std::size_t amplitude_rows = 0;
  double rms_m = 0;  ///< RMS residual of the fit
  /// Bootstrap replicates of the shape (WalkFitOptions::replicates; those
  /// whose refit failed are left out).
  std::vector<ranging::WalkShape> shape_replicates;
  int iterations = 0;
  bool converged = false;
  [[nodiscard]] std::string summary() const;
};

/// `status[i]`: kWalkRowClipped when row i's echo clipped (kRawSaturated),
/// kWalkRowPartial when the echo itself was missed on some shots (the mean
/// over the shots that crossed is biased by which shots crossed, which a
/// noise-free crossing does not model; such rows are not fitted. fit_chain
/// marks the kRawPartialEchoes rows no wider than a row with every shot
/// echoed: wider ones lost shots to false alarms, not to weakness); may be
/// empty (all plain). `amplitude`: each row's amplitude reading (volts; may be
/// empty: widths alone, as without readings); rows with a non-finite or
/// non-positive reading are left out of the amplitude block, which is used
/// with at least 3 such unclipped rows. `metres_per_ns`: c_air / 2. Throws std::invalid_argument
/// for mismatched sizes, fewer than 6 rows (without partial echoes), non-finite values or no spread
/// in pulse width.
[[nodiscard]] WalkFitResult fit_walk(std::span<const double> pulse_width_ns,
                                     std::span<const double> error_m,
                                     std::span<const std::uint8_t> status,
                                     std::span<const double> amplitude,
                                     double reference_pulse_width_ns, double metres_per_ns,
                                     const WalkFitOptions& options = {});

}  // namespace tofkit::calib
