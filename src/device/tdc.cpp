#include "tofkit/device/tdc.hpp"

#include <algorithm>

#include "tofkit/physics/constants.hpp"

namespace tofkit::device {

Tdc::Tdc(const TdcConfig& config) {
  // The interpolator divides one coarse period into an integer number of bins.
  const double period_ns = 1e3 / config.coarse_clock_mhz;
  bins_ = std::max<std::int64_t>(1, std::llround(period_ns / (config.lsb_ps * 1e-3)));
  lsb_ns_ = period_ns / static_cast<double>(bins_);
  inv_lsb_ = 1.0 / lsb_ns_;
  inl_lsb_.resize(static_cast<std::size_t>(bins_));
  for (std::int64_t k = 0; k < bins_; ++k) {
    // Sinusoidal INL over the coarse period, a common shape of carry-chain TDCs.
    inl_lsb_[static_cast<std::size_t>(k)] =
        config.inl_lsb *
        std::sin(2.0 * physics::kPi * (static_cast<double>(k) + 0.5) / static_cast<double>(bins_));
  }
}

}  // namespace tofkit::device
