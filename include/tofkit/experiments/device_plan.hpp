#pragma once
/// \file A calibration plan for a device: calib::plan_calibration (link
/// budget, paper Eq. 6) with what the device's receiver adds, the received
/// power at which its echo clips.

#include "tofkit/calib/calibration_plan.hpp"
#include "tofkit/device/virtual_rangefinder.hpp"
#include "tofkit/experiments/measurement_grid.hpp"

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

#include <cstdint>

#include "tofkit/calib/model_fit.hpp"

namespace tofkit::experiments {

/// The chain a factory calibration fits (`tofkit fit --chain` spelling).
inline constexpr const char* kFactoryChain = "offset,grayvalue,temperature";

/// The plan's measurements as `tofkit plan` prints them: every plate
/// `count` times at 20 C, then the temperature run (distances and
/// reflectances rounded to 4 decimals, as the printed lines carry them).
[[nodiscard]] std::vector<PlannedMeasurement> plan_measurements(const calib::CalibrationPlan& plan,
                                                                int count = 5);

/// Spacing of the factory calibration's distance sweep, m.
inline constexpr double kFactorySweepStep_m = 0.003;

/// A factory calibration of the device, measured at `seed`: the default plan
/// (`tofkit plan` without options: plates at 20 C and the temperature run),
/// plus the temperature run's plate swept over the field's ranges (0.5-8 m)
/// every kFactorySweepStep_m; fitted: the chain kFactoryChain, behind a
/// periodic step in the time of flight when the laser fires on the TDC's
/// clock (`fit --tdc-periodic`), with its calibrated confidence. What `tofkit scan` corrects with
/// when no --model is given, so a scan's ranges are calibrated, as a lidar's are.
[[nodiscard]] calib::ModelFitResult factory_calibration(const device::DeviceConfig& config,
                                                        std::uint64_t seed = 1);

}  // namespace tofkit::experiments
