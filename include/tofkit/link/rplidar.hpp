#pragma once
/// \file Slamtec RPLIDAR A1/A2 standard scan ("SCAN", answer type 0x81):
/// after the response descriptor A5 5A 05 00 00 40 81, 5-byte samples
///
///   byte 0: quality (bits 2-7), !S (bit 1), S (bit 0; 1 = new revolution)
///   byte 1-2: check bit C = 1 (bit 0), angle_q6 (bits 1-15; degrees * 64)
///   byte 3-4: distance_q2 (mm * 4; 0 = no measurement)
///
/// There is no checksum: S != !S and C = 1 are the only checks (a random
/// 5-byte window passes them 1 time in 8). The decoder therefore locks onto
/// the 5-byte phase only after 4 samples in a row pass, keeps the lock over a
/// single failing sample (a flipped bit does not shift the stream), and
/// hunts byte by byte again after two failures in a row.

#include <array>
#include <cstdint>

namespace tofkit::link {

inline constexpr std::size_t kRplidarSampleBytes = 5;
inline constexpr std::array<std::uint8_t, 7> kRplidarScanDescriptor = {0xA5, 0x5A, 0x05, 0x00,
                                                                       0x00, 0x40, 0x81};

struct RplidarSample {
  bool start = false;             ///< first sample of a revolution
  std::uint8_t quality = 0;       ///< 0-63
  std::uint16_t angle_q6 = 0;     ///< 0-32767 (degrees * 64)
  std::uint16_t distance_q2 = 0;  ///< mm * 4
};

[[nodiscard]] std::array<std::uint8_t, kRplidarSampleBytes> encode_rplidar(const RplidarSample& s);

}  // namespace tofkit::link
