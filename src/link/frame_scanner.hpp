#pragma once
// The scanning engine shared by every link decoder (private to src/link).
//
// A format policy says, for the bytes at one position, whether a frame starts
// there: `Attempt attempt(const std::uint8_t* p, std::size_t n, bool end, Frame& f)`
// with n >= 1 bytes available (n < kMaxFrameBytes only at the end of a chunk).
// The engine owns skipping, holding back a partial frame between chunks,
// stream offsets and the counters.

#include <algorithm>
#include <cstdint>
#include <cstring>
#include <span>
#include <stdexcept>
#include <vector>

#include "tofkit/link/decoder.hpp"

namespace tofkit::link::detail {

enum class Verdict {
  kFrame,      ///< a measurement frame of `length` bytes (f filled in)
  kOther,      ///< a valid packet of `length` bytes without a measurement
  kNeedMore,   ///< a candidate that needs more bytes than available (only when !end)
  kNoSync,     ///< no frame starts here; the next candidate is `length` bytes on (>= 1)
  kBadCheck,   ///< sync found, checksum failed: reject, rescan from `length` bytes on (>= 1)
  kBadLength,  ///< sync found, impossible length or version: same
};

struct Attempt {
  Verdict verdict = Verdict::kNoSync;
  std::size_t length = 1;
};

template <class Policy>
class ScanningDecoder final : public Decoder {
 public:
  explicit ScanningDecoder(Policy policy) : policy_(std::move(policy)) {
    pending_.reserve(2 * Policy::kMaxFrameBytes);
  }

  void feed(std::span<const std::uint8_t> bytes, std::vector<Frame>& out) override {
    counters_.bytes_in += bytes.size();
    if (!pending_.empty()) {
      // Complete the held-back candidate with at most one frame's worth of new
      // bytes; any frame starting in the held-back bytes fits in that.
      const std::size_t held = pending_.size();
      const std::size_t take = std::min(bytes.size(), Policy::kMaxFrameBytes);
      pending_.insert(pending_.end(), bytes.begin(), bytes.begin() + take);
      const std::size_t pos = scan(pending_.data(), pending_.size(), false, out);
      if (pos < held) {
        // Still waiting inside the held-back bytes: then all new bytes were taken
        // (a policy never asks for more than kMaxFrameBytes).
        if (take < bytes.size())
          throw std::logic_error("link decoder: candidate longer than a frame");
        pending_.erase(pending_.begin(), pending_.begin() + static_cast<std::ptrdiff_t>(pos));
        pending_offset_ += pos;
        return;
      }
      pending_.clear();
      pending_offset_ += pos;
      bytes = bytes.subspan(pos - held);
    }
    const std::size_t pos = scan(bytes.data(), bytes.size(), false, out);
    pending_.assign(bytes.begin() + static_cast<std::ptrdiff_t>(pos), bytes.end());
    pending_offset_ += pos;
  }

  void finish(std::vector<Frame>& out) override {
    const std::size_t pos = scan(pending_.data(), pending_.size(), true, out);
    counters_.bytes_skipped += pending_.size() - pos;  // a scan with end = true consumes all
    pending_offset_ += pending_.size();
    pending_.clear();
  }

  [[nodiscard]] const DecoderCounters& counters() const override { return counters_; }
  [[nodiscard]] Format format() const override { return Policy::kFormat; }
  [[nodiscard]] std::size_t pending_bytes() const override { return pending_.size(); }

 private:
  // Scans data[0, n) (stream offset pending_offset_ at data[0]); returns the
  // position of the first byte not consumed (a held-back candidate).
  std::size_t scan(const std::uint8_t* data, std::size_t n, bool end, std::vector<Frame>& out) {
    std::size_t pos = 0;
    while (pos < n) {
      Frame frame;
      const Attempt a = policy_.attempt(data + pos, n - pos, end, frame);
      switch (a.verdict) {
        case Verdict::kFrame:
          frame.stream_offset = pending_offset_ + pos;
          if (frame.sequence == 0 && !Policy::kHasSequence) frame.sequence = counters_.frames;
          ++counters_.frames;
          counters_.frame_bytes += a.length;
          if (skipping_) ++counters_.resyncs;
          skipping_ = false;
          out.push_back(frame);
          pos += a.length;
          break;
        case Verdict::kOther:
          ++counters_.other_packets;
          counters_.other_packet_bytes += a.length;
          if (skipping_) ++counters_.resyncs;
          skipping_ = false;
          pos += a.length;
          break;
        case Verdict::kNeedMore:
          return pos;
        case Verdict::kBadCheck:
        case Verdict::kBadLength:
          (a.verdict == Verdict::kBadCheck ? counters_.checksum_failures
                                           : counters_.length_errors) += 1;
          [[fallthrough]];
        case Verdict::kNoSync: {
          const std::size_t skip = std::min(std::max<std::size_t>(a.length, 1), n - pos);
          counters_.bytes_skipped += skip;
          skipping_ = true;
          pos += skip;
          break;
        }
      }
    }
    return pos;
  }

  Policy policy_;
  DecoderCounters counters_;
  std::vector<std::uint8_t> pending_;
  std::uint64_t pending_offset_ = 0;  // stream offset of the first byte not yet consumed
  bool skipping_ = false;
};

// Little-endian field readers.
inline std::uint16_t le16(const std::uint8_t* p) {
  return static_cast<std::uint16_t>(p[0] | (p[1] << 8));
}
inline std::uint32_t le32(const std::uint8_t* p) {
  return static_cast<std::uint32_t>(p[0]) | (static_cast<std::uint32_t>(p[1]) << 8) |
         (static_cast<std::uint32_t>(p[2]) << 16) | (static_cast<std::uint32_t>(p[3]) << 24);
}

// Bytes to skip before the next occurrence of `sync` in p[1, n) (n if none).
inline std::size_t distance_to_next(const std::uint8_t* p, std::size_t n, std::uint8_t sync) {
  if (n <= 1) return 1;
  const void* hit = std::memchr(p + 1, sync, n - 1);
  return hit == nullptr ? n : static_cast<std::size_t>(static_cast<const std::uint8_t*>(hit) - p);
}

}  // namespace tofkit::link::detail
