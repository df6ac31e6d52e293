// The receiver stage's front end, alone (device/front_end.hpp). Oracles: the
// noise at the comparator against the link budget's own noise currents
// (paper Eq. 8, physics::noise_currents) through the transimpedance, with the
// signal's shot noise at the voltage the signal gives (V = R0 M P Z); the
// space-charge limit's closed-form points; the AC coupling's baseline
// against the charge of a pulse integrated here; its offset's e-folding.
#include <gtest/gtest.h>

#include <cmath>

#include "tofkit/device/device_config.hpp"
#include "tofkit/device/front_end.hpp"
#include "tofkit/physics/link_budget.hpp"
#include "tofkit/physics/pulse_template.hpp"

using namespace tofkit;

TEST(FrontEnd, NoiseIsTheLinkBudgetsNoiseCurrentsAtTheComparator) {
  const auto rx = device::preset("paper").link.receiver;
  const double z = rx.transimpedance_kohm * 1e3;
  for (const double gain : {50.0, 100.0, 150.0}) {
    SCOPED_TRACE("gain " + std::to_string(gain));
    const auto noise = device::front_end_noise(rx, gain);
    for (const double background_w : {0.0, 2e-8, 5e-7}) {
      for (const double signal_w : {0.0, 1e-7, 1e-5}) {
        const auto n = physics::noise_currents(rx, signal_w, background_w, gain);
        const double expected = z * z * n.total_a * n.total_a;  // all four Eq. 8 terms
        const double signal_v = rx.responsivity_a_per_w * gain * signal_w * z;
        EXPECT_NEAR(noise.variance_v2(signal_v, background_w) / expected, 1.0, 1e-9)
            << "background " << background_w << " W, signal " << signal_w << " W";
      }
    }
    // Negative excursions of the signal (below the baseline) add no shot noise.
    EXPECT_EQ(noise.variance_v2(-1.0, 0.0), noise.floor_var_v2);
  }
}

TEST(FrontEnd, SpaceChargeBoundsTheEcho) {
  constexpr double kLimit = 11.0;
  EXPECT_DOUBLE_EQ(device::space_charge_limited_v(kLimit, kLimit), kLimit / 2);
  EXPECT_NEAR(device::space_charge_limited_v(1e-3, kLimit), 1e-3, 1e-3 * 1e-3 / kLimit * 1.01);
  EXPECT_LT(device::space_charge_limited_v(1e9, kLimit), kLimit);
  EXPECT_NEAR(device::space_charge_limited_v(1e9, kLimit), kLimit, 1e-6);
  EXPECT_EQ(device::space_charge_limited_v(436.0, 0.0), 436.0);  // no limit set
  // Monotone: a stronger return never gives a weaker echo.
  double previous = 0;
  for (double a = 0.01; a < 1e4; a *= 1.5) {
    const double v = device::space_charge_limited_v(a, kLimit);
    EXPECT_GT(v, previous);
    previous = v;
  }
}

TEST(FrontEnd, ClipRecoveryGrowsOneTimeConstantPerNeper) {
  EXPECT_EQ(device::clip_recovery_ns(3.9, 4.0, 2.0), 0.0);
  EXPECT_EQ(device::clip_recovery_ns(4.0, 4.0, 2.0), 0.0);
  EXPECT_NEAR(device::clip_recovery_ns(4.0 * std::exp(1.0), 4.0, 2.0), 2.0, 1e-12);
  EXPECT_NEAR(device::clip_recovery_ns(4.0 * std::exp(3.0), 4.0, 2.0), 6.0, 1e-12);
}

TEST(FrontEnd, CouplingBaselineIsTheEchoTrainsMeanCharge) {
  const auto cfg = device::preset("paper");
  const physics::PulseTemplate pulse(cfg.link.laser.pulse_width_ns, cfg.link.receiver.bandwidth_mhz,
                                     5.0, cfg.link.laser.lasing_onset_ns);
  // The pulse's area by the trapezoid rule on a 1 ps grid.
  double area_ns = 0;
  for (double t = pulse.begin_ns(); t < pulse.end_ns(); t += 1e-3)
    area_ns += 0.5 * (pulse(t) + pulse(t + 1e-3)) * 1e-3;
  const double f_rep = 1e6, share = 0.5, sat = 4.0;
  const device::ClippedChargeShare clipped(pulse);
  // Linear: share x amplitude x area x f_rep.
  const double a = 0.8;
  EXPECT_EQ(clipped(a / sat), 1.0);
  EXPECT_NEAR(device::coupling_baseline_v(a, area_ns, clipped(a / sat), sat, 0.0, share, f_rep),
              share * a * area_ns * 1e-9 * f_rep, 1e-15);
  // Clipped: the echo as the amplifier passes it, a sampled oracle on a 0.1 ps
  // grid: the linear echo clipped at sat, and the recovery holding sat for
  // its duration. 1.5x, 10x (where scaling the charge by sat / peak took 0.71
  // of it) and 1000x overdrive.
  double previous = 0;
  for (const double peak : {1.5 * sat, 10.0 * sat, 1000.0 * sat}) {
    SCOPED_TRACE("peak " + std::to_string(peak));
    const double recovery = device::clip_recovery_ns(peak, sat, 2.0);
    double clipped_area = 0;
    for (double t = pulse.begin_ns(); t < pulse.end_ns(); t += 1e-4)
      clipped_area += std::min(peak * pulse(t), sat) * 1e-4;
    const double model = device::coupling_baseline_v(peak, area_ns, clipped(peak / sat), sat,
                                                     recovery, share, f_rep);
    const double sampled = share * (clipped_area + sat * recovery) * f_rep * 1e-9;
    EXPECT_NEAR(model / sampled, 1.0, 2e-3);
    EXPECT_GT(model, previous);  // more overdrive never charges less
    previous = model;
  }
  // No coupling share: no baseline.
  EXPECT_EQ(device::coupling_baseline_v(a, area_ns, a, sat, 0.0, 0.0, f_rep), 0.0);
}

TEST(FrontEnd, CouplingOffsetRelaxesWithTheTimeConstant) {
  const double offset = -0.02, shots_per_tau = 1000.0;
  EXPECT_EQ(device::coupling_offset_v(offset, 0, shots_per_tau), offset);
  EXPECT_NEAR(device::coupling_offset_v(offset, 1000, shots_per_tau), offset / std::exp(1.0),
              1e-15);
  EXPECT_NEAR(device::coupling_offset_v(offset, 3000, shots_per_tau), offset * std::exp(-3.0),
              1e-15);
  EXPECT_EQ(device::coupling_offset_v(0.0, 500, shots_per_tau), 0.0);
}
