#pragma once
/// \file The paper's published figures ("The Short-Range, High-Accuracy Compact
/// Pulsed Laser Ranging System", Sensors 2022; reference/ranging_paper.md and
/// reference/table2_accuracy.csv), printed beside tofkit's results.

#include <array>

#include "tofkit/experiments/paper_study.hpp"

namespace tofkit::experiments::paper {

inline constexpr double kRangeAtSnr10_m = 10.0;            ///< Figure 3 (simulation)
inline constexpr double kLongestDistance_m = 8.08;         ///< Section 5.3
inline constexpr double kGrayvalueStd_mm = 4.60;           ///< Section 5.1, at 2355 mm
inline constexpr double kGrayvalueAccuracy_mm = 9.0;       ///< Section 5.1, "within +-9 mm"
inline constexpr double kGrayvalueKnee_ns = 6.5;           ///< Section 5.1, inflection
inline constexpr double kTemperatureStd_mm = 4.70;         ///< Section 5.2, at 2402 mm
inline constexpr double kTemperatureAccuracy_mm = 10.0;    ///< Section 5.2
inline constexpr double kTemperatureKnee_c = 16.0;         ///< Section 5.2
inline constexpr double kTemperatureCoeff_mm_per_c = 3.8;  ///< Section 5.2
inline constexpr double kVerificationAccuracy_mm = 11.0;   ///< Section 5.3, 1-8 m

/// Table 2: ranging value, actual value, deviation (m).
inline constexpr std::array<PaperTable2Row, 8> kTable2{{
    {1.012, 1.005, -0.007},
    {2.008, 2.006, -0.002},
    {3.010, 3.006, -0.004},
    {4.004, 4.000, -0.004},
    {5.021, 5.010, -0.011},
    {6.024, 6.019, -0.005},
    {7.000, 7.000, 0.000},
    {8.000, 8.006, 0.006},
}};

}  // namespace tofkit::experiments::paper
