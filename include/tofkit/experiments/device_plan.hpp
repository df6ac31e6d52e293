#pragma once
/// \file A calibration plan for a device: calib::plan_calibration (link
/// budget, paper Eq. 6) with what the device's receiver adds, the received
/// power at which its echo clips.

#include "tofkit/calib/calibration_plan.hpp"
#include "tofkit/device/virtual_rangefinder.hpp"

namespace tofkit::experiments {

/// Received peak power (W, paper Eq. 6 at normal incidence) above which the
/// device's echo clips (receiver.saturation_v): the echo peak is linear in the
/// received power, so one noise-free echo of a white plate, far enough for the
/// receiver to see the whole footprint, gives the volts per watt (20 C).
[[nodiscard]] double clip_power_w(const device::VirtualRangefinder& device);

/// calib::plan_calibration for the device's link, with its clip power (the
/// single distance then makes the brightest plates clip when the field does).
[[nodiscard]] calib::CalibrationPlan plan_for_device(const device::VirtualRangefinder& device,
                                                     calib::CalibrationPlanOptions options);

}  // namespace tofkit::experiments
