#include "tofkit/device/virtual_rangefinder.hpp"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <bit>
#include <cmath>
#include <cstring>
#include <limits>
#include <map>
#include <memory>
#include <mutex>
#include <stdexcept>
#include <string>
#include <type_traits>
#include <vector>

#include "pulsed_measurement.hpp"
#include "random_draws.hpp"
#include "tofkit/device/config_limits.hpp"
#include "tofkit/device/discriminator.hpp"
#include "tofkit/device/emitter.hpp"
#include "tofkit/device/front_end.hpp"
#include "tofkit/device/operating_point.hpp"
#include "tofkit/device/optics.hpp"
#include "tofkit/device/oscillator_loop.hpp"
#include "tofkit/device/receiver_echo.hpp"
#include "tofkit/device/slow_offsets.hpp"
#include "tofkit/device/tdc.hpp"
#include "tofkit/device/thermal.hpp"
#include "tofkit/physics/air.hpp"
#include "tofkit/physics/constants.hpp"
#include "tofkit/physics/pulse_template.hpp"

namespace tofkit::device {
namespace {

using detail::CounterRng;
using detail::footprint_nodes;
using detail::normal_pair;
using detail::sincos_of_phase;
using detail::unit_open;
using physics::kPi;
constexpr std::size_t kLevels = 129;       // entries of the level -> crossing-time tables
constexpr double kLevelSpanSigma = 6.0;    // the tables cover threshold +- 6 sigma
constexpr double kCompositeStepNs = 0.01;  // grid of the noise-free composite echo
constexpr std::uint32_t kMeasurementCounter = 0xFFFFFFFFu;  // per-measurement draws
constexpr double kSyncStartPhase = 0.37;  // laser_sync: the start's fixed place in a coarse period
// Analytic crossings need the noise frozen over each edge: at most this many
// extra (chatter) crossings per edge on average, else the noise is sampled.
constexpr double kChatterTolerance = 1e-4;

/// Monotone table lookup: values y at equally spaced x from x0 with step dx.
inline double table_at(const std::vector<double>& y, double x0, double inv_dx, double x) {
  double f = (x - x0) * inv_dx;
  f = std::clamp(f, 0.0, static_cast<double>(kLevels - 1) - 1e-9);
  const auto i = static_cast<std::size_t>(f);
  const double w = f - static_cast<double>(i);
  return y[i] + w * (y[i + 1] - y[i]);
}

using detail::EchoComponent;
using detail::kLanes;
using detail::Lanes;
using detail::MeasurementSetup;
using detail::MeasurementValues;

std::atomic<std::uint64_t> next_device_id{1};

}  // namespace

struct VirtualRangefinder::Impl {
  DeviceConfig config;
  SimulationMode mode;
  physics::PulseTemplate pulse;
  Tdc tdc;
  double volts_per_watt_unity_gain;  // responsivity x transimpedance x bandwidth peak loss
  double c_nominal_m_per_ns;         // the device's assumed speed of light in air
  double pulse_period_ns;            // 1 / f_rep
  double waveform_dt_ns;             // waveform mode's sampling step (waveform_step_ns)
  std::uint64_t id;                  // tags the per-thread caches of this device
  std::shared_ptr<const SpreadEchoTable> shapes;  // analytic mode: one surface's echoes
  bool background_free = false;  // no sun, no sky: no background light on any surface
  bool coupled = false;          // AC coupling before the comparator (memory.time_constant_ms)
  double shots_per_time_constant = 0;  // pulses per coupling time constant
  double pulse_area_ns = 0;            // integral of the pulse template (V ns per V of amplitude)
  ClippedChargeShare clipped_share;    // coupled: the share of an echo's charge past the clip
  double level_wander_span_v = 0;      // the level tables' extra span for the level's wander
  SlowOffsets slow;                    // timing: power-on offset, flicker, delay and level wander

  Impl(DeviceConfig cfg, SimulationMode m)
      : config(std::move(cfg)),
        mode(m),
        pulse(config.link.laser.pulse_width_ns, config.link.receiver.bandwidth_mhz, 5.0,
              config.link.laser.lasing_onset_ns),
        tdc(config.tdc),
        id(next_device_id.fetch_add(1)),
        slow(config, id) {
    const auto& rx = config.link.receiver;
    volts_per_watt_unity_gain =
        rx.responsivity_a_per_w * rx.transimpedance_kohm * 1e3 * pulse.peak_gain();
    c_nominal_m_per_ns = nominal_light_speed_m_per_ns(config);
    pulse_period_ns = 1e9 / config.link.laser.repetition_hz;
    waveform_dt_ns = waveform_step_ns(config);
    // The table serves the pulsed core only: an oscillator-loop device never asks.
    if (mode == SimulationMode::kAnalytic && !config.oscillator.enabled)
      shapes = spread_table(pulse, config.link.laser.pulse_width_ns, rx.bandwidth_mhz,
                            config.link.laser.lasing_onset_ns);
    // None on a white surface facing the receiver: none on any (Eq. 9's terms are >= 0).
    background_free = physics::background_power_w(config.link, 1.0, 0.0) == 0.0;
    coupled = config.memory.time_constant_ms > 0.0 && config.memory.coupling_share > 0.0;
    shots_per_time_constant =
        config.memory.time_constant_ms * 1e-3 * config.link.laser.repetition_hz;
    for (double t = pulse.begin_ns(); t < pulse.end_ns(); t += kCompositeStepNs)
      pulse_area_ns += pulse(t) * kCompositeStepNs;
    if (coupled) clipped_share = ClippedChargeShare(pulse);
    // 5 sigma of the level's wander (a sum of 12 bounded-variance normals).
    level_wander_span_v = 5.0 * config.discriminator.level_wander_mv * 1e-3;
  }

  /// The comparator's effective level for shot `shot` of a measurement: the
  /// threshold plus the AC coupling's baseline (the comparator sees the echo
  /// minus the capacitor's voltage), whose unrecovered offset relaxes as
  /// exp(-shot / (f_rep tau)) over the measurement's shots.
  [[nodiscard]] double comparator_level(const MeasurementSetup& m, std::uint32_t shot) const {
    const double threshold = config.discriminator.threshold_v + m.level_offset_v;
    if (!coupled) return threshold;
    return threshold + m.baseline_v +
           coupling_offset_v(m.baseline_offset_v, shot, shots_per_time_constant);
  }

