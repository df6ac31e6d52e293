#pragma once
/// \file Time-to-digital converter: a coarse counter and a fine interpolator
/// with a code-dependent integral nonlinearity (INL).

#include <cmath>
#include <cstdint>
#include <vector>

#include "tofkit/device/device_config.hpp"

namespace tofkit::device {

class Tdc {
 public:
  explicit Tdc(const TdcConfig& config);

  /// The time the TDC reports for an event at absolute time t (ns): the
  /// centre of its fine bin, displaced by that bin's INL.
  [[nodiscard]] double quantize_ns(double t_ns) const {
    const double bin = std::floor(t_ns * inv_lsb_);
    const auto code = static_cast<std::int64_t>(bin);
    const auto in_period = static_cast<std::size_t>(((code % bins_) + bins_) % bins_);
    return (bin + 0.5 + inl_lsb_[in_period]) * lsb_ns_;
  }

  [[nodiscard]] double lsb_ns() const { return lsb_ns_; }  ///< effective LSB
  [[nodiscard]] double period_ns() const { return lsb_ns_ * static_cast<double>(bins_); }

 private:
  double lsb_ns_ = 0, inv_lsb_ = 0;
  std::int64_t bins_ = 1;
  std::vector<double> inl_lsb_;
};

}  // namespace tofkit::device
