// The optics stage, alone (device/optics.hpp). Oracles: the extended
// Lambertian target's scaling (paper Eq. 6: power ~ rho cos(phi) / R^2, times
// the surface's share of the footprint and the biaxial overlap), the round
// trip 2 R / c and its ambiguity modulo the pulse period, the footprint's
// depth D tan(phi) with D = exit diameter + R x divergence written out here,
// and the space-charge limit on a strong echo.
#include <gtest/gtest.h>

#include <cmath>

#include "tofkit/device/device_config.hpp"
#include "tofkit/device/optics.hpp"

using namespace tofkit;

namespace {

constexpr double kC = 0.2997;  // m/ns, about air's
constexpr double kPeriodNs = 1000.0;

device::SurfaceEcho echo_of(const physics::LinkConfig& link, double distance_m, double rho,
                            double cos_phi = 1.0, double fraction = 1.0) {
  device::SurfaceEcho e;
  const device::Surface s{fraction, distance_m, rho, cos_phi};
  EXPECT_TRUE(device::surface_echo(link, s, 1e4, kC, kPeriodNs, e));
  return e;
}

}  // namespace

TEST(Optics, EchoFollowsTheExtendedLambertianTarget) {
  auto link = device::preset("paper").link;
  link.receiver.space_charge_v = 0.0;  // linear
  const double d = 6.0;
  ASSERT_EQ(physics::overlap_fraction(link.laser, link.receiver, d), 1.0);
  const auto base = echo_of(link, d, 0.2);
  EXPECT_NEAR(echo_of(link, d, 0.8).amplitude_v / base.amplitude_v, 4.0, 1e-12);
  EXPECT_NEAR(echo_of(link, d, 0.2, 1.0, 0.25).amplitude_v / base.amplitude_v, 0.25, 1e-12);
  EXPECT_NEAR(echo_of(link, d, 0.2, 0.5).amplitude_v / base.amplitude_v, 0.5, 1e-12);
  // 1 / R^2 over the overlap.
  for (const double r : {0.3, 1.0, 3.0, 12.0}) {
    const double overlap = physics::overlap_fraction(link.laser, link.receiver, r);
    if (overlap <= 0.0) continue;
    EXPECT_NEAR(echo_of(link, r, 0.2).amplitude_v / base.amplitude_v, overlap * d * d / (r * r),
                1e-12 * d * d / (r * r))
        << r << " m";
  }
  // Nothing returns from no share, no reflectance or a surface seen edge-on.
  device::SurfaceEcho e;
  EXPECT_FALSE(device::surface_echo(link, {0.0, d, 0.2, 1.0}, 1e4, kC, kPeriodNs, e));
  EXPECT_FALSE(device::surface_echo(link, {1.0, d, 0.0, 1.0}, 1e4, kC, kPeriodNs, e));
  EXPECT_FALSE(device::surface_echo(link, {1.0, d, 0.2, 0.0}, 1e4, kC, kPeriodNs, e));
}

TEST(Optics, DelayAndSpreadAreTheRoundTripAndTheFootprintsDepth) {
  const auto link = device::preset("paper").link;
  const auto e = echo_of(link, 4.5, 0.5);
  EXPECT_DOUBLE_EQ(e.delay_ns, 2.0 * 4.5 / kC);
  EXPECT_EQ(e.spread_ns, 0.0);  // facing the beam: a point echo
  // Beyond the pulse period's range the echo is timed from a later pulse.
  const double far_m = 0.5 * kC * kPeriodNs + 3.0;
  EXPECT_NEAR(echo_of(link, far_m, 0.9).delay_ns, 2.0 * 3.0 / kC, 1e-9);
  // Tilted 60 degrees: half the footprint's depth, there and back.
  const double r = 5.0, cos_phi = 0.5;
  const double diameter_m =
      link.laser.exit_beam_diameter_mm * 1e-3 + r * link.laser.beam_divergence_mrad * 1e-3;
  const double tan_phi = std::sqrt(1.0 - cos_phi * cos_phi) / cos_phi;
  EXPECT_NEAR(echo_of(link, r, 0.5, cos_phi).spread_ns, 2.0 * 0.5 * diameter_m * tan_phi / kC,
              1e-12);
}

