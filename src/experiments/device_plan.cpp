#include "tofkit/experiments/device_plan.hpp"

#include <cmath>

#include "tofkit/physics/link_budget.hpp"

namespace tofkit::experiments {

double clip_power_w(const device::VirtualRangefinder& device) {
  const physics::LinkConfig& link = device.config().link;
  double distance_m = 10.0;  // biaxial optics: where the field of view holds the footprint
  while (physics::overlap_fraction(link.laser, link.receiver, distance_m) < 1.0 && distance_m < 1e4)
    distance_m *= 2.0;
  const double power_w = physics::received_power_extended_w(link, distance_m, 1.0, 0.0);
  const double peak_v = device.echo(device::Target::plate(distance_m, 1.0), {}).peak_v;
  return link.receiver.saturation_v * power_w / peak_v;
}

calib::CalibrationPlan plan_for_device(const device::VirtualRangefinder& device,
                                       calib::CalibrationPlanOptions options) {
  options.clip_power_w = clip_power_w(device);
  return calib::plan_calibration(device.config().link, options);
}

std::vector<PlannedMeasurement> plan_measurements(const calib::CalibrationPlan& plan, int count) {
  // The printed lines carry 4 decimals; the factory measures what they say.
  const auto rounded = [](double v) { return std::round(v * 1e4) / 1e4; };
  const double ambient_c = device::Conditions{}.ambient_c;
  std::vector<PlannedMeasurement> out;
  for (const auto& p : plan.plates) {
    for (int k = 0; k < count; ++k)
      out.push_back(plate(rounded(p.distance_m), rounded(p.reflectance), ambient_c));
  }
  for (const double t : plan.temperatures_c) {
    for (int k = 0; k < count; ++k)
      out.push_back(plate(rounded(plan.temperature_plate.distance_m),
                          rounded(plan.temperature_plate.reflectance), t));
  }
  return out;
}

calib::ModelFitResult factory_calibration(const device::DeviceConfig& config, std::uint64_t seed) {
  const device::VirtualRangefinder device(config);
  const calib::CalibrationPlanOptions field;
  const calib::CalibrationPlan plan = plan_for_device(device, field);
  std::vector<PlannedMeasurement> measurements = plan_measurements(plan);
  // A sweep of the temperature run's plate over the field's ranges, one
  // measurement every kFactorySweepStep_m: with the laser fired on the TDC's
  // clock the interpolator's nonlinearity repeats every coarse period
  // (0.75 m at 200 MHz), and plates at a few distances cannot see it.
  const double ambient_c = device::Conditions{}.ambient_c;
  for (double d = field.range_min_m; d <= field.range_max_m; d += kFactorySweepStep_m)
    measurements.push_back(plate(d, plan.temperature_plate.reflectance, ambient_c));
  const std::vector<ranging::Record> records = run(device, measurements, seed);
  calib::ModelFitOptions options;
  options.time_to_distance = device::nominal_time_to_distance(config);
  options.chain = calib::parse_chain_steps(kFactoryChain);
  if (config.tdc.laser_sync && !config.oscillator.enabled)
    options.tdc_period_ns = 1e3 / config.tdc.coarse_clock_mhz;
  return calib::fit_model(records, options);
}

}  // namespace tofkit::experiments
