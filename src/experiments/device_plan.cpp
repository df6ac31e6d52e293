#include "tofkit/experiments/device_plan.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <stdexcept>
#include <string>

#include "tofkit/calib/uncertainty_budget.hpp"
#include "tofkit/physics/link_budget.hpp"

namespace tofkit::experiments {
namespace {

double rounded4(double v) {
  return std::round(v * 1e4) / 1e4;
}

}  // namespace

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
  const double tdc_period_ns = 1e3 / config.tdc.coarse_clock_mhz;
  if (config.tdc.laser_sync && !config.oscillator.enabled) options.tdc_period_ns = tdc_period_ns;
  options.extrapolation_refit = true;  // the budget's extrapolation term
  calib::ModelFitResult fit = calib::fit_model(records, options);

  // The budget, every term from the factory's own rows (type A): the
  // repeats (repeatability), the sweep (the periodic residual: it spans the
  // TDC's period whether or not the laser fires on its clock), the plates
  // cross-validated (the correction's residual), the temperature run, a
  // stability record of the temperature run's plate after the calibration
  // (drift since calibration, same power-on) and the plan's plates once on
  // kFactoryPowerOns other power-ons (what a row on another power-on, a
  // customer's scan, carries: the offset between power-ons and the wander at
  // its time against the calibration's).
  const ProtocolOptions protocol;
  const double period_s = output_period_s(config);
  std::vector<PlannedMeasurement> stability(
      static_cast<std::size_t>(
          std::lround(protocol.stability_minutes * 60 / protocol.stability_every_s)) +
          1,
      plate(rounded4(plan.temperature_plate.distance_m),
            rounded4(plan.temperature_plate.reflectance), ambient_c));
  const RunTiming after{std::ceil(static_cast<double>(records.size()) * period_s),
                        protocol.stability_every_s};
  const std::vector<ranging::Record> stability_rows = run(device, stability, seed, after);
  calib::ProtocolSteps steps;
  steps.stability = stability_rows;
  steps.stability_every_s = protocol.stability_every_s;
  steps.tdc_period_ns = tdc_period_ns;
  const std::vector<PlannedMeasurement> plates = plan_measurements(plan, 1);
  const std::vector<PlannedMeasurement> at_ambient(
      plates.begin(), plates.begin() + static_cast<std::ptrdiff_t>(plan.plates.size()));
  for (int k = 0; k < kFactoryPowerOns; ++k) {
    // Power-ons of their own (a SplitMix64 step of the seed): a customer's
    // run on seed s is not one of them.
    std::uint64_t z = seed + 0x9E3779B97F4A7C15ULL * static_cast<std::uint64_t>(k + 1);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ULL;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBULL;
    steps.power_on_runs.push_back(run(device, at_ambient, z ^ (z >> 31)));
  }
  calib::BudgetFitResult budget = calib::fit_model_budget(records, fit, steps, {});
  fit.budget = std::move(budget.budget);
  fit.report += budget.report;
  return fit;
}

namespace {

/// One grid per distance of a plate list (plates sharing a distance together).
std::vector<PlateGrid> grids_of(const std::vector<calib::PlannedPlate>& plates, int count) {
  std::vector<PlateGrid> grids;
  for (const auto& p : plates) {
    const double d = rounded4(p.distance_m);
    auto it = std::find_if(grids.begin(), grids.end(),
                           [&](const PlateGrid& g) { return g.distances_m.front() == d; });
    if (it == grids.end()) {
      PlateGrid g;
      g.distances_m = {d};
      g.count = count;
      grids.push_back(g);
      it = grids.end() - 1;
    }
    it->reflectances.push_back(rounded4(p.reflectance));
  }
  return grids;
}

/// The grid at the plan's distance: the one with the most plates (the
/// field's middle powers; the others are plates moved for the extremes).
PlateGrid main_grid(const std::vector<calib::PlannedPlate>& plates, int count) {
  const std::vector<PlateGrid> grids = grids_of(plates, count);
  return *std::max_element(grids.begin(), grids.end(), [](const auto& a, const auto& b) {
    return a.reflectances.size() < b.reflectances.size();
  });
}

}  // namespace

