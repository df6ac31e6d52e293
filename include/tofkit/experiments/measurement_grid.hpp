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

/// `count` values from `first` to `last`, evenly spaced on a log scale.
[[nodiscard]] std::vector<double> log_spaced(double first, double last, int count);
/// `count` values from `first` to `last`, evenly spaced.
[[nodiscard]] std::vector<double> lin_spaced(double first, double last, int count);

/// The config with the sunlight switched off: the paper's Section 5 tests ran
/// indoors, where only the echo and the receiver's own noise reach the APD.
[[nodiscard]] device::DeviceConfig indoors(device::DeviceConfig config);

}  // namespace tofkit::experiments
