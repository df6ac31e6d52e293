#include "tofkit/link/native_frame.hpp"

#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>

#include "frame_scanner.hpp"
#include "tofkit/link/crc16.hpp"
#include "tofkit/ranging/time_to_distance.hpp"

namespace tofkit::link {
namespace {

constexpr std::uint32_t kNone32 = 0xFFFFFFFF;
constexpr std::uint16_t kNone16 = 0xFFFF;
constexpr std::int16_t kNoTemperature = std::numeric_limits<std::int16_t>::min();
constexpr double kTemperatureLsbC = 1.0 / 128.0;

// value / lsb rounded to the nearest integer in [0, max], `none` for NaN.
std::uint64_t quantize(double value, double lsb, std::uint64_t max, std::uint64_t none,
                       const char* field) {
  if (std::isnan(value)) return none;
  const double q = std::nearbyint(value / lsb);
  if (!(q >= 0 && q <= static_cast<double>(max))) {
    throw std::out_of_range(std::string("native frame: ") + field + " " + std::to_string(value) +
                            " does not fit its field");
  }
  return static_cast<std::uint64_t>(q);
}

void put16(std::uint8_t* p, std::uint32_t v) {
  p[0] = static_cast<std::uint8_t>(v);
  p[1] = static_cast<std::uint8_t>(v >> 8);
}
void put32(std::uint8_t* p, std::uint32_t v) {
  put16(p, v);
  put16(p + 2, v >> 16);
}

// Extends a wrapping 32-bit counter to 64 bits, assuming it moves less than
// half its range between two frames.
class Unwrapper {
 public:
  std::uint64_t operator()(std::uint32_t v) {
    if (!started_) {
      started_ = true;
      last_ = v;
      return v;
    }
    const auto step = static_cast<std::int32_t>(v - static_cast<std::uint32_t>(last_));
    last_ = static_cast<std::uint64_t>(static_cast<std::int64_t>(last_) + step);
    return last_;
  }

 private:
  bool started_ = false;
  std::uint64_t last_ = 0;
};

struct NativePolicy {
  static constexpr Format kFormat = Format::kNative;
  static constexpr bool kHasSequence = true;
  static constexpr std::size_t kMaxFrameBytes = 4 + 255 + 2;

  double metres_per_ns = 0;
  Unwrapper sequence;
  Unwrapper time_us;
  bool have_last = false;
  std::uint64_t last_sequence = 0;
  std::uint64_t* sequence_gaps = nullptr;

  detail::Attempt attempt(const std::uint8_t* p, std::size_t n, bool end, Frame& f) {
    using detail::Verdict;
    if (p[0] != kNativeSync0)
      return {Verdict::kNoSync, detail::distance_to_next(p, n, kNativeSync0)};
    if (n < 4) {
      if (n >= 2 && p[1] != kNativeSync1) return {Verdict::kNoSync, 1};
      return {end ? Verdict::kNoSync : Verdict::kNeedMore, 1};
    }
    if (p[1] != kNativeSync1) return {Verdict::kNoSync, 1};
    const std::uint8_t version = p[2];
    const std::size_t payload = p[3];
    if (version == 0 || (version == kNativeVersion && payload < kNativePayloadBytes)) {
      return {Verdict::kBadLength, 1};
    }
    const std::size_t length = 4 + payload + 2;
    if (n < length) return {end ? Verdict::kBadLength : Verdict::kNeedMore, 1};
    const std::uint16_t crc = crc16_ccitt_false({p, 4 + payload});
    if (crc != detail::le16(p + 4 + payload)) return {Verdict::kBadCheck, 1};
    if (version != kNativeVersion)
      return {Verdict::kOther, length};  // a later version we cannot read

    const std::uint64_t seq = sequence(detail::le32(p + 4));
    if (have_last && seq != last_sequence + 1) {
      f.status |= kLinkSequenceGap;
      if (seq > last_sequence) *sequence_gaps += seq - last_sequence - 1;
    }
    have_last = true;
    last_sequence = seq;
    f.sequence = seq;
    f.device_time_s = static_cast<double>(time_us(detail::le32(p + 8))) / 1e6;

    ranging::RawMeasurement& m = f.raw;
    const std::uint32_t tof_fs = detail::le32(p + 12);
    const std::uint32_t amplitude_uv = detail::le32(p + 16);
    const std::uint16_t width_ps = detail::le16(p + 20);
    const auto temperature = static_cast<std::int16_t>(detail::le16(p + 22));
    m.tof_ns = tof_fs == kNone32 ? ranging::kNaN : static_cast<double>(tof_fs) / 1e6;
    m.distance_raw_m = m.tof_ns * metres_per_ns;
    m.amplitude =
        amplitude_uv == kNone32 ? ranging::kNaN : static_cast<double>(amplitude_uv) / 1e6;
    m.pulse_width_ns = width_ps == kNone16 ? ranging::kNaN : static_cast<double>(width_ps) / 1e3;
    m.temperature_c =
        temperature == kNoTemperature ? ranging::kNaN : temperature * kTemperatureLsbC;
    m.shots_valid = detail::le16(p + 24);
    m.flags = detail::le16(p + 26);
    if (!m.has_echo()) {
      // A frame that says "no echo" carries no range, whatever its tof field holds (REP-117).
      m.tof_ns = ranging::kNaN;
      m.distance_raw_m = ranging::kNaN;
    }
    return {Verdict::kFrame, length};
  }
};

class NativeDecoder final : public Decoder {
 public:
  explicit NativeDecoder(double metres_per_ns) : inner_(make_policy(metres_per_ns)) {}
  void feed(std::span<const std::uint8_t> bytes, std::vector<Frame>& out) override {
    inner_.feed(bytes, out);
  }
  void finish(std::vector<Frame>& out) override { inner_.finish(out); }
  [[nodiscard]] const DecoderCounters& counters() const override {
    counters_ = inner_.counters();
    counters_.sequence_gaps = gaps_;
    return counters_;
  }
  [[nodiscard]] Format format() const override { return Format::kNative; }
  [[nodiscard]] std::size_t pending_bytes() const override { return inner_.pending_bytes(); }