  /// The coupling's settled baseline on this echo train: its capacitor charges
  /// to the train's mean, the charge of one echo as the amplifier passes it
  /// (linear up to saturation_v, then clipped and stretched by the recovery)
  /// times the repetition rate, times the coupling's share. The comparator's
  /// level tables are widened to the levels the baseline can put it at.
  void set_baseline(MeasurementSetup& m, double amplitude_sum_v) const {
    if (!coupled) return;
    const auto& rx = config.link.receiver;
    // The echo's clipped share as the template's at the echo's overdrive (a
    // mixed echo, wider than the template, is clipped as one of its peak).
    m.baseline_v = device::coupling_baseline_v(
        amplitude_sum_v, pulse_area_ns, clipped_share(m.peak_v / rx.saturation_v), rx.saturation_v,
        m.recovery_ns, config.memory.coupling_share, config.link.laser.repetition_hz);
    const double threshold = config.discriminator.threshold_v;
    const double sigma = m.noise_at_threshold_v;
    const double lo = m.baseline_v + std::min(m.baseline_offset_v, 0.0);
    const double hi = m.baseline_v + std::max(m.baseline_offset_v, 0.0);
    m.level_begin_v =
        std::max(threshold + lo - kLevelSpanSigma * sigma - level_wander_span_v, 0.05 * threshold);
    m.level_end_v = threshold + hi + kLevelSpanSigma * sigma + level_wander_span_v;
  }

  /// The conditions' share of a measurement's setup, cached per thread (a scan
  /// or a batch has few distinct conditions).
  [[nodiscard]] const OperatingPoint& operating_point_at(const Conditions& cond) const {
    struct Cache {
      std::uint64_t device = 0;
      double ambient_c = 0, minutes = 0;
      OperatingPoint state;
    };
    thread_local Cache cache;
    // Warmed up (every exp(-t / tau) of the thermal model underflows to 0):
    // all such times give the same state, bit for bit.
    const auto& thermal = config.thermal;
    const double settled_min =
        800.0 * std::max(thermal.warmup_time_constant_min, thermal.sensor_lag_min);
    const double minutes = cond.minutes_since_power_on > settled_min
                               ? std::numeric_limits<double>::infinity()
                               : cond.minutes_since_power_on;
    if (cache.device == id && cache.ambient_c == cond.ambient_c && cache.minutes == minutes)
      return cache.state;
    cache.state = operating_point(config, cond.ambient_c, cond.minutes_since_power_on,
                                  volts_per_watt_unity_gain, c_nominal_m_per_ns);
    cache.device = id;
    cache.ambient_c = cond.ambient_c;
    cache.minutes = minutes;
    return cache.state;
  }

  /// All echo components: one per surface, or one per footprint node if spread.
  void components(const Target& target, const OperatingPoint& c,
                  std::vector<EchoComponent>& out) const {
    const auto& nodes = footprint_nodes();
    out.clear();
    for (const auto& s : target.surfaces) {
      SurfaceEcho e;
      if (!surface_echo(config.link, s, c.volts_per_watt, c.c_m_per_ns, pulse_period_ns, e))
        continue;
      if (e.spread_ns == 0.0) {
        out.push_back({e.amplitude_v, e.delay_ns});
        continue;
      }
      for (std::size_t k = 0; k < nodes.u.size(); ++k)
        out.push_back({e.amplitude_v * nodes.w[k], e.delay_ns + nodes.u[k] * e.spread_ns});
    }
  }

  /// Crossing times of a comparator level (clamped to the tabulated span
  /// threshold +- 6 sigma), from emission.
  [[nodiscard]] double rise_at(const MeasurementSetup& m, double level) const {
    if (!m.fast) return table_at(m.rise_ns, m.level_begin_v, m.inv_level_step, level);
    const double l = std::clamp(level, m.level_begin_v, m.level_end_v);
    return m.delay_ns + shapes->rise_ns(m.spread, l * m.inv_row_peak_v[0], l * m.inv_row_peak_v[1]);
  }
  [[nodiscard]] double fall_at(const MeasurementSetup& m, double level) const {
    if (!m.fast) return table_at(m.fall_ns, m.level_begin_v, m.inv_level_step, level);
    const double l = std::clamp(level, m.level_begin_v, m.level_end_v);
    return m.delay_ns + shapes->fall_ns(m.spread, l * m.inv_row_peak_v[0], l * m.inv_row_peak_v[1]);
  }

  /// How a measurement's setup goes on after its common part.
  enum class Echo {
    kNone,   ///< nothing returns (the setup is complete)
    kFast,   ///< one surface, single peak: the device's tabulated echo (fast_echo)
    kExact,  ///< several surfaces, crosstalk or blanking: the composite echo (exact_echo)
  };

  [[nodiscard]] MeasurementSetup setup(const Target& target, const Conditions& cond) const {
    MeasurementSetup m;
    SurfaceEcho e;
    switch (setup_common(target, cond, m, e)) {
      case Echo::kNone:
        break;
      case Echo::kFast:
        fast_echo(m, e);
        fast_edges(m, fast_lag_ns(m));
        if (!noise_frozen_at_edges(m)) sample_fast_echo(m);
        break;
      case Echo::kExact:
        exact_echo(target, cond, m);
        break;
    }
    return m;
  }

