// Shared body of the link decoders' fuzz targets: decode the input in one
// chunk and again in chunks whose sizes come from the input itself; the two
// must agree frame for frame and counter for counter, the held-back bytes
// must stay within one frame, and every byte must be accounted for.

#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <vector>

#include "tofkit/link/decoder.hpp"
#include "tofkit/link/lwnx.hpp"

namespace tofkit::link::fuzz {

inline void check(bool ok) {
  if (!ok) __builtin_trap();
}

inline bool same_double(double a, double b) {
  return (std::isnan(a) && std::isnan(b)) || a == b;
}

inline int decode_both_ways(Format format, const std::uint8_t* data, std::size_t size) {
  std::vector<Frame> whole, chunked;
  auto a = make_decoder(format);
  a->feed({data, size}, whole);
  check(a->pending_bytes() <= kLwnxMaxPacketBytes);
  a->finish(whole);

  auto b = make_decoder(format);
  std::size_t pos = 0;
  std::uint32_t state = size > 0 ? data[0] : 1;
  while (pos < size) {
    state = state * 1103515245u + 12345u;
    const std::size_t n = std::min<std::size_t>(size - pos, (state >> 16) % 40);
    b->feed({data + pos, n}, chunked);
    check(b->pending_bytes() <= kLwnxMaxPacketBytes);
    pos += n;
  }
  b->finish(chunked);

  check(whole.size() == chunked.size());
  for (std::size_t i = 0; i < whole.size(); ++i) {
    const Frame& x = whole[i];
    const Frame& y = chunked[i];
    check(x.stream_offset == y.stream_offset && x.sequence == y.sequence && x.status == y.status);
    check(same_double(x.raw.tof_ns, y.raw.tof_ns) &&
          same_double(x.raw.distance_raw_m, y.raw.distance_raw_m) &&
          same_double(x.raw.amplitude, y.raw.amplitude) && x.raw.flags == y.raw.flags);
    check(x.stream_offset < size);
    // REP-117: a frame without an echo never carries a range.
    if (!x.raw.has_echo()) check(std::isnan(x.raw.distance_raw_m));
  }
  const DecoderCounters& c = a->counters();
  const DecoderCounters& d = b->counters();
  check(c.bytes_in == size && d.bytes_in == size);
  check(c.frame_bytes + c.other_packet_bytes + c.bytes_skipped == size);
  check(c.frames == d.frames && c.bytes_skipped == d.bytes_skipped &&
        c.checksum_failures == d.checksum_failures && c.length_errors == d.length_errors &&
        c.resyncs == d.resyncs);
  return 0;
}

}  // namespace tofkit::link::fuzz
