#include "tofkit/experiments/measurement_grid.hpp"

#include <cmath>
#include <stdexcept>

namespace tofkit::experiments {

PlannedMeasurement plate(double distance_m, double reflectance, double ambient_c, double angle_deg,
                         int shots) {
  PlannedMeasurement p;
  p.request.target = device::Target::plate(distance_m, reflectance, angle_deg);
  p.request.conditions.ambient_c = ambient_c;
  p.request.shots = shots;
  p.truth = {distance_m, reflectance, angle_deg, ambient_c};
  return p;
}

std::vector<ranging::Record> measure_records(const device::VirtualRangefinder& device,
                                             std::span<const device::MeasureRequest> requests,
                                             std::span<const ranging::GroundTruth> truths,
                                             std::uint64_t seed) {
  if (requests.size() != truths.size())
    throw std::invalid_argument("measure_records: requests and truths differ in length");
  std::vector<ranging::RawMeasurement> raw(requests.size());
  device.measure_batch(requests, seed, raw);
  std::vector<ranging::Record> records(requests.size());
  for (std::size_t i = 0; i < raw.size(); ++i) records[i] = {truths[i], raw[i]};
  return records;
}

std::vector<ranging::Record> run(const device::VirtualRangefinder& device,
                                 std::span<const PlannedMeasurement> plan, std::uint64_t seed) {
  std::vector<device::MeasureRequest> requests;
  std::vector<ranging::GroundTruth> truths;
  requests.reserve(plan.size());
  truths.reserve(plan.size());
  for (const auto& p : plan) {
    requests.push_back(p.request);
    truths.push_back(p.truth);
  }
  return measure_records(device, requests, truths, seed);
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
