#include "tofkit/link/tfmini.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

#include "frame_scanner.hpp"

namespace tofkit::link {
namespace {

std::uint8_t sum8(const std::uint8_t* p, std::size_t n) {
  unsigned sum = 0;
  for (std::size_t i = 0; i < n; ++i) sum += p[i];
  return static_cast<std::uint8_t>(sum);
}

struct TfminiPolicy {
  static constexpr Format kFormat = Format::kTfmini;
  static constexpr bool kHasSequence = false;
  static constexpr std::size_t kMaxFrameBytes = kTfminiFrameBytes;

  bool temperature_field = true;

  detail::Attempt attempt(const std::uint8_t* p, std::size_t n, bool end, Frame& f) const {
    using detail::Verdict;
    if (p[0] != kTfminiHeader)
      return {Verdict::kNoSync, detail::distance_to_next(p, n, kTfminiHeader)};
    if (n >= 2 && p[1] != kTfminiHeader) return {Verdict::kNoSync, 1};
    if (n < kTfminiFrameBytes) return {end ? Verdict::kNoSync : Verdict::kNeedMore, 1};
    if (sum8(p, 8) != p[8]) return {Verdict::kBadCheck, 1};

    const std::uint16_t distance = detail::le16(p + 2);
    const std::uint16_t strength = detail::le16(p + 4);
    ranging::RawMeasurement& m = f.raw;
    m.amplitude = strength;
    if (temperature_field) m.temperature_c = detail::le16(p + 6) / 8.0 - 256.0;
    if (strength == 0xFFFF) {
      f.status |= kLinkStrengthSaturated;
      m.flags |= ranging::kRawSaturated;
    }
    switch (distance) {
      case kTfminiLowSignal:
        f.status |= kLinkLowSignal;
        break;
      case kTfminiSaturated:
        f.status |= kLinkStrengthSaturated;
        m.flags |= ranging::kRawSaturated;
        break;
      case kTfminiAmbient:
        f.status |= kLinkAmbientSaturated;
        break;
      case 0:  // TFmini Plus / TF-Luna: no reading (weak or saturated signal)
        if (strength != 0xFFFF) f.status |= kLinkLowSignal;
        break;
      default:
        // The other negative codes are undocumented: not a range either.
        if (distance > kTfminiMaxDistanceCm) {
          f.status |= kLinkLowSignal;
          break;
        }
        m.distance_raw_m = distance * 0.01;
        m.shots_valid = 1;
        return {Verdict::kFrame, kTfminiFrameBytes};
    }
    m.flags |= ranging::kRawNoEcho;  // REP-117: no fake range
    return {Verdict::kFrame, kTfminiFrameBytes};
  }
};

}  // namespace

std::array<std::uint8_t, kTfminiFrameBytes> encode_tfmini(const TfminiReading& r) {
  std::array<std::uint8_t, kTfminiFrameBytes> f{};
  f[0] = f[1] = kTfminiHeader;
  f[2] = static_cast<std::uint8_t>(r.distance_cm);
  f[3] = static_cast<std::uint8_t>(r.distance_cm >> 8);
  f[4] = static_cast<std::uint8_t>(r.strength);
  f[5] = static_cast<std::uint8_t>(r.strength >> 8);
  f[6] = static_cast<std::uint8_t>(r.temperature_raw);
  f[7] = static_cast<std::uint8_t>(r.temperature_raw >> 8);
  f[8] = sum8(f.data(), 8);
  return f;
}

TfminiReading tfmini_reading_from(const ranging::RawMeasurement& raw) {
  TfminiReading r;
  if (!std::isnan(raw.temperature_c)) {
    r.temperature_raw = static_cast<std::uint16_t>(
        std::clamp(std::nearbyint((raw.temperature_c + 256.0) * 8.0), 0.0, 65535.0));
  }
  if (!raw.has_echo() || std::isnan(raw.distance_raw_m)) {
    r.distance_cm = kTfminiLowSignal;
    r.strength = 0;
    return r;
  }
  // A distance the field cannot hold is refused, as the native frame's
  // (clamped, 1000 m had read 655.31 m).
  const double cm = std::nearbyint(raw.distance_raw_m * 100.0);
  if (!(cm >= 0.0 && cm <= static_cast<double>(kTfminiMaxDistanceCm))) {
    throw std::out_of_range("TFmini frame: distance_raw_m " + std::to_string(raw.distance_raw_m) +
                            " m does not fit its field (0 to 655.31 m)");
  }
  r.distance_cm = static_cast<std::uint16_t>(cm);
  const double mv = std::isnan(raw.amplitude) ? 0.0 : raw.amplitude * 1e3;
  r.strength = static_cast<std::uint16_t>(std::clamp(std::nearbyint(mv), 0.0, 65534.0));
  return r;
}

namespace detail {
std::unique_ptr<Decoder> make_tfmini_decoder(const DecoderOptions& options) {
  TfminiPolicy policy;
  policy.temperature_field = options.tfmini_temperature;
  return std::make_unique<ScanningDecoder<TfminiPolicy>>(policy);
}
}  // namespace detail

}  // namespace tofkit::link
