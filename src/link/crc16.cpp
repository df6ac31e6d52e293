#include "tofkit/link/crc16.hpp"

#include <array>

namespace tofkit::link {
namespace {

// Slicing-by-2 tables for the MSB-first polynomial 0x1021: table[0][b] is the
// CRC of byte b, table[1][b] that of b followed by a zero byte.
struct Tables {
  std::array<std::array<std::uint16_t, 256>, 2> t{};
  constexpr Tables() {
    for (unsigned b = 0; b < 256; ++b) {
      auto crc = static_cast<std::uint16_t>(b << 8);
      for (int bit = 0; bit < 8; ++bit) {
        crc = static_cast<std::uint16_t>((crc & 0x8000) != 0 ? (crc << 1) ^ 0x1021 : crc << 1);
      }
      t[0][b] = crc;
    }
    for (unsigned b = 0; b < 256; ++b) {
      t[1][b] = static_cast<std::uint16_t>((t[0][b] << 8) ^ t[0][t[0][b] >> 8]);
    }
  }
};
constexpr Tables kTables;

}  // namespace

std::uint16_t crc16_update(std::uint16_t crc, std::span<const std::uint8_t> bytes) {
  const auto& t = kTables.t;
  std::size_t i = 0;
  // Two bytes per step: the CRC register's two bytes meet the next two data
  // bytes and each goes through its own table (independent lookups).
  for (; i + 2 <= bytes.size(); i += 2) {
    const unsigned hi = (crc >> 8) ^ bytes[i];
    const unsigned lo = (crc & 0xFF) ^ bytes[i + 1];
    crc = static_cast<std::uint16_t>(t[1][hi] ^ t[0][lo]);
  }
  for (; i < bytes.size(); ++i) {
    crc = static_cast<std::uint16_t>((crc << 8) ^ t[0][((crc >> 8) ^ bytes[i]) & 0xFF]);
  }
  return crc;
}

}  // namespace tofkit::link
