// link/: frame decoders and encoders. Oracles: the CRC catalogue's check
// values, the encoders' own inputs (round trips), one big chunk against random
// chunkings, and an independent count of which frames a corruption touched.

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <iostream>
#include <random>
#include <set>
#include <string>
#include <vector>

#include "tofkit/link/crc16.hpp"
#include "tofkit/link/decoder.hpp"
#include "tofkit/link/lwnx.hpp"
#include "tofkit/link/native_frame.hpp"
#include "tofkit/link/rplidar.hpp"
#include "tofkit/link/tfmini.hpp"

namespace tofkit::link {
namespace {

using Bytes = std::vector<std::uint8_t>;

// ---------------------------------------------------------------- streams

ranging::RawMeasurement random_raw(std::mt19937_64& rng) {
  std::uniform_real_distribution<double> u(0.0, 1.0);
  ranging::RawMeasurement m;
  if (u(rng) < 0.05) {
    m.flags = ranging::kRawNoEcho;
    m.temperature_c = 20 + 10 * u(rng);
    return m;
  }
  m.tof_ns = 1 + 600 * u(rng);
  m.distance_raw_m = 0.15 * m.tof_ns;
  m.pulse_width_ns = 1 + 30 * u(rng);
  m.amplitude = std::exp(-5 + 10 * u(rng));
  m.temperature_c = -20 + 80 * u(rng);
  m.shots_valid = 1 + static_cast<std::uint32_t>(999 * u(rng));
  m.flags = u(rng) < 0.1 ? ranging::kRawSaturated : 0;
  return m;
}

struct Stream {
  Bytes bytes;
  std::vector<std::size_t> offsets;  // first byte of frame i
  std::size_t frame_bytes(std::size_t i) const {
    return (i + 1 < offsets.size() ? offsets[i + 1] : bytes.size()) - offsets[i];
  }
};

void append(Stream& s, const auto& frame) {
  s.offsets.push_back(s.bytes.size());
  s.bytes.insert(s.bytes.end(), frame.begin(), frame.end());
}

Stream native_stream(std::size_t frames, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  Stream s;
  for (std::size_t i = 0; i < frames; ++i) {
    NativeSample sample{static_cast<std::uint32_t>(i), static_cast<std::uint32_t>(i * 100),
                        random_raw(rng)};
    append(s, encode_native(sample));
  }
  return s;
}

Stream tfmini_stream(std::size_t frames, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  Stream s;
  for (std::size_t i = 0; i < frames; ++i)
    append(s, encode_tfmini(tfmini_reading_from(random_raw(rng))));
  return s;
}

Bytes lwnx_distance_data(std::int16_t distance_cm, std::int16_t strength) {
  Bytes data(4);
  std::memcpy(data.data(), &distance_cm, 2);
  std::memcpy(data.data() + 2, &strength, 2);
  return data;
}

Stream lwnx_stream(std::size_t frames, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_int_distribution<int> distance(-1, 10000), strength(0, 100);
  Stream s;
  for (std::size_t i = 0; i < frames; ++i) {
    append(s, encode_lwnx(kLwnxDistanceData,
                          lwnx_distance_data(static_cast<std::int16_t>(distance(rng)),
                                             static_cast<std::int16_t>(strength(rng)))));
  }
  return s;
}

Stream rplidar_stream(std::size_t frames, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_int_distribution<int> distance(0, 48000), quality(0, 63);
  Stream s;
  s.bytes.assign(kRplidarScanDescriptor.begin(), kRplidarScanDescriptor.end());
  for (std::size_t i = 0; i < frames; ++i) {
    RplidarSample sample;
    sample.angle_q6 = static_cast<std::uint16_t>((i * 64 * 360 / 400) % (360 * 64));
    sample.start = i % 400 == 0;
    sample.quality = static_cast<std::uint8_t>(quality(rng));
    sample.distance_q2 = static_cast<std::uint16_t>(distance(rng));
    append(s, encode_rplidar(sample));
  }
  return s;
}

Stream make_stream(Format format, std::size_t frames, std::uint64_t seed) {
  switch (format) {
    case Format::kNative:
      return native_stream(frames, seed);
    case Format::kTfmini:
      return tfmini_stream(frames, seed);
    case Format::kLwnx:
      return lwnx_stream(frames, seed);
    case Format::kRplidar:
      return rplidar_stream(frames, seed);
  }
  return {};
}

std::vector<Frame> decode(Format format, const Bytes& bytes, std::vector<std::size_t> chunks,
                          DecoderCounters* counters = nullptr) {
  auto decoder = make_decoder(format);
  std::vector<Frame> frames;
  std::size_t pos = 0;
  for (const std::size_t c : chunks) {
    const std::size_t n = std::min(c, bytes.size() - pos);
    decoder->feed({bytes.data() + pos, n}, frames);
    EXPECT_LE(decoder->pending_bytes(), kLwnxMaxPacketBytes);
    pos += n;
  }
  decoder->feed({bytes.data() + pos, bytes.size() - pos}, frames);
  decoder->finish(frames);
  if (counters != nullptr) *counters = decoder->counters();
  return frames;
}

bool same_double(double a, double b) {
  return (std::isnan(a) && std::isnan(b)) || a == b;
}

bool same_frame(const Frame& a, const Frame& b) {
  return a.stream_offset == b.stream_offset && a.sequence == b.sequence &&
         same_double(a.device_time_s, b.device_time_s) && same_double(a.raw.tof_ns, b.raw.tof_ns) &&
         same_double(a.raw.distance_raw_m, b.raw.distance_raw_m) &&
         same_double(a.raw.pulse_width_ns, b.raw.pulse_width_ns) &&
         same_double(a.raw.amplitude, b.raw.amplitude) &&
         same_double(a.raw.temperature_c, b.raw.temperature_c) &&
         a.raw.shots_valid == b.raw.shots_valid && a.raw.flags == b.raw.flags &&
         same_double(a.scan_angle_deg, b.scan_angle_deg) && a.scan_start == b.scan_start &&
         a.status == b.status;
}

std::vector<std::size_t> random_chunks(std::size_t total, std::mt19937_64& rng) {
  std::uniform_int_distribution<std::size_t> size(0, 70);
  std::vector<std::size_t> chunks;
  for (std::size_t sum = 0; sum < total;) {
    chunks.push_back(size(rng));
    sum += chunks.back();
  }
  return chunks;
}

// Flips one random bit in a share p of the bytes; returns the flipped positions.
std::vector<std::size_t> corrupt(Bytes& bytes, double p, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::geometric_distribution<std::size_t> gap(p);
  std::uniform_int_distribution<int> bit(0, 7);
  std::vector<std::size_t> flipped;
  for (std::size_t i = gap(rng); i < bytes.size(); i += 1 + gap(rng)) {
    bytes[i] ^= static_cast<std::uint8_t>(1u << bit(rng));
    flipped.push_back(i);
  }
  return flipped;
}

const Format kFormats[] = {Format::kNative, Format::kTfmini, Format::kLwnx, Format::kRplidar};

// ---------------------------------------------------------------- tests

TEST(LinkCrc, CatalogueCheckValues) {
  const std::string check = "123456789";
  const std::span<const std::uint8_t> bytes(reinterpret_cast<const std::uint8_t*>(check.data()),
                                            check.size());
  EXPECT_EQ(crc16_ccitt_false(bytes), 0x29B1);
  EXPECT_EQ(crc16_xmodem(bytes), 0x31C3);
  // Odd and even lengths take different paths through the two-byte loop.
  EXPECT_EQ(crc16_update(crc16_ccitt_false(bytes.first(4)), bytes.subspan(4)), 0x29B1);
}

TEST(LinkNative, RoundTripWithinHalfAResolutionStep) {
  std::mt19937_64 rng(7);
  auto decoder = make_decoder(Format::kNative);
  for (std::uint32_t i = 0; i < 2000; ++i) {
    const NativeSample sample{i, 1000 * i, random_raw(rng)};
    const auto bytes = encode_native(sample);
    std::vector<Frame> frames;
    decoder->feed(bytes, frames);
    ASSERT_EQ(frames.size(), 1u);
    const auto& m = frames[0].raw;
    EXPECT_EQ(frames[0].sequence, i);
    EXPECT_DOUBLE_EQ(frames[0].device_time_s, 1e-3 * i);
    const auto near = [](double got, double want, double half_lsb) {
      return (std::isnan(got) && std::isnan(want)) || std::abs(got - want) <= half_lsb * (1 + 1e-9);
    };
    EXPECT_TRUE(near(m.tof_ns, sample.raw.tof_ns, 0.5e-6));
    EXPECT_TRUE(near(m.amplitude, sample.raw.amplitude, 0.5e-6));
    EXPECT_TRUE(near(m.pulse_width_ns, sample.raw.pulse_width_ns, 0.5e-3));
    EXPECT_TRUE(near(m.temperature_c, sample.raw.temperature_c, 0.5 / 128));
    EXPECT_EQ(m.shots_valid, sample.raw.shots_valid);
    EXPECT_EQ(m.flags, sample.raw.flags);
    // Encoding is idempotent: what was decoded encodes to the same bytes.
    EXPECT_EQ(encode_native({i, 1000 * i, m}), bytes);
  }
  EXPECT_EQ(decoder->counters().bytes_skipped, 0u);
}

TEST(LinkNative, RejectsValuesThatDoNotFit) {
  ranging::RawMeasurement m;
  m.tof_ns = -1;
  EXPECT_THROW((void)encode_native({0, 0, m}), std::out_of_range);
  m.tof_ns = 5000;  // 5 us > 4.29 us
  EXPECT_THROW((void)encode_native({0, 0, m}), std::out_of_range);
  m.tof_ns = 10;
  m.pulse_width_ns = 70;
  EXPECT_THROW((void)encode_native({0, 0, m}), std::out_of_range);
  m.pulse_width_ns = 10;
  m.shots_valid = 70000;
  EXPECT_THROW((void)encode_native({0, 0, m}), std::out_of_range);
}

TEST(LinkNative, AFrameWithoutEchoCarriesNoRange) {
  // Found by fuzzing: a frame whose flags say "no echo" but whose tof field
  // holds a number must not produce a distance (REP-117).
  ranging::RawMeasurement m;
  m.tof_ns = 12.5;
  m.shots_valid = 0;
  m.flags = ranging::kRawNoEcho;
  const auto frame = encode_native({0, 0, m});
  const auto frames = decode(Format::kNative, Bytes(frame.begin(), frame.end()), {});
  ASSERT_EQ(frames.size(), 1u);
  EXPECT_TRUE(std::isnan(frames[0].raw.tof_ns));
  EXPECT_TRUE(std::isnan(frames[0].raw.distance_raw_m));
}

TEST(LinkNative, SequenceAndClockUnwrapAndGapsAreCounted) {
  Bytes bytes;
  const std::uint32_t start = 0xFFFFFFFE;
  for (std::uint32_t k = 0; k < 6; ++k) {
    if (k == 3) continue;  // a lost frame
    ranging::RawMeasurement m;
    m.flags = ranging::kRawNoEcho;
    const auto f = encode_native({start + k, start + 1000 * k, m});
    bytes.insert(bytes.end(), f.begin(), f.end());
  }
  DecoderCounters c;
  const auto frames = decode(Format::kNative, bytes, {}, &c);
  ASSERT_EQ(frames.size(), 5u);
  EXPECT_EQ(frames[4].sequence, std::uint64_t{start} + 5);  // past 2^32
  EXPECT_NEAR(frames[4].device_time_s - frames[0].device_time_s, 5000e-6, 1e-9);
  EXPECT_EQ(frames[3].status & kLinkSequenceGap, kLinkSequenceGap);
  EXPECT_EQ(c.sequence_gaps, 1u);
}

TEST(LinkNative, LaterVersionsAreSkippedWholeAndLongerV1PayloadsRead) {
  // A version-2 packet with a valid CRC between two v1 frames; a v1 frame with
  // two extra payload bytes (a later minor addition) still decodes.
  ranging::RawMeasurement m;
  m.tof_ns = 10;
  m.shots_valid = 1;
  auto f1 = encode_native({1, 0, m});
  Bytes v2 = {kNativeSync0, kNativeSync1, 2, 3, 1, 2, 3};
  const auto crc = crc16_ccitt_false(v2);
  v2.push_back(static_cast<std::uint8_t>(crc));
  v2.push_back(static_cast<std::uint8_t>(crc >> 8));
  Bytes longer(f1.begin(), f1.begin() + 28);
  longer[3] = 26;
  longer.push_back(0xAB);
  longer.push_back(0xCD);
  const auto crc2 = crc16_ccitt_false(longer);
  longer.push_back(static_cast<std::uint8_t>(crc2));
  longer.push_back(static_cast<std::uint8_t>(crc2 >> 8));
  Bytes bytes(f1.begin(), f1.end());
  bytes.insert(bytes.end(), v2.begin(), v2.end());
  bytes.insert(bytes.end(), longer.begin(), longer.end());
  DecoderCounters c;
  const auto frames = decode(Format::kNative, bytes, {}, &c);
  ASSERT_EQ(frames.size(), 2u);
  EXPECT_EQ(c.other_packets, 1u);
  EXPECT_EQ(c.bytes_skipped, 0u);
  EXPECT_DOUBLE_EQ(frames[1].raw.tof_ns, 10);
}

TEST(LinkTfmini, FieldsAndInvalidCodesFollowTheManual) {
  // Dist 1234 cm, strength 500, temperature (2240 / 8 - 256) = 24 C.
  const auto frame = encode_tfmini({1234, 500, 2240});
  EXPECT_EQ(frame[0], 0x59);
  EXPECT_EQ(frame[2], 1234 & 0xFF);
  unsigned sum = 0;
  for (int i = 0; i < 8; ++i) sum += frame[i];
  EXPECT_EQ(frame[8], sum & 0xFF);

  Bytes bytes(frame.begin(), frame.end());
  for (const std::uint16_t code :
       {kTfminiLowSignal, kTfminiSaturated, kTfminiAmbient, std::uint16_t{0}}) {
    const auto f = encode_tfmini(
        {code, code == kTfminiSaturated ? std::uint16_t{65535} : std::uint16_t{40}, 2240});
    bytes.insert(bytes.end(), f.begin(), f.end());
  }
  const auto frames = decode(Format::kTfmini, bytes, {});
  ASSERT_EQ(frames.size(), 5u);
  EXPECT_DOUBLE_EQ(frames[0].raw.distance_raw_m, 12.34);
  EXPECT_DOUBLE_EQ(frames[0].raw.amplitude, 500);
  EXPECT_DOUBLE_EQ(frames[0].raw.temperature_c, 24);
  EXPECT_TRUE(frames[0].raw.has_echo());
  const std::uint32_t reasons[] = {kLinkLowSignal, kLinkStrengthSaturated, kLinkAmbientSaturated,
                                   kLinkLowSignal};
  for (int i = 1; i < 5; ++i) {
    SCOPED_TRACE(i);
    EXPECT_TRUE(std::isnan(frames[i].raw.distance_raw_m));  // REP-117: no fake range
    EXPECT_FALSE(frames[i].raw.has_echo());
    EXPECT_EQ(frames[i].status & reasons[i - 1], reasons[i - 1]);
  }
  EXPECT_NE(frames[2].raw.flags & ranging::kRawSaturated, 0u);
}

TEST(LinkLwnx, DistancePacketsDecodeAndOtherPacketsAreSkipped) {
  Bytes bytes =
      encode_lwnx(0, {reinterpret_cast<const std::uint8_t*>("LW20\0\0\0\0\0\0\0\0\0\0\0"), 16});
  const auto d = encode_lwnx(kLwnxDistanceData, lwnx_distance_data(1234, 87));
  const auto lost = encode_lwnx(kLwnxDistanceData, lwnx_distance_data(-1, 0));
  bytes.insert(bytes.end(), d.begin(), d.end());
  bytes.insert(bytes.end(), lost.begin(), lost.end());
  // The packet layout of LightWare's own sample code: AA, flags = (N << 6), id, data, CRC.
  EXPECT_EQ(d[1] | (d[2] << 8), 5 << 6);
  DecoderCounters c;
  const auto frames = decode(Format::kLwnx, bytes, {}, &c);
  ASSERT_EQ(frames.size(), 2u);
  EXPECT_EQ(c.other_packets, 1u);
  EXPECT_DOUBLE_EQ(frames[0].raw.distance_raw_m, 12.34);
  EXPECT_DOUBLE_EQ(frames[0].raw.amplitude, 87);
  EXPECT_FALSE(frames[1].raw.has_echo());
  EXPECT_TRUE(std::isnan(frames[1].raw.distance_raw_m));
}

TEST(LinkRplidar, SamplesGiveAngleAndRange) {
  Bytes bytes(kRplidarScanDescriptor.begin(), kRplidarScanDescriptor.end());
  for (int i = 0; i < 8; ++i) {
    const auto s = encode_rplidar({i == 0, 15, static_cast<std::uint16_t>(64 * 45 * i + 32),
                                   static_cast<std::uint16_t>(i == 3 ? 0 : 4 * (1000 + i))});
    bytes.insert(bytes.end(), s.begin(), s.end());
  }
  DecoderCounters c;
  const auto frames = decode(Format::kRplidar, bytes, {}, &c);
  ASSERT_EQ(frames.size(), 8u);
  EXPECT_EQ(c.other_packets, 1u);  // the descriptor
  EXPECT_TRUE(frames[0].scan_start);
  EXPECT_FALSE(frames[1].scan_start);
  EXPECT_DOUBLE_EQ(frames[2].scan_angle_deg, 90.5);
  EXPECT_DOUBLE_EQ(frames[2].raw.distance_raw_m, 1.002);
  EXPECT_DOUBLE_EQ(frames[2].raw.amplitude, 15);
  EXPECT_FALSE(frames[3].raw.has_echo());
  EXPECT_EQ(frames[3].status, kLinkNoRange);
}

TEST(LinkProperty, AnyChunkingGivesTheSameFramesAndCounters) {
  for (const Format format : kFormats) {
    SCOPED_TRACE(std::string(format_name(format)));
    Stream s = make_stream(format, 3000, 11);
    corrupt(s.bytes, 0.01, 12);  // with damage too: resync must not depend on chunk borders
    DecoderCounters whole_counters;
    const auto whole = decode(format, s.bytes, {}, &whole_counters);
    std::mt19937_64 rng(13);
    for (int trial = 0; trial < 5; ++trial) {
      DecoderCounters c;
      const auto chunked = decode(format, s.bytes, random_chunks(s.bytes.size(), rng), &c);
      ASSERT_EQ(chunked.size(), whole.size());
      for (std::size_t i = 0; i < whole.size(); ++i)
        ASSERT_TRUE(same_frame(chunked[i], whole[i])) << i;
      EXPECT_EQ(c.bytes_skipped, whole_counters.bytes_skipped);
      EXPECT_EQ(c.checksum_failures, whole_counters.checksum_failures);
      EXPECT_EQ(c.resyncs, whole_counters.resyncs);
    }
    // Byte by byte as well.
    const auto single = decode(format, s.bytes, std::vector<std::size_t>(s.bytes.size(), 1));
    ASSERT_EQ(single.size(), whole.size());
    for (std::size_t i = 0; i < whole.size(); ++i) ASSERT_TRUE(same_frame(single[i], whole[i]));
  }
}

// One format over 1 M frames with 1 % of bytes carrying a single-bit flip.
struct CorruptionCount {
  std::size_t intact = 0, intact_recovered = 0, corrupted = 0, corrupted_accepted = 0;
  std::size_t corrupted_passing_check = 0;  // oracle: damaged frames whose own check still passes
};

CorruptionCount corruption_run(Format format, std::size_t n_frames) {
  Stream s = make_stream(format, n_frames, 21);
  const Stream clean = s;
  const auto flipped = corrupt(s.bytes, 0.01, 22);
  std::vector<bool> damaged(n_frames, false);
  std::size_t f = 0;
  for (const std::size_t pos : flipped) {
    while (f + 1 < n_frames && s.offsets[f + 1] <= pos) ++f;
    if (pos >= s.offsets[0]) damaged[f] = true;
  }
  DecoderCounters counters;
  const auto frames = decode(format, s.bytes, {}, &counters);
  // The clean stream's frames are the reference content at each offset.
  const auto reference = decode(format, clean.bytes, {});
  EXPECT_EQ(reference.size(), n_frames);
  CorruptionCount c;
  for (const Frame& fr : frames) {
    const auto it = std::lower_bound(s.offsets.begin(), s.offsets.end(), fr.stream_offset);
    const bool aligned = it != s.offsets.end() && *it == fr.stream_offset;
    const auto i = static_cast<std::size_t>(it - s.offsets.begin());
    Frame expected = aligned ? reference[i] : Frame{};
    if (aligned && format != Format::kNative) expected.sequence = fr.sequence;  // frame counts
    if (aligned) expected.status |= fr.status & kLinkSequenceGap;  // frames before it were lost
    if (aligned && !damaged[i] && same_frame(fr, expected)) {
      ++c.intact_recovered;
    } else {
      ++c.corrupted_accepted;
    }
  }
  for (std::size_t i = 0; i < n_frames; ++i) {
    if (!damaged[i]) {
      ++c.intact;
      continue;
    }
    ++c.corrupted;
    if (format == Format::kTfmini) {
      const std::uint8_t* p = s.bytes.data() + s.offsets[i];
      unsigned sum = 0;
      for (int k = 0; k < 8; ++k) sum += p[k];
      if (p[0] == 0x59 && p[1] == 0x59 && (sum & 0xFF) == p[8]) ++c.corrupted_passing_check;
    }
  }
  std::cout << format_name(format) << ": " << n_frames << " frames, " << flipped.size()
            << " bytes flipped, " << c.corrupted << " frames damaged; intact " << c.intact_recovered
            << " / " << c.intact << " recovered; " << c.corrupted_accepted
            << " damaged or false frames accepted (" << c.corrupted_passing_check
            << " damaged frames pass their own check); " << counters.summary() << "\n";
  return c;
}

TEST(LinkCorruption, CrcFormatsRecoverEveryIntactFrameAndAcceptNoDamagedOne) {
  for (const Format format : {Format::kNative, Format::kLwnx}) {
    const CorruptionCount c = corruption_run(format, 1'000'000);
    EXPECT_GT(c.corrupted, 1000u);  // the experiment did damage frames
    EXPECT_EQ(c.intact_recovered, c.intact);
    EXPECT_EQ(c.corrupted_accepted, 0u);
  }
}

TEST(LinkCorruption, TfminiAcceptsOnlyWhatItsEightBitSumLetsThrough) {
  const CorruptionCount c = corruption_run(Format::kTfmini, 1'000'000);
  // An accepted false frame (a damaged 59 59 off the frame grid whose sum
  // matches) covers bytes of the intact frame after it: at most one each.
  const std::size_t false_frames = c.corrupted_accepted - c.corrupted_passing_check;
  EXPECT_GE(c.intact_recovered + false_frames, c.intact);
  EXPECT_GE(static_cast<double>(c.intact_recovered), 0.9999 * static_cast<double>(c.intact));
  // Damaged frames at their place pass exactly when the sum still matches (the
  // oracle); false frames at other offsets need 59 59 and a 1/256 sum: allow
  // as many again. Two flips that cancel: ~1e-4 of frames at this rate.
  EXPECT_GE(c.corrupted_accepted, c.corrupted_passing_check);
  EXPECT_LE(c.corrupted_accepted, 2 * c.corrupted_passing_check + 10);
  EXPECT_LT(static_cast<double>(c.corrupted_accepted), 3e-4 * 1e6);
}

TEST(LinkCorruption, RplidarKeepsItsPhaseOverFlippedBits) {
  const CorruptionCount c = corruption_run(Format::kRplidar, 1'000'000);
  EXPECT_GE(static_cast<double>(c.intact_recovered), 0.9999 * static_cast<double>(c.intact));
}

TEST(LinkResync, FalseSyncWordsInsidePayloadsAndBeforeFramesCostNoFrame) {
  // TFmini: a distance and strength of 0x5959 put "59 59" inside the payload,
  // and a stray "59 59 xx" before a frame is a false header (PX4's and
  // ArduPilot's parsers drop their buffer here and lose the real frame).
  Bytes bytes = {0x59, 0x59, 0x10};
  for (int i = 0; i < 3; ++i) {
    const auto f = encode_tfmini({0x5959, 0x5959, 0x5959});
    bytes.insert(bytes.end(), f.begin(), f.end());
  }
  DecoderCounters c;
  auto frames = decode(Format::kTfmini, bytes, {}, &c);
  EXPECT_EQ(frames.size(), 3u);
  EXPECT_EQ(c.bytes_skipped, 3u);
  EXPECT_DOUBLE_EQ(frames[0].raw.distance_raw_m, 228.73);

  // Native: the sync word in the tof field, and a false header claiming a
  // 255-byte payload right before real frames.
  ranging::RawMeasurement m;
  m.tof_ns = (0xD57E + 0xD57E * 65536.0) * 1e-6;
  m.shots_valid = 1;
  Bytes native = {kNativeSync0, kNativeSync1, 1, 255};
  for (std::uint32_t i = 0; i < 20; ++i) {
    const auto f = encode_native({i, i, m});
    native.insert(native.end(), f.begin(), f.end());
  }
  frames = decode(Format::kNative, native, {}, &c);
  EXPECT_EQ(frames.size(), 20u);
  EXPECT_EQ(c.checksum_failures, 1u);
  EXPECT_EQ(c.bytes_skipped, 4u);

  // LWNX: a 0xAA claiming 1023 bytes, then packets; they arrive in 7-byte chunks.
  Bytes lwnx = {0xAA, 0xC0, 0xFF};
  for (int i = 0; i < 200; ++i) {
    const auto p = encode_lwnx(
        kLwnxDistanceData, lwnx_distance_data(static_cast<std::int16_t>(0xAAAA & 0x7FFF), 0xAA));
    lwnx.insert(lwnx.end(), p.begin(), p.end());
  }
  frames = decode(Format::kLwnx, lwnx, std::vector<std::size_t>(lwnx.size() / 7, 7), &c);
  EXPECT_EQ(frames.size(), 200u);
  EXPECT_EQ(c.bytes_skipped, 3u);
}

TEST(LinkResync, GarbageIsSkippedInBoundedMemory) {
  std::mt19937_64 rng(5);
  Bytes garbage(1 << 20);
  for (auto& b : garbage) b = static_cast<std::uint8_t>(rng());
  for (const Format format : kFormats) {
    auto decoder = make_decoder(format);
    std::vector<Frame> frames;
    for (std::size_t pos = 0; pos < garbage.size(); pos += 4096) {
      decoder->feed({garbage.data() + pos, 4096}, frames);
      ASSERT_LE(decoder->pending_bytes(), kLwnxMaxPacketBytes);
    }
    decoder->finish(frames);
    const auto& c = decoder->counters();
    EXPECT_EQ(c.bytes_in, garbage.size());
    EXPECT_EQ(c.frame_bytes + c.other_packet_bytes + c.bytes_skipped, c.bytes_in);
    if (format == Format::kNative || format == Format::kLwnx) EXPECT_EQ(frames.size(), 0u);
  }
}

TEST(LinkFormat, NamesRoundTrip) {
  for (const Format f : kFormats) EXPECT_EQ(format_from_name(format_name(f)), f);
  EXPECT_THROW((void)format_from_name("mavlink"), std::invalid_argument);
}

}  // namespace
}  // namespace tofkit::link
