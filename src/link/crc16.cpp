#include "tofkit/link/crc16.hpp"

#include <array>

namespace tofkit::link {
namespace {

// Slicing-by-8 tables for the MSB-first polynomial 0x1021: t[k][b] is the CRC
// (from a zero register) of byte b followed by k zero bytes. By linearity the
// CRC of eight bytes is the XOR of eight independent lookups, the register's
// two bytes folded into the first two: a short dependency chain per 8 bytes.
struct Tables {
  std::array<std::array<std::uint16_t, 256>, 8> t{};
  constexpr Tables() {
    for (unsigned b = 0; b < 256; ++b) {
      auto crc = static_cast<std::uint16_t>(b << 8);
      for (int bit = 0; bit < 8; ++bit) {
        crc = static_cast<std::uint16_t>((crc & 0x8000) != 0 ? (crc << 1) ^ 0x1021 : crc << 1);
      }
      t[0][b] = crc;
    }
    for (std::size_t k = 1; k < 8; ++k) {
      for (unsigned b = 0; b < 256; ++b) {
        const std::uint16_t prev = t[k - 1][b];
        t[k][b] = static_cast<std::uint16_t>((prev << 8) ^ t[0][prev >> 8]);
      }
    }
  }
};
constexpr Tables kTables;

}  // namespace

std::uint16_t crc16_update(std::uint16_t crc, std::span<const std::uint8_t> bytes) {
  const auto& t = kTables.t;
  const std::uint8_t* p = bytes.data();
  std::size_t n = bytes.size();
  for (; n >= 8; p += 8, n -= 8) {
    crc = static_cast<std::uint16_t>(t[7][(crc >> 8) ^ p[0]] ^ t[6][(crc & 0xFF) ^ p[1]] ^
                                     t[5][p[2]] ^ t[4][p[3]] ^ t[3][p[4]] ^ t[2][p[5]] ^
                                     t[1][p[6]] ^ t[0][p[7]]);
  }
  for (; n > 0; ++p, --n) {
    crc = static_cast<std::uint16_t>((crc << 8) ^ t[0][((crc >> 8) ^ *p) & 0xFF]);
  }
  return crc;
}

}  // namespace tofkit::link
