#include "tofkit/ranging/time_to_distance.hpp"

#include <cmath>
#include <stdexcept>
#include <string>

namespace tofkit::ranging {

void TimeToDistance::validate() const {
  // The IAG group-index formula is stated for 0.3-1.7 um and terrestrial air.
  if (!(wavelength_nm >= 300.0 && wavelength_nm <= 1700.0)) {
    throw std::invalid_argument("time_to_distance.wavelength_nm = " +
                                std::to_string(wavelength_nm) + " is out of range [300, 1700]");
  }
  if (!(air.temperature_c >= -60.0 && air.temperature_c <= 80.0)) {
    throw std::invalid_argument("time_to_distance.air.temperature_c = " +
                                std::to_string(air.temperature_c) + " is out of range [-60, 80]");
  }
  if (!(air.pressure_hpa >= 300.0 && air.pressure_hpa <= 1200.0)) {
    throw std::invalid_argument("time_to_distance.air.pressure_hpa = " +
                                std::to_string(air.pressure_hpa) + " is out of range [300, 1200]");
  }
  if (!(air.relative_humidity_pct >= 0.0 && air.relative_humidity_pct <= 100.0)) {
    throw std::invalid_argument("time_to_distance.air.relative_humidity_pct = " +
                                std::to_string(air.relative_humidity_pct) +
                                " is out of range [0, 100]");
  }
}

double metres_per_ns(const TimeToDistance& conversion) {
  // Round trip: S = c_air t / 2 (paper Section 2), c_air the group velocity c / n_g.
  return 0.5 * physics::speed_of_light_in_air_m_per_s(conversion.wavelength_nm, conversion.air) *
         1e-9;
}

double tof_to_distance_m(double tof_ns, const TimeToDistance& conversion) {
  return tof_ns * metres_per_ns(conversion);
}

}  // namespace tofkit::ranging
