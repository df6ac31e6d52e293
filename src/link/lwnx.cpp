#include "tofkit/link/lwnx.hpp"

#include <bit>
#include <cmath>
#include <stdexcept>

#include "frame_scanner.hpp"
#include "tofkit/link/crc16.hpp"

namespace tofkit::link {
namespace {

// Distance-output bits (command 27) the decoder reads.
constexpr int kFirstReturnFirstDistanceBit = 0;  // raw, closest, median, furthest: bits 0-3
constexpr int kFirstReturnStrengthBit = 4;
constexpr int kDistanceOutputBits = 11;

struct LwnxPolicy {
  static constexpr Format kFormat = Format::kLwnx;
  static constexpr bool kHasSequence = false;
  static constexpr std::size_t kMaxFrameBytes = kLwnxMaxPacketBytes;

  std::uint32_t distance_output = 0b1'0001;

  detail::Attempt attempt(const std::uint8_t* p, std::size_t n, bool end, Frame& f) const {
    using detail::Verdict;
    if (p[0] != kLwnxStart) return {Verdict::kNoSync, detail::distance_to_next(p, n, kLwnxStart)};
    if (n < 3) return {end ? Verdict::kNoSync : Verdict::kNeedMore, 1};
    const std::size_t payload = detail::le16(p + 1) >> 6;  // command id + data
    if (payload == 0) return {Verdict::kBadLength, 1};
    const std::size_t length = 3 + payload + 2;
    if (n < length) return {end ? Verdict::kBadLength : Verdict::kNeedMore, 1};
    if (crc16_xmodem({p, 3 + payload}) != detail::le16(p + 3 + payload)) {
      return {Verdict::kBadCheck, 1};
    }
    const std::uint8_t command = p[3];
    const std::size_t fields = static_cast<std::size_t>(std::popcount(distance_output));
    if (command != kLwnxDistanceData || payload - 1 != 2 * fields) return {Verdict::kOther, length};

    // int16 fields in bit order; the first first-return distance present is the range.
    const std::uint8_t* field = p + 4;
    double distance_cm = ranging::kNaN;
    double strength = ranging::kNaN;
    for (int bit = 0; bit < kDistanceOutputBits; ++bit) {
      if ((distance_output & (1u << bit)) == 0) continue;
      const auto value = static_cast<std::int16_t>(detail::le16(field));
      field += 2;
      if (bit >= kFirstReturnFirstDistanceBit && bit < kFirstReturnStrengthBit &&
          std::isnan(distance_cm)) {
        distance_cm = value;
      } else if (bit == kFirstReturnStrengthBit) {
        strength = value;
      }
    }
    ranging::RawMeasurement& m = f.raw;
    m.amplitude = strength;
    if (distance_cm > 0) {
      m.distance_raw_m = distance_cm * 0.01;
      m.shots_valid = 1;
    } else {
      // Lost signal (LightWare reports it as a non-positive distance): no range.
      f.status |= kLinkLowSignal;
      m.flags |= ranging::kRawNoEcho;
    }
    return {Verdict::kFrame, length};
  }
};

}  // namespace

std::vector<std::uint8_t> encode_lwnx(std::uint8_t command, std::span<const std::uint8_t> data,
                                      bool write) {
  if (data.size() + 1 > kLwnxMaxPayloadBytes) {
    throw std::invalid_argument("encode_lwnx: more than 1022 data bytes");
  }
  const auto flags = static_cast<std::uint16_t>(((data.size() + 1) << 6) | (write ? 1u : 0u));
  std::vector<std::uint8_t> packet;
  packet.reserve(3 + 1 + data.size() + 2);
  for (const std::uint8_t b : {kLwnxStart, static_cast<std::uint8_t>(flags),
                               static_cast<std::uint8_t>(flags >> 8), command}) {
    packet.push_back(b);
  }
  for (const std::uint8_t b : data) packet.push_back(b);
  const std::uint16_t crc = crc16_xmodem(packet);
  packet.push_back(static_cast<std::uint8_t>(crc));
  packet.push_back(static_cast<std::uint8_t>(crc >> 8));
  return packet;
}

namespace detail {
std::unique_ptr<Decoder> make_lwnx_decoder(const DecoderOptions& options) {
  if (options.lwnx_distance_output >= (1u << kDistanceOutputBits) ||
      (options.lwnx_distance_output & 0b1111) == 0) {
    throw std::invalid_argument(
        "LWNX distance output: needs a first-return distance bit (0-3) and only bits 0-10");
  }
  LwnxPolicy policy;
  policy.distance_output = options.lwnx_distance_output;
  return std::make_unique<ScanningDecoder<LwnxPolicy>>(policy);
}
}  // namespace detail

}  // namespace tofkit::link
