// Calibration planning from the link budget: the plates' echo powers must
// span the field's and be realizable with the plates available.

#include "tofkit/calib/calibration_plan.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

#include "tofkit/device/device_config.hpp"

namespace tofkit::calib {
namespace {

TEST(CalibrationPlan, PlatesSpanTheFieldsPowersLogEvenly) {
  const physics::LinkConfig link = device::DeviceConfig{}.link;
  CalibrationPlanOptions o;
  o.range_max_m = 8.0;
  o.reflectance_min = 0.05;
  const CalibrationPlan plan = plan_calibration(link, o);
  ASSERT_EQ(plan.plates.size(), 10u);
  // Pr ~ rho / R^2 (paper Eq. 6): the field spans (0.9 / 0.5^2) / (0.05 / 8^2).
  EXPECT_NEAR(plan.field_power_max_w / plan.field_power_min_w,
              (0.9 / (0.5 * 0.5)) / (0.05 / (8.0 * 8.0)), 1e-6 * 4608);
  EXPECT_NEAR(plan.plates.front().received_power_w / plan.field_power_min_w, 1.0, 1e-6);
  EXPECT_NEAR(plan.plates.back().received_power_w / plan.field_power_max_w, 1.0, 1e-6);
  const double ratio = std::pow(plan.field_power_max_w / plan.field_power_min_w, 1.0 / 9.0);
  for (std::size_t k = 1; k < plan.plates.size(); ++k) {
    const PlannedPlate& p = plan.plates[k];
    EXPECT_NEAR(p.received_power_w / plan.plates[k - 1].received_power_w, ratio, 1e-6 * ratio);
    EXPECT_GE(p.reflectance, o.plate_reflectance_min - 1e-12);
    EXPECT_LE(p.reflectance, o.plate_reflectance_max + 1e-12);
    // At the calibration distance when a plate allows it, else off it with an extreme plate.
    if (p.distance_m != plan.calibration_distance_m) {
      EXPECT_TRUE(p.reflectance == o.plate_reflectance_min ||
                  p.reflectance == o.plate_reflectance_max);
    }
  }
  EXPECT_EQ(plan.temperatures_c.size(), 9u);
}

// One distance for every plate: the field's weakest and strongest echoes lie
// equally far (in log power) beyond the plates' when the plates cannot span
// the field, and no other distance does better (minimax extrapolation).
TEST(CalibrationPlan, SingleDistanceCentresThePlatesPowersOnTheField) {
  const physics::LinkConfig link = device::DeviceConfig{}.link;
  CalibrationPlanOptions o;
  o.range_min_m = 0.7;
  o.range_max_m = 7.4;
  o.reflectance_min = 0.06;
  o.reflectance_max = 0.85;
  o.single_distance = true;
  const CalibrationPlan plan = plan_calibration(link, o);
  ASSERT_EQ(plan.plates.size(), 10u);
  for (const PlannedPlate& p : plan.plates) EXPECT_EQ(p.distance_m, plan.calibration_distance_m);
  EXPECT_NEAR(plan.plates.front().reflectance, o.plate_reflectance_min, 1e-9);
  EXPECT_NEAR(plan.plates.back().reflectance, o.plate_reflectance_max, 1e-9);
  EXPECT_EQ(plan.temperature_plate.distance_m, plan.calibration_distance_m);
  const auto worst_gap = [&](const CalibrationPlan& p) {
    return std::max(std::log(p.field_power_max_w / p.plates.back().received_power_w),
                    std::log(p.plates.front().received_power_w / p.field_power_min_w));
  };
  const double below = std::log(plan.plates.front().received_power_w / plan.field_power_min_w);
  const double above = std::log(plan.field_power_max_w / plan.plates.back().received_power_w);
  EXPECT_GT(below, 0.5);  // this field is wider than the plates (x1583 vs x47.5)
  EXPECT_NEAR(below, above, 1e-6);
  for (double factor : {0.8, 0.95, 1.05, 1.25}) {
    CalibrationPlanOptions moved = o;
    moved.calibration_distance_m = plan.calibration_distance_m * factor;
    const CalibrationPlan other = plan_calibration(link, moved);
    EXPECT_EQ(other.calibration_distance_m, moved.calibration_distance_m);
    EXPECT_GT(worst_gap(other), worst_gap(plan) + 1e-3) << "at x" << factor;
  }
  // A field the plates over-span: plates only over the field's powers.
  o.reflectance_min = 0.5;
  o.range_max_m = 0.9;
  const CalibrationPlan narrow = plan_calibration(link, o);
  EXPECT_NEAR(narrow.plates.front().received_power_w / narrow.field_power_min_w, 1.0, 1e-6);
  EXPECT_NEAR(narrow.plates.back().received_power_w / narrow.field_power_max_w, 1.0, 1e-6);
  // A distance at which no plate reaches the field: refused.
  o.calibration_distance_m = 100.0;
  EXPECT_THROW((void)plan_calibration(link, o), std::invalid_argument);
}

TEST(CalibrationPlan, RejectsAnEmptyField) {
  CalibrationPlanOptions o;
  o.range_max_m = 0.1;
  EXPECT_THROW((void)plan_calibration(device::DeviceConfig{}.link, o), std::invalid_argument);
  o = {};
  o.reflectance_min = 0;
  EXPECT_THROW((void)plan_calibration(device::DeviceConfig{}.link, o), std::invalid_argument);
}

/// The message plan_calibration throws for `o`, "" when it plans.
std::string refusal(const CalibrationPlanOptions& o) {
  try {
    (void)plan_calibration(device::DeviceConfig{}.link, o);
  } catch (const std::invalid_argument& e) {
    return e.what();
  }
  return "";
}

// A field whose echoes no plate can return within 1 mm .. 10 km is refused
// naming the option to change, instead of a plan of plates clamped at 10 km
// (reflectance_min 1e-30: seven plates "at 10000 m", exit 0) or of a
// calibration distance rounded to 0 m (range_min_m 1e-7).
TEST(CalibrationPlan, FieldsBeyondThePlatesReachAreRefusedNamingTheOption) {
  CalibrationPlanOptions o;
  o.range_max_m = 1e308;
  EXPECT_NE(refusal(o).find("range_max_m must be <= 10000 m"), std::string::npos) << refusal(o);
  o = {};
  o.range_max_m = 8;
  o.reflectance_min = 1e-30;
  EXPECT_NE(refusal(o).find("plan: reflectance_min: a plate of reflectance 0.02"),
            std::string::npos)
      << refusal(o);
  o.single_distance = true;
  EXPECT_NE(refusal(o).find("reflectance_min"), std::string::npos) << refusal(o);
  o = {};
  o.range_min_m = 1e-7;
  o.range_max_m = 8;
  EXPECT_NE(refusal(o).find("plan: range_min_m: a plate of reflectance 0.95"), std::string::npos)
      << refusal(o);
  // A small field within reach plans, at a distance that is not rounded to 0.
  o = {};
  o.range_min_m = 0.01;
  o.range_max_m = 0.05;
  ASSERT_EQ(refusal(o), "");
  const CalibrationPlan plan = plan_calibration(device::DeviceConfig{}.link, o);
  EXPECT_NEAR(plan.calibration_distance_m, std::sqrt(0.01 * 0.05), 1e-12);
  for (const PlannedPlate& p : plan.plates) EXPECT_GT(p.distance_m, 1e-3);
}

}  // namespace
}  // namespace tofkit::calib
