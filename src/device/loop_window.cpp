#include "tofkit/device/loop_window.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

namespace tofkit::device {

ranging::RawMeasurement count_loop_window(const OscillatorLoop& loop,
                                          std::span<const LoopStretch> stretches,
                                          std::uint64_t seed, std::uint64_t stream, int shots) {
  if (stretches.empty() || shots < 1)
    throw std::invalid_argument("count_loop_window: needs stretches and shots >= 1");
  const auto& cfg = loop.config();
  const double window_ns = shots / cfg.link.laser.repetition_hz * 1e9;
  const double gate_ns = cfg.oscillator.gate_fraction * window_ns;
  const double zero_ns = cfg.oscillator.zero_half_period_ns;

  ranging::RawMeasurement out;
  double t = 0, first_edge = ranging::kNaN, last_edge = ranging::kNaN;
  double periods = 0, locked_sum = 0, amp = 0, width = 0, temp = 0;
  int temp_n = 0;
  std::uint32_t flags = 0, valid = 0;
  bool lost = false;
  for (std::size_t k = 0; k < stretches.size(); ++k) {
    const LoopStretch& s = stretches[k];
    if (!(s.duration_ns >= 0) || !(s.stall_ns >= 0) || s.stall_ns > s.duration_ns + 1e-9)
      throw std::invalid_argument("count_loop_window: stretch " + std::to_string(k) +
                                  " needs 0 <= stall_ns <= duration_ns");
    if (!(s.count_factor >= 0))
      throw std::invalid_argument("count_loop_window: stretch " + std::to_string(k) +
                                  " needs count_factor >= 0");
    // Locked time of this stretch inside the gate [0, gate).
    const double lo = std::min(t + s.stall_ns, gate_ns), hi = std::min(t + s.duration_ns, gate_ns);
    const double locked_ns = hi - lo;
    // The loop on this target over the locked time: its count gives the
    // stretch's mean period with the noise of that many periods. A stretch
    // outside the gate still reads the temperature sensor.
    const int sub_shots = std::max(1, static_cast<int>(std::lround(shots * locked_ns / gate_ns)));
    const auto m = loop.measure(s.target, s.conditions, seed, stream + k, sub_shots, shots);
    if (std::isfinite(m.temperature_c)) {
      temp += m.temperature_c;
      ++temp_n;
    }
    if (s.stall_ns > 0) lost = true;
    if (locked_ns > 0 && m.has_echo() && s.count_factor > 0) {
      const double period_ns = 2.0 * (m.tof_ns + zero_ns);
      if (std::isnan(first_edge)) first_edge = lo;
      last_edge = hi;
      periods += s.count_factor * locked_ns / period_ns;
      locked_sum += locked_ns;
      amp += locked_ns * m.amplitude;
      width += locked_ns * m.pulse_width_ns;
      valid += m.shots_valid;
      flags |= m.flags;
    } else if (locked_ns > 0 || (t < gate_ns && s.duration_ns > 0 && !m.has_echo())) {
      lost = true;  // the loop does not oscillate on this target: no edges
      flags |= m.flags & ~static_cast<std::uint32_t>(ranging::kRawNoEcho);
    }
    t += s.duration_ns;
  }
  out.temperature_c = temp_n > 0 ? temp / temp_n : ranging::kNaN;
  // Whole periods between the first edge and the last: fewer than one, no output.
  if (!(periods >= 1.0)) {
    out.flags = flags | ranging::kRawNoEcho;
    return out;
  }
  // Reciprocal counting: the span from the first edge to the last (stalls between
  // them included) over the periods counted.
  const double mean_period_ns = (last_edge - first_edge) / periods;
  out.tof_ns = 0.5 * mean_period_ns - zero_ns;
  out.distance_raw_m = loop.tof_to_distance_m(out.tof_ns);
  out.amplitude = amp / locked_sum;
  out.pulse_width_ns = width / locked_sum;
  out.shots_valid = valid;
  out.flags = flags & ~static_cast<std::uint32_t>(ranging::kRawNoEcho);
  if (lost) out.flags |= ranging::kRawPartialEchoes;
  return out;
}

}  // namespace tofkit::device
