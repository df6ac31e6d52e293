#pragma once
/// \file The two CRC-16s of the link formats, both polynomial 0x1021, not
/// reflected, no final XOR: CRC-16/CCITT-FALSE (init 0xFFFF; the native frame;
/// check value of "123456789" is 0x29B1) and CRC-16/XMODEM (init 0x0000;
/// LightWare LWNX; check value 0x31C3). A 16-bit CRC with this polynomial
/// detects every error of up to 3 flipped bits in frames shorter than 4 kB.

#include <cstdint>
#include <span>

namespace tofkit::link {

/// Continue a CRC (poly 0x1021, MSB first) over `bytes` from `crc`.
[[nodiscard]] std::uint16_t crc16_update(std::uint16_t crc, std::span<const std::uint8_t> bytes);

[[nodiscard]] inline std::uint16_t crc16_ccitt_false(std::span<const std::uint8_t> bytes) {
  return crc16_update(0xFFFF, bytes);
}
[[nodiscard]] inline std::uint16_t crc16_xmodem(std::span<const std::uint8_t> bytes) {
  return crc16_update(0x0000, bytes);
}

}  // namespace tofkit::link
