#pragma once
/// \file Time of flight to distance: S = c_air t / 2 (paper Section 2), with the
/// group speed of light in air (a pulse travels at c / n_g).

#include "tofkit/physics/air.hpp"

namespace tofkit::ranging {

/// What the conversion assumes about the light and the air it travels through.
struct TimeToDistance {
  double wavelength_nm = 905.0;  ///< laser vacuum wavelength (paper Table 1)
  physics::AirConditions air;    ///< assumed air state (default 20 C, 1013.25 hPa, 50 %)

  /// Throws std::invalid_argument naming the bad field.
  void validate() const;
};

/// Metres of distance per nanosecond of round-trip time, c_air / 2.
[[nodiscard]] double metres_per_ns(const TimeToDistance& conversion);

/// S = c_air t / 2.
[[nodiscard]] double tof_to_distance_m(double tof_ns, const TimeToDistance& conversion);

}  // namespace tofkit::ranging
