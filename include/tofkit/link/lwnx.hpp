#pragma once
/// \file LightWare LWNX binary packets (LW20, SF20, SF30/D, SF45 ...):
///
///   0xAA, flags (uint16 LE: bits 6-15 payload length N incl. the command id,
///   bit 0 write), command id, N-1 data bytes, CRC-16/XMODEM (LE) of all bytes
///   from 0xAA to the last data byte.
///
/// Measurements come in command 44 ("distance data"), whose int16 LE fields
/// follow the bits set in command 27 ("distance output"), in bit order: 0 first
/// return raw [cm], 1 closest, 2 median, 3 furthest, 4 first return strength
/// [%], 5-9 the same for the last return, 10 background noise. Other packets
/// are counted and skipped.

#include <cstdint>
#include <span>
#include <vector>

namespace tofkit::link {

inline constexpr std::uint8_t kLwnxStart = 0xAA;
inline constexpr std::uint8_t kLwnxDistanceData = 44;
inline constexpr std::size_t kLwnxMaxPayloadBytes = 1023;
inline constexpr std::size_t kLwnxMaxPacketBytes = 3 + kLwnxMaxPayloadBytes + 2;

/// A complete packet (for tests and host tools). Throws std::invalid_argument
/// when data is longer than 1022 bytes.
[[nodiscard]] std::vector<std::uint8_t> encode_lwnx(std::uint8_t command,
                                                    std::span<const std::uint8_t> data,
                                                    bool write = false);

}  // namespace tofkit::link
