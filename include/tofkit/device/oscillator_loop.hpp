#pragma once
/// \file The self-oscillating loop of an AccuRange-like rangefinder (thesis
/// Section 3.1, Fig. 3.2): not a single-pulse timer. The laser stays on until
/// the detector sees the return, then turns off, and on again when the return
/// has gone, so the loop's period encodes range:
///
///   T = t_on + t_off + 2 loop_delay,
///   t_on  = round trip + time for the receiver to rise through its threshold,
///   t_off = round trip + time for it to fall back through it,
///
/// about 17 ns at zero range and 284 ns at 20 m with the accurange preset
/// (thesis: ~20 ns and 280 ns). Causes, each from a key:
///  - the return is a step of optical power (link budget, as the pulsed core,
///    without the short pulse's bandwidth loss; a receiver focused at a finite
///    distance passes physics::field_stop_share of it), through a single-pole receiver
///    (receiver.bandwidth_mhz) whose state clips at receiver.saturation_v;
///  - the receiver is AC-coupled: on the loop's square wave its baseline sits at
///    oscillator.coupling_duty of the swing, and the comparator
///    (discriminator.threshold_v) fires that far above the baseline on both edges.
///    A weak return rises slowly through it (reads long); a return too weak to
///    lift the swing above the threshold stops the loop (no echo). A saturated
///    return rises ever faster while it falls from the clip level (reads short),
///    and an overdriven receiver recovers erratically
///    (oscillator.overdrive_jitter_ps_per_neper);
///  - noise per edge: receiver noise (paper Eq. 8 terms) over the slope at each
///    crossing; each period's jitter is independent, so the mean period of M
///    periods carries sigma_T / sqrt(M); a slow wander of the loop delay
///    (oscillator.flicker_delay_ps) does not average within an output, nor does
///    the loop's duty unbalanced at each switch-on of the laser
///    (oscillator.duty_wander: the driver's turn-on and turn-off delays start
///    apart by a draw per switch-on and settle together as the junction heats,
///    laser.turn_on_time_constant_ms; a point-by-point scan switches the laser on
///    at every point, a continuous acquisition runs settled): the AC-coupled
///    baseline sits at the duty share of the swing, so it moves the comparator's
///    level on both edges by dv = d_duty x swing, delaying the rise by dv / rise
///    slope and advancing the fall by dv / fall slope. A weak return (slow rise,
///    the level near its top) turns it into much more time than a strong one:
///    noise that depends on intensity;
///  - the interface board counts its clock (oscillator.count_clock_mhz, 80 MHz)
///    from the first loop edge in its gate to the last (reciprocal counting, both
///    ends asynchronous to the clock), the gate being oscillator.gate_fraction
///    of the output period measurement.shots / laser.repetition_hz
///    (312,500 / 2^N samples/s): resolution = c/4 x t_clk x T / gate, so it
///    trades against the sampling rate (thesis Fig. 4.4);
///  - the laser is gated by the counting window (Assumption: on while the
///    board counts, off while it transfers and reads the unit's ambient-light
///    channel): the laser chip heats in each gate and cools in each pause with
///    its thermal time constant (oscillator.chip_time_constant_us), and a cold
///    chip's lower threshold current shortens its turn-on delay, so the loop runs
///    fast (oscillator.chip_bias_mm of range, cold against hot). Short gates keep
///    the chip half warm, long ones let it reach hot early in each gate: the mean
///    rises with the gate's length, i.e. falls with the sampling rate (thesis
///    Fig. 4.4: 19.64 in at 4883 samples/s rising to 19.90 in at 153);
///  - the intensity output is a peak detector on the linear stage (clipping at
///    receiver.amplitude_clip_v) behind the same AC coupling: on a still target it
///    reads the step amplitude; a baseline left high by a stronger return
///    (Conditions::baseline_offset_v, in a scan) lowers it by
///    offset / (1 - coupling_duty), so what the memory does to range is visible
///    in intensity;
///  - the device reports the mean half period minus its vendor zero
///    (oscillator.zero_half_period_ns) as the round-trip time; thermal drift,
///    warm-up and the laser's turn-on transient add to the half period as in the
///    pulsed core.
/// No correction's functional form appears here: the walk is the receiver's
/// exponential step response crossing a fixed threshold.
///
/// Randomness is counter-based (Philox4x32): an output depends on (seed,
/// stream) only, whatever thread computes it.

#include <cstdint>

#include "tofkit/device/device_config.hpp"
#include "tofkit/device/target.hpp"
#include "tofkit/device/virtual_rangefinder.hpp"
#include "tofkit/ranging/raw_measurement.hpp"

