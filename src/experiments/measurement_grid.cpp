#include "tofkit/experiments/measurement_grid.hpp"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <cmath>
#include <stdexcept>
#include <string>

namespace tofkit::experiments {

PlannedMeasurement planned(device::Target target, const device::Conditions& conditions, int shots) {
  PlannedMeasurement p;
  p.truth.ambient_c = conditions.ambient_c;
  if (!target.surfaces.empty()) {
    const auto& s = target.surfaces.front();
    p.truth.distance_m = s.distance_m;
    p.truth.reflectance = s.reflectance;
    p.truth.angle_deg = device::incidence_angle_deg(s.cos_incidence);
  }
  p.request = {std::move(target), conditions, shots};
  return p;
}

PlannedMeasurement plate(double distance_m, double reflectance, double ambient_c, double angle_deg,
                         int shots) {
  device::Conditions conditions;
  conditions.ambient_c = ambient_c;
  PlannedMeasurement p =
      planned(device::Target::plate(distance_m, reflectance, angle_deg), conditions, shots);
  p.truth.angle_deg = angle_deg;  // as given (not back from its cosine)
  return p;
}

std::vector<ranging::Record> run(const device::VirtualRangefinder& device,
                                 std::span<const PlannedMeasurement> plan, std::uint64_t seed) {
  std::vector<ranging::Record> records(plan.size());
  run(device, plan, seed, records);
  return records;
}

void run(const device::VirtualRangefinder& device, std::span<const PlannedMeasurement> plan,
         std::uint64_t seed, std::span<ranging::Record> out) {
  if (out.size() != plan.size())
    throw std::invalid_argument("run: " + std::to_string(out.size()) + " records for a plan of " +
                                std::to_string(plan.size()));
  std::vector<device::MeasureRequest> requests;
  requests.reserve(plan.size());
  for (const auto& p : plan) requests.push_back(p.request);
  std::vector<ranging::RawMeasurement> raw(requests.size());
  device.measure_batch(requests, seed, raw);
  for (std::size_t i = 0; i < raw.size(); ++i) out[i] = {plan[i].truth, raw[i]};
}

double output_period_s(const device::DeviceConfig& config) {
  return static_cast<double>(config.measurement.shots) / config.link.laser.repetition_hz;
}

void RunTiming::validate(const device::DeviceConfig& config) const {
  const double period = output_period_s(config);
  if (!(std::isfinite(start_s) && start_s >= 0 && start_s <= 1e7))
    throw std::invalid_argument("start_s must be in [0, 1e7] s");
  if (!(std::isfinite(every_s) && every_s >= 0 && every_s <= 1e6))
    throw std::invalid_argument("every_s must be in [0, 1e6] s");
  if (every_s > 0 && every_s < period)
    throw std::invalid_argument("every_s must be 0 or at least one output period (" +
                                std::to_string(period) +
                                " s: measurement.shots / "
                                "laser.repetition_hz)");
}

std::vector<ranging::Record> run(const device::VirtualRangefinder& device,
                                 std::span<const PlannedMeasurement> plan, std::uint64_t seed,
                                 const RunTiming& timing) {
  timing.validate(device.config());
  if (timing.start_s == 0 && timing.every_s == 0) return run(device, plan, seed);
  // The device's slow offsets (power-on offset, flicker, wander) read the time
  // of stream i as i output periods after power-on: output k of this run is
  // on the stream of its start time (its own shots' draws, so no two outputs
  // share them when every_s >= one period).
  const double period = output_period_s(device.config());
  const auto first = static_cast<std::uint64_t>(std::llround(timing.start_s / period));
  const auto step = static_cast<std::uint64_t>(
      std::max(1LL, std::llround((timing.every_s > 0 ? timing.every_s : period) / period)));
  std::vector<ranging::Record> out(plan.size());
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, plan.size(), 16),
                    [&](const tbb::blocked_range<std::size_t>& range) {
                      for (std::size_t k = range.begin(); k != range.end(); ++k) {
                        const auto& r = plan[k].request;
                        out[k] = {
                            plan[k].truth,
                            device.measure(r.target, r.conditions, seed,
                                           first + static_cast<std::uint64_t>(k) * step, r.shots)};
                      }
                    });
  return out;
}

std::vector<double> log_spaced(double first, double last, int count) {
  std::vector<double> v;
  for (int i = 0; i < count; ++i) {
    const double f = count > 1 ? double(i) / (count - 1) : 0.0;
    v.push_back(first * std::pow(last / first, f));
  }
  return v;
}

std::vector<double> lin_spaced(double first, double last, int count) {
  std::vector<double> v;
  for (int i = 0; i < count; ++i) {
    const double f = count > 1 ? double(i) / (count - 1) : 0.0;
    v.push_back(first + (last - first) * f);
  }
  return v;
}

device::DeviceConfig indoors(device::DeviceConfig config) {
  config.link.environment.solar_irradiance_w_per_m2_um = 0.0;
  config.link.environment.sky_radiance_w_per_m2_sr_um = 0.0;
  return config;
}

}  // namespace tofkit::experiments
