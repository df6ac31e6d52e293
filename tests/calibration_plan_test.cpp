// Calibration planning from the link budget: the plates' echo powers must
// span the field's and be realizable with the plates available.

#include "tofkit/calib/calibration_plan.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <stdexcept>

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

TEST(CalibrationPlan, RejectsAnEmptyField) {
  CalibrationPlanOptions o;
  o.range_max_m = 0.1;
  EXPECT_THROW((void)plan_calibration(device::DeviceConfig{}.link, o), std::invalid_argument);
  o = {};
  o.reflectance_min = 0;
  EXPECT_THROW((void)plan_calibration(device::DeviceConfig{}.link, o), std::invalid_argument);
}

}  // namespace
}  // namespace tofkit::calib
