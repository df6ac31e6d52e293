#pragma once
/// \file The tofkit native frame, version 1: 30 bytes, little-endian.
///
///   offset size field
///        0    2 sync 0x7E 0xD5
///        2    1 version (1)
///        3    1 payload length L (24 in version 1; later versions may append
///               fields, which version-1 readers skip)
///        4    4 sequence number (uint32, wraps; the decoder unwraps it)
///        8    4 device time stamp, microseconds (uint32, wraps after 71.6 min)
///       12    4 time of flight, femtoseconds (uint32; 0xFFFFFFFF = none; max 4.29 us = 643 m)
///       16    4 amplitude, microvolts (uint32; 0xFFFFFFFF = none)
///       20    2 echo pulse width, picoseconds (uint16; 0xFFFF = none; max 65.534 ns)
///       22    2 temperature, 1/128 C (int16; -32768 = none)
///       24    2 valid shots (uint16)
///       26    2 flags (RawFlag bits)
///     4+L     2 CRC-16/CCITT-FALSE of bytes 0 .. 4+L-1
///
/// Rate: 30 bytes = 240 bits (300 on an 8N1 UART). 1 MHz of measurements is
/// 240 Mbit/s: USB 2.0 high speed (480 Mbit/s) or gigabit Ethernet carry it;
/// a 3 Mbaud UART carries 10 kHz, 12 Mbaud (FT232H) 40 kHz.
/// Resolution (1 fs, 1 ps, 1 uV, 1/128 C) is below the device's noise and
/// its sensor's resolution; encoding is round-to-nearest.

#include <array>
#include <cstdint>

#include "tofkit/ranging/raw_measurement.hpp"

namespace tofkit::link {

inline constexpr std::uint8_t kNativeSync0 = 0x7E;
inline constexpr std::uint8_t kNativeSync1 = 0xD5;
inline constexpr std::uint8_t kNativeVersion = 1;
inline constexpr std::size_t kNativePayloadBytes = 24;
inline constexpr std::size_t kNativeFrameBytes = 4 + kNativePayloadBytes + 2;

/// What one native frame carries.
struct NativeSample {
  std::uint32_t sequence = 0;
  std::uint32_t time_us = 0;
  ranging::RawMeasurement raw;  ///< distance_raw_m is not sent (the receiver derives it from tof)
};

/// Throws std::out_of_range naming the field when a value does not fit
/// (negative, above the field's maximum, shots or flags above 65535).
[[nodiscard]] std::array<std::uint8_t, kNativeFrameBytes> encode_native(const NativeSample& sample);

}  // namespace tofkit::link