  /// The part of the setup every echo needs: noise, delays, comparator
  /// levels; and which echo the target gives (`e`: the fast path's one surface).
  [[nodiscard]] Echo setup_common(const Target& target, const Conditions& cond, MeasurementSetup& m,
                                  SurfaceEcho& e) const {
    const auto& rx = config.link.receiver;
    const OperatingPoint& c = operating_point_at(cond);
    const double background_w =
        background_free ? 0.0 : device::background_power_w(config.link, target);
    const double threshold = config.discriminator.threshold_v;
    m.noise_floor_var_v2 = c.noise.variance_v2(0.0, background_w);
    m.shot_var_per_v = c.noise.shot_var_per_v;
    {
      // Noise at the threshold and Rice's rate, cached per thread on the noise
      // (the same for every target without background light).
      struct NoiseCache {
        std::uint64_t device = 0;
        double floor_var = -1, shot_var = -1, at_threshold = 0, u = 0, rate = 0;
      };
      thread_local NoiseCache cache;
      if (cache.device != id || cache.floor_var != m.noise_floor_var_v2 ||
          cache.shot_var != m.shot_var_per_v) {
        cache.at_threshold = std::sqrt(m.noise_floor_var_v2 + m.shot_var_per_v * threshold);
        // Rice's formula for the upcrossing rate of the receiver's noise.
        cache.u = threshold / std::sqrt(m.noise_floor_var_v2);
        const double tau_p = pulse.pole_time_constant_ns();
        cache.rate = rice_upcrossing_rate_per_ns(cache.u, tau_p);
        cache.device = id;
        cache.floor_var = m.noise_floor_var_v2;
        cache.shot_var = m.shot_var_per_v;
      }
      m.noise_at_threshold_v = cache.at_threshold;
      m.alarms.rate_per_ns = cache.rate;
      m.alarms.threshold_over_noise = cache.u;  // the excursion width is worked out when one occurs
    }
    m.fixed_delay_ns = c.fixed_delay_ns;
    m.tdc_bin_scale = c.tdc_bin_scale;
    m.temperature_reading_c = c.temperature_reading_c;
    m.amplitude_noise_rel = rx.amplitude_noise_rel;
    m.turn_on_start_ms = cond.ms_since_laser_on;
    m.baseline_offset_v = coupled ? cond.baseline_offset_v : 0.0;
    // Comparator levels: the threshold shifted by up to +- 6 sigma of noise.
    const double sigma = m.noise_at_threshold_v;
    m.level_begin_v =
        std::max(threshold - kLevelSpanSigma * sigma - level_wander_span_v, 0.05 * threshold);
    m.level_end_v = threshold + kLevelSpanSigma * sigma + level_wander_span_v;
    m.blanking_ns = config.discriminator.blanking_ns;
    m.alarms.armed_ns = m.blanking_ns > 0.0 ? m.blanking_ns : armed_time_ns();
    if (!shapes) return Echo::kExact;
    // Fast path: one surface whose echo has a single peak, analytic mode.
    int surfaces = 0;
    for (const auto& s : target.surfaces) {
      SurfaceEcho one;
      if (surface_echo(config.link, s, c.volts_per_watt, c.c_m_per_ns, pulse_period_ns, one)) {
        e = one;
        if (++surfaces > 1) return Echo::kExact;  // a mixed pixel
      }
    }
    const double crosstalk_v = crosstalk_at(c);
    if (surfaces == 0 && crosstalk_v <= 0.0) {
      m.alarms.set_window(next_start_ns());  // armed until the next pulse's start
      return Echo::kNone;
    }
    // (No crosstalk, and the echo starts after any blanking.)
    const bool after_blanking =
        m.blanking_ns <= 0.0 || m.blanking_ns <= e.delay_ns + pulse.begin_ns() - e.spread_ns;
    return surfaces == 1 && e.spread_ns <= shapes->max_spread_ns() && crosstalk_v <= 0.0 &&
                   after_blanking
               ? Echo::kFast
               : Echo::kExact;
  }

  /// Optical crosstalk from the emitter into the receiver: a copy of the pulse
  /// at zero range (the same receive chain as the echoes); optical, so it
  /// follows the laser power and the APD gain.
  [[nodiscard]] double crosstalk_at(const OperatingPoint& c) const {
    const auto& rx = config.link.receiver;
    return rx.crosstalk_v * c.gain / rx.apd_gain * c.power_scale;
  }

  /// Fast path: the echo A g_h(t - delay) of one surface, read off the table.
  void fast_echo(MeasurementSetup& m, const SurfaceEcho& e) const {
    const auto& rx = config.link.receiver;
    m.fast = true;
    m.delay_ns = e.delay_ns;
    m.amplitude_v = e.amplitude_v;
    m.spread_ns = e.spread_ns;
    m.spread = shapes->at(e.spread_ns);
    m.inv_row_peak_v[0] = 1.0 / (e.amplitude_v * shapes->row_peak(m.spread.row));
    m.inv_row_peak_v[1] =
        m.spread.w > 0 ? 1.0 / (e.amplitude_v * shapes->row_peak(m.spread.row + 1)) : 0.0;
    m.peak_v = e.amplitude_v * shapes->peak(m.spread);
    m.peak_time_ns = e.delay_ns + shapes->peak_time_ns(m.spread);
    m.level_top_v = m.peak_v;
    m.saturated = m.peak_v > rx.saturation_v;
    m.recovery_ns = clip_recovery_ns(m.peak_v, rx.saturation_v, rx.recovery_ns_per_neper);
    set_baseline(m, e.amplitude_v);
  }

  /// Fast path: time over the threshold of the noise-free echo (0 if it stays below).
  [[nodiscard]] double fast_lag_ns(const MeasurementSetup& m) const {
    const double threshold = config.discriminator.threshold_v;
    if (m.peak_v < threshold) return 0.0;
    double rise = 0, fall = 0;
    crossings_at(m, threshold, rise, fall);
    return fall - rise;
  }

  /// rise_at and fall_at of one level together (on the fast path the level is
  /// placed in the spread table's rows once for both).
  void crossings_at(const MeasurementSetup& m, double level, double& rise, double& fall) const {
    if (!m.fast) {
      rise = table_at(m.rise_ns, m.level_begin_v, m.inv_level_step, level);
      fall = table_at(m.fall_ns, m.level_begin_v, m.inv_level_step, level);
      return;
    }
    const double l = std::clamp(level, m.level_begin_v, m.level_end_v);
    shapes->rise_fall_ns(m.spread, l * m.inv_row_peak_v[0], l * m.inv_row_peak_v[1], rise, fall);
    rise += m.delay_ns;
    fall += m.delay_ns;
  }

  /// Fast path: the noise's correlation at the two crossings and the false alarms.
  void fast_edges(MeasurementSetup& m, double lag_ns) const {
    const double threshold = config.discriminator.threshold_v;
    // No crossing at the threshold: the tables' flat top.
    set_edge_correlation(m, m.peak_v >= threshold ? pulse.noise_correlation(lag_ns) : 1.0);
    // A shot's alarm needs its 24-bit uniform below the probability, so one
    // below 2^-26 never fires: the window need not be worked out.
    const double longest_window_ns =
        pulse_period_ns + pulse.end_ns() + shapes->max_spread_ns() - armed_time_ns();
    if (m.alarms.rate_per_ns * longest_window_ns < 0x1p-26)
      m.alarms.probability = 0.0;
    else
      m.alarms.set_window(m.level_begin_v <= m.peak_v ? rise_at(m, m.level_begin_v)
                                                      : m.peak_time_ns);
  }

