#pragma once
/// \file The scene's surroundings: sunlight, atmosphere, air.

#include "tofkit/physics/air.hpp"

namespace tofkit::physics {

struct EnvironmentConfig {
  double solar_irradiance_w_per_m2_um = 748.5;  ///< H at 905 nm, Table 1
  double sun_angle_deg = 44.0;                  ///< sun to target normal theta, Table 1
  double sky_radiance_w_per_m2_sr_um = 0.0;     ///< N (Eq. 9); the paper's case has none
  double atmospheric_transmission = 0.99;       ///< one-way Ta, Table 1
  double pressure_hpa = 1013.25;                ///< for the group index of air
  double relative_humidity_pct = 50.0;          ///< for the group index of air
};

}  // namespace tofkit::physics
