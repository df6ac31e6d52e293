// Physics oracles: the link budget's scaling laws (paper Eqs. 4-9), the SNR
// (Eq. 8), the paper's Figure 3 figure, and the group index of air.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <vector>

#include "tofkit/device/device_config.hpp"
#include "tofkit/physics/air.hpp"
#include "tofkit/physics/constants.hpp"
#include "tofkit/physics/link_budget.hpp"
#include "tofkit/physics/pulse_template.hpp"

using namespace tofkit;
using namespace tofkit::physics;

namespace {
LinkConfig paper_link() {
  return device::preset("paper").link;
}
}  // namespace

TEST(LinkBudget, ExtendedTargetScalesAsRhoCosPhiOverRSquared) {
  const auto link = paper_link();
  const double p0 = received_power_extended_w(link, 2.0, 0.1, 0.0);
  for (double r : {0.5, 1.0, 3.0, 7.5, 15.0}) {
    for (double rho : {0.02, 0.3, 0.99}) {
      for (double phi : {0.0, 30.0, 60.0}) {
        const double expected =
            p0 * (rho / 0.1) * std::cos(deg_to_rad(phi)) * (2.0 * 2.0) / (r * r);
        EXPECT_NEAR(received_power_extended_w(link, r, rho, phi) / expected, 1.0, 1e-12);
      }
    }
  }
}

TEST(LinkBudget, SmallTargetFormWithExtendedCrossSectionIsEq6) {
  // Eq. 6 is Eq. 4 for a target filling the footprint. The laser-radar cross
  // section of a Lambertian area A is 4 rho A cos^2(phi); the footprint on a
  // plane tilted by phi has A = pi R^2 theta_t^2 / cos(phi), so
  // sigma = 4 pi rho R^2 theta_t^2 cos(phi) (the paper's sigma lacks the pi of
  // the footprint's area, and its Eq. 4 a pi with it).
  const auto link = paper_link();
  const double theta_t = 0.5 * link.laser.beam_divergence_mrad * 1e-3;
  for (double r : {1.0, 4.0, 9.0}) {
    const double rho = 0.4, phi = 20.0;
    const double cos_phi = std::cos(deg_to_rad(phi));
    const double area = kPi * r * r * theta_t * theta_t / cos_phi;
    const double sigma = 4.0 * rho * area * cos_phi * cos_phi;
    EXPECT_NEAR(
        received_power_small_w(link, r, sigma) / received_power_extended_w(link, r, rho, phi), 1.0,
        1e-12);
    // A small target's power falls as R^-4.
    EXPECT_NEAR(received_power_small_w(link, 2 * r, 1e-4) / received_power_small_w(link, r, 1e-4),
                1.0 / 16.0, 1e-12);
  }
}

TEST(LinkBudget, MaxRangeEq7InvertsEq6) {
  const auto link = paper_link();
  const double pr = received_power_extended_w(link, 6.3, 0.25, 10.0);
  EXPECT_NEAR(max_range_extended_m(link, 0.25, 10.0, pr), 6.3, 1e-9);
}

TEST(LinkBudget, BackgroundPowerIsLinearInSunAndZeroInTheDark) {
  auto link = paper_link();
  EXPECT_EQ(link.environment.solar_irradiance_w_per_m2_um, 0.0);  // indoors by default
  link.environment.solar_irradiance_w_per_m2_um = kTable1SolarIrradiance_w_per_m2_um;
  const double pb = background_power_w(link, 0.1, 0.0);
  EXPECT_GT(pb, 0.0);
  // One rho: the sunlit term is linear in rho. As printed (a switch), rho^2.
  EXPECT_NEAR(background_power_w(link, 0.8, 0.0) / pb, 8.0, 1e-9);
  auto printed = link;
  printed.environment.eq9_as_printed = true;
  EXPECT_NEAR(background_power_w(printed, 0.1, 0.0) / pb, 0.1, 1e-12);
  EXPECT_NEAR(background_power_w(printed, 0.8, 0.0) / pb, 6.4, 1e-9);
  link.environment.solar_irradiance_w_per_m2_um *= 2.0;
  EXPECT_NEAR(background_power_w(link, 0.1, 0.0) / pb, 2.0, 1e-12);
  link.environment.solar_irradiance_w_per_m2_um = 0.0;
  EXPECT_EQ(background_power_w(link, 0.1, 0.0), 0.0);
}

TEST(Snr, FallsAsOneOverRWhenSignalShotNoiseDominates) {
  // Signal shot noise only: I_s ~ 1/R^2, I_n ~ sqrt(I_s) ~ 1/R  ->  SNR ~ 1/R exactly.
  auto link = paper_link();
  link.receiver.nep_w_per_sqrt_hz = 0.0;
  link.receiver.dark_current_na = 0.0;
  link.environment.solar_irradiance_w_per_m2_um = 0.0;
  const double s1 = link_budget_at(link, 1.0, 0.1).snr;
  for (double r : {2.0, 5.0, 12.0})
    EXPECT_NEAR(link_budget_at(link, r, 0.1).snr * r / s1, 1.0, 1e-9);
  // With the paper's full noise budget the law still holds within a few % at short range,
  // where the signal's own shot noise is the largest term.
  const auto full = paper_link();
  const auto near = link_budget_at(full, 2.0, 0.1);
  EXPECT_GT(near.noise.signal_shot_a, 3.0 * near.noise.thermal_a);
  EXPECT_NEAR(link_budget_at(full, 4.0, 0.1).snr * 2.0 / near.snr, 1.0, 0.03);
}