  /// The exact path: the composite echo of all surfaces (and the crosstalk)
  /// on a fine grid, and its crossing tables.
  void exact_echo(const Target& target, const Conditions& cond, MeasurementSetup& m) const {
    const auto& rx = config.link.receiver;
    const OperatingPoint& c = operating_point_at(cond);
    const double threshold = config.discriminator.threshold_v;
    const double crosstalk_v = crosstalk_at(c);
    thread_local std::vector<EchoComponent> comps;
    components(target, c, comps);
    if (crosstalk_v > 0.0) comps.push_back({crosstalk_v, 0.0});
    if (comps.empty()) {
      m.alarms.set_window(next_start_ns());  // armed until the next pulse's start
      return;
    }

    // Noise-free composite echo on a fine grid.
    double first = comps.front().delay_ns, last = first;
    for (const auto& comp : comps) {
      first = std::min(first, comp.delay_ns);
      last = std::max(last, comp.delay_ns);
    }
    m.grid_begin_ns = first + pulse.begin_ns();
    const double grid_end = last + pulse.end_ns();
    const auto n = static_cast<std::size_t>((grid_end - m.grid_begin_ns) / kCompositeStepNs) + 2;
    m.composite.assign(n, 0.0);
    for (const auto& comp : comps) {
      // Only over the component's support (zero outside): far-apart components,
      // such as the crosstalk and a far echo, cost their spans, not the gap.
      const double lo = (comp.delay_ns + pulse.begin_ns() - m.grid_begin_ns) / kCompositeStepNs;
      const double hi = (comp.delay_ns + pulse.end_ns() - m.grid_begin_ns) / kCompositeStepNs;
      const auto i_lo = static_cast<std::size_t>(std::max(std::floor(lo), 0.0));
      const auto i_hi = std::min(n, static_cast<std::size_t>(std::max(std::ceil(hi) + 1.0, 0.0)));
      if (i_lo < i_hi)
        pulse.add_to(comp.amplitude_v, comp.delay_ns,
                     m.grid_begin_ns + static_cast<double>(i_lo) * kCompositeStepNs,
                     kCompositeStepNs, m.composite.data() + i_lo, i_hi - i_lo);
    }
    // The comparator (and the peak detector) are blanked before blanking_ns.
    const bool gated = m.blanking_ns > 0.0 && m.blanking_ns > m.grid_begin_ns;
    const std::size_t i_gate =
        gated ? std::min(n, static_cast<std::size_t>(
                                std::ceil((m.blanking_ns - m.grid_begin_ns) / kCompositeStepNs)))
              : 0;
    if (i_gate >= n) {
      m.alarms.set_window(next_start_ns());  // everything blanked
      m.composite.clear();
      return;
    }
    const std::size_t i_peak = first_peak_index(m.composite, i_gate);
    m.peak_v = m.composite[i_peak];
    m.peak_time_ns = m.grid_begin_ns + static_cast<double>(i_peak) * kCompositeStepNs;
    m.saturated = m.peak_v > rx.saturation_v;
    m.recovery_ns = clip_recovery_ns(m.peak_v, rx.saturation_v, rx.recovery_ns_per_neper);
    double amplitude_sum_v = 0;
    for (const auto& comp : comps) amplitude_sum_v += comp.amplitude_v;
    set_baseline(m, amplitude_sum_v);
    const double level_lo = m.level_begin_v, level_hi = m.level_end_v;

    // Crossing tables: for each comparator level L (threshold shifted by the
    // noise), the first upcrossing and the following downcrossing of the echo.
    const double level_step = (level_hi - level_lo) / static_cast<double>(kLevels - 1);
    m.inv_level_step = 1.0 / level_step;
    m.rise_ns.resize(kLevels);
    m.fall_ns.resize(kLevels);
    m.level_top_v = sampled_crossing_times(m.composite, m.grid_begin_ns, kCompositeStepNs,
                                           m.peak_time_ns, level_lo, level_step, gated, i_gate,
                                           m.blanking_ns, m.rise_ns, m.fall_ns);
    // Noise at the two crossings is correlated through the receiver bandwidth.
    const double rise0 = table_at(m.rise_ns, m.level_begin_v, m.inv_level_step, threshold);
    const double fall0 = table_at(m.fall_ns, m.level_begin_v, m.inv_level_step, threshold);
    set_edge_correlation(m, std::isnan(rise0) ? 1.0 : pulse.noise_correlation(fall0 - rise0));
    // Earliest and latest rising crossing over the levels (the first and last
    // level's without blanking, where the crossing time grows with the level).
    double first_rise = m.rise_ns[0], last_rise = m.rise_ns[kLevels - 1];
    if (gated) {
      first_rise = last_rise = m.peak_time_ns;
      bool any = false;
      for (const double r : m.rise_ns) {
        if (std::isnan(r)) continue;
        first_rise = any ? std::min(first_rise, r) : r;
        last_rise = any ? std::max(last_rise, r) : r;
        any = true;
      }
      first_rise = std::max(first_rise, m.blanking_ns);
    }
    set_record(m, first_rise, last_rise, m.fall_ns[0]);
    // Or the whole echo when gated (crosstalk or blanking may end the first
    // excursion before the echo).
    if (gated || crosstalk_v > 0.0)
      m.record_end_ns = std::max(
          m.record_end_ns,
          m.grid_begin_ns + static_cast<double>(n - 1) * kCompositeStepNs + m.recovery_ns + 4.0);
    m.sampled = mode == SimulationMode::kWaveform || !noise_frozen_at_edges(m);
    if (m.sampled) {
      // Over the record only (the sampler reads no further): the echo's
      // tail beyond it can be most of the grid.
      const double lo = std::floor((m.record_begin_ns - m.grid_begin_ns) / kCompositeStepNs) - 1;
      const double hi = std::ceil((m.record_end_ns - m.grid_begin_ns) / kCompositeStepNs) + 2;
      const auto i_lo = static_cast<std::size_t>(std::clamp(lo, 0.0, static_cast<double>(n)));
      const auto i_hi = static_cast<std::size_t>(std::clamp(hi, 0.0, static_cast<double>(n)));
      m.noise_sigma.assign(n, 0.0);
      for (std::size_t i = i_lo; i < i_hi; ++i) m.noise_sigma[i] = noise_sigma_v(m, m.composite[i]);
    }
    m.alarms.set_window(m.sampled ? m.record_begin_ns : first_rise);
  }

  /// The fast path with its noise sampled (its edges are slower than the
  /// noise): the waveform sampler reads the echo off the pulse template
  /// (fast_signal_at), over the record the table's crossings bound, as the exact
  /// path's tables bound it.
  void sample_fast_echo(MeasurementSetup& m) const {
    // (The crossings of levels above the peak read the peak's time.)
    set_record(m, rise_at(m, m.level_begin_v), rise_at(m, m.level_end_v),
               fall_at(m, m.level_begin_v));
    m.sampled = true;
    m.alarms.set_window(m.record_begin_ns);
  }

  /// The waveform record: from before the earliest rise of any comparator
  /// level (and the filter's settling before the latest) to past the lowest
  /// level's fall, the amplifier's recovery included.
  void set_record(MeasurementSetup& m, double first_rise, double last_rise,
                  double lowest_fall) const {
    const double tau = pulse.pole_time_constant_ns();
    m.record_begin_ns = std::min(last_rise - 4.0 - 6.0 * tau, first_rise - 4.0);
    m.record_end_ns = lowest_fall + m.recovery_ns + 4.0;
  }

