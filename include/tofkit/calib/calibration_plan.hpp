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
///
/// Clipping: the walk model (calib/walk_fit.hpp) learns where the amplifier
/// starts to clip and how its recovery lengthens the echo only from clipped
/// plates. When the receiver's clip power is known (`clip_power_w`) and the
/// field's strongest echo exceeds it, the single distance is moved nearer
/// if needed so that the brightest plate is overdriven by `clip_depth_nepers`
/// (or returns the field's strongest echo, if that is weaker): with 10 plates
/// (0.43 neper apart over 0.02-0.95) three clip, which pins the onset and the
/// recovery per neper. Centred plates of a low-gain receiver clip none while
/// the field's strong echoes clip by 1-2 nepers, whose walk is then a guess.

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
  /// Received peak power (W, paper Eq. 6 at normal incidence) above which
  /// the receiver's echo clips (receiver.saturation_v over the chain's volts
  /// per watt; experiments::plan_for_device asks the device); NaN: unknown.
  double clip_power_w = std::numeric_limits<double>::quiet_NaN();
  double clip_depth_nepers = 1.0;  ///< overdrive of the brightest plate, when the field clips
  double temperature_min_c = 0;    ///< temperature run
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
  double field_power_min_w = 0, field_power_max_w = 0;             ///< the span to cover
  double clip_power_w = std::numeric_limits<double>::quiet_NaN();  ///< the options' (NaN: unknown)
  double calibration_distance_m = 0;
  std::vector<PlannedPlate> plates;  ///< ascending power
  PlannedPlate temperature_plate;    ///< the plate of the temperature run
  std::vector<double> temperatures_c;
};

[[nodiscard]] CalibrationPlan plan_calibration(const physics::LinkConfig& link,
                                               const CalibrationPlanOptions& options);

}  // namespace tofkit::calib
