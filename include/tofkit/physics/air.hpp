#pragma once
/// \file Group refractive index of air and the speed of a light pulse in air.

namespace tofkit::physics {

/// State of the air the pulse travels through.
struct AirConditions {
  double temperature_c = 20.0;          ///< air temperature
  double pressure_hpa = 1013.25;        ///< total pressure
  double relative_humidity_pct = 50.0;  ///< relative humidity
};

/// Group refractive index n_g of air at a vacuum wavelength, from the IAG
/// (1999) resolution formula for standard air (0 C, 1013.25 hPa, 375 ppm CO2)
/// scaled to temperature, pressure and water-vapour partial pressure (Magnus).
/// A pulse travels at the group velocity c / n_g.
[[nodiscard]] double group_index_of_air(double wavelength_nm, const AirConditions& air);

/// Speed of a light pulse in air, c / n_g.
[[nodiscard]] double speed_of_light_in_air_m_per_s(double wavelength_nm, const AirConditions& air);

}  // namespace tofkit::physics