  /// The fast path's noise-free echo at t (V): A g_h(t - delay) from the
  /// pulse template, g_h the sum over the footprint's nodes.
  [[nodiscard]] double fast_signal_at(const MeasurementSetup& m, double t) const {
    if (m.spread_ns == 0.0) return m.amplitude_v * pulse(t - m.delay_ns);
    const auto& nodes = footprint_nodes();
    double g = 0;
    for (std::size_t k = 0; k < nodes.u.size(); ++k)
      g += nodes.w[k] * pulse(t - m.delay_ns - nodes.u[k] * m.spread_ns);
    return m.amplitude_v * g;
  }

  /// Noise (1 sigma, V) at a signal level: the floor plus the signal's shot
  /// noise (Eq. 8 terms).
  [[nodiscard]] static double noise_sigma_v(const MeasurementSetup& m, double signal_v) {
    return std::sqrt(m.noise_floor_var_v2 + m.shot_var_per_v * std::max(signal_v, 0.0));
  }

  /// Whether the noise stays frozen over the echo's threshold crossings, as
  /// the analytic crossings assume. An edge crossing the threshold at slope a
  /// through band-limited Gaussian noise (sigma, derivative sigma / tau_p) is
  /// crossed 1 + 2c times on average (Rice's formula integrated over the edge),
  /// c = r phi(1/r) - Q(1/r) with r = sigma / (a tau_p): its jitter over the
  /// noise's correlation time. A slow edge (a long pulse, a weak echo near its
  /// peak) makes the comparator chatter: the first crossing comes early and a
  /// fall can follow the rise within a nanosecond, which one frozen noise value
  /// per crossing cannot give. Where c exceeds kChatterTolerance at either
  /// edge, the measurement samples its noise on the waveform instead.
  [[nodiscard]] bool noise_frozen_at_edges(const MeasurementSetup& m) const {
    const double threshold = config.discriminator.threshold_v;
    if (m.peak_v < threshold) return true;  // crossed by noise only when at all (analytic levels)
    const double half = 0.5 * m.noise_at_threshold_v;
    // The edges' times across the noise band threshold +- sigma / 2 (clamped at the peak).
    double rise_lo = 0, fall_lo = 0, rise_hi = 0, fall_hi = 0;
    crossings_at(m, threshold - half, rise_lo, fall_lo);
    crossings_at(m, threshold + half, rise_hi, fall_hi);
    if (threshold + half >= m.level_top_v) fall_hi = m.peak_time_ns;
    const double rise = rise_hi - rise_lo, fall = fall_lo - fall_hi;
    static const double r_limit = chatter_ratio_limit(kChatterTolerance);
    // (NaN: a blanked edge, crossed by noise or not at all as the analytic levels give it.)
    return !(rise > r_limit * pulse.pole_time_constant_ns()) &&
           !(fall > r_limit * pulse.pole_time_constant_ns());
  }

  /// The noise's correlation at the two crossings, and the fall's own share
  /// sqrt(1 - rho^2) that every shot's comparator levels use.
  static void set_edge_correlation(MeasurementSetup& m, double correlation) {
    m.edge_correlation = correlation;
    m.edge_independence = std::sqrt(1.0 - correlation * correlation);
  }

  /// When the comparator's stops start to count without blanking (echo time):
  /// when the TDC starts. The paper's FPGA both fires the laser driver and
  /// counts the time of flight (its Fig. 2 architecture; S = c n tau / 2 in its
  /// clock's periods), so the count starts with the trigger, before any light
  /// leaves; how long before is folded into measurement.fixed_delay_ns with the
  /// receive chain's delay, so the start is taken at the light's onset, the
  /// pulse template's begin (lasing_onset_ns, or 6 sigma before a Gaussian's
  /// peak). No echo crosses earlier, a strong echo of a long pulse may cross
  /// before the pulse's centre (t = 0), and noise crossings count from here in
  /// both modes: as Rice's false alarms before an analytic echo or a sampled
  /// record, and on the sampled record itself.
  [[nodiscard]] double armed_time_ns() const { return pulse.begin_ns(); }
  /// The next pulse's start: the TDC restarts there.
  [[nodiscard]] double next_start_ns() const { return pulse_period_ns + armed_time_ns(); }

  /// The comparator's effective levels at the rising and the falling crossing
  /// for the noise z_rise there and z_fall_ind independent of it (the noise at
  /// the fall is correlated with the rise's through the receiver bandwidth).
  /// Analytic mode: the noise, band-limited like the echo, shifts the effective
  /// threshold (crossing_level_v); the crossing is read off the noise-free echo
  /// (first order: jitter = sigma / slope).
  void analytic_levels(const MeasurementSetup& m, double threshold, double z_rise,
                       double z_fall_ind, double& level_rise, double& level_fall) const {
    level_rise = crossing_level_v(m.noise_floor_var_v2, m.shot_var_per_v, threshold, z_rise);
    const double z_fall = m.edge_correlation * z_rise + m.edge_independence * z_fall_ind;
    level_fall = crossing_level_v(m.noise_floor_var_v2, m.shot_var_per_v, threshold, z_fall);
  }

  /// The echo's crossings of those levels; false when the rising level is not crossed.
  [[nodiscard]] bool analytic_crossings(const MeasurementSetup& m, double level_rise,
                                        double level_fall, double& rise, double& fall) const {
    if ((!m.fast && m.composite.empty()) || level_rise > m.peak_v || level_rise > m.level_top_v)
      return false;
    rise = rise_at(m, level_rise);
    if (std::isnan(rise)) return false;  // blanked: no crossing after the comparator is released
    fall = level_fall >= m.level_top_v ? m.peak_time_ns : fall_at(m, level_fall);
    fall = std::max(fall, rise) + m.recovery_ns;
    return true;
  }

