#include "tofkit/link/rplidar.hpp"

#include <algorithm>

#include "frame_scanner.hpp"

namespace tofkit::link {
namespace {

constexpr std::size_t kLockSamples = 4;  // samples in a row that must pass to (re)acquire the phase

bool sample_passes(const std::uint8_t* p) {
  const bool s = (p[0] & 1) != 0;
  const bool not_s = (p[0] & 2) != 0;
  return s != not_s && (p[1] & 1) != 0;
}

struct RplidarPolicy {
  static constexpr Format kFormat = Format::kRplidar;
  static constexpr bool kHasSequence = false;
  static constexpr std::size_t kMaxFrameBytes = kLockSamples * kRplidarSampleBytes;

  bool locked = false;

  detail::Attempt attempt(const std::uint8_t* p, std::size_t n, bool end, Frame& f) {
    using detail::Verdict;
    constexpr std::size_t k = kRplidarSampleBytes;
    if (!locked) {
      // The response descriptor: skipped whole, and the samples follow it.
      const std::size_t d = std::min(n, kRplidarScanDescriptor.size());
      if (std::equal(p, p + d, kRplidarScanDescriptor.begin())) {
        if (d == kRplidarScanDescriptor.size()) return {Verdict::kOther, d};
        if (!end) return {Verdict::kNeedMore, 1};
      }
      // Hunting: a phase is accepted when kLockSamples samples in a row pass.
      for (std::size_t s = 0; s < kLockSamples; ++s) {
        if (n < (s + 1) * k) {
          if (end && s > 0) break;  // the stream ends: what passed so far is all there is
          return {end ? Verdict::kNoSync : Verdict::kNeedMore, 1};
        }
        if (!sample_passes(p + s * k)) return {Verdict::kNoSync, 1};
      }
      locked = true;
    } else {
      if (n < k) return {end ? Verdict::kNoSync : Verdict::kNeedMore, 1};
      if (!sample_passes(p)) {
        // A flipped bit does not move the stream: if the next sample passes,
        // drop this one and keep the phase; otherwise hunt again from the next byte.
        if (n < 2 * k && !end) return {Verdict::kNeedMore, 1};
        if (n >= 2 * k && sample_passes(p + k)) return {Verdict::kBadCheck, k};
        locked = false;
        return {Verdict::kBadCheck, 1};
      }
    }
    const std::uint16_t angle_q6 = detail::le16(p + 1) >> 1;
    const std::uint16_t distance_q2 = detail::le16(p + 3);
    f.scan_start = (p[0] & 1) != 0;
    f.scan_angle_deg = angle_q6 / 64.0;
    f.raw.amplitude = p[0] >> 2;  // quality
    if (distance_q2 == 0) {
      f.status |= kLinkNoRange;
      f.raw.flags |= ranging::kRawNoEcho;
    } else {
      f.raw.distance_raw_m = distance_q2 * 0.25e-3;
      f.raw.shots_valid = 1;
    }
    return {Verdict::kFrame, k};
  }
};

}  // namespace

std::array<std::uint8_t, kRplidarSampleBytes> encode_rplidar(const RplidarSample& s) {
  const auto quality = static_cast<std::uint8_t>(std::min<unsigned>(s.quality, 63));
  const auto angle = static_cast<std::uint16_t>(((s.angle_q6 & 0x7FFF) << 1) | 1);
  return {static_cast<std::uint8_t>((quality << 2) | (s.start ? 0b01 : 0b10)),
          static_cast<std::uint8_t>(angle), static_cast<std::uint8_t>(angle >> 8),
          static_cast<std::uint8_t>(s.distance_q2), static_cast<std::uint8_t>(s.distance_q2 >> 8)};
}

namespace detail {
std::unique_ptr<Decoder> make_rplidar_decoder(const DecoderOptions&) {
  return std::make_unique<ScanningDecoder<RplidarPolicy>>(RplidarPolicy{});
}
}  // namespace detail

}  // namespace tofkit::link
