#pragma once
/// \file Fitting the memory correction (ranging/memory_correction.hpp) from a
/// step-edge scan with known truth: for each candidate time constant (a log
/// grid) the error true - measured is regressed by least squares on
/// [1, strength, lag(tau)] (the strength term absorbs the steady walk difference
/// between the two sides of the edge); the time constant with the smallest
/// residual wins, its lag coefficient is the gain.

#include <span>

#include "tofkit/ranging/memory_correction.hpp"

namespace tofkit::calib {

struct MemoryFitOptions {
  double time_constant_min_s = 1e-6;
  double time_constant_max_s = 1.0;
  int candidates = 61;  ///< log-spaced time constants
  /// Throws std::invalid_argument naming the bad field.
  void validate() const;
};

struct MemoryFitResult {
  ranging::MemoryCorrection correction;
  std::size_t rows = 0;       ///< outputs with an echo and a finite truth
  double residual_rms_m = 0;  ///< of the regression at the chosen time constant
  double error_rms_m = 0;     ///< of the error before (about its mean)
};

/// Throws std::invalid_argument on size mismatches or fewer than 10 usable rows.
[[nodiscard]] MemoryFitResult fit_memory_correction(std::span<const double> time_s,
                                                    std::span<const ranging::RawMeasurement> raw,
                                                    std::span<const double> truth_m,
                                                    const MemoryFitOptions& options = {});

}  // namespace tofkit::calib