  /// Waveform mode: band-limited noise added to the sampled echo, the amplifier
  /// clips and recovers, the comparator's crossings are found on the samples
  /// (sampled_crossings). The white noise is the shot's draws from block 1 on.
  [[nodiscard]] bool crossings_waveform(const MeasurementSetup& m, const CounterRng& rng,
                                        std::uint64_t stream, std::uint32_t shot, double phase_u,
                                        double& rise, double& fall) const {
    if (!m.fast && m.composite.empty()) return false;
    const auto& rx = config.link.receiver;
    SampledComparator comparator;
    comparator.threshold_v = config.discriminator.threshold_v;
    // The AC coupling's baseline at this shot: the comparator sees the
    // amplifier's output (which clips) minus it.
    comparator.baseline_v = comparator_level(m, shot) - comparator.threshold_v;
    comparator.step_ns = waveform_dt_ns;
    comparator.pole_time_constant_ns = pulse.pole_time_constant_ns();
    comparator.record_begin_ns = m.record_begin_ns;
    comparator.record_end_ns = m.record_end_ns;
    comparator.armed_ns = m.alarms.armed_ns;
    comparator.saturation_v = rx.saturation_v;
    comparator.recovery_ns_per_neper = rx.recovery_ns_per_neper;
    const double inv_grid = 1.0 / kCompositeStepNs;
    const auto grid_last = static_cast<double>(m.composite.size() - 1);
    // Standard normal white samples, four per counter block (two Box-Muller pairs).
    std::array<double, 4> normals{};
    std::uint32_t block_index = 0;
    auto white = [&](std::size_t k) {
      if ((k & 3u) == 0) {
        const auto block = rng.draw(stream, shot, 1u + block_index++);
        const auto lo = normal_pair(block[0], block[1]), hi = normal_pair(block[2], block[3]);
        normals = {lo[0], lo[1], hi[0], hi[1]};
      }
      return normals[k & 3u];
    };
    auto input_at = [&](double t, double unit_noise) {
      if (m.fast) {
        const double s = fast_signal_at(m, t);
        return s + noise_sigma_v(m, s) * unit_noise;
      }
      const double g = std::clamp((t - m.grid_begin_ns) * inv_grid, 0.0, grid_last - 1e-9);
      const auto gi = static_cast<std::size_t>(g);
      const double w = g - static_cast<double>(gi);
      const double s = m.composite[gi] + w * (m.composite[gi + 1] - m.composite[gi]);
      const double sigma = m.noise_sigma[gi] + w * (m.noise_sigma[gi + 1] - m.noise_sigma[gi]);
      return s + sigma * unit_noise;
    };
    return comparator.crossings(phase_u, white, input_at, rise, fall);
  }

  /// Delay offset (ns) common to every shot of one measurement: the run's
  /// power-on offset plus the slow 1/f flicker and the random wander at the
  /// measurement's time (stream i starts i measurement periods after power-on);
  /// the comparator level's wander into m.
  [[nodiscard]] double slow_offset_ns(std::uint64_t seed, std::uint64_t stream,
                                      const Conditions& cond, MeasurementSetup& m) const {
    double offset = 0;
    slow.offsets_ns(seed, slow.run_draws(seed), stream, 1, &cond, &offset, &m.level_offset_v);
    return offset;
  }

  /// One shot, returning false when no echo crossed the threshold. `r` is the
  /// shot's first draw, rng.draw(stream, index, 0).
  [[nodiscard]] bool shot(const MeasurementSetup& m, const std::array<std::uint32_t, 4>& r,
                          const CounterRng& rng, std::uint64_t stream, std::uint32_t index,
                          double offset_ns, double& start_ns, double& stop_rise_ns,
                          double& stop_fall_ns) const {
    double rise = 0, fall = 0;
    bool echo = false;
    if (m.alarms.first_crossing(unit_open(r[3]), rise, fall)) {
      echo = true;
    } else if (!m.sampled) {
      const auto z = normal_pair(r[0], r[1]);
      double level_rise = 0, level_fall = 0;
      analytic_levels(m, comparator_level(m, index), z[0], z[1], level_rise, level_fall);
      echo = analytic_crossings(m, level_rise, level_fall, rise, fall);
    } else {
      echo = crossings_waveform(m, rng, stream, index, unit_open(r[0]), rise, fall);
    }
    if (!echo) return false;
    stops(m, r, index, offset_ns, rise, fall, start_ns, stop_rise_ns, stop_fall_ns);
    return true;
  }

  /// The TDC's start and stops of a shot whose echo crosses at rise and fall.
  void stops(const MeasurementSetup& m, const std::array<std::uint32_t, 4>& r, std::uint32_t index,
             double offset_ns, double rise, double fall, double& start_ns, double& stop_rise_ns,
             double& stop_fall_ns) const {
    // laser_sync: the laser fires on a clock edge, so the start has a fixed
    // phase and the stop's phase is set by the range: the INL stays, periodic
    // in range. Asynchronous: the start phase is uniform over a coarse period,
    // so quantization and INL average out.
    const double phase =
        (config.tdc.laser_sync ? kSyncStartPhase : unit_open(r[2])) * tdc.period_ns();
    const double delay =
        m.fixed_delay_ns + offset_ns +
        turn_on_bias_ns(config.link.laser, m.turn_on_start_ms, index, c_nominal_m_per_ns);
    start_ns = tdc.quantize_ns(phase, m.tdc_bin_scale);
    stop_rise_ns = tdc.quantize_ns(phase + delay + rise, m.tdc_bin_scale);
    stop_fall_ns = tdc.quantize_ns(phase + delay + fall, m.tdc_bin_scale);
  }

  [[nodiscard]] ranging::RawMeasurement measure(const Target& target, const Conditions& cond,
                                                std::uint64_t seed, std::uint64_t stream,
                                                int shots) const {
    const int n = shots > 0 ? shots : config.measurement.shots;
    if (n == 1) {
      ranging::RawMeasurement out;
      measure_single_shots({&target, 1}, {&cond, 1}, seed, stream, {&out, 1});
      return out;
    }
    const CounterRng rng(seed);
    auto m = setup(target, cond);
    const double offset_ns = slow_offset_ns(seed, stream, cond, m);
    // The firmware keeps each shot's stop, then rejects false stops before
    // averaging: stops farther than measurement.stop_gate_ns from the median
    // stop (range gate around the median). Rejected stops lower shots_valid.
    double sum_tof = 0, sum_width = 0;
    std::uint32_t valid = 0;
    thread_local std::vector<std::array<double, 2>> stops;
    stops.clear();
    for (int i = 0; i < n; ++i) {
      double start = 0, rise = 0, fall = 0;
      const auto index = static_cast<std::uint32_t>(i);
      if (!shot(m, rng.draw(stream, index, 0), rng, stream, index, offset_ns, start, rise, fall))
        continue;
      stops.push_back({rise - start, fall - rise});
    }
    const double gate = config.measurement.stop_gate_ns;
    double median = 0;
    if (gate > 0 && !stops.empty()) {
      thread_local std::vector<double> tofs;
      tofs.clear();
      for (const auto& st : stops) tofs.push_back(st[0]);
      const auto mid = tofs.begin() + static_cast<std::ptrdiff_t>(tofs.size() / 2);
      std::nth_element(tofs.begin(), mid, tofs.end());
      median = *mid;
    }
    for (const auto& st : stops) {
      if (gate > 0 && std::abs(st[0] - median) > gate) continue;
      sum_tof += st[0];
      sum_width += st[1];
      ++valid;
    }
    // The median stop is the echo's only while the echo's stops are the
    // majority: false stops come before the echo (the first crossing stops the
    // TDC), so once they outnumber it the median, and the gate around it, sit
    // on noise and the average reads short by up to the time of flight. The
    // firmware then gives no distance (the gate keeps too few of the stops).
    if (gate > 0 && valid < config.measurement.stop_gate_min_share * double(stops.size())) {
      valid = 0;
      sum_tof = sum_width = 0;
    }
    const auto extra = rng.draw(stream, kMeasurementCounter, 0);
    return finish(m, cond, normal_pair(extra[0], extra[1]), n, sum_tof, sum_width, valid);
  }