TEST(Snr, PaperFigure3RangeAtSnr10IsAbout10m) {
  // Fig. 3's budget: Table 1's sunlight, background by Eq. 9 as printed.
  auto link = paper_link();
  link.environment.solar_irradiance_w_per_m2_um = kTable1SolarIrradiance_w_per_m2_um;
  link.environment.eq9_as_printed = true;
  const double r10 = range_at_snr(link, 10.0, 0.1);
  EXPECT_GT(r10, 9.0);
  EXPECT_LT(r10, 11.0);
  EXPECT_NEAR(link_budget_at(link, r10, 0.1).snr, 10.0, 1e-6);
  // reference/ranging_paper.md: with Table 1 read this way SNR(10 m) comes out near 9.6.
  EXPECT_NEAR(link_budget_at(link, 10.0, 0.1).snr, 9.6, 0.3);
}

TEST(Air, GroupIndexMatchesStandardAirAndScalesWithDensity) {
  // Dry standard air at 905 nm: IAG group refractivity 287.6155 + 4.8866/l^2 + 0.068/l^4 ppm.
  const AirConditions standard{0.0, 1013.25, 0.0};
  const double l2 = 0.905 * 0.905;
  EXPECT_NEAR((group_index_of_air(905.0, standard) - 1.0) * 1e6,
              287.6155 + 4.8866 / l2 + 0.068 / (l2 * l2), 1e-6);
  // Dry refractivity is proportional to density p / T.
  const AirConditions warm_low{30.0, 950.0, 0.0};
  const double ratio =
      (group_index_of_air(905.0, warm_low) - 1.0) / (group_index_of_air(905.0, standard) - 1.0);
  EXPECT_NEAR(ratio, (950.0 / 1013.25) * (273.15 / 303.15), 1e-12);
  // Humidity lowers the index; dispersion makes the group index fall with wavelength.
  EXPECT_LT(group_index_of_air(905.0, {20.0, 1013.25, 90.0}),
            group_index_of_air(905.0, {20.0, 1013.25, 0.0}));
  EXPECT_GT(group_index_of_air(780.0, standard), group_index_of_air(905.0, standard));
  EXPECT_NEAR(speed_of_light_in_air_m_per_s(905.0, {20.0, 1013.25, 50.0}), 299709000.0, 20000.0);
}

// add_to's strided sum equals the template evaluated sample by sample, for
// delays on and off the template's grid, supports cut at either end, and a
// sampling step that is not a whole number of template steps (the fallback).
TEST(PulseTemplate, AddToMatchesPointwiseEvaluation) {
  const physics::PulseTemplate p(3.0, 120.0);
  for (const double dt : {0.01, 0.005, 0.0137}) {
    for (const double delay : {0.0, 7.0, 13.00123456789, 55.5}) {
      for (const double t0 : {-30.0, 2.0, 40.0}) {
        const std::size_t n = 9000;
        std::vector<double> got(n, 0.25), want(n, 0.25);
        p.add_to(1.7, delay, t0, dt, got.data(), n);
        for (std::size_t k = 0; k < n; ++k)
          want[k] += 1.7 * p(t0 + static_cast<double>(k) * dt - delay);
        double worst = 0;
        for (std::size_t k = 0; k < n; ++k) worst = std::max(worst, std::abs(got[k] - want[k]));
        EXPECT_LT(worst, 1e-9) << dt << " " << delay << " " << t0;
      }
    }
  }
}

TEST(PulseTemplate, TwoPoleBandwidthAndNoiseCorrelation) {
  const double tau = two_pole_time_constant_ns(150.0);
  // |H(B)|^2 = 1 / (1 + (2 pi B tau)^2)^2 = 1/2 at the -3 dB bandwidth.
  const double x = 2.0 * kPi * 150e6 * tau * 1e-9;
  EXPECT_NEAR(1.0 / ((1 + x * x) * (1 + x * x)), 0.5, 1e-12);
  const PulseTemplate p(1.0, 150.0);
  EXPECT_NEAR(p.noise_correlation(0.0), 1.0, 1e-15);
  EXPECT_NEAR(p.noise_correlation(tau), 2.0 * std::exp(-1.0), 1e-12);
  // A pulse much longer than the response passes almost unchanged (FWHM, peak);
  // a short one is widened and loses peak height.
  const PulseTemplate long_pulse(20.0, 150.0);
  // Widths add roughly in quadrature (receiver FWHM 2.45 tau).
  EXPECT_NEAR(long_pulse.width_at_level_ns(0.5), std::hypot(20.0, 2.45 * tau), 0.1);
  EXPECT_GT(long_pulse.peak_gain(), 0.99);
  EXPECT_GT(p.width_at_level_ns(0.5), 1.5);
  EXPECT_LT(p.peak_gain(), 0.6);
  // The 10-90 % rise time of the receiver alone is about 0.35 / B (2.3 ns at 150 MHz).
  const PulseTemplate impulse(0.01, 150.0);
  EXPECT_NEAR(impulse.width_at_level_ns(0.5), 2.45 * tau, 0.05);
}
