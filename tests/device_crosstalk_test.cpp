// Emitter-receiver optical crosstalk and comparator blanking: the crosstalk is
// an echo at zero range; without blanking it stops the TDC, with blanking past
// it the far echoes read as before, near echoes inside the blanking are not
// seen (the blind zone follows), and the two simulation modes agree.
#include <gtest/gtest.h>

#include <cmath>
#include <string>

#include "tofkit/device/config_limits.hpp"
#include "tofkit/device/virtual_rangefinder.hpp"

using namespace tofkit;
using namespace tofkit::device;

namespace {

DeviceConfig indoor() {
  auto cfg = preset("paper");
  cfg.link.environment.solar_irradiance_w_per_m2_um = 0.0;  // no false alarms
  return cfg;
}

bool names_key(const std::vector<std::string>& errors, const std::string& key) {
  for (const auto& e : errors)
    if (e.rfind(key, 0) == 0) return true;
  return false;
}

}  // namespace

TEST(DeviceCrosstalk, WithoutBlankingTheCrosstalkStopsTheTdc) {
  auto cfg = indoor();
  const VirtualRangefinder clean(cfg);
  cfg.link.receiver.crosstalk_v = 0.5;  // 12 x threshold
  const VirtualRangefinder leaky(cfg);
  const auto far = Target::plate(5.0, 0.5);
  const auto near = Target::plate(0.01, 0.5);  // inside the biaxial blind zone: no echo
  const auto d_clean = clean.measure(far, {}, 3, 0, 500);
  const auto d_leaky = leaky.measure(far, {}, 3, 0, 500);
  ASSERT_TRUE(d_clean.has_echo());
  ASSERT_TRUE(d_leaky.has_echo());
  EXPECT_FALSE(clean.measure(near, {}, 3, 0, 500).has_echo());
  // The crosstalk reads as a target at zero range: 5 m short, whatever the target.
  EXPECT_NEAR(d_leaky.distance_raw_m, d_clean.distance_raw_m - 5.0, 0.1);
  EXPECT_NEAR(leaky.measure(near, {}, 3, 0, 500).distance_raw_m, d_leaky.distance_raw_m, 0.01);
  // Echo shape: the rising crossing is the crosstalk's (before any range delay).
  EXPECT_LT(leaky.echo(far, {}).rise_crossing_ns, 0.1 * clean.echo(far, {}).rise_crossing_ns);
  // Crosstalk below the threshold never crosses by itself, and has died out
  // before a far echo: that reads as without it.
  auto weak = cfg;
  weak.link.receiver.crosstalk_v = 0.02;  // half the threshold: never crosses
  const VirtualRangefinder faint(weak);
  EXPECT_NEAR(faint.measure(far, {}, 3, 0, 500).distance_raw_m, d_clean.distance_raw_m, 2e-3);
}

TEST(DeviceCrosstalk, BlankingPastTheCrosstalkRestoresFarEchoesAndMakesANearBlindZone) {
  auto cfg = indoor();
  const VirtualRangefinder clean(cfg);
  cfg.link.receiver.crosstalk_v = 0.5;
  // The crosstalk's echo falls below threshold within the pulse template's span.
  const double crosstalk_end = VirtualRangefinder(cfg).echo(Target{}, {}).fall_crossing_ns;
  EXPECT_GT(crosstalk_end, 0.0);
  cfg.discriminator.blanking_ns = crosstalk_end + 1.0;
  for (auto mode : {SimulationMode::kAnalytic, SimulationMode::kWaveform}) {
    SCOPED_TRACE(mode == SimulationMode::kAnalytic ? "analytic" : "waveform");
    const VirtualRangefinder blanked(cfg, mode);
    const VirtualRangefinder reference(indoor(), mode);
    // Far echoes (well after the blanking) read as without crosstalk.
    for (double r : {3.0, 6.0}) {
      const auto a = blanked.measure(Target::plate(r, 0.5), {}, 3, 0, 2000);
      const auto b = reference.measure(Target::plate(r, 0.5), {}, 3, 0, 2000);
      ASSERT_TRUE(a.has_echo());
      EXPECT_NEAR(a.distance_raw_m, b.distance_raw_m, 1e-3) << r;
      EXPECT_NEAR(a.pulse_width_ns, b.pulse_width_ns, 0.02) << r;
    }
    // An echo entirely inside the blanking is not seen; one whose rise comes
    // after it is. Echo time 2 R / c against the blanking.
    const double blind_m = 0.5 * 0.2998 * cfg.discriminator.blanking_ns;
    EXPECT_FALSE(blanked.measure(Target::plate(0.5 * blind_m, 0.5), {}, 3, 0, 200).has_echo());
    EXPECT_TRUE(blanked.measure(Target::plate(blind_m + 1.0, 0.5), {}, 3, 0, 200).has_echo());
  }
  // The two modes agree on a target just past the blanking.
  const VirtualRangefinder analytic(cfg, SimulationMode::kAnalytic);
  const VirtualRangefinder waveform(cfg, SimulationMode::kWaveform);
  const double r = 0.5 * 0.2998 * (cfg.discriminator.blanking_ns + 3.0);
  const auto a = analytic.measure(Target::plate(r, 0.5), {}, 5, 0, 4000);
  const auto w = waveform.measure(Target::plate(r, 0.5), {}, 5, 0, 4000);
  ASSERT_TRUE(a.has_echo());
  ASSERT_TRUE(w.has_echo());
  EXPECT_NEAR(a.distance_raw_m, w.distance_raw_m, 2e-3);
  (void)clean;
}

TEST(DeviceCrosstalk, BadKeysAreRejectedNamingThem) {
  auto cfg = preset("paper");
  cfg.link.receiver.crosstalk_v = -0.1;
  EXPECT_TRUE(names_key(validate(cfg), "receiver.crosstalk_v"));
  cfg = preset("paper");
  cfg.discriminator.blanking_ns = -1.0;
  EXPECT_TRUE(names_key(validate(cfg), "discriminator.blanking_ns"));
  cfg = preset("paper");
  cfg.discriminator.blanking_ns = 2e9 / cfg.link.laser.repetition_hz;  // two pulse periods
  EXPECT_TRUE(names_key(validate(cfg), "discriminator.blanking_ns"));
  cfg.discriminator.blanking_ns = 10.0;
  EXPECT_TRUE(validate(cfg).empty());
  // With crosstalk the composite echo spans a pulse period: a slow laser is
  // refused naming both keys.
  cfg = preset("paper");
  cfg.link.receiver.crosstalk_v = 0.5;
  EXPECT_TRUE(check_config_limits(cfg).empty());
  cfg.link.laser.repetition_hz = 1e3;  // 1 ms period: 1e8 samples of 10 ps
  const auto limits = check_config_limits(cfg);
  ASSERT_EQ(limits.size(), 1u);
  EXPECT_EQ(limits[0].keys.front(), "receiver.crosstalk_v");
  cfg.link.receiver.crosstalk_v = 0.0;
  EXPECT_TRUE(check_config_limits(cfg).empty());
}
