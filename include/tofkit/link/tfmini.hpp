#pragma once
/// \file Benewake TFmini-S / TFmini Plus / TF-Luna serial frame (9 bytes):
///
///   0x59 0x59, Dist (uint16 LE, cm), Strength (uint16 LE), Temp (uint16 LE,
///   C = Temp / 8 - 256), Checksum (low 8 bits of the sum of bytes 0..7).
///
/// Invalid readings (TFmini-S manual, Table 8; TFmini Plus / TF-Luna): Dist -1
/// (0xFFFF) strength below 100, -2 (0xFFFE) strength saturation, -4 (0xFFFC)
/// ambient light saturation; TFmini Plus and TF-Luna report Dist 0 with
/// strength < 100 or 65535. The decoder turns these into kRawNoEcho with a
/// NaN distance and a LinkStatus reason, never a range.

#include <array>
#include <cstdint>

#include "tofkit/ranging/raw_measurement.hpp"

namespace tofkit::link {

inline constexpr std::size_t kTfminiFrameBytes = 9;
inline constexpr std::uint8_t kTfminiHeader = 0x59;
inline constexpr std::uint16_t kTfminiLowSignal = 0xFFFF;      ///< Dist -1
inline constexpr std::uint16_t kTfminiSaturated = 0xFFFE;      ///< Dist -2
inline constexpr std::uint16_t kTfminiAmbient = 0xFFFC;        ///< Dist -4
inline constexpr std::uint16_t kTfminiMaxDistanceCm = 0xFFFB;  ///< largest valid distance

/// The three fields of a TFmini frame, as sent.
struct TfminiReading {
  std::uint16_t distance_cm = 0;  ///< or one of the invalid codes
  std::uint16_t strength = 0;
  std::uint16_t temperature_raw = 2048;  ///< 8 * (C + 256)
};

[[nodiscard]] std::array<std::uint8_t, kTfminiFrameBytes> encode_tfmini(const TfminiReading& r);

/// How the emulator reports a RawMeasurement as a TFmini would: distance_raw_m
/// rounded to cm (std::out_of_range outside 0 .. 655.31 m), strength = amplitude in mV
/// (clamped to 65534; 65535 means saturation), temperature rounded to 1/8 C;
/// no echo -> Dist -1 with strength 0.
[[nodiscard]] TfminiReading tfmini_reading_from(const ranging::RawMeasurement& raw);

}  // namespace tofkit::link
