#pragma once
/// \file Running a list of (target, conditions) measurements on a device and
/// keeping the truth beside each result: the common core of every protocol.

#include <cstdint>
#include <span>
#include <vector>

#include "tofkit/device/virtual_rangefinder.hpp"
#include "tofkit/ranging/raw_measurement.hpp"

namespace tofkit::experiments {

/// One planned measurement: what is out there, and what the truth columns say.
struct PlannedMeasurement {
  device::MeasureRequest request;
  ranging::GroundTruth truth;
};

/// A measurement of `target` under `conditions` (`shots` 0: the device's
/// measurement.shots), its truth that of the target's first surface.
[[nodiscard]] PlannedMeasurement planned(device::Target target,
                                         const device::Conditions& conditions, int shots = 0);

/// A flat Lambertian plate at normal or oblique incidence.
[[nodiscard]] PlannedMeasurement plate(double distance_m, double reflectance, double ambient_c,
                                       double angle_deg = 0.0, int shots = 0);

/// Measures every plan (plan i on random stream i, all cores; reproducible for
/// a seed, any thread count) and pairs each result with its truth: the one way
/// every protocol, characterization and test measures.
[[nodiscard]] std::vector<ranging::Record> run(const device::VirtualRangefinder& device,
                                               std::span<const PlannedMeasurement> plan,
                                               std::uint64_t seed);
/// The same into `out` (one record per plan; throws std::invalid_argument when
/// the sizes differ), e.g. a NumPy array's memory.
void run(const device::VirtualRangefinder& device, std::span<const PlannedMeasurement> plan,
         std::uint64_t seed, std::span<ranging::Record> out);

/// Time between a device's outputs, s (measurement.shots / laser.repetition_hz):
/// the device's slow offsets read output i of a run as i periods after power-on.
[[nodiscard]] double output_period_s(const device::DeviceConfig& config);

/// When a run's outputs are taken: output k starts start_s + k * every_s after
/// power-on (the seed is the power-on); every_s 0: back to back, one output
/// period apart. {0, 0} is run()'s timing.
struct RunTiming {
  double start_s = 0;
  double every_s = 0;
  /// Throws std::invalid_argument naming the bad field.
  void validate(const device::DeviceConfig& config) const;
};

/// run() at the given timing (the same bytes as run() for {0, 0}); so a field
/// test can follow its calibration on the same power-on, and a stability
/// record can span an hour in a few hundred outputs.
[[nodiscard]] std::vector<ranging::Record> run(const device::VirtualRangefinder& device,
                                               std::span<const PlannedMeasurement> plan,
                                               std::uint64_t seed, const RunTiming& timing);

/// `count` values from `first` to `last`, evenly spaced on a log scale.
[[nodiscard]] std::vector<double> log_spaced(double first, double last, int count);
/// `count` values from `first` to `last`, evenly spaced.
[[nodiscard]] std::vector<double> lin_spaced(double first, double last, int count);

/// The config with the sunlight switched off: the paper's Section 5 tests ran
/// indoors, where only the echo and the receiver's own noise reach the APD.
[[nodiscard]] device::DeviceConfig indoors(device::DeviceConfig config);

}  // namespace tofkit::experiments
