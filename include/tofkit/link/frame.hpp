#pragma once
/// \file What a link decoder emits: one Frame per accepted frame of a device's
/// byte stream (the RawMeasurement it carries, where it came from, its
/// vendor-specific status), and the counters a decoder keeps of what it
/// accepted, skipped and why.

#include <cstdint>
#include <string>
#include <string_view>

#include "tofkit/ranging/raw_measurement.hpp"

namespace tofkit::link {

/// Byte-stream formats the link stage understands.
enum class Format { kNative, kTfmini, kLwnx, kRplidar };

/// "native", "tfmini", "lwnx", "rplidar".
[[nodiscard]] std::string_view format_name(Format format);
/// Inverse of format_name; throws std::invalid_argument on an unknown name.
[[nodiscard]] Format format_from_name(std::string_view name);

/// Vendor conditions a frame reports beside its RawMeasurement (`status`).
/// A frame that reports no range keeps a NaN distance and kRawNoEcho (REP-117:
/// no fake ranges); these bits say why.
enum LinkStatus : std::uint32_t {
  kLinkLowSignal = 1u << 0,          ///< TFmini Dist -1 (strength < 100), LWNX distance <= 0
  kLinkStrengthSaturated = 1u << 1,  ///< TFmini Dist -2 / strength 65535
  kLinkAmbientSaturated = 1u << 2,   ///< TFmini Dist -4
  kLinkNoRange = 1u << 3,            ///< RPLIDAR distance 0 (no measurement at that angle)
  kLinkSequenceGap = 1u << 4,        ///< native: frames were lost just before this one
};

/// One accepted frame.
struct Frame {
  std::uint64_t stream_offset = 0;  ///< byte offset of the frame's first byte in the stream
  std::uint64_t sequence = 0;  ///< device sequence number (native, unwrapped), else frame count
  double device_time_s = ranging::kNaN;  ///< device clock (native, unwrapped), else NaN
  ranging::RawMeasurement raw;
  double scan_angle_deg = ranging::kNaN;  ///< RPLIDAR: heading of the sample, degrees
  bool scan_start = false;                ///< RPLIDAR: first sample of a new revolution
  std::uint32_t status = 0;               ///< LinkStatus bits
};

/// What a decoder saw. bytes_in = bytes in accepted frames + bytes in other
/// packets + bytes_skipped + bytes still pending.
struct DecoderCounters {
  std::uint64_t bytes_in = 0;       ///< bytes fed
  std::uint64_t frames = 0;         ///< measurement frames accepted
  std::uint64_t frame_bytes = 0;    ///< bytes in accepted frames
  std::uint64_t other_packets = 0;  ///< valid packets that carry no measurement (skipped whole)
  std::uint64_t other_packet_bytes = 0;  ///< their bytes
  std::uint64_t bytes_skipped = 0;       ///< bytes that belonged to no valid frame
  std::uint64_t checksum_failures = 0;   ///< candidate frames whose checksum (or check bits) failed
  std::uint64_t length_errors = 0;       ///< candidate frames with an impossible length or version
  std::uint64_t resyncs = 0;        ///< times the decoder found frames again after skipping bytes
  std::uint64_t sequence_gaps = 0;  ///< native: frames missing by sequence number

  /// One line: "frames 1000, skipped 12 bytes, 2 checksum failures, ...".
  [[nodiscard]] std::string summary() const;
};

}  // namespace tofkit::link
