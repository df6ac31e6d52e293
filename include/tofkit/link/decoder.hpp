#pragma once
/// \file An incremental frame decoder: bytes in (any chunking), frames out.
///
/// Every decoder scans the same way: at each position it asks the format
/// whether a frame starts there. A frame is emitted and the scan jumps past it;
/// a candidate whose checksum fails or whose length is impossible is rejected
/// and the scan resumes at the byte after its sync (never the whole buffer: a
/// false sync inside a payload must not cost the real frame behind it);
/// bytes before a sync are skipped. A candidate cut by the end of a chunk is
/// kept (at most one frame's worth of bytes) and completed by the next chunk,
/// so any chunking gives the same frames and counters as one big chunk.

#include <cstdint>
#include <memory>
#include <span>
#include <vector>

#include "tofkit/link/frame.hpp"

namespace tofkit::link {

class Decoder {
 public:
  virtual ~Decoder() = default;

  /// Decode `bytes`, appending accepted frames to `out` in stream order.
  virtual void feed(std::span<const std::uint8_t> bytes, std::vector<Frame>& out) = 0;
  /// End of stream: decode what the held-back bytes still contain (a false
  /// sync whose claimed length runs past the end is rejected and the bytes
  /// after it rescanned); the rest counts as skipped.
  virtual void finish(std::vector<Frame>& out) = 0;

  [[nodiscard]] virtual const DecoderCounters& counters() const = 0;
  [[nodiscard]] virtual Format format() const = 0;
  /// Bytes held back for the next feed (bounded by the format's largest frame).
  [[nodiscard]] virtual std::size_t pending_bytes() const = 0;
};

/// Options of the formats that need them.
struct DecoderOptions {
  /// native: distance_raw_m = tof_ns * this (nominal speed of light in air / 2).
  double metres_per_ns = 0;  ///< 0: ranging::metres_per_ns(TimeToDistance{})
  /// TFmini: bytes 6-7 carry the chip temperature (TFmini-S, Plus, TF-Luna);
  /// false for the original TFmini, whose bytes 6-7 are mode and reserved.
  bool tfmini_temperature = true;
  /// LWNX: bits of the "Distance output" parameter (command 27), which fix the
  /// int16 fields of a distance-data packet (command 44), in bit order.
  /// Default: bit 0 (first return raw, cm) and bit 4 (first return strength, %).
  std::uint32_t lwnx_distance_output = 0b1'0001;
};

[[nodiscard]] std::unique_ptr<Decoder> make_decoder(Format format,
                                                    const DecoderOptions& options = {});

}  // namespace tofkit::link
