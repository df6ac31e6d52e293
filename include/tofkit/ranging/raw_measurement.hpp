#pragma once
/// \file
/// The record every rangefinder reports, whatever produced it (virtual device,
/// a real device's byte stream, a CSV file), and the corrected range the
/// ranging pipeline turns it into.

#include <cstdint>
#include <limits>

namespace tofkit::ranging {

inline constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

/// Largest |value| of a measurement's number that is a measurement: fits and
/// evaluations refuse a larger one as a corrupt cell (their squares and sums of
/// squares over any realistic row count stay finite: 1e100^2 * 1e9 rows <<
/// DBL_MAX), and the pipeline reads it as missing (NaN).
inline constexpr double kMaxMagnitude = 1e100;

/// Status bits of a RawMeasurement (`flags` column).
enum RawFlag : std::uint32_t {
  kRawNoEcho = 1u << 0,           ///< no echo (no shot crossed the threshold, or false stops
                                  ///< outnumbered the echo's); distance is empty
  kRawPartialEchoes = 1u << 1,    ///< some, not all, shots gave an echo
  kRawSaturated = 1u << 2,        ///< the amplifier clipped (mean echo above saturation)
  kRawTurnOnTransient = 1u << 3,  ///< taken while the laser was still in its turn-on transient
  kRawWarmingUp = 1u << 4,        ///< taken before the electronics reached thermal equilibrium
};

/// One output of a rangefinder: the average of `shots_valid` shots.
struct RawMeasurement {
  double tof_ns = kNaN;           ///< mean round-trip time of flight (rising-edge timing)
  double distance_raw_m = kNaN;   ///< tof converted with the nominal speed of light in air
  double pulse_width_ns = kNaN;   ///< mean echo pulse width (time over threshold)
  double amplitude = kNaN;        ///< echo peak amplitude ("intensity"), volts at the comparator
  double temperature_c = kNaN;    ///< internal temperature sensor reading
  std::uint32_t shots_valid = 0;  ///< shots that produced an echo
  std::uint32_t flags = 0;        ///< RawFlag bits

  [[nodiscard]] bool has_echo() const { return shots_valid > 0 && (flags & kRawNoEcho) == 0; }
};

/// What was true when a measurement was taken (known in calibration; NaN otherwise).
struct GroundTruth {
  double distance_m = kNaN;   ///< true distance to the target
  double reflectance = kNaN;  ///< Lambertian reflectance of the (main) surface
  double angle_deg = kNaN;    ///< incidence angle of the beam on the surface
  double ambient_c = kNaN;    ///< ambient temperature
};

/// A row of the raw CSV: truth beside what the device reported.
struct Record {
  GroundTruth truth;
  RawMeasurement raw;
};

/// Bits of `correction_flags`.
enum CorrectionFlag : std::uint32_t {
  kCorrNoEcho = 1u << 0,       ///< nothing to correct
  kCorrOutOfDomain = 1u << 1,  ///< an input lies outside the domain the model was fitted on
  kCorrNonFinite = 1u << 2,    ///< an input needed by the model is NaN (or beyond kMaxMagnitude)
};

/// A corrected range with its expected error.
struct Range {
  double distance_m = kNaN;            ///< corrected distance
  double sigma_m = kNaN;               ///< expected error (1 sigma) of distance_m
  std::uint32_t correction_flags = 0;  ///< CorrectionFlag bits
};

}  // namespace tofkit::ranging
