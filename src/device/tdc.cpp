#include "tofkit/device/tdc.hpp"

#include <algorithm>
#include <cmath>

namespace tofkit::device {
namespace {

/// SplitMix64: a fixed pseudo-random sequence (the INL is a property of the
/// chip, the same at every power-on).
std::uint64_t splitmix64(std::uint64_t& state) {
  std::uint64_t z = (state += 0x9E3779B97F4A7C15ull);
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
  return z ^ (z >> 31);
}

}  // namespace

Tdc::Tdc(const TdcConfig& config) {
  // The interpolator divides one coarse period into an integer number of bins.
  period_ns_ = 1e3 / config.coarse_clock_mhz;
  inv_period_ = 1.0 / period_ns_;
  const auto bins = std::max<std::int64_t>(1, std::llround(period_ns_ / (config.lsb_ps * 1e-3)));
  lsb_ns_ = period_ns_ / static_cast<double>(bins);
  inv_lsb_ = 1.0 / lsb_ns_;
  last_bin_ = static_cast<double>(bins - 1);
  const auto n = static_cast<std::size_t>(bins);
  // Code-density style INL: carry-chain bin widths (DNL) err randomly, and the
  // errors are correlated over a few bins (slices of the chain share routing),
  // so the INL, their running sum, wanders over several bins. The chain spans
  // exactly one coarse period, so the INL closes (zero at both ends).
  std::uint64_t state = 0x7D1C0DE5u;
  std::vector<double> white(n);
  for (auto& w : white) w = static_cast<double>(splitmix64(state) >> 11) * 0x1.0p-53 - 0.5;
  constexpr std::size_t kCorrelationBins = 4;
  std::vector<double> dnl(n, 0.0);
  for (std::size_t k = 0; k < n; ++k)
    for (std::size_t j = 0; j < kCorrelationBins; ++j) dnl[k] += white[(k + j) % n];
  double mean = 0;
  for (double d : dnl) mean += d;
  mean /= static_cast<double>(n);
  inl_lsb_.assign(n, 0.0);
  double acc = 0, peak = 0;
  for (std::size_t k = 0; k < n; ++k) {
    acc += dnl[k] - mean;  // the bins' edges; the code's centre sits half a DNL in
    inl_lsb_[k] = acc - 0.5 * (dnl[k] - mean);
  }
  double centre = 0;
  for (double v : inl_lsb_) centre += v;
  centre /= static_cast<double>(n);
  for (auto& v : inl_lsb_) {
    v -= centre;
    peak = std::max(peak, std::abs(v));
  }
  for (auto& v : inl_lsb_) v = peak > 0 ? v * config.inl_lsb / peak : 0.0;
  if (config.code_density_hits > 0) code_density_correct(config.code_density_hits);
}

void Tdc::code_density_correct(int hits) {
  // The code-density test (Wu, IEEE TNS 2008): hits uniform in time over one
  // coarse period (an asynchronous oscillator) are histogrammed per fine code;
  // code k's measured centre is (C_{k-1} + c_k / 2) / hits periods, C the
  // cumulative count, and the firmware reports that centre instead of the
  // nominal one. Whatever the chain's INL, what remains is the histogram's
  // counting error, ~ bins sqrt(F (1 - F) / hits) LSB (a Brownian bridge over
  // the codes). The test runs once, at the factory, with its own fixed
  // sequence (the table is a property of the unit, stored in its flash).
  const std::size_t n = inl_lsb_.size();
  std::vector<double> count(n, 0.0);
  std::uint64_t state = 0xC0DEDE45u;
  for (int h = 0; h < hits; ++h) {
    const double u = static_cast<double>(splitmix64(state) >> 11) * 0x1.0p-53;
    ++count[std::min(n - 1, static_cast<std::size_t>(u * static_cast<double>(n)))];
  }
  // The model's codes are the nominal bins; their true centres k + 0.5 carry
  // the INL only in the uncorrected reading. Corrected: measured minus true.
  double cumulative = 0;
  const double bins_per_hit = static_cast<double>(n) / static_cast<double>(hits);
  for (std::size_t k = 0; k < n; ++k) {
    const double centre = (cumulative + 0.5 * count[k]) * bins_per_hit;
    inl_lsb_[k] = centre - (static_cast<double>(k) + 0.5);
    cumulative += count[k];
  }
}

}  // namespace tofkit::device
