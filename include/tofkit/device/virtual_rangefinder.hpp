#pragma once
/// \file The virtual pulsed ToF rangefinder: the device physics of DESIGN.md
/// (link budget, APD, noise, echo waveform with saturation, fixed-threshold
/// discriminator, delays and thermal drift, TDC, N-shot averaging, warm-up and
/// laser turn-on, speed of light in air) in two evaluation modes that agree.
/// With `oscillator.enabled` the device measures by the self-oscillating loop
/// principle instead (device/oscillator_loop.hpp, the AccuRange's).

#include <cstdint>
#include <memory>
#include <span>

#include "tofkit/device/device_config.hpp"
#include "tofkit/device/target.hpp"
#include "tofkit/ranging/raw_measurement.hpp"

namespace tofkit::device {

enum class SimulationMode {
  kAnalytic,  ///< crossings from the pulse template, jitter = noise / slope (fast)
  kWaveform,  ///< noise added to a sampled waveform, crossings found on it (reference)
};

/// The deterministic (noise-free) echo seen by the discriminator.
struct EchoShape {
  double peak_v = 0;               ///< linear (unclipped) peak amplitude at the comparator
  double rise_crossing_ns = 0;     ///< rising threshold crossing, from emission (no delays)
  double fall_crossing_ns = 0;     ///< falling threshold crossing
  bool detected = false;           ///< peak above threshold
  bool saturated = false;          ///< peak above the amplifier's clip level
  double rise_slope_v_per_ns = 0;  ///< slope at the rising crossing
  double noise_at_rise_v = 0;      ///< noise (1 sigma) at the rising crossing
};

/// One shot's discriminator output (for tests and diagnostics).
struct Shot {
  bool echo = false;
  double tof_ns = 0;          ///< TDC stop (rising edge) minus TDC start, delays included
  double pulse_width_ns = 0;  ///< TDC falling minus rising edge (time over threshold)
};

/// One measurement request of a batch.
class OscillatorLoop;  // device/oscillator_loop.hpp: the self-oscillating principle

struct MeasureRequest {
  Target target;
  Conditions conditions;
  int shots = 0;  ///< 0: the config's measurement.shots
};

class VirtualRangefinder {
 public:
  /// Throws std::invalid_argument listing every invalid key.
  explicit VirtualRangefinder(DeviceConfig config, SimulationMode mode = SimulationMode::kAnalytic);
  ~VirtualRangefinder();
  VirtualRangefinder(const VirtualRangefinder&) = delete;
  VirtualRangefinder& operator=(const VirtualRangefinder&) = delete;
  VirtualRangefinder(VirtualRangefinder&&) noexcept;
  VirtualRangefinder& operator=(VirtualRangefinder&&) noexcept;

  [[nodiscard]] const DeviceConfig& config() const;
  [[nodiscard]] SimulationMode mode() const;

  /// Noise-free echo for a target (no thermal or TDC effects).
  [[nodiscard]] EchoShape echo(const Target& target, const Conditions& conditions) const;

  /// One shot. `seed` selects the run, `stream` the measurement, `shot` the shot:
  /// the result depends on these three numbers only (counter-based Philox RNG).
  [[nodiscard]] Shot shoot(const Target& target, const Conditions& conditions, std::uint64_t seed,
                           std::uint64_t stream, std::uint32_t shot) const;

  /// An N-shot averaged measurement (N = shots, or measurement.shots if 0).
  [[nodiscard]] ranging::RawMeasurement measure(const Target& target, const Conditions& conditions,
                                                std::uint64_t seed, std::uint64_t stream,
                                                int shots = 0) const;

  /// Measurements of consecutive streams on the calling thread (a scanner's
  /// block of beams): target k under conditions[k] on stream first_stream + k,
  /// the same bytes as measure(targets[k], conditions[k], seed, first_stream + k,
  /// shots). Single-shot measurements run in lanes, several at a time (faster).
  void measure(std::span<const Target> targets, std::span<const Conditions> conditions,
               std::uint64_t seed, std::uint64_t first_stream, int shots,
               std::span<ranging::RawMeasurement> out) const;

  /// Many measurements on all cores (TBB); request i uses stream i, so the
  /// output does not depend on the number of threads.
  void measure_batch(std::span<const MeasureRequest> requests, std::uint64_t seed,
                     std::span<ranging::RawMeasurement> out) const;

  /// The AC coupling's settled baseline (V) on a target's echo train
  /// (memory.time_constant_ms > 0; else 0): the mean of the amplifier's output,
  /// one echo's charge as the amplifier passes it times the repetition rate,
  /// times memory.coupling_share. 0 for the loop (oscillator.enabled), whose
  /// comparator does not take the baseline yet.
  [[nodiscard]] double coupling_baseline_v(const Target& target,
                                           const Conditions& conditions) const;

  /// Distance the device reports for a time of flight (nominal c in air).
  [[nodiscard]] double tof_to_distance_m(double tof_ns) const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
  std::unique_ptr<const OscillatorLoop> oscillator_;  ///< set when oscillator.enabled
};

}  // namespace tofkit::device