 private:
  NativePolicy make_policy(double metres_per_ns) {
    NativePolicy p;
    p.metres_per_ns = metres_per_ns;
    p.sequence_gaps = &gaps_;
    return p;
  }
  std::uint64_t gaps_ = 0;
  detail::ScanningDecoder<NativePolicy> inner_;
  mutable DecoderCounters counters_;
};

}  // namespace

std::array<std::uint8_t, kNativeFrameBytes> encode_native(const NativeSample& s) {
  const ranging::RawMeasurement& m = s.raw;
  std::array<std::uint8_t, kNativeFrameBytes> f{};
  f[0] = kNativeSync0;
  f[1] = kNativeSync1;
  f[2] = kNativeVersion;
  f[3] = static_cast<std::uint8_t>(kNativePayloadBytes);
  put32(&f[4], s.sequence);
  put32(&f[8], s.time_us);
  put32(&f[12],
        static_cast<std::uint32_t>(quantize(m.tof_ns, 1e-6, kNone32 - 1, kNone32, "tof_ns")));
  put32(&f[16],
        static_cast<std::uint32_t>(quantize(m.amplitude, 1e-6, kNone32 - 1, kNone32, "amplitude")));
  put16(&f[20], static_cast<std::uint32_t>(
                    quantize(m.pulse_width_ns, 1e-3, kNone16 - 1, kNone16, "pulse_width_ns")));
  std::int16_t temperature = kNoTemperature;
  if (!std::isnan(m.temperature_c)) {
    const double q = std::nearbyint(m.temperature_c / kTemperatureLsbC);
    if (!(q > kNoTemperature && q <= std::numeric_limits<std::int16_t>::max())) {
      throw std::out_of_range("native frame: temperature_c " + std::to_string(m.temperature_c) +
                              " does not fit its field");
    }
    temperature = static_cast<std::int16_t>(q);
  }
  put16(&f[22], static_cast<std::uint16_t>(temperature));
  if (m.shots_valid > 0xFFFF) throw std::out_of_range("native frame: shots_valid above 65535");
  if (m.flags > 0xFFFF) throw std::out_of_range("native frame: flags above 0xFFFF");
  put16(&f[24], m.shots_valid);
  put16(&f[26], m.flags);
  put16(&f[28], crc16_ccitt_false({f.data(), 28}));
  return f;
}

namespace detail {
std::unique_ptr<Decoder> make_native_decoder(const DecoderOptions& options) {
  const double mpn = options.metres_per_ns > 0 ? options.metres_per_ns
                                               : ranging::metres_per_ns(ranging::TimeToDistance{});
  return std::make_unique<NativeDecoder>(mpn);
}
}  // namespace detail

}  // namespace tofkit::link