Protocol plan_protocol(const device::VirtualRangefinder& device,
                       calib::CalibrationPlanOptions field, const ProtocolOptions& o) {
  if (o.count < 2)
    throw std::invalid_argument("count must be >= 2 (the repeatability needs repeats)");
  if (!(o.rail_steps_per_period >= 4 && o.rail_steps_per_period <= 1000))
    throw std::invalid_argument("rail_steps_per_period must be in [4, 1000]");
  if (!(o.stability_minutes > 0 && o.stability_every_s > 0 &&
        o.stability_minutes * 60 / o.stability_every_s >= 8 &&
        o.stability_minutes * 60 / o.stability_every_s <= 1e5))
    throw std::invalid_argument("stability_minutes / stability_every_s must give 8 to 100000 rows");
  if (!(o.temperature_ramp_every_c >= 0.1 && o.temperature_ramp_every_c <= 100))
    throw std::invalid_argument("temperature_ramp_every_c must be in [0.1, 100] C");
  if (!(o.ramp_c_per_min > 0 && o.ramp_c_per_min <= 100))
    throw std::invalid_argument("ramp_c_per_min must be in (0, 100] C/min");
  if (o.power_ons < 0 || o.power_ons > 20)
    throw std::invalid_argument("power_ons must be in [0, 20]");
  const auto& config = device.config();
  Protocol protocol;
  protocol.tdc_period_ns = 1e3 / config.tdc.coarse_clock_mhz;
  protocol.tdc_period_m =
      protocol.tdc_period_ns * ranging::metres_per_ns(device::nominal_time_to_distance(config));
  field.single_distance = !o.complete;
  const calib::CalibrationPlan plan = plan_for_device(device, field);
  const double period_s = output_period_s(config);
  if (o.complete) {
    ProtocolStep s;
    s.file = "stability.csv";
    s.observes = "drift after calibration (Allan deviation of a static target)";
    s.role = StepRole::stability;
    s.grid.distances_m = {rounded4(plan.temperature_plate.distance_m)};
    s.grid.reflectances = {rounded4(plan.temperature_plate.reflectance)};
    s.grid.count =
        static_cast<int>(std::lround(o.stability_minutes * 60 / o.stability_every_s)) + 1;
    s.timing.every_s = o.stability_every_s;
    s.bench_minutes = o.stability_minutes;
    protocol.steps.push_back(s);
    protocol.calibration_start_s =
        std::ceil(static_cast<double>(s.grid.count) * o.stability_every_s);
  }
  // The calibration rows, back to back from calibration_start_s.
  double start_s = protocol.calibration_start_s;
  const auto add = [&](ProtocolStep s) {
    s.timing.start_s = start_s;
    start_s += s.grid.rows() * period_s;
    protocol.steps.push_back(std::move(s));
  };
  int part = 0;
  for (const PlateGrid& g : grids_of(plan.plates, o.count)) {
    ProtocolStep s;
    s.file = "plates" + std::to_string(++part) + ".csv";
    s.observes = "walk and gray value over the field's echo powers";
    s.grid = g;
    s.bench_minutes = 2.0 * static_cast<double>(g.reflectances.size());
    add(s);
  }
  if (o.complete) {
    // Plates at a second distance, farther: the range dependence the chain's
    // offset cannot see from one.
    calib::CalibrationPlanOptions second = field;
    second.single_distance = false;
    second.calibration_distance_m =
        std::round(10.0 * 0.5 * (plan.calibration_distance_m + field.range_max_m)) / 10.0;
    const calib::CalibrationPlan far = plan_for_device(device, second);
    // Only the plates standing there: the ones moved nearer or farther for
    // powers no plate returns at the second distance are the first set's.
    std::vector<calib::PlannedPlate> there;
    for (const auto& p : far.plates)
      if (rounded4(p.distance_m) == rounded4(second.calibration_distance_m)) there.push_back(p);
    for (const PlateGrid& g : grids_of(there, o.count)) {
      ProtocolStep s;
      s.file = "plates" + std::to_string(++part) + ".csv";
      s.observes = "the same echo powers at a second distance";
      s.grid = g;
      s.bench_minutes = 2.0 * static_cast<double>(g.reflectances.size());
      add(s);
    }
    // The rail: at least one TDC period, steps that resolve its harmonics.
    ProtocolStep s;
    s.file = "rail.csv";
    s.observes = "errors periodic in the time of flight (TDC nonlinearity, period " +
                 std::to_string(protocol.tdc_period_m).substr(0, 5) + " m)";
    const double step = protocol.tdc_period_m / o.rail_steps_per_period;
    const double last = std::max(field.range_max_m, field.range_min_m + protocol.tdc_period_m);
    for (double d = field.range_min_m; d <= last + 1e-9; d += step)
      s.grid.distances_m.push_back(rounded4(d));
    s.grid.reflectances = {rounded4(plan.temperature_plate.reflectance)};
    s.grid.count = o.count;
    s.bench_minutes = 0.5 * static_cast<double>(s.grid.distances_m.size());
    add(s);
  }
  {
    ProtocolStep s;
    s.file = "temperature.csv";
    s.observes = "delays' temperature dependence (temperature run)";
    s.grid.distances_m = {rounded4(plan.temperature_plate.distance_m)};
    s.grid.reflectances = {rounded4(plan.temperature_plate.reflectance)};
    if (o.complete) {
      // A weak, the middle and a strong plate of the plan's distance: the
      // APD's gain and the walk change with temperature by echo strength.
      const PlateGrid at = main_grid(plan.plates, o.count);
      s.grid.distances_m = at.distances_m;
      s.grid.reflectances = {at.reflectances.front(), at.reflectances[at.reflectances.size() / 2],
                             at.reflectances.back()};
      std::sort(s.grid.reflectances.begin(), s.grid.reflectances.end());
      s.grid.reflectances.erase(std::unique(s.grid.reflectances.begin(), s.grid.reflectances.end()),
                                s.grid.reflectances.end());
      s.observes = "delays' and walk's temperature dependence, by echo strength (temperature run)";
    }
    s.grid.ambient_c = plan.temperatures_c;
    s.grid.count = o.count;
    s.bench_minutes = 30.0 * static_cast<double>(plan.temperatures_c.size());  // soak per step
    if (o.complete && plan.temperatures_c.size() >= 2) {
      // A slow ramp instead of soaked steps: the field's temperatures fall
      // anywhere, and what the temperature function leaves between the steps
      // (a kink it placed wrong) is seen only where the run was read.
      const double lo = plan.temperatures_c.front(), hi = plan.temperatures_c.back();
      s.grid.ambient_c.clear();
      for (double t = lo; t <= hi + 1e-9; t += o.temperature_ramp_every_c)
        s.grid.ambient_c.push_back(std::round(t * 100) / 100);
      char every[32];
      std::snprintf(every, sizeof every, "%g", o.temperature_ramp_every_c);
      s.observes += std::string(", a ramp read every ") + every + " C";
      s.bench_minutes = (hi - lo) / o.ramp_c_per_min;
    }
    add(s);
    if (o.complete && protocol.tdc_period_m > 0) {
      // The temperature plate at 16 phases of the TDC's period in the same
      // ramp: the fine bins' width follows the timing board's
      // temperature, so what the temperature does to a row depends on where
      // its stop falls in the coarse period (a sawtooth over the distance);
      // one distance sees one phase of that, and the temperature function
      // fitted there absorbs it. Sixteen phases make the function fit their
      // mean and show the rest (both stops are quantized, and the walk
      // correction reads their difference: more than a sawtooth's harmonics).
      constexpr int kPhases = 16;
      ProtocolStep phases = s;
      phases.file = "temperature2.csv";
      phases.observes = "the temperature dependence over the TDC's period (fine-bin width)";
      phases.grid.reflectances = {rounded4(plan.temperature_plate.reflectance)};
      phases.grid.distances_m.clear();
      // At the soaked run's temperatures, each twice: their change from the
      // reference, not their noise, is what is sought (the ramp's plates give
      // the temperature function's shape between them).
      phases.grid.ambient_c = plan.temperatures_c;
      phases.grid.count = 2;
      const double d0 = rounded4(plan.temperature_plate.distance_m);
      for (int k = 0; k < kPhases; ++k) {
        const double d = d0 + protocol.tdc_period_m * k / kPhases;
        phases.grid.distances_m.push_back(
            rounded4(d <= field.range_max_m ? d : d - protocol.tdc_period_m));
      }
      phases.bench_minutes = 0;  // read in the same ramp
      add(phases);
    }
    const calib::PlannedPlate* weakest = plan.plates.empty() ? nullptr : &plan.plates.front();
    if (o.complete && weakest && rounded4(weakest->distance_m) != s.grid.distances_m.front()) {
      // The field's weakest echo power, at its own distance, in the same
      // ramp: the plan places it by power at the receiver's nominal
      // temperature, and the APD's gain falls with heat, so hot it returns
      // less than any plate of the plan's distance does and shots begin to
      // miss the threshold. The walk's weak end, the extrapolation and the
      // lost-shot terms see that corner only here.
      ProtocolStep weak = s;
      weak.file = "temperature3.csv";
      weak.observes =
          "the field's weakest echo power over the temperature run (gain falls with heat)";
      weak.grid.distances_m = {rounded4(weakest->distance_m)};  // plates ascend in power
      weak.grid.reflectances = {rounded4(weakest->reflectance)};
      weak.bench_minutes = 0;  // read in the same ramp
      add(weak);
    }
  }
  if (o.complete) {
    for (int k = 0; k < o.power_ons; ++k) {
      ProtocolStep s;
      s.file = "poweron" + std::to_string(k + 2) + ".csv";
      s.observes = "the offset between power-ons";
      s.role = StepRole::power_on;
      s.grid = main_grid(plan.plates, o.count);
      s.seed = static_cast<std::uint64_t>(k + 2);
      s.timing.start_s = protocol.calibration_start_s;
      s.bench_minutes = o.stability_minutes + 2.0 * static_cast<double>(s.grid.reflectances.size());
      protocol.steps.push_back(s);
    }
  } else {
    protocol.unobserved = {
        "the TDC's nonlinearity, periodic in the time of flight (every plate at one distance)",
        "drift after the calibration (no stability record)",
        "the offset between power-ons (one power-on)"};
  }
  return protocol;
}

}  // namespace tofkit::experiments
