#include "tofkit/device/config_limits.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <string>

#include "tofkit/physics/pulse_template.hpp"

namespace tofkit::device {
namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr double kTemplateStepNs = 0.005;  // the twin's pulse template step (5 ps)
constexpr double kEchoStepNs = 0.01;       // the twin's composite echo grid (10 ps)
constexpr double kLightMPerNs = 0.299792458;

// Pulse sigma from its FWHM.
double pulse_sigma_ns(const DeviceConfig& c) {
  return c.link.laser.pulse_width_ns / (2.0 * std::sqrt(2.0 * std::log(2.0)));
}

// Time constant of the receiver's two equal poles with overall -3 dB bandwidth B.
double receiver_tau_ns(const DeviceConfig& c) {
  return physics::two_pole_time_constant_ns(c.link.receiver.bandwidth_mhz);
}

double template_span_ns(const DeviceConfig& c) {
  return 12.0 * pulse_sigma_ns(c) + 20.0 * receiver_tau_ns(c);
}

std::string number(double v) {
  char buffer[32];
  std::snprintf(buffer, sizeof buffer, "%.3g", v);
  return buffer;
}

}  // namespace

std::vector<LimitViolation> check_config_limits(const DeviceConfig& config) {
  std::vector<LimitViolation> out;
  const double sigma_part = 12.0 * pulse_sigma_ns(config);
  const double tau_part = 20.0 * receiver_tau_ns(config);
  const double samples = (sigma_part + tau_part) / kTemplateStepNs;
  if (!(samples <= kMaxTemplateSamples)) {
    LimitViolation v;
    const std::string bandwidth =
        "receiver.bandwidth_mhz = " + number(config.link.receiver.bandwidth_mhz);
    const std::string width = "laser.pulse_width_ns = " + number(config.link.laser.pulse_width_ns);
    v.keys = tau_part >= sigma_part
                 ? std::vector<std::string>{"receiver.bandwidth_mhz", "laser.pulse_width_ns"}
                 : std::vector<std::string>{"laser.pulse_width_ns", "receiver.bandwidth_mhz"};
    v.message = (tau_part >= sigma_part ? bandwidth + " (with " + width + ")"
                                        : width + " (with " + bandwidth + ")") +
                " needs a pulse template of " + number(samples) + " samples of 5 ps, more than " +
                number(kMaxTemplateSamples) + " (the receiver's response lasts " +
                number(tau_part) + " ns, the pulse " + number(sigma_part) +
                " ns); raise the bandwidth or shorten the pulse";
    out.push_back(v);
  }
  // Crosstalk is an echo at zero range: with it, the composite echo spans from
  // emission to the farthest (aliased) echo, up to a pulse period.
  const double period_ns = 1e9 / config.link.laser.repetition_hz;
  const double crosstalk_samples = (period_ns + template_span_ns(config)) / kEchoStepNs;
  if (config.link.receiver.crosstalk_v > 0 && !(crosstalk_samples <= kMaxEchoSamples)) {
    LimitViolation v;
    v.keys = {"receiver.crosstalk_v", "laser.repetition_hz"};
    v.message = "receiver.crosstalk_v = " + number(config.link.receiver.crosstalk_v) +
                " (with laser.repetition_hz = " + number(config.link.laser.repetition_hz) +
                ") spans echoes over a pulse period of " + number(period_ns) +
                " ns: " + number(crosstalk_samples) + " samples of 10 ps, more than " +
                number(kMaxEchoSamples) + "; raise the repetition rate or set no crosstalk";
    out.push_back(v);
  }
  return out;
}

double waveform_step_ns(const DeviceConfig& config) {
  return std::min(config.measurement.sample_period_ps * 1e-3,
                  receiver_tau_ns(config) / kWaveformSamplesPerPole);
}

std::vector<LimitViolation> check_waveform_limits(const DeviceConfig& config,
                                                  double echo_spread_ns) {
  std::vector<LimitViolation> out = check_config_limits(config);
  const double dt_ns = waveform_step_ns(config);
  const double tau = receiver_tau_ns(config);
  // Record: from before the earliest rise (4 ns + 6 tau) to after the latest
  // fall (4 ns), around the echo and the template; burn-in of 6 tau before it.
  const double record_ns = std::max(config.measurement.window_ns,
                                    template_span_ns(config) + echo_spread_ns + 8.0 + 6.0 * tau) +
                           6.0 * tau;
  const double samples = record_ns / dt_ns;
  if (!(samples <= kMaxRecordSamples)) {
    LimitViolation v;
    v.keys = {"measurement.sample_period_ps", "measurement.window_ns"};
    v.message = "measurement.sample_period_ps = " + number(config.measurement.sample_period_ps) +
                " samples the waveform record of " + number(record_ns) + " ns (window " +
                number(config.measurement.window_ns) + " ns, echo, pulse and receiver) in " +
                number(samples) + " samples per shot, more than " + number(kMaxRecordSamples) +
                "; raise the sample period";
    out.push_back(v);
  }
  return out;
}

double plate_echo_spread_ns(const DeviceConfig& config, double distance_m, double angle_deg) {
  const auto& laser = config.link.laser;
  const double footprint_m =
      laser.exit_beam_diameter_mm * 1e-3 + distance_m * laser.beam_divergence_mrad * 1e-3;
  const double depth_m = footprint_m * std::tan(angle_deg * kPi / 180.0);
  return 2.0 * depth_m / kLightMPerNs;
}

std::string check_plate_echo(const DeviceConfig& config, double distance_m, double angle_deg) {
  const double spread_ns = plate_echo_spread_ns(config, distance_m, angle_deg);
  const double samples = (spread_ns + template_span_ns(config)) / kEchoStepNs;
  if (samples <= kMaxEchoSamples) return {};
  return "a plate at " + number(distance_m) + " m and " + number(angle_deg) +
         " deg spreads its echo over " + number(spread_ns) + " ns (" + number(samples) +
         " samples of 10 ps, more than " + number(kMaxEchoSamples) +
         "); use a smaller distance or angle";
}

}  // namespace tofkit::device
