#pragma once
/// \file Physical constants (CODATA 2018 exact values where defined).

namespace tofkit::physics {

inline constexpr double kPi = 3.14159265358979323846;
inline constexpr double kSpeedOfLightVacuum_m_per_s = 299792458.0;
inline constexpr double kElementaryCharge_c = 1.602176634e-19;
inline constexpr double kBoltzmann_j_per_k = 1.380649e-23;
inline constexpr double kZeroCelsius_k = 273.15;
inline constexpr double kMetersPerInch = 0.0254;

inline constexpr double deg_to_rad(double deg) {
  return deg * kPi / 180.0;
}

}  // namespace tofkit::physics