namespace tofkit::device {

/// The noise-free state of the loop on one target.
struct LoopState {
  bool oscillates = false;        ///< the swing crosses the threshold on both edges
  bool saturated = false;         ///< the receiver's state clips
  double amplitude_v = 0;         ///< linear step amplitude of the return (sum of surfaces)
  double swing_v = 0;             ///< clipped swing
  double on_detect_ns = 0;        ///< laser on -> return seen (round trip + rise latency)
  double off_detect_ns = 0;       ///< laser off -> return gone (round trip + fall latency)
  double period_ns = 0;           ///< on_detect + off_detect + 2 loop delays (+ thermal)
  double period_jitter_ns = 0;    ///< 1 sigma of one period (independent per period)
  double comparator_high_ns = 0;  ///< comparator output high per period (reported width)
  double noise_v = 0;             ///< receiver noise (1 sigma) at the threshold level
  double rise_slope_v_per_ns = 0;
  double fall_slope_v_per_ns = 0;  ///< magnitude of the falling edge's slope at the level
};

/// The comparator near the top of a weak swing (thesis Fig. 4.28: on black after
/// mid grey the range swings erratically, both short and long of the truth).
/// Where the swing's top sits only a few noise sigmas above or below the
/// comparator's level (margin_v = top - level), the receiver noise (noise_v rms,
/// band-limited to bandwidth_mhz: an ideal low pass, so it crosses a level u at
/// Rice's rate nu(u) = B / sqrt(3) exp(-u^2 / 2 sigma^2)) decides the edges:
///  - extra edges: while the return sits at its top (the comparator's high time,
///    high_ns), each dip of the noise below the level minus the comparator's
///    hysteresis takes the comparator low and high again, an edge the board
///    counts as one more period (reads short): high_ns nu(margin + hysteresis)
///    per period;
///  - missed crossings: when the rise reaches the top, the noise is below -margin
///    with probability Phi(-margin / sigma); the rise then waits for that
///    excursion to end, on average Phi(-margin / sigma) / nu(margin) (Rice's mean
///    excursion time), so the period lengthens (reads long):
///    Phi(-margin / sigma)^2 / nu(margin) per period; far below the top that is
///    the wait for a rare up-crossing, 1 / nu(margin).
/// Far above the top (margin >= kNearTopSigmas sigma) both are zero; far below
/// it the wait is infinite (lock lost: the loop has no edges).
struct NearTopEdges {
  double extra_edges_per_period = 0;  ///< chatter edges counted per loop period
  double missed_wait_ns = 0;          ///< mean wait per period for a missed rise
};
/// Margin, in noise sigmas, beyond which the comparator sees a clean swing
/// (Rice's rate there is exp(-32) ~ 1e-14 of nu(0): below one edge per hour).
inline constexpr double kNearTopSigmas = 8.0;
[[nodiscard]] NearTopEdges near_top_edges(double margin_v, double noise_v, double bandwidth_mhz,
                                          double high_ns, double hysteresis_v = 0.0);

class OscillatorLoop {
 public:
  /// `config.oscillator.enabled` need not be set (tests compare principles).
  explicit OscillatorLoop(DeviceConfig config);

  [[nodiscard]] const DeviceConfig& config() const { return config_; }

  /// Noise-free loop on a target (thermal drift and warm-up included), with the
  /// loop's duty (hence the AC-coupled baseline) raised by duty_offset.
  [[nodiscard]] LoopState state(const Target& target, const Conditions& conditions,
                                double duty_offset = 0.0) const;

  /// The receiver's view as the pulsed core reports it (for EchoMemory's strength).
  [[nodiscard]] EchoShape echo(const Target& target, const Conditions& conditions) const;

  /// One loop period (the half period minus the zero as tof_ns).
  [[nodiscard]] Shot shoot(const Target& target, const Conditions& conditions, std::uint64_t seed,
                           std::uint64_t stream, std::uint32_t shot) const;

  /// The loop's duty offset (oscillator.duty_wander) a switch-on starts with,
  /// averaged over an output window of window_ms starting conditions.ms_since_laser_on
  /// after it: the draw (one per second of conditions.session_time_s, from the run's
  /// seed) times exp(-t0 / tau) (1 - exp(-W / tau)) / (W / tau), tau =
  /// laser.turn_on_time_constant_ms; 0 without wander or past the transient.
  [[nodiscard]] double duty_offset(const Conditions& conditions, std::uint64_t seed,
                                   double window_ms = 0.0) const;

  /// One output: the board counts the loop over a gate of gate_fraction x
  /// shots / laser.repetition_hz (shots = 0: measurement.shots). gate_shots > 0:
  /// this is a stretch of a longer output of gate_shots (device/loop_window.hpp),
  /// whose gate sets the laser chip's heating (oscillator.chip_*).
  [[nodiscard]] ranging::RawMeasurement measure(const Target& target, const Conditions& conditions,
                                                std::uint64_t seed, std::uint64_t stream,
                                                int shots = 0, int gate_shots = 0) const;

  /// The laser chip's cold share averaged over a gate (oscillator.chip_*): in the
  /// periodic state of a gate of gate_ms (laser on, the chip heating toward hot
  /// with tau) and a pause of off_ms (cooling toward cold with tau),
  ///   (1 - h0) (1 - exp(-a)) / a,  h0 = (1 - exp(-a)) exp(-b) / (1 - exp(-a - b)),
  /// a = gate / tau, b = off / tau (equal gate and pause: tanh(a / 2) / a);
  /// 1/2 for gates far shorter than tau, tau / gate for far longer ones.
  [[nodiscard]] static double chip_cold_share(double gate_ms, double off_ms, double tau_ms);

  /// Range step of one clock count for an output of `shots` (0: the config's)
  /// on a target: c/4 x t_clk x T / gate (thesis Fig. 4.4's resolution column).
  [[nodiscard]] double resolution_m(const Target& target, const Conditions& conditions,
                                    int shots = 0) const;

  /// Distance the device reports for a round-trip time (nominal c in air).
  [[nodiscard]] double tof_to_distance_m(double tof_ns) const;

 private:
  DeviceConfig config_;
  double c_nominal_m_per_ns_ = 0;
  double tau_ns_ = 0;  // receiver pole time constant 1 / (2 pi B)
};

}  // namespace tofkit::device
