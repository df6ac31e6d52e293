#include "tofkit/ranging/memory_correction.hpp"

#include <cmath>
#include <stdexcept>
#include <vector>

namespace tofkit::ranging {

double echo_strength_neper(const RawMeasurement& raw) {
  if (!raw.has_echo() || !(raw.amplitude > 0) || !(raw.pulse_width_ns > 0)) return kNaN;
  return std::log(raw.amplitude * raw.pulse_width_ns);
}

void memory_lag(double time_constant_s, double reset_time_constants, std::span<const double> time_s,
                std::span<const RawMeasurement> raw, std::span<double> lag_neper) {
  if (time_s.size() != raw.size() || lag_neper.size() != raw.size())
    throw std::invalid_argument("memory_lag: spans differ in size");
  // The state relaxes towards the last strength seen; a gap longer than
  // reset_time_constants time constants starts afresh (the memory has decayed).
  double state = kNaN, last_x = kNaN, last_time = kNaN;
  for (std::size_t i = 0; i < raw.size(); ++i) {
    const double x = echo_strength_neper(raw[i]);
    if (std::isnan(x)) {
      lag_neper[i] = kNaN;  // no echo: nothing measured, nothing to correct
      continue;
    }
    const double dt = time_s[i] - last_time;
    if (!(time_constant_s > 0) || std::isnan(state) ||
        !(dt <= reset_time_constants * time_constant_s)) {
      state = x;
    } else {
      state = last_x + (state - last_x) * std::exp(-dt / time_constant_s);
    }
    lag_neper[i] = x - state;  // unrecovered step at the start of this output
    last_x = x;
    last_time = time_s[i];
  }
}

void apply_memory_correction(const MemoryCorrection& correction, std::span<const double> time_s,
                             std::span<const RawMeasurement> raw, std::span<double> distance_m) {
  if (distance_m.size() != raw.size())
    throw std::invalid_argument("apply_memory_correction: spans differ in size");
  if (!(correction.time_constant_s > 0)) return;
  std::vector<double> lag(raw.size());
  memory_lag(correction.time_constant_s, correction.reset_time_constants, time_s, raw, lag);
  for (std::size_t i = 0; i < raw.size(); ++i) {
    if (std::isfinite(lag[i])) distance_m[i] += correction.gain_m_per_neper * lag[i];
  }
}

}  // namespace tofkit::ranging
