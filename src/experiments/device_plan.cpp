#include "tofkit/experiments/device_plan.hpp"

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

}  // namespace tofkit::experiments
