#include "tofkit/calib/calibration_plan.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <stdexcept>
#include <string>

namespace tofkit::calib {
namespace {

void require(bool ok, const char* field, const char* what) {
  if (!ok) throw std::invalid_argument(std::string("plan: ") + field + " " + what);
}

/// Received power of a plate (paper Eq. 6).
double power_w(const physics::LinkConfig& link, double distance_m, double reflectance) {
  return physics::received_power_extended_w(link, distance_m, reflectance, 0.0);
}

/// The plan's reach: plates stand between 1 mm and 10 km.
constexpr double kNearestPlateM = 1e-3, kFarthestPlateM = 1e4;

/// Distance at which a plate of `reflectance` returns `power` (Pr is
/// monotone in R: bisection on log R over the plan's reach). A power no plate
/// returns within the reach is refused: the field's weakest or strongest echo
/// lies beyond what a bench can set up (`option` names what to change).
double distance_for_power(const physics::LinkConfig& link, double reflectance, double power,
                          const char* option) {
  if (!(power_w(link, kFarthestPlateM, reflectance) <= power &&
        power_w(link, kNearestPlateM, reflectance) >= power)) {
    char buffer[240];
    std::snprintf(buffer, sizeof buffer,
                  "plan: %s: a plate of reflectance %.3g returns %.3g W nowhere between %g m and "
                  "%g m (the field's echoes span more than plates can)",
                  option, reflectance, power, kNearestPlateM, kFarthestPlateM);
    throw std::invalid_argument(buffer);
  }
  double lo = std::log(kNearestPlateM), hi = std::log(kFarthestPlateM);
  for (int it = 0; it < 200; ++it) {
    const double mid = 0.5 * (lo + hi);
    (power_w(link, std::exp(mid), reflectance) > power ? lo : hi) = mid;
  }
  return std::exp(0.5 * (lo + hi));
}

/// The single distance of the plan: the plates' log-power span centred on the
/// field's (Pr is proportional to reflectance, so the plate of the geometric mean
/// reflectance returns the geometric mean power there).
double centred_distance(const physics::LinkConfig& link, const CalibrationPlanOptions& o,
                        double field_min_w, double field_max_w) {
  return distance_for_power(link, std::sqrt(o.plate_reflectance_min * o.plate_reflectance_max),
                            std::sqrt(field_min_w * field_max_w), "range_max_m / reflectance_min");
}

/// A distance rounded to 0.1 m for the bench (as it is, below 0.1 m: never 0).
double bench_distance(double d) {
  return d >= 0.1 ? std::round(10.0 * d) / 10.0 : d;
}

PlannedPlate plate(const physics::LinkConfig& link, double distance_m, double reflectance) {
  PlannedPlate p;
  p.distance_m = distance_m;
  p.reflectance = reflectance;
  p.received_power_w = power_w(link, distance_m, reflectance);
  p.snr = physics::link_budget_at(link, distance_m, reflectance, 0.0,
                                  link.receiver.nominal_temperature_c)
              .snr;
  return p;
}

}  // namespace

void CalibrationPlanOptions::validate() const {
  require(std::isfinite(range_min_m) && range_min_m > 0, "range_min_m", "must be > 0");
  require(std::isfinite(range_max_m) && range_max_m > range_min_m, "range_max_m",
          "must be > range_min_m");
  require(range_max_m <= kFarthestPlateM, "range_max_m", "must be <= 10000 m (the plan's reach)");
  require(std::isfinite(reflectance_min) && reflectance_min > 0 && reflectance_min <= 1,
          "reflectance_min", "must be in (0, 1]");
  require(
      std::isfinite(reflectance_max) && reflectance_max >= reflectance_min && reflectance_max <= 1,
      "reflectance_max", "must be in [reflectance_min, 1]");
  require(std::isnan(calibration_distance_m) || (calibration_distance_m >= kNearestPlateM &&
                                                 calibration_distance_m <= kFarthestPlateM),
          "calibration_distance_m", "must be in [0.001, 10000] m (the plan's reach)");
  require(plates >= 2 && plates <= 100, "plates", "must be in [2, 100]");
  require(std::isnan(clip_power_w) || (std::isfinite(clip_power_w) && clip_power_w > 0),
          "clip_power_w", "must be > 0 (or NaN: unknown)");
  require(std::isfinite(clip_depth_nepers) && clip_depth_nepers >= 0 && clip_depth_nepers <= 10,
          "clip_depth_nepers", "must be in [0, 10]");
  require(std::isfinite(plate_reflectance_min) && plate_reflectance_min > 0 &&
              plate_reflectance_max > plate_reflectance_min && plate_reflectance_max <= 1,
          "plate_reflectance_min/max", "must satisfy 0 < min < max <= 1");
  require(std::isfinite(temperature_min_c) && std::isfinite(temperature_max_c) &&
              temperature_max_c >= temperature_min_c,
          "temperature_max_c", "must be >= temperature_min_c");
  require(std::isfinite(temperature_step_c) && temperature_step_c > 0 &&
              (temperature_max_c - temperature_min_c) / temperature_step_c <= 1000,
          "temperature_step_c", "must be > 0 (at most 1000 steps)");
}

CalibrationPlan plan_calibration(const physics::LinkConfig& link,
                                 const CalibrationPlanOptions& options) {
  options.validate();
  CalibrationPlan plan;
  plan.field_power_min_w = power_w(link, options.range_max_m, options.reflectance_min);
  plan.field_power_max_w = power_w(link, options.range_min_m, options.reflectance_max);
  plan.clip_power_w = options.clip_power_w;
  const bool centred = options.single_distance && std::isnan(options.calibration_distance_m);
  double at = centred
                  ? centred_distance(link, options, plan.field_power_min_w, plan.field_power_max_w)
              : std::isnan(options.calibration_distance_m)
                  ? bench_distance(std::sqrt(options.range_min_m * options.range_max_m))
                  : options.calibration_distance_m;
  if (centred && plan.field_power_max_w > options.clip_power_w) {
    // The field clips: the brightest plate must too (by the depth asked, or
    // as far as the field's strongest echo), never less than centred.
    const double top_w = std::min(plan.field_power_max_w,
                                  options.clip_power_w * std::exp(options.clip_depth_nepers));
    if (power_w(link, at, options.plate_reflectance_max) < top_w)
      at = distance_for_power(link, options.plate_reflectance_max, top_w, "range_min_m");
  }
  plan.calibration_distance_m = at;
  const double unit_power = power_w(link, at, 1.0);  // a perfect reflector at `at`
  double log_lo = std::log(plan.field_power_min_w);
  double log_hi = std::log(plan.field_power_max_w);
  if (options.single_distance) {
    // The part of the field's powers the plates reach at `at`.
    log_lo = std::max(log_lo, std::log(unit_power * options.plate_reflectance_min));
    log_hi = std::min(log_hi, std::log(unit_power * options.plate_reflectance_max));
    if (!(log_hi > log_lo)) {
      throw std::invalid_argument(
          "plan: calibration_distance_m: no plate reflectance there reaches the field's powers");
    }
  }
  for (int k = 0; k < options.plates; ++k) {
    const double power = std::exp(log_lo + (log_hi - log_lo) * k / (options.plates - 1));
    const double rho = power / unit_power;
    if (options.single_distance) {  // in range up to rounding
      plan.plates.push_back(plate(
          link, at, std::clamp(rho, options.plate_reflectance_min, options.plate_reflectance_max)));
      continue;
    }
    if (rho >= options.plate_reflectance_min && rho <= options.plate_reflectance_max) {
      plan.plates.push_back(plate(link, at, rho));
      continue;
    }
    // Too bright for any plate at `at`: the brightest plate, nearer; too dim: the darkest, farther.
    const double r = rho > options.plate_reflectance_max ? options.plate_reflectance_max
                                                         : options.plate_reflectance_min;
    plan.plates.push_back(plate(
        link,
        distance_for_power(link, r, power,
                           r == options.plate_reflectance_max ? "range_min_m" : "reflectance_min"),
        r));
  }
  // Temperature run: the middle plate (mid power) over the temperatures.
  plan.temperature_plate = plan.plates[plan.plates.size() / 2];
  for (double t = options.temperature_min_c; t <= options.temperature_max_c + 1e-9;
       t += options.temperature_step_c) {
    plan.temperatures_c.push_back(t);
  }
  return plan;
}

}  // namespace tofkit::calib
