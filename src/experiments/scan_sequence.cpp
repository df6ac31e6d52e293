#include "tofkit/experiments/scan_sequence.hpp"

#include <tbb/parallel_for.h>

#include <stdexcept>

namespace tofkit::experiments {

void SequenceScanOptions::validate() const {
  if (shots < 0) throw std::invalid_argument("sequence scan: shots must be >= 0");
  if (window_points < 1 || window_points > 64)
    throw std::invalid_argument("sequence scan: window_points must be in 1..64");
}

SequenceScan run_sequence_scan(const scan::RayCaster& caster, const scan::Footprint& footprint,
                               const device::VirtualRangefinder& device,
                               const scan::BeamPattern& pattern,
                               const SequenceScanOptions& options) {
  options.validate();
  using scan::operator+, scan::operator-, scan::operator*;
  const device::EchoMemory memory(device);
  const int shots = scan::shots_per_beam(device.config(), options.shots, pattern);
  const double window_s = memory.window_s(shots);
  SequenceScan out;
  auto& result = out.result;
  result.pattern = pattern;
  result.sensor = caster.scene().sensor;
  const std::size_t n = pattern.beams.size();
  result.beams.resize(n);
  std::vector<device::SequenceItem> items(n);
  const scan::RigidTransform to_world = result.sensor.to_world();
  tbb::parallel_for(
      tbb::blocked_range<std::size_t>(0, n, 256),
      [&](const tbb::blocked_range<std::size_t>& block) {
        scan::Footprint::Result fp;
        for (std::size_t i = block.begin(); i != block.end(); ++i) {
          const scan::Beam& beam = pattern.beams[i];
          scan::BeamResult& b = result.beams[i];
          scan::beam_to_world(beam, to_world, b.beam);
          footprint.trace(caster, b.beam.origin_m, b.beam.direction, fp);
          scan::record_footprint(fp, b);
          auto& item = items[i];
          item.conditions = options.conditions;
          // The session's clock runs with the scan: slow wander (the loop's duty)
          // holds over a line, not over the whole scan.
          item.conditions.session_time_s = options.conditions.session_time_s + beam.time_s;
          item.time_s = beam.time_s;
          item.shots = shots;
          // The beam moves towards the next beam of its row during the
          // window: a share window / (t_next - t) of the way.
          const bool moving = options.window_points > 1 && i + 1 < n &&
                              pattern.beams[i + 1].row == beam.row &&
                              pattern.beams[i + 1].time_s > beam.time_s;
          if (!moving) {
            item.path.assign(1, fp.target);
            continue;
          }
          const scan::Beam& next = pattern.beams[i + 1];
          const double share = std::min(1.0, window_s / (next.time_s - beam.time_s));
          // `line` beams sit at the window's middle; others at its start.
          const double centre = pattern.name == "line" ? -0.5 : 0.0;
          item.path.resize(static_cast<std::size_t>(options.window_points));
          for (int k = 0; k < options.window_points; ++k) {
            const double f = share * (centre + (k + 0.5) / options.window_points);
            const scan::Vec3 origin = beam.origin_m + f * (next.origin_m - beam.origin_m);
            const scan::Vec3 dir =
                scan::normalized(beam.direction + f * (next.direction - beam.direction));
            footprint.trace(caster, to_world.transform(origin), to_world.rotate(dir), fp);
            item.path[static_cast<std::size_t>(k)] = fp.target;
          }
        }
      });
  std::vector<ranging::RawMeasurement> raw(n);
  out.memory.resize(n);
  memory.measure_sequence(items, options.seed, raw, out.memory);
  for (std::size_t i = 0; i < n; ++i) result.beams[i].raw = raw[i];
  return out;
}

}  // namespace tofkit::experiments
