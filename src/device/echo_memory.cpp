#include "tofkit/device/echo_memory.hpp"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

#include "random_draws.hpp"
#include "tofkit/device/loop_window.hpp"

namespace tofkit::device {
namespace {

// Streams of a moving window's sub-measurements: item i, path element k. The
// top bit keeps them apart from the streams of still beams (stream i).
constexpr std::uint64_t kPathStreamBit = 1ull << 63;
constexpr int kMaxPathElements = 256;
// Salt of the loop's re-lock draws (apart from the measurement's blocks).
constexpr std::uint32_t kRelockBlock = 0x524C434Bu;  // "RLCK"

/// Path element k of n in a moving window: its shots (shared, the remainder
/// to the first elements) and its random stream (item i's own when still).
struct PathElement {
  int shots;
  std::uint64_t stream;
};
PathElement path_element(std::size_t i, int k, int n, int shots) {
  return {std::max(1, shots / n + (k < shots % n ? 1 : 0)),
          n == 1 ? i
                 : (kPathStreamBit | (static_cast<std::uint64_t>(i) << 8) |
                    static_cast<std::uint64_t>(k))};
}

/// The share of a lag present at a window's start that remains on average over
/// the window: (1/T) integral_0^T exp(-t / tau) dt.
double mean_remaining(double window_s, double tau_s) {
  if (!(tau_s > 0)) return 0.0;
  const double x = window_s / tau_s;
  if (x < 1e-9) return 1.0;
  return (1.0 - std::exp(-x)) / x;
}

/// Edges the loop's board counts per clean period over a locked time of
/// locked_s whose swing top sits margin_v - offset_v exp(-t / tau_s) above the
/// comparator's level at t (the baseline recovering from a stronger return):
/// (1 / L) integral_0^L T (1 + extra(t)) / (T + wait(t)) dt with near_top_edges'
/// extra edges and missed-rise waits per period T (the settled state's period,
/// noise and comparator high time). Exactly 1 when the top stays
/// kNearTopSigmas noise sigmas above the level over the whole time.
double near_top_count_factor(const LoopState& s, double margin_v, double offset_v, double locked_s,
                             double tau_s, double bandwidth_mhz, double hysteresis_v) {
  if (!(locked_s > 0) || !(offset_v > 0) || !(s.noise_v > 0)) return 1.0;
  // The margin grows as the baseline comes down: its least is at the start.
  if (margin_v - offset_v >= kNearTopSigmas * s.noise_v) return 1.0;
  constexpr int kNodes = 64;  // midpoint rule over the locked time
  double sum = 0;
  for (int j = 0; j < kNodes; ++j) {
    const double t = (j + 0.5) / kNodes * locked_s;
    const auto e = near_top_edges(margin_v - offset_v * std::exp(-t / tau_s), s.noise_v,
                                  bandwidth_mhz, s.comparator_high_ns, hysteresis_v);
    sum += s.period_ns * (1.0 + e.extra_edges_per_period) / (s.period_ns + e.missed_wait_ns);
  }
  return sum / kNodes;
}

/// Valid-shot weighted average of the sub-measurements of a moving window.
ranging::RawMeasurement combine(std::span<const ranging::RawMeasurement> parts) {
  ranging::RawMeasurement out;
  double w_sum = 0, tof = 0, dist = 0, width = 0, amp = 0, temp = 0;
  std::uint32_t flags = 0, valid = 0;
  int temp_n = 0;
  bool partial = false;
  for (const auto& p : parts) {
    if (std::isfinite(p.temperature_c)) {
      temp += p.temperature_c;
      ++temp_n;
    }
    if (!p.has_echo()) {
      partial = true;
      continue;
    }
    const double w = p.shots_valid;
    w_sum += w;
    tof += w * p.tof_ns;
    dist += w * p.distance_raw_m;
    width += w * p.pulse_width_ns;
    amp += w * p.amplitude;
    valid += p.shots_valid;
    flags |= p.flags;
  }
  out.temperature_c = temp_n > 0 ? temp / temp_n : ranging::kNaN;
  if (valid == 0) {
    for (const auto& p : parts) out.flags |= p.flags;
    out.flags |= ranging::kRawNoEcho;
    return out;
  }
  out.tof_ns = tof / w_sum;
  out.distance_raw_m = dist / w_sum;
  out.pulse_width_ns = width / w_sum;
  out.amplitude = amp / w_sum;
  out.shots_valid = valid;
  out.flags = flags & ~static_cast<std::uint32_t>(ranging::kRawNoEcho);
  if (partial) out.flags |= ranging::kRawPartialEchoes;
  return out;
}

}  // namespace

EchoMemory::EchoMemory(const VirtualRangefinder& device) : device_(&device) {
  if (device.config().oscillator.enabled)
    loop_ = std::make_shared<const OscillatorLoop>(device.config());
}

double EchoMemory::window_s(int shots) const {
  const auto& c = device_->config();
  const int n = shots > 0 ? shots : c.measurement.shots;
  return n / c.link.laser.repetition_hz;
}

double EchoMemory::echo_strength(const Target& target, const Conditions& conditions) const {
  const auto& c = device_->config();
  // Floor: an echo just at the threshold lasting one receiver rise time (0.35 / B);
  // the receiver's operating point cannot move further than a no-echo state.
  const double rise_ns = 0.35 / c.link.receiver.bandwidth_mhz * 1e3;
  const double floor_charge = c.discriminator.threshold_v * rise_ns;
  if (target.surfaces.empty()) return std::log(floor_charge);
  const EchoShape e = device_->echo(target, conditions);
  if (!e.detected) return std::log(floor_charge);
  // The amplifier clips at saturation_v and stays clipped longer (charge storage):
  // what passes the coupling grows with the width, not the linear peak. In the
  // self-oscillating loop (oscillator.enabled) the fast coupling sits inside the
  // loop (its baseline is part of the loop's walk); the slow operating point (AGC)
  // is driven from the linear stage, the intensity channel, which clips at
  // amplitude_clip_v, and the width is the comparator's high time per period.
  const double clip_v =
      c.oscillator.enabled ? c.link.receiver.amplitude_clip_v : c.link.receiver.saturation_v;
  const double peak = std::min(e.peak_v, clip_v);
  const double width = std::max(e.fall_crossing_ns - e.rise_crossing_ns, rise_ns);
  return std::log(std::max(peak * width, floor_charge));
}

std::vector<std::size_t> EchoMemory::segments(std::span<const SequenceItem> items) const {
  std::vector<std::size_t> starts;
  if (items.empty()) return starts;
  starts.push_back(0);
  const double tau_s = device_->config().memory.time_constant_ms * 1e-3;
  for (std::size_t i = 1; i < items.size(); ++i) {
    const double gap = items[i].time_s - items[i - 1].time_s;
    if (!(tau_s > 0) || gap > kDecayedTimeConstants * tau_s) starts.push_back(i);
  }
  return starts;
}

void EchoMemory::measure_sequence(std::span<const SequenceItem> items, std::uint64_t seed,
                                  std::span<ranging::RawMeasurement> out,
                                  std::span<MemoryTrace> trace) const {
  if (out.size() != items.size())
    throw std::invalid_argument("measure_sequence: output span size differs from the item count");
  if (!trace.empty() && trace.size() != items.size())
    throw std::invalid_argument("measure_sequence: trace span size differs from the item count");
  for (std::size_t i = 0; i < items.size(); ++i) {
    if (items[i].path.empty() || items[i].path.size() > kMaxPathElements)
      throw std::invalid_argument("measure_sequence: item " + std::to_string(i) + " needs 1.." +
                                  std::to_string(kMaxPathElements) + " path targets");
    if (!std::isfinite(items[i].time_s) || (i > 0 && items[i].time_s < items[i - 1].time_s))
      throw std::invalid_argument("measure_sequence: item " + std::to_string(i) +
                                  " has a time before the previous item's");
  }
  const auto& cfg = device_->config();
  const double tau_s = cfg.memory.time_constant_ms * 1e-3;
  const bool loop = cfg.oscillator.enabled;
  const bool memory_on = !loop && tau_s > 0 && cfg.memory.coupling_share > 0;
  const auto starts = segments(items);

  // The loop (device/oscillator_loop.hpp): its comparator fires the threshold
  // above the AC coupling's baseline, which on a still target settles at
  // coupling_duty of the swing and in a scan follows the swings of the last
  // time constants. A baseline left high by a stronger return raises the level:
  // the rise comes later, the fall earlier (reads long), and where the level
  // reaches the swing's top the loop loses lock until the baseline has come down
  // (device/loop_window.hpp counts the window around the stall).
  const bool loop_memory_on = loop && tau_s > 0;
  const double duty = cfg.oscillator.coupling_duty;
  const double threshold_v = cfg.discriminator.threshold_v;
  const double bandwidth_mhz = cfg.link.receiver.bandwidth_mhz;
  const double hysteresis_v = cfg.oscillator.comparator_hysteresis_mv * 1e-3;
  auto loop_segment = [&](std::size_t begin, std::size_t end) {
    double baseline_v = ranging::kNaN;  // the loop's coupling capacitor voltage
    std::vector<LoopStretch> stretches;
    for (std::size_t i = begin; i < end; ++i) {
      const SequenceItem& item = items[i];
      const int shots = item.shots > 0 ? item.shots : cfg.measurement.shots;
      const auto k_count = static_cast<int>(item.path.size());
      const double sub_window = window_s(shots) / k_count;
      if (!loop_memory_on) {  // DC coupled: no stalls, the window still counts its targets
        const auto [first_shots, first_stream] = path_element(i, 0, k_count, shots);
        if (k_count == 1) {
          out[i] =
              device_->measure(item.path.front(), item.conditions, seed, first_stream, first_shots);
          continue;
        }
        stretches.clear();
        for (const Target& target : item.path)
          stretches.push_back({target, item.conditions, sub_window * 1e9, 0.0});
        out[i] = count_loop_window(*loop_, stretches, seed, first_stream, shots);
        continue;
      }
      stretches.clear();
      double settled_sum = 0, offset_sum = 0, stall_sum = 0, strength_sum = 0;
      bool factor_unclean = false;
      // The loop's duty in this output's window (oscillator.duty_wander: a
      // switch-on's unbalance, settling over the turn-on transient) sets the share
      // of the swing the baseline settles at.
      const double item_duty =
          duty + loop_->duty_offset(item.conditions, seed, window_s(shots) * 1e3);
      for (int k = 0; k < k_count; ++k) {
        const Target& target = item.path[static_cast<std::size_t>(k)];
        // The baseline this target's square wave would settle at (a miss or a
        // return too weak to lock on: the watchdog keeps toggling the laser, the
        // baseline still goes to the duty share of what comes back).
        const LoopState settled_state = loop_->state(target, item.conditions, item_duty - duty);
        const double settled_v = item_duty * settled_state.swing_v;
        if (std::isnan(baseline_v)) baseline_v = settled_v;  // a fresh segment: settled
        const double offset_v = baseline_v - settled_v;
        // Lock needs the level (baseline + threshold) below the swing's top; the
        // loop re-locks when the receiver's noise first lifts the swing over it,
        // so within a few noise sigmas of the top which side the level is on is a
        // draw (thesis Fig. 4.28: the range on black after mid grey is erratic).
        const double settled_margin_v = settled_state.swing_v - threshold_v - settled_v;
        double margin_v = settled_margin_v;
        double stall_s = 0;
        if (!settled_state.oscillates) {
          stall_s = sub_window;
        } else if (offset_v > 0) {
          const auto r =
              detail::CounterRng(seed).draw(i, static_cast<std::uint32_t>(k), kRelockBlock);
          margin_v += settled_state.noise_v * detail::normal_pair(r[0], r[1])[0];
          if (!(margin_v > 0))
            stall_s = sub_window;
          else if (offset_v >= margin_v)
            stall_s = std::min(sub_window, tau_s * std::log(offset_v / margin_v));
        }
        const double locked_s = sub_window - stall_s;
        Conditions conditions = item.conditions;
        // The offset left when the loop locks, relaxing over the locked time.
        const double locked_offset_v = offset_v * std::exp(-stall_s / tau_s);
        conditions.baseline_offset_v = locked_offset_v * mean_remaining(locked_s, tau_s);
        // Locked with the top near the level, the noise adds and drops edges
        // (near_top_edges, thesis Fig. 4.28's erratic range on black).
        const double count_factor =
            settled_state.oscillates
                ? near_top_count_factor(settled_state, settled_margin_v, locked_offset_v, locked_s,
                                        tau_s, bandwidth_mhz, hysteresis_v)
                : 1.0;
        stretches.push_back({target, conditions, sub_window * 1e9, stall_s * 1e9, count_factor});
        factor_unclean |= count_factor != 1.0;
        settled_sum += settled_v;
        offset_sum += conditions.baseline_offset_v;
        stall_sum += stall_s;
        if (!trace.empty()) strength_sum += echo_strength(target, item.conditions);
        // The capacitor relaxes towards this target's baseline over the sub-window.
        baseline_v = settled_v + offset_v * std::exp(-sub_window / tau_s);
      }
      const auto [first_shots, first_stream] = path_element(i, 0, k_count, shots);
      if (k_count == 1 && stall_sum == 0 && !factor_unclean) {
        out[i] = device_->measure(stretches.front().target, stretches.front().conditions, seed,
                                  first_stream, first_shots);
      } else {
        out[i] = count_loop_window(*loop_, stretches, seed, first_stream, shots);
      }
      // Between windows the beam stays on the last target until the next output.
      if (i + 1 < end) {
        const double idle = items[i + 1].time_s - item.time_s - window_s(shots);
        if (idle > 0) {
          const double settled_v =
              item_duty * loop_->state(item.path.back(), item.conditions).swing_v;
          baseline_v = settled_v + (baseline_v - settled_v) * std::exp(-idle / tau_s);
        }
      }
      if (!trace.empty()) {
        auto& t = trace[i];
        t.strength_neper = strength_sum / k_count;
        t.settled_baseline_v = settled_sum / k_count;
        t.baseline_offset_v = offset_sum / k_count;
        t.stall_s = stall_sum;
      }
    }
  };
  auto run_segment = [&](std::size_t begin, std::size_t end) {
    double baseline_v = ranging::kNaN;  // the coupling capacitor's voltage
    std::vector<ranging::RawMeasurement> parts;
    for (std::size_t i = begin; i < end; ++i) {
      const SequenceItem& item = items[i];
      const int shots = item.shots > 0 ? item.shots : cfg.measurement.shots;
      const auto k_count = static_cast<int>(item.path.size());
      const double sub_window = window_s(shots) / k_count;
      const double remaining = mean_remaining(sub_window, tau_s);
      parts.assign(item.path.size(), {});
      double settled_sum = 0, offset_sum = 0, strength_sum = 0;
      for (int k = 0; k < k_count; ++k) {
        const Target& target = item.path[static_cast<std::size_t>(k)];
        const auto [sub_shots, stream] = path_element(i, k, k_count, shots);
        auto& m = parts[static_cast<std::size_t>(k)];
        if (!memory_on) {
          m = device_->measure(target, item.conditions, seed, stream, sub_shots);
          continue;
        }
        // The baseline this target's echo train would settle at, and how far
        // the capacitor still is from it (a fresh segment: settled).
        const double settled_v = device_->coupling_baseline_v(target, item.conditions);
        if (std::isnan(baseline_v)) baseline_v = settled_v;
        const double offset_v = baseline_v - settled_v;
        Conditions conditions = item.conditions;
        conditions.baseline_offset_v = offset_v;  // the core relaxes it shot by shot
        m = device_->measure(target, conditions, seed, stream, sub_shots);
        settled_sum += settled_v;
        offset_sum += offset_v * remaining;
        if (!trace.empty()) strength_sum += echo_strength(target, item.conditions);
        // The capacitor relaxes towards this target's baseline over the sub-window.
        baseline_v = settled_v + offset_v * std::exp(-sub_window / tau_s);
      }
      out[i] = k_count == 1 ? parts.front() : combine(parts);
      // Between windows the beam stays on the last target until the next output.
      if (memory_on && i + 1 < end) {
        const double idle = items[i + 1].time_s - item.time_s - window_s(shots);
        if (idle > 0) {
          const double settled_v = device_->coupling_baseline_v(item.path.back(), item.conditions);
          baseline_v = settled_v + (baseline_v - settled_v) * std::exp(-idle / tau_s);
        }
      }
      if (!trace.empty()) {
        auto& t = trace[i];
        t.strength_neper = strength_sum / k_count;
        t.settled_baseline_v = settled_sum / k_count;
        t.baseline_offset_v = offset_sum / k_count;
      }
    }
  };
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, starts.size(), 1),
                    [&](const tbb::blocked_range<std::size_t>& range) {
                      for (std::size_t s = range.begin(); s != range.end(); ++s) {
                        const std::size_t end =
                            s + 1 < starts.size() ? starts[s + 1] : items.size();
                        if (loop)
                          loop_segment(starts[s], end);
                        else
                          run_segment(starts[s], end);
                      }
                    });
}

}  // namespace tofkit::device
