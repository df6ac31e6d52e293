#pragma once
/// \file Noise and systematic residual of repeated measurements, told apart.
///
/// A test set measures each condition (a group: one plate, distance and
/// temperature) n_g times. Two different things make its errors e_gk:
///   noise (repeatability)  the spread of one measurement about its group's
///                          mean: the pooled within-group standard deviation
///                          s = sqrt( sum_g sum_k (e_gk - ebar_g)^2 / sum_g (n_g - 1) );
///   systematic residual    the error of the mean of the repeats, ebar_g: what
///                          averaging cannot remove and a better correction could.
/// ebar_g still holds noise of s / sqrt(n_g); the RMS of ebar_g is reported
/// with that noise removed in quadrature (never below 0), and the noise of a
/// group mean is given so a reader can tell whether a systematic figure is
/// resolved at all.

#include <cstddef>
#include <span>

#include "tofkit/ranging/raw_measurement.hpp"

namespace tofkit::calib {

struct RepeatabilitySplit {
  std::size_t groups = 0;                  ///< groups with at least one finite error
  std::size_t rows = 0;                    ///< finite errors counted
  double noise_m = ranging::kNaN;          ///< pooled within-group std of one measurement (1 sigma)
  double noise_of_mean_m = ranging::kNaN;  ///< noise_m / sqrt(mean repeats per group)
  double systematic_rms_m = ranging::kNaN;      ///< RMS of group means, group-mean noise removed
  double systematic_max_abs_m = ranging::kNaN;  ///< largest |group mean error| (noise included)
  double systematic_mean_m = ranging::kNaN;     ///< mean of the group means (overall bias)
};

/// error_m[i] belongs to group group_id[i] (any labels; equal ids = one
/// condition). Non-finite errors are skipped. Noise needs some group with two
/// or more finite repeats; otherwise it and the noise-corrected RMS are NaN.
[[nodiscard]] RepeatabilitySplit split_noise_systematic(std::span<const double> error_m,
                                                        std::span<const std::size_t> group_id);

}  // namespace tofkit::calib