TEST(Optics, SpaceChargeBoundsAStrongEcho) {
  auto link = device::preset("paper").link;
  link.receiver.space_charge_v = 0.0;
  const double linear = echo_of(link, 0.5, 0.9).amplitude_v;
  link.receiver.space_charge_v = 11.0;
  const double limited = echo_of(link, 0.5, 0.9).amplitude_v;
  EXPECT_NEAR(limited, linear / (1.0 + linear / 11.0), 1e-12 * linear);
  EXPECT_LT(limited, 11.0);
}

TEST(Optics, BackgroundIsEachSurfacesShareOfTheSunlight) {
  auto link = device::preset("paper").link;
  link.environment.solar_irradiance_w_per_m2_um = 748.5;
  device::Target t;
  t.surfaces = {{0.7, 3.0, 0.4, 1.0}, {0.3, 3.2, 0.8, 0.6}};
  const double expected = 0.7 * physics::background_power_cos_w(link, 0.4, 1.0) +
                          0.3 * physics::background_power_cos_w(link, 0.8, 0.6);
  EXPECT_NEAR(device::background_power_w(link, t), expected, 1e-15 * expected + 1e-30);
  EXPECT_GT(expected, 0.0);
  link.environment.solar_irradiance_w_per_m2_um = 0.0;
  EXPECT_EQ(device::background_power_w(link, t), 0.0);
}

// Thin-lens oracle for a receiver focused at a finite distance, written out
// here: blur beta = D |1/R - 1/R_focus|, footprint alpha = (exit + R div) / R,
// a Gaussian spot of width^2 = alpha^2 + beta^2 through a circular stop:
// share = 1 - exp(-theta^2 / (alpha^2 + beta^2)).
TEST(Optics, FieldStopPassesADefocusedNearTargetsShare) {
  auto link = device::preset("paper").link;
  link.receiver.space_charge_v = 0.0;
  link.receiver.axis_offset_mm = 0.0;  // coaxial: no biaxial blind zone in the way
  // Off (the far-field budget): every ray passes.
  ASSERT_EQ(link.receiver.focus_distance_m, 0.0);
  EXPECT_EQ(physics::field_stop_share(link.laser, link.receiver, 0.3), 1.0);
  link.receiver.aperture_diameter_mm = 60.0;
  link.receiver.field_of_view_rad = 0.04;
  link.receiver.focus_distance_m = 1.0;
  auto oracle = [&](double r) {
    const double beta = 0.060 * std::abs(1.0 / r - 1.0);
    const double alpha =
        (link.laser.exit_beam_diameter_mm * 1e-3 + r * link.laser.beam_divergence_mrad * 1e-3) / r;
    return 1.0 - std::exp(-0.04 * 0.04 / (alpha * alpha + beta * beta));
  };
  for (const double r : {0.2, 0.3, 0.5, 0.7, 1.0, 3.0, 50.0}) {
    EXPECT_NEAR(physics::field_stop_share(link.laser, link.receiver, r), oracle(r), 1e-12) << r;
  }
  // In focus, a footprint much smaller than the stop passes whole; far out of
  // focus the share is the stop's over the blur's area, theta^2 / beta^2.
  EXPECT_GT(physics::field_stop_share(link.laser, link.receiver, 1.0), 1.0 - 1e-9);
  const double beta_far = 0.060 * (1.0 / 0.05 - 1.0);
  EXPECT_NEAR(physics::field_stop_share(link.laser, link.receiver, 0.05),
              0.04 * 0.04 / (beta_far * beta_far), 0.02 * 0.04 * 0.04 / (beta_far * beta_far));
  // The echo carries the share: far inside the focus the R^2 of the share
  // cancels Eq. 6's 1 / R^2, so a defocused near target's echo rises with range
  // (the near-field overlap of a coaxial receiver) instead of falling as 1 / R^2.
  const double e02 = echo_of(link, 0.2, 0.2).amplitude_v;
  const double e03 = echo_of(link, 0.3, 0.2).amplitude_v;
  EXPECT_NEAR(e03 / e02, oracle(0.3) / oracle(0.2) * (0.2 * 0.2) / (0.3 * 0.3), 1e-9);
  EXPECT_GT(e03, e02);
  link.receiver.focus_distance_m = 0.0;
  EXPECT_NEAR(echo_of(link, 0.3, 0.2).amplitude_v / echo_of(link, 0.2, 0.2).amplitude_v,
              (0.2 * 0.2) / (0.3 * 0.3), 1e-12);
}
