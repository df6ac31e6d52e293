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
#include <string>
#include <vector>

#include "tofkit/calib/model_fit.hpp"
#include "tofkit/experiments/plate_grid.hpp"

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

/// Other power-ons the factory calibration measures the plan's plates on, once
/// each: its budget's power-on term (a customer's row on another power-on) is
/// their mean residuals' rms.
inline constexpr int kFactoryPowerOns = 100;

/// A factory calibration of the device, measured at `seed`: the default plan
/// (`tofkit plan` without options: plates at 20 C and the temperature run),
/// plus the temperature run's plate swept over the field's ranges (0.5-8 m)
/// every kFactorySweepStep_m; fitted: the chain kFactoryChain, behind a
/// periodic step in the time of flight when the laser fires on the TDC's
/// clock (`fit --tdc-periodic`), with its calibrated confidence and an
/// uncertainty budget (ModelFitResult::budget) fitted from the same rows, a
/// stability record after them and the plates on kFactoryPowerOns other
/// power-ons (every term type A). What `tofkit scan` corrects with
/// when no --model is given, so a scan's ranges are calibrated, as a lidar's are.
[[nodiscard]] calib::ModelFitResult factory_calibration(const device::DeviceConfig& config,
                                                        std::uint64_t seed = 1);

// ------------------------------------------------------------ the protocol

/// What a protocol's step is for.
enum class StepRole {
  calibration,  ///< rows the correction is fitted on (`fit --in`)
  stability,    ///< a static target over time (`fit --stability`)
  power_on,     ///< repeats on another power-on (`fit --power-on`)
};

/// One `tofkit measure` line of a protocol: a plate grid, its power-on (seed)
/// and its timing after power-on.
struct ProtocolStep {
  std::string file;      ///< output file, "plates1.csv"
  std::string observes;  ///< the cause (or budget component) it observes
  StepRole role = StepRole::calibration;
  PlateGrid grid;
  std::uint64_t seed = 1;
  RunTiming timing;
  double bench_minutes = 0;  ///< on a bench: moving targets, soaking, waiting
};

struct ProtocolOptions {
  int count = 5;  ///< repeats per plate
  /// false: the paper's protocol (plates at one distance and a temperature
  /// run); true: every cause (plates at two distances, a rail over the TDC's
  /// period, the temperature run, a stability record, other power-ons).
  bool complete = true;
  /// rail distances per TDC period: as many phases of the period; the echo's
  /// walk along the rail spreads the stops between them (held-out case 0: 240
  /// distinct phases of 1000 among the calibration's rows, 11 harmonics chosen)
  double rail_steps_per_period = 8;
  /// The stability record's length: its structure function reaches 3/4 of it
  /// (a lag needs pairs), so 80 min observe the drift to 60 min after the
  /// calibration; beyond the last lag the drift term is held.
  double stability_minutes = 80;
  double stability_every_s = 15;  ///< its spacing
  int power_ons = 2;              ///< repeats on this many other power-ons
  /// The temperature run as a slow ramp read every this many C (the field's
  /// temperatures fall anywhere between a soaked run's steps, where a fitted
  /// temperature function can miss the device's kinks: a heater's setpoint
  /// and its limit); ramped at ramp_c_per_min for the bench's duration.
  double temperature_ramp_every_c = 2.5;
  double ramp_c_per_min = 0.2;
};

struct Protocol {
  std::vector<ProtocolStep> steps;
  double calibration_start_s = 0;  ///< the calibration rows' start after power-on
  double tdc_period_ns = 0;        ///< the device's coarse clock period
  double tdc_period_m = 0;         ///< the same as a distance
  /// Causes this protocol leaves to type B terms (the paper's: the TDC's
  /// periodic nonlinearity, drift after calibration, the power-on offset).
  std::vector<std::string> unobserved;
};

/// The protocol for a device and a field (calib::CalibrationPlanOptions):
/// with `complete`, a stability record first (a static target for
/// stability_minutes, while the device settles), then the calibration rows
/// (plates at the plan's distance and at a second one, farther, a rail of the
/// temperature run's plate over the field's ranges in steps of a TDC period /
/// rail_steps_per_period, at least one period long, and the temperature run),
/// then repeats of the plates at the plan's distance on `power_ons` other
/// seeds at the same time after their power-on. The paper's protocol: the plan
/// with single_distance and the temperature run only.
[[nodiscard]] Protocol plan_protocol(const device::VirtualRangefinder& device,
                                     calib::CalibrationPlanOptions field,
                                     const ProtocolOptions& options);

}  // namespace tofkit::experiments
