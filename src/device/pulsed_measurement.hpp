#pragma once
/// \file Internal to device/: the state one measurement of the pulsed core
/// (virtual_rangefinder.cpp) carries from its setup to its shots, each
/// stage's share of it: the echo (receiver_echo.hpp: the tabulated fast echo
/// or the sampled composite and its crossing tables), the front end's noise
/// and baseline (front_end.hpp), the discriminator's false alarms
/// (discriminator.hpp), the timing (operating_point.hpp, slow_offsets.hpp,
/// emitter.hpp); and the working storage of the single-shot lanes.

#include <array>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <type_traits>
#include <vector>

#include "tofkit/device/discriminator.hpp"
#include "tofkit/device/optics.hpp"
#include "tofkit/device/receiver_echo.hpp"
#include "tofkit/device/slow_offsets.hpp"

namespace tofkit::device::detail {

/// One delayed, scaled copy of the pulse template in the receiver.
struct EchoComponent {
  double amplitude_v;
  double delay_ns;
};

/// Everything that is the same for all shots of one measurement: its numbers
/// (MeasurementValues), and on the exact path its sampled echo and tables.
struct MeasurementValues {
  double grid_begin_ns = 0;
  double peak_v = 0;
  double peak_time_ns = 0;
  // Threshold-crossing tables over levels threshold +- 6 sigma (level-shift noise model).
  double level_begin_v = 0, inv_level_step = 0;
  double level_end_v = 0;
  double level_top_v = 0;  // largest level that is crossed at all
  // Fast path (one surface, analytic mode): the echo is A g_h(t - delay_ns)
  // with g_h the device's tabulated normalized echo at spread h.
  bool fast = false;
  double delay_ns = 0;
  double amplitude_v = 0, spread_ns = 0;  // the surface's echo (sampled noise reads it)
  SpreadEchoTable::At spread{};
  double inv_row_peak_v[2] = {0, 0};  // 1 / (amplitude x peak) of the two rows
  double noise_at_threshold_v = 0;
  double noise_floor_var_v2 = 0;  // noise variance without signal
  double shot_var_per_v = 0;      // signal shot noise variance per volt of signal
  double edge_correlation = 0;    // correlation of the noise at the two crossings
  double edge_independence = 1;   // sqrt(1 - correlation^2): the fall's noise's own share
  double recovery_ns = 0;         // extra clip time of an overdriven amplifier
  bool saturated = false;
  // AC-coupled receiver (memory.time_constant_ms > 0): the comparator's
  // effective level is the threshold plus the coupling's baseline, settled on
  // this echo train (baseline_v) plus an unrecovered offset that relaxes over
  // the shots (comparator_level).
  double baseline_v = 0, baseline_offset_v = 0;
  // The comparator level's slow wander at this measurement's time (V;
  // discriminator.level_wander_mv): the reference's and the amplifier's
  // offset drift, the same for all its shots.
  double level_offset_v = 0;
  double fixed_delay_ns = 0;  // trigger + receive chain, incl. thermal drift
  double tdc_bin_scale = 1;   // fine-bin width relative to nominal (timing board temperature)
  double temperature_reading_c = 0;
  double amplitude_noise_rel = 0;
  double turn_on_start_ms = 0;
  // Noise alone crossing the threshold before the echo (false alarms): Rice's
  // rate at the threshold, the arming (the stops count from there: the
  // blanking's end, or the TDC's start, armed_time_ns) and the window.
  FalseAlarms alarms;
  // The noise is sampled on the waveform (waveform mode, or an analytic
  // measurement whose edges are too slow for a frozen-noise crossing).
  bool sampled = false;
  double record_begin_ns = 0;  // waveform mode samples from here on
  double blanking_ns = 0;      // comparator ignores crossings (and alarms) before this
  double record_end_ns = 0;    // waveform mode samples up to here
};

struct MeasurementSetup : MeasurementValues {
  // Noise-free linear echo on a fine grid (the sum of all components).
  std::vector<double> composite;
  std::vector<double> noise_sigma;  // sampled noise: 1 sigma along the composite (over the record)
  std::vector<double> rise_ns, fall_ns;  // kLevels each, filled on the exact path only
  /// Back to a fresh setup, keeping the vectors' storage.
  void reset() {
    // Copied 32 bytes at a time: a whole-struct copy becomes `rep stos`, whose
    // start-up cost dominated the fast path's setup (a lane's reset took ~12 ns).
    static constexpr MeasurementValues kFresh{};
    static_assert(std::is_trivially_copyable_v<MeasurementValues>);
    constexpr std::size_t kChunk = 32, kSize = sizeof(MeasurementValues);
    auto* to = reinterpret_cast<unsigned char*>(static_cast<MeasurementValues*>(this));
    const auto* from = reinterpret_cast<const unsigned char*>(&kFresh);
    for (std::size_t i = 0; i + kChunk <= kSize; i += kChunk) {
      unsigned char chunk[kChunk];
      std::memcpy(chunk, from + i, kChunk);
      std::memcpy(to + i, chunk, kChunk);
    }
    std::memcpy(to + kSize / kChunk * kChunk, from + kSize / kChunk * kChunk, kSize % kChunk);
    composite.clear();
    noise_sigma.clear();
    rise_ns.clear();
    fall_ns.clear();
  }
};

/// Working storage of measure_single_shots: kLanes measurements at a time.
constexpr std::size_t kLanes = 64;
static_assert(kLanes <= SlowOffsets::kMaxOutputs);
struct Lanes {
  std::array<MeasurementSetup, kLanes> setups;
  std::array<SurfaceEcho, kLanes> echoes;
  std::array<std::size_t, kLanes> fast;  // the lanes on the fast path
  std::array<std::array<std::uint32_t, kLanes>, 4> shot_words, extra_words;  // draws, word-major
  std::array<std::array<double, 2>, kLanes> z, z_extra;
  std::array<double, kLanes> lag, offsets, level_offsets, level_rise, level_fall, rise, fall;
  std::array<bool, kLanes> echo;
};

}  // namespace tofkit::device::detail
