#pragma once
/// \file What the beam hits: one or more surfaces sharing the beam footprint.

#include <vector>

namespace tofkit::device {

/// A flat Lambertian surface patch inside the beam footprint.
struct Surface {
  double fraction = 1.0;     ///< share of the footprint's power landing on this surface
  double distance_m = 1.0;   ///< distance along the beam axis
  double reflectance = 0.1;  ///< Lambertian reflectance rho
  double angle_deg = 0.0;    ///< incidence angle phi between beam and surface normal
};

/// One or more surfaces in one footprint; several make a mixed pixel whose
/// echoes add in the receiver.
struct Target {
  std::vector<Surface> surfaces;

  static Target plate(double distance_m, double reflectance, double angle_deg = 0.0) {
    return Target{{Surface{1.0, distance_m, reflectance, angle_deg}}};
  }
};

/// Operating conditions of one measurement.
struct Conditions {
  double ambient_c = 20.0;              ///< ambient (air) temperature
  double minutes_since_power_on = 1e9;  ///< electronics warm-up (large: warmed up)
  double ms_since_laser_on = 1e9;       ///< laser turn-on transient (large: settled)
};

}  // namespace tofkit::device
