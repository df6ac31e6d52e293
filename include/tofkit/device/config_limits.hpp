#pragma once
/// \file Limits on the quantities a configuration implies, checked before any
/// work. validate() checks each key against its own range; a combination of
/// legal values can still imply a pulse template of millions of samples, a
/// waveform record of gigabytes or an echo spread over kilometres. These
/// checks estimate those derived quantities from the keys (conservatively,
/// with the twin's sampling steps) and name the keys to change.
///
/// Documented limits (README "Errors and robustness"):
/// - pulse template: at most kMaxTemplateSamples samples of 5 ps (250 ns:
///   12 sigma of the pulse plus 20 time constants of the receiver): a
///   receiver bandwidth below ~8 MHz is refused, and at 150 MHz a pulse
///   width above ~46 ns;
/// - waveform record (waveform mode): at most kMaxRecordSamples samples per
///   shot, from the real record length (the echo with its tilt spread, the
///   pulse template and the noise burn-in, at least measurement.window_ns)
///   over measurement.sample_period_ps;
/// - echo of one target: at most kMaxEchoSamples samples of 10 ps
///   (a plate far away at grazing incidence spreads its echo over
///   footprint x tan(angle)).

#include <cstddef>
#include <string>
#include <vector>

#include "tofkit/device/device_config.hpp"

namespace tofkit::device {

constexpr double kMaxTemplateSamples = 50'000;
constexpr double kMaxRecordSamples = 200'000;
constexpr double kMaxEchoSamples = 2'000'000;

/// A derived quantity over its limit: the message and the config keys that
/// determine it (most influential first).
struct LimitViolation {
  std::string message;
  std::vector<std::string> keys;
};

/// Samples per receiver pole time constant the waveform mode takes at least.
constexpr double kWaveformSamplesPerPole = 6;

/// The waveform mode's sampling step, ns: measurement.sample_period_ps, or
/// finer where the receiver is fast (at least kWaveformSamplesPerPole samples
/// per pole time constant). The sampled band-limited noise is interpolated
/// between samples, and a step near the time constant biases the crossings:
/// at 1 GHz (tau 0.10 ns) 100 ps sampling read 0.8-2.0 mm long against the
/// analytic mode, 17 ps about 0.3 mm, 5 ps within 0.1 mm.
[[nodiscard]] double waveform_step_ns(const DeviceConfig& config);

/// Derived quantities of the configuration alone (every mode).
[[nodiscard]] std::vector<LimitViolation> check_config_limits(const DeviceConfig& config);

/// Also the waveform record (waveform mode only), for a target with the given
/// extent in depth (0 for a plate seen head-on).
[[nodiscard]] std::vector<LimitViolation> check_waveform_limits(const DeviceConfig& config,
                                                                double echo_spread_ns);

/// Round-trip time spread of a plate's echo at `distance_m` and `angle_deg`
/// (beam footprint x tan(angle), there and back).
[[nodiscard]] double plate_echo_spread_ns(const DeviceConfig& config, double distance_m,
                                          double angle_deg);

/// The echo of a plate (empty when within limits): its sample count on the
/// twin's 10 ps grid against kMaxEchoSamples.
[[nodiscard]] std::string check_plate_echo(const DeviceConfig& config, double distance_m,
                                           double angle_deg);

}  // namespace tofkit::device
