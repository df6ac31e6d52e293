#pragma once
/// \file Correcting device memory in a scan (device/echo_memory.hpp): a causal
/// first-order filter. The receiver's operating point is tracked as a state that
/// relaxes towards each output's echo strength x = ln(amplitude x pulse width)
/// with the fitted time constant; the unrecovered step x - state, times the
/// fitted gain, is added back to the range. Works on any time-ordered sequence
/// of raw measurements (a scan line, a mirror profile), from a real device too.

#include <span>

#include "tofkit/ranging/raw_measurement.hpp"

namespace tofkit::ranging {

struct MemoryCorrection {
  double time_constant_s = 0;   ///< recovery time constant (0: no correction)
  double gain_m_per_neper = 0;  ///< range added per neper of unrecovered strength step
  /// Outputs further apart than this many time constants start afresh.
  double reset_time_constants = 30;
};

/// Echo strength of a raw measurement, ln(amplitude [V] x pulse width [ns]);
/// NaN without an echo.
[[nodiscard]] double echo_strength_neper(const RawMeasurement& raw);

/// The unrecovered strength step of each output (NaN without an echo): the
/// regressor of the correction and of its fit. `time_s` non-decreasing.
void memory_lag(double time_constant_s, double reset_time_constants, std::span<const double> time_s,
                std::span<const RawMeasurement> raw, std::span<double> lag_neper);

/// distance_m[i] += gain x lag[i] (outputs without an echo are left alone).
/// Throws std::invalid_argument on span size mismatches.
void apply_memory_correction(const MemoryCorrection& correction, std::span<const double> time_s,
                             std::span<const RawMeasurement> raw, std::span<double> distance_m);

}  // namespace tofkit::ranging