  /// Single-shot measurements, target k on stream first_stream + k, worked in
  /// lanes of kLanes measurements: each stage (the setup's parts, the random
  /// draws, the slow offsets, the comparator levels, the crossings, the TDC and
  /// the result) runs over all lanes before the next, so the lanes' independent
  /// chains of arithmetic overlap. Every lane runs the same functions, in the
  /// same order, as a lone measurement: the bytes do not depend on the grouping.
  /// Also compiled for AVX2 (chosen at load where the CPU has it; the Philox
  /// rounds and the slow offsets vectorize): AVX2 brings no FMA, so neither
  /// build contracts a multiply-add and both give the same bytes.
  __attribute__((target_clones("avx2", "default"))) void measure_single_shots(
      std::span<const Target> targets, std::span<const Conditions> conds, std::uint64_t seed,
      std::uint64_t first_stream, std::span<ranging::RawMeasurement> out) const {
    const CounterRng rng(seed);
    const SlowOffsets::RunDraws& run = slow.run_draws(seed);
    thread_local Lanes lanes;
    auto& m = lanes.setups;
    for (std::size_t begin = 0; begin < targets.size(); begin += kLanes) {
      const std::size_t n = std::min(kLanes, targets.size() - begin);
      const std::uint64_t stream0 = first_stream + begin;
      std::size_t n_fast = 0;
      for (std::size_t k = 0; k < n; ++k) {
        m[k].reset();
        switch (setup_common(targets[begin + k], conds[begin + k], m[k], lanes.echoes[k])) {
          case Echo::kNone:
            break;
          case Echo::kFast:
            lanes.fast[n_fast++] = k;
            break;
          case Echo::kExact:
            exact_echo(targets[begin + k], conds[begin + k], m[k]);
            break;
        }
      }
      for (std::size_t j = 0; j < n_fast; ++j)
        fast_echo(m[lanes.fast[j]], lanes.echoes[lanes.fast[j]]);
      for (std::size_t j = 0; j < n_fast; ++j) lanes.lag[j] = fast_lag_ns(m[lanes.fast[j]]);
      for (std::size_t j = 0; j < n_fast; ++j) fast_edges(m[lanes.fast[j]], lanes.lag[j]);
      for (std::size_t j = 0; j < n_fast; ++j) {
        const std::size_t k = lanes.fast[j];
        if (!noise_frozen_at_edges(m[k])) sample_fast_echo(m[k]);
      }
      rng.draw_streams(stream0, 0, 0, n, lanes.shot_words);
      rng.draw_streams(stream0, kMeasurementCounter, 0, n, lanes.extra_words);
      slow.offsets_ns(seed, run, stream0, n, conds.data() + begin, lanes.offsets.data(),
                      lanes.level_offsets.data());
      for (std::size_t k = 0; k < n; ++k) m[k].level_offset_v = lanes.level_offsets[k];
      for (std::size_t k = 0; k < n; ++k) {
        lanes.z[k] = normal_pair(lanes.shot_words[0][k], lanes.shot_words[1][k]);
        lanes.z_extra[k] = normal_pair(lanes.extra_words[0][k], lanes.extra_words[1][k]);
      }
      for (std::size_t k = 0; k < n; ++k) {
        if (!m[k].sampled)
          analytic_levels(m[k], comparator_level(m[k], 0), lanes.z[k][0], lanes.z[k][1],
                          lanes.level_rise[k], lanes.level_fall[k]);
      }
      for (std::size_t k = 0; k < n; ++k) {
        double& rise = lanes.rise[k];
        double& fall = lanes.fall[k];
        const auto& r = lanes.shot_words;
        if (m[k].alarms.first_crossing(unit_open(r[3][k]), rise, fall))
          lanes.echo[k] = true;
        else if (!m[k].sampled)
          lanes.echo[k] =
              analytic_crossings(m[k], lanes.level_rise[k], lanes.level_fall[k], rise, fall);
        else
          lanes.echo[k] =
              crossings_waveform(m[k], rng, stream0 + k, 0, unit_open(r[0][k]), rise, fall);
      }
      for (std::size_t k = 0; k < n; ++k) {
        // One stop is its own median: the gate keeps it.
        double sum_tof = 0, sum_width = 0;
        std::uint32_t valid = 0;
        if (lanes.echo[k]) {
          double start = 0, stop_rise = 0, stop_fall = 0;
          const auto& w = lanes.shot_words;
          stops(m[k], {w[0][k], w[1][k], w[2][k], w[3][k]}, 0, lanes.offsets[k], lanes.rise[k],
                lanes.fall[k], start, stop_rise, stop_fall);
          sum_tof = stop_rise - start;
          sum_width = stop_fall - stop_rise;
          valid = 1;
        }
        out[begin + k] =
            finish(m[k], conds[begin + k], lanes.z_extra[k], 1, sum_tof, sum_width, valid);
      }
    }
  }

