#pragma once
/// \file The scene's surroundings: sunlight, atmosphere, air.

#include "tofkit/physics/air.hpp"

namespace tofkit::physics {

/// Table 1's solar spectral irradiance at 905 nm (W/m^2/um), for sunlit studies
/// such as the paper's Fig. 3 budget.
inline constexpr double kTable1SolarIrradiance_w_per_m2_um = 748.5;

struct EnvironmentConfig {
  double solar_irradiance_w_per_m2_um = 0.0;  ///< H at the wavelength: indoors by default (the
                                              ///< paper's Section 5 tests); Table 1's sunlight
                                              ///< is 748.5 W/m^2/um at 905 nm
  double sun_angle_deg = 44.0;                ///< sun to target normal theta, Table 1
  double sky_radiance_w_per_m2_sr_um = 0.0;   ///< N (Eq. 9); the paper's case has none
  double atmospheric_transmission = 0.99;     ///< one-way Ta, Table 1
  double pressure_hpa = 1013.25;              ///< for the group index of air
  double relative_humidity_pct = 50.0;        ///< for the group index of air
  bool eq9_as_printed = false;  ///< background by Eq. 9 exactly as printed, with rho twice (this
                                ///< is what reproduces the paper's Fig. 3); false: one rho
};

}  // namespace tofkit::physics
