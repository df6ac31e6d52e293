#pragma once
/// \file What the beam hits: one or more surfaces sharing the beam footprint.

#include <cmath>
#include <vector>

#include "tofkit/physics/constants.hpp"

namespace tofkit::device {

/// cos phi of an incidence angle phi in degrees; 0 at 90 degrees and beyond
/// (grazing: nothing returns).
[[nodiscard]] inline double incidence_cos(double angle_deg) {
  return angle_deg >= 90.0 ? 0.0 : std::cos(physics::deg_to_rad(angle_deg));
}

/// The incidence angle in degrees of cos phi in [0, 1] (NaN stays NaN).
[[nodiscard]] inline double incidence_angle_deg(double cos_incidence) {
  return std::acos(cos_incidence) * 180.0 / physics::kPi;
}

/// A flat Lambertian surface patch inside the beam footprint.
struct Surface {
  double fraction = 1.0;     ///< share of the footprint's power landing on this surface
  double distance_m = 1.0;   ///< distance along the beam axis
  double reflectance = 0.1;  ///< Lambertian reflectance rho
  /// cos phi, phi the incidence angle between beam and surface normal (the
  /// physics reads the cosine: Lambert's law, the footprint's depth tan phi).
  double cos_incidence = 1.0;
};

/// One or more surfaces in one footprint; several make a mixed pixel whose
/// echoes add in the receiver.
struct Target {
  std::vector<Surface> surfaces;

  static Target plate(double distance_m, double reflectance, double angle_deg = 0.0) {
    return Target{{Surface{1.0, distance_m, reflectance, incidence_cos(angle_deg)}}};
  }
};

/// Operating conditions of one measurement.
struct Conditions {
  double ambient_c = 20.0;              ///< ambient (air) temperature
  double minutes_since_power_on = 1e9;  ///< electronics warm-up (large: warmed up)
  double ms_since_laser_on = 1e9;       ///< laser turn-on transient (large: settled)
  /// Time of the output within its acquisition session (s): slow wander that an
  /// acquisition's consecutive outputs share but points taken apart do not
  /// (the loop's duty wander; the pulsed core's delay and comparator-level
  /// wander, at the output's stream time plus this) follows it.
  double session_time_s = 0.0;
  /// AC-coupled receiver (memory.time_constant_ms > 0): the baseline at the
  /// first shot minus its settled value on this target, V (a scan's memory,
  /// device/echo_memory.hpp); it relaxes over the shots with the coupling's
  /// time constant. 0: settled.
  double baseline_offset_v = 0.0;
};

}  // namespace tofkit::device