  /// The measurement from its shots' sums: averages, temperature reading, flags.
  /// `z` are the measurement's own normals, from rng.draw(stream, kMeasurementCounter, 0).
  [[nodiscard]] ranging::RawMeasurement finish(const MeasurementSetup& m, const Conditions& cond,
                                               const std::array<double, 2>& z, int n,
                                               double sum_tof, double sum_width,
                                               std::uint32_t valid) const {
    const double internal_c = m.temperature_reading_c;
    ranging::RawMeasurement out;
    // Temperature sensor: noise, then its resolution.
    const auto& th = config.thermal;
    out.temperature_c = sensor_reading_c(th, internal_c, z[0]);
    out.shots_valid = valid;
    if (valid == 0) {
      out.flags |= ranging::kRawNoEcho;
    } else {
      out.tof_ns = sum_tof / valid;
      out.pulse_width_ns = sum_width / valid;
      out.distance_raw_m = 0.5 * out.tof_ns * c_nominal_m_per_ns;
      // Peak amplitude from the receiver's peak detector, averaged over the shots;
      // it follows the amplifier, so it reads no more than the clip level.
      const double peak = std::min(m.peak_v, config.link.receiver.amplitude_clip_v);
      out.amplitude =
          std::min(peak * (1.0 + m.amplitude_noise_rel * z[1] / std::sqrt(double(valid))),
                   config.link.receiver.amplitude_clip_v);
      if (valid < static_cast<std::uint32_t>(n)) out.flags |= ranging::kRawPartialEchoes;
      if (m.saturated) out.flags |= ranging::kRawSaturated;
    }
    const auto& laser = config.link.laser;
    if (cond.ms_since_laser_on < 5.0 * laser.turn_on_time_constant_ms)
      out.flags |= ranging::kRawTurnOnTransient;
    if (cond.minutes_since_power_on < 4.0 * th.warmup_time_constant_min)
      out.flags |= ranging::kRawWarmingUp;
    return out;
  }
};

VirtualRangefinder::VirtualRangefinder(DeviceConfig config, SimulationMode mode) {
  const auto errors = validate(config);
  if (!errors.empty()) {
    std::string message = "invalid device configuration:";
    for (const auto& e : errors) message += "\n  " + e;
    throw std::invalid_argument(message);
  }
  if (config.oscillator.enabled && mode == SimulationMode::kWaveform) {
    // The loop's crossings are closed-form step responses: a "waveform" run would
    // repeat the analytic one and check nothing.
    throw std::invalid_argument(
        "oscillator.enabled = true (the self-oscillating loop) has no sampled-waveform "
        "evaluation; use the analytic mode");
  }
  if (config.oscillator.enabled) oscillator_ = std::make_unique<const OscillatorLoop>(config);
  impl_ = std::make_unique<Impl>(std::move(config), mode);
}

VirtualRangefinder::~VirtualRangefinder() = default;
VirtualRangefinder::VirtualRangefinder(VirtualRangefinder&&) noexcept = default;
VirtualRangefinder& VirtualRangefinder::operator=(VirtualRangefinder&&) noexcept = default;

const DeviceConfig& VirtualRangefinder::config() const {
  return impl_->config;
}
SimulationMode VirtualRangefinder::mode() const {
  return impl_->mode;
}

EchoShape VirtualRangefinder::echo(const Target& target, const Conditions& conditions) const {
  if (oscillator_) return oscillator_->echo(target, conditions);
  const auto m = impl_->setup(target, conditions);
  EchoShape e;
  e.peak_v = m.peak_v;
  e.saturated = m.saturated;
  e.noise_at_rise_v = m.noise_at_threshold_v;
  const double threshold = impl_->config.discriminator.threshold_v;
  e.detected = (m.fast || !m.composite.empty()) && m.peak_v >= threshold &&
               !std::isnan(impl_->rise_at(m, threshold));
  if (!e.detected) return e;
  e.rise_crossing_ns = impl_->rise_at(m, threshold);
  e.fall_crossing_ns = impl_->fall_at(m, threshold) + m.recovery_ns;
  // Slope from two nearby levels of the crossing table.
  const double dl = 0.01 * m.noise_at_threshold_v;
  const double dt = impl_->rise_at(m, threshold + dl) - impl_->rise_at(m, threshold - dl);
  e.rise_slope_v_per_ns = dt > 0 ? 2.0 * dl / dt : 0.0;
  return e;
}

Shot VirtualRangefinder::shoot(const Target& target, const Conditions& conditions,
                               std::uint64_t seed, std::uint64_t stream, std::uint32_t shot) const {
  if (oscillator_) return oscillator_->shoot(target, conditions, seed, stream, shot);
  const CounterRng rng(seed);
  auto m = impl_->setup(target, conditions);
  const double offset_ns = impl_->slow_offset_ns(seed, stream, conditions, m);
  Shot s;
  double start = 0, rise = 0, fall = 0;
  s.echo =
      impl_->shot(m, rng.draw(stream, shot, 0), rng, stream, shot, offset_ns, start, rise, fall);
  if (s.echo) {
    s.tof_ns = rise - start;
    s.pulse_width_ns = fall - rise;
  }
  return s;
}

ranging::RawMeasurement VirtualRangefinder::measure(const Target& target,
                                                    const Conditions& conditions,
                                                    std::uint64_t seed, std::uint64_t stream,
                                                    int shots) const {
  if (oscillator_) return oscillator_->measure(target, conditions, seed, stream, shots);
  return impl_->measure(target, conditions, seed, stream, shots);
}

void VirtualRangefinder::measure(std::span<const Target> targets,
                                 std::span<const Conditions> conditions, std::uint64_t seed,
                                 std::uint64_t first_stream, int shots,
                                 std::span<ranging::RawMeasurement> out) const {
  if (conditions.size() != targets.size() || out.size() != targets.size())
    throw std::invalid_argument("measure: targets, conditions and output differ in size");
  const int n = shots > 0 ? shots : impl_->config.measurement.shots;
  if (n == 1 && !oscillator_) {
    impl_->measure_single_shots(targets, conditions, seed, first_stream, out);
    return;
  }
  for (std::size_t k = 0; k < targets.size(); ++k)
    out[k] = measure(targets[k], conditions[k], seed, first_stream + k, shots);
}

void VirtualRangefinder::measure_batch(std::span<const MeasureRequest> requests, std::uint64_t seed,
                                       std::span<ranging::RawMeasurement> out) const {
  if (out.size() != requests.size())
    throw std::invalid_argument("measure_batch: output span size differs from the request count");
  // Runs of requests with one shot count go through the span form (single
  // shots as lanes); its bytes are those of one-at-a-time calls, so neither the
  // blocks nor the thread count shows in the output.
  // Blocks of about 256 shots: 256 single-shot lanes, or one long measurement.
  double shots_total = 0;
  for (const auto& r : requests)
    shots_total += r.shots > 0 ? r.shots : impl_->config.measurement.shots;
  const double mean_shots =
      requests.empty() ? 1.0 : shots_total / static_cast<double>(requests.size());
  const auto grain = static_cast<std::size_t>(std::clamp(256.0 / mean_shots, 1.0, 256.0));
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, requests.size(), grain),
                    [&](const tbb::blocked_range<std::size_t>& range) {
                      thread_local std::vector<Target> targets;
                      thread_local std::vector<Conditions> conditions;
                      for (std::size_t i = range.begin(); i != range.end();) {
                        std::size_t j = i + 1;
                        while (j != range.end() && requests[j].shots == requests[i].shots) ++j;
                        targets.resize(j - i);
                        conditions.resize(j - i);
                        for (std::size_t k = i; k != j; ++k) {
                          targets[k - i] = requests[k].target;  // keeps its capacity
                          conditions[k - i] = requests[k].conditions;
                        }
                        measure(targets, conditions, seed, i, requests[i].shots,
                                out.subspan(i, j - i));
                        i = j;
                      }
                    });
}

double VirtualRangefinder::coupling_baseline_v(const Target& target,
                                               const Conditions& conditions) const {
  // (The loop's comparator does not take the baseline yet.)
  if (!impl_->coupled || oscillator_) return 0.0;
  Conditions settled = conditions;
  settled.baseline_offset_v = 0.0;
  return impl_->setup(target, settled).baseline_v;
}

double VirtualRangefinder::tof_to_distance_m(double tof_ns) const {
  return 0.5 * tof_ns * impl_->c_nominal_m_per_ns;
}

}  // namespace tofkit::device
