#pragma once
/// \file Calibration planning from the link budget (issue 8, item 4): which
/// (distance, reflectance) plates make the echoes span the powers the field
/// will produce, so that every correction is fitted where it will be used
/// instead of extrapolated.
///
/// The field is ranges [range_min_m, range_max_m] x reflectances
/// [reflectance_min, reflectance_max] at normal incidence; its received peak
/// powers (paper Eq. 6, extended Lambertian target: Pr ~ rho / R^2) span
/// [Pr(range_max, reflectance_min), Pr(range_min, reflectance_max)]. The plan
/// puts `plates` target powers log-evenly over that span and realizes each at
/// the calibration distance when a plate reflectance in [plate_reflectance_min,
/// plate_reflectance_max] gives it, else at the nearest distance that does
/// (nearer for stronger echoes, farther for weaker ones). A temperature run
/// (one mid-power plate over the field's temperatures) completes the paper's
/// protocol.
///
/// With `single_distance`, every plate stands at one distance (the paper's
/// protocol): by default the one that centres the plates' log-power span
/// (plate_reflectance_min..max) on the field's, so that the field's weakest and
/// strongest echoes lie equally far (in log power) beyond the plates' when the
/// plates cannot span the field (minimax extrapolation); the plates then take
/// log-even reflectances over the part of the field's powers they reach.

#include <limits>
#include <string>
#include <vector>

#include "tofkit/physics/link_budget.hpp"

namespace tofkit::calib {

struct CalibrationPlanOptions {
  double range_min_m = 0.5;
  double range_max_m = 8.0;
  double reflectance_min = 0.05;
  double reflectance_max = 0.9;
  /// Where the plates stand when they can; NaN: the geometric mean of the
  /// field's ranges (rounded to 0.1 m).
  double calibration_distance_m = std::numeric_limits<double>::quiet_NaN();
  /// All plates at one distance (see the file comment); `calibration_distance_m`
  /// overrides the centred distance.
  bool single_distance = false;
  int plates = 10;                      ///< target powers (plate positions)
  double plate_reflectance_min = 0.02;  ///< darkest plate available
  double plate_reflectance_max = 0.95;  ///< brightest plate available
  double temperature_min_c = 0;         ///< temperature run
  double temperature_max_c = 40;
  double temperature_step_c = 5;
  /// Throws std::invalid_argument naming the bad field.
  void validate() const;
};

struct PlannedPlate {
  double distance_m = 0;
  double reflectance = 0;
  double received_power_w = 0;  ///< paper Eq. 6
  double snr = 0;               ///< paper Eq. 8 at the receiver's nominal temperature
};

struct CalibrationPlan {
  double field_power_min_w = 0, field_power_max_w = 0;  ///< the span to cover
  double calibration_distance_m = 0;
  std::vector<PlannedPlate> plates;  ///< ascending power
  PlannedPlate temperature_plate;    ///< the plate of the temperature run
  std::vector<double> temperatures_c;
};

[[nodiscard]] CalibrationPlan plan_calibration(const physics::LinkConfig& link,
                                               const CalibrationPlanOptions& options);

}  // namespace tofkit::calib
