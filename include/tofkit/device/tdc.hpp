#pragma once
/// \file Time-to-digital converter: an exact coarse counter and a fine
/// interpolator (carry chain) with a code-dependent integral nonlinearity (INL)
/// and a bin width that drifts with the timing board's temperature.

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <vector>

#include "tofkit/device/device_config.hpp"

namespace tofkit::device {

class Tdc {
 public:
  explicit Tdc(const TdcConfig& config);

  /// The time the TDC reports for an event at absolute time t (ns). The coarse
  /// counter is exact; the fine interpolator's bins are `bin_scale` times their
  /// nominal width (temperature), and each reported bin is displaced by its INL.
  [[nodiscard]] double quantize_ns(double t_ns, double bin_scale = 1.0) const {
    const double coarse = std::floor(t_ns * inv_period_);
    const double fine_t = t_ns - coarse * period_ns_;
    const double fine = std::min(std::floor(fine_t * inv_lsb_ / bin_scale), last_bin_);
    const auto code = static_cast<std::size_t>(fine);
    return coarse * period_ns_ + (fine + 0.5 + inl_lsb_[code]) * lsb_ns_;
  }

  [[nodiscard]] double lsb_ns() const { return lsb_ns_; }  ///< effective LSB
  [[nodiscard]] double period_ns() const { return period_ns_; }
  /// The INL of each fine code (LSB) as the device reports it: the chain's own,
  /// or after a code-density calibration (tdc.code_density_hits) its residual.
  [[nodiscard]] const std::vector<double>& inl_lsb() const { return inl_lsb_; }

 private:
  /// Replaces the INL table by the residual of a code-density calibration with `hits`.
  void code_density_correct(int hits);

  double lsb_ns_ = 0, inv_lsb_ = 0, period_ns_ = 0, inv_period_ = 0, last_bin_ = 0;
  std::vector<double> inl_lsb_;
};

}  // namespace tofkit::device
