#include "tofkit/experiments/measurement_grid.hpp"

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
