#pragma once
/// \file The emitter stage's turn-on transient (DESIGN, "Thermal and
/// start-up"): the first shots after the laser is switched on come out
/// biased in range while the diode's junction and driver settle, the bias
/// decaying exponentially with the laser's turn-on time constant. (The
/// pulse's own shape, with its lasing onset, is physics/pulse_template.hpp;
/// its power's temperature coefficient enters the operating point.)

#include <cmath>
#include <cstdint>

#include "tofkit/physics/laser.hpp"

namespace tofkit::device {

/// Extra round-trip time (ns) of shot `shot` of a measurement whose first
/// shot fires `first_shot_ms` after the laser was switched on: the bias
/// turn_on_bias_mm x exp(-t / turn_on_time_constant_ms) in range, as time at
/// `c_m_per_ns`; exactly 0 beyond 30 time constants.
[[nodiscard]] inline double turn_on_bias_ns(const physics::LaserConfig& laser, double first_shot_ms,
                                            std::uint32_t shot, double c_m_per_ns) {
  const double t_ms = first_shot_ms + 1e3 * static_cast<double>(shot) / laser.repetition_hz;
  if (t_ms > 30.0 * laser.turn_on_time_constant_ms) return 0.0;
  const double bias_mm = laser.turn_on_bias_mm * std::exp(-t_ms / laser.turn_on_time_constant_ms);
  return 2.0 * bias_mm * 1e-3 / c_m_per_ns;
}

}  // namespace tofkit::device
