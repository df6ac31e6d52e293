// The measure grid: its order (distance outermost, repeats innermost), its
// validation messages, and that it reproduces a hand-built plan's numbers.

#include "tofkit/experiments/plate_grid.hpp"

#include <gtest/gtest.h>

#include <cstring>
#include <vector>

#include "tofkit/device/virtual_rangefinder.hpp"

namespace tofkit::experiments {
namespace {

TEST(PlateGrid, OrderIsDistanceReflectanceAngleTemperatureRepeat) {
  PlateGrid grid;
  grid.distances_m = {1.0, 2.0};
  grid.reflectances = {0.1, 0.5, 0.9};
  grid.angles_deg = {0.0, 30.0};
  grid.ambient_c = {10.0, 20.0};
  grid.count = 3;
  grid.shots = 7;
  const auto plan = plate_grid_plan(grid);
  ASSERT_EQ(plan.size(), 2u * 3u * 2u * 2u * 3u);
  EXPECT_DOUBLE_EQ(grid.rows(), 72.0);
  std::size_t i = 0;
  for (double d : grid.distances_m) {
    for (double rho : grid.reflectances) {
      for (double angle : grid.angles_deg) {
        for (double t : grid.ambient_c) {
          for (int k = 0; k < grid.count; ++k, ++i) {
            const PlannedMeasurement& p = plan[i];
            EXPECT_EQ(p.truth.distance_m, d);
            EXPECT_EQ(p.truth.reflectance, rho);
            EXPECT_EQ(p.truth.angle_deg, angle);
            EXPECT_EQ(p.truth.ambient_c, t);
            ASSERT_EQ(p.request.target.surfaces.size(), 1u);
            EXPECT_EQ(p.request.target.surfaces[0].distance_m, d);
            EXPECT_EQ(p.request.target.surfaces[0].cos_incidence, device::incidence_cos(angle));
            EXPECT_EQ(p.request.conditions.ambient_c, t);
            EXPECT_EQ(p.request.shots, 7);
          }
        }
      }
    }
  }
}

TEST(PlateGrid, ProblemsNameTheList) {
  PlateGrid grid;
  grid.distances_m = {1.0, 0.0};
  grid.reflectances = {};
  grid.angles_deg = {95.0};
  grid.count = 0;
  const auto problems = grid.problems();
  ASSERT_EQ(problems.size(), 4u);
  EXPECT_EQ(problems[0], "distance_m: 0 is outside [0.001, 100000]");
  EXPECT_EQ(problems[1], "reflectance: no values");
  EXPECT_EQ(problems[2], "angle_deg: 95 is outside [0, 89.9]");
  EXPECT_EQ(problems[3], "count: 0 is below 1");
  EXPECT_THROW((void)plate_grid_plan(grid), std::invalid_argument);
}

TEST(PlateGrid, RowLimit) {
  PlateGrid grid;
  grid.distances_m = {1.0, 2.0};
  grid.reflectances = {0.5};
  grid.count = 6;
  EXPECT_TRUE(grid.problems(12).empty());
  const auto problems = grid.problems(11);
  ASSERT_EQ(problems.size(), 1u);
  EXPECT_EQ(problems[0], "the grid has 12 rows, more than 11");
}

// run() into caller's memory gives the bytes of run() into a vector, refuses a
// span of another length, and planned() takes the truth from the target's
// first surface (a mixed pixel's truth is its first surface's).
TEST(PlateGrid, RunIntoASpanAndPlannedTruth) {
  PlateGrid grid;
  grid.distances_m = {1.0, 3.0};
  grid.reflectances = {0.2, 0.8};
  grid.count = 2;
  grid.shots = 50;
  const auto plan = plate_grid_plan(grid);
  const device::VirtualRangefinder device{device::DeviceConfig{}};
  const std::vector<ranging::Record> a = run(device, plan, 5);
  std::vector<ranging::Record> b(plan.size());
  run(device, plan, 5, b);
  for (std::size_t i = 0; i < a.size(); ++i) {
    EXPECT_EQ(std::memcmp(&a[i].raw, &b[i].raw, sizeof a[i].raw), 0) << i;
    EXPECT_EQ(a[i].truth.distance_m, plan[i].truth.distance_m);
  }
  std::vector<ranging::Record> short_out(plan.size() - 1);
  EXPECT_THROW(run(device, plan, 5, short_out), std::invalid_argument);
  device::Conditions warm;
  warm.ambient_c = 31.0;
  const PlannedMeasurement mixed = planned(
      device::Target{{{0.4, 2.0, 0.3, device::incidence_cos(10.0)}, {0.6, 2.5, 0.7}}}, warm, 9);
  EXPECT_EQ(mixed.truth.distance_m, 2.0);
  EXPECT_EQ(mixed.truth.reflectance, 0.3);
  EXPECT_NEAR(mixed.truth.angle_deg, 10.0, 1e-12);
  EXPECT_EQ(mixed.truth.ambient_c, 31.0);
  EXPECT_EQ(mixed.request.shots, 9);
  EXPECT_EQ(mixed.request.target.surfaces.size(), 2u);
}

}  // namespace
}  // namespace tofkit::experiments
