#include "tofkit/physics/air.hpp"

#include <cmath>

#include "tofkit/physics/constants.hpp"

namespace tofkit::physics {
namespace {

/// Saturation vapour pressure over water (Magnus formula, WMO constants), hPa.
double saturation_vapour_pressure_hpa(double temperature_c) {
  return 6.1078 * std::exp(17.27 * temperature_c / (temperature_c + 237.3));
}

}  // namespace

double group_index_of_air(double wavelength_nm, const AirConditions& air) {
  const double lambda_um = wavelength_nm * 1e-3;
  const double l2 = lambda_um * lambda_um;
  // Group refractivity of standard air, IAG 1999 (Rueger): N_g in ppm.
  const double group_refractivity_std = 287.6155 + 4.88660 / l2 + 0.06800 / (l2 * l2);
  const double temperature_k = air.temperature_c + kZeroCelsius_k;
  const double vapour_hpa =
      air.relative_humidity_pct / 100.0 * saturation_vapour_pressure_hpa(air.temperature_c);
  // Ideal-gas scaling of the dry part; water vapour lowers the index (-11.27 e / T).
  const double refractivity =
      group_refractivity_std * (kZeroCelsius_k / temperature_k) * (air.pressure_hpa / 1013.25) -
      11.27 * vapour_hpa / temperature_k;
  return 1.0 + refractivity * 1e-6;
}

double speed_of_light_in_air_m_per_s(double wavelength_nm, const AirConditions& air) {
  return kSpeedOfLightVacuum_m_per_s / group_index_of_air(wavelength_nm, air);
}

}  // namespace tofkit::physics
