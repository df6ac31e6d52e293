#include "tofkit/experiments/scan_memory.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <stdexcept>

#include "tofkit/experiments/scan_sequence.hpp"
#include "tofkit/experiments/thesis_grey_chart.hpp"
#include "tofkit/scan/footprint.hpp"
#include "tofkit/scan/pattern.hpp"
#include "tofkit/scan/ray_caster.hpp"

namespace tofkit::experiments {
namespace {

constexpr std::uint64_t kCalibrationSalt = 1, kEdgesSalt = 2, kTransitionSalt = 3,
                        kTransitionLineSalt = 4;

scan::Primitive wall(double x_m, double z_lo, double z_hi, double reflectance) {
  scan::Primitive p;
  p.kind = scan::PrimitiveKind::kPlane;
  p.center_m = {x_m, 0, 0.5 * (z_lo + z_hi)};
  p.normal = {-1, 0, 0};
  p.size_m = {1.0, z_hi - z_lo};
  p.reflectance.value = reflectance;
  p.name = "wall";
  return p;
}

/// A block's front face: a plate (no top and bottom faces at grazing
/// incidence, which would add their own, non-memory, errors at the edges).
scan::Primitive block(const MemoryScanOptions& o, double z_lo, double z_hi) {
  scan::Primitive p = wall(o.block_front_m, z_lo, z_hi, o.block_reflectance);
  p.size_m = {0.4, z_hi - z_lo};
  p.name = "block";
  return p;
}

/// One mirror scan, measured as a sequence, with the memory correction applied.
struct MirrorScan {
  scan::ScanResult result;
  std::vector<device::MemoryTrace> memory;
  std::vector<double> time_s, corrected_m;
};

MirrorScan mirror_scan(const device::VirtualRangefinder& device, const MemoryScanOptions& o,
                       const scan::Scene& scene, std::uint64_t seed) {
  const scan::RayCaster caster(scene);
  const scan::Footprint footprint(device.config());
  scan::MirrorOptions mo;
  for (double e = o.elevation_min_deg; e <= o.elevation_max_deg + 1e-9; e += o.elevation_step_deg)
    mo.elevation_deg.push_back(e);
  mo.revolutions = o.revolutions;
  mo.revolutions_per_s = o.revolutions_per_s;
  const auto pattern = scan::mirror_pattern(mo);
  SequenceScanOptions so;
  so.seed = seed;
  so.shots = o.shots;
  so.conditions.ambient_c = o.ambient_c;
  so.window_points = 2;  // the mirror keeps turning during the window
  auto s = run_sequence_scan(caster, footprint, device, pattern, so);
  MirrorScan out{std::move(s.result), std::move(s.memory), {}, {}};
  for (const auto& b : out.result.beams) {
    out.time_s.push_back(b.beam.time_s);
    out.corrected_m.push_back(b.raw.distance_raw_m);
  }
  return out;
}

std::vector<ranging::Record> records_of(const MirrorScan& s, double ambient_c) {
  std::vector<ranging::Record> out;
  for (const auto& b : s.result.beams)
    out.push_back({{b.true_range_m, ranging::kNaN, 0.0, ambient_c}, b.raw});
  return out;
}

void correct(MirrorScan& s, const ranging::MemoryCorrection& c) {
  std::vector<ranging::RawMeasurement> raw;
  for (const auto& b : s.result.beams) raw.push_back(b.raw);
  apply_memory_correction(c, s.time_s, raw, s.corrected_m);
}

double mean_of(const std::vector<double>& v) {
  double sum = 0;
  std::size_t n = 0;
  for (const double x : v) {
    if (!std::isfinite(x)) continue;
    sum += x;
    ++n;
  }
  return n ? sum / static_cast<double>(n) : ranging::kNaN;
}

/// The profile of a scan: columns in time order (the mirror turns upwards).
Profile profile_of(const std::string& name, const MirrorScan& s, const MemoryScanOptions& o,
                   double time_constant_s) {
  Profile p;
  p.name = name;
  const int cols = s.result.pattern.columns;
  const int revs = s.result.pattern.rows;
  const auto at = [&](int rev, int k) { return static_cast<std::size_t>(rev * cols + k); };
  std::vector<double> time_s(static_cast<std::size_t>(cols));
  std::vector<int> surfaces(static_cast<std::size_t>(cols));
  std::vector<double> strength(static_cast<std::size_t>(cols));
  for (int k = 0; k < cols; ++k) {
    const auto& b0 = s.result.beams[at(0, k)];
    std::vector<double> before, after;
    for (int r = 0; r < revs; ++r) {
      const auto& b = s.result.beams[at(r, k)];
      if (!b.raw.has_echo()) continue;
      before.push_back(b.true_range_m - b.raw.distance_raw_m);
      after.push_back(b.true_range_m - s.corrected_m[at(r, k)]);
    }
    const double e = o.elevation_min_deg + k * o.elevation_step_deg;
    p.elevation_deg.push_back(e);
    p.truth_m.push_back(b0.true_range_m);
    p.error_before_m.push_back(mean_of(before));
    p.error_after_m.push_back(mean_of(after));
    p.single_before_m.push_back(b0.raw.has_echo() ? b0.true_range_m - b0.raw.distance_raw_m
                                                  : ranging::kNaN);
    p.single_after_m.push_back(b0.raw.has_echo() ? b0.true_range_m - s.corrected_m[at(0, k)]
                                                 : ranging::kNaN);
    time_s[static_cast<std::size_t>(k)] = b0.beam.time_s;
    surfaces[static_cast<std::size_t>(k)] = b0.surfaces;
    strength[static_cast<std::size_t>(k)] = s.memory[at(0, k)].strength_neper;
  }
  // Edges: steps of the noise-free echo strength between neighbouring columns.
  std::vector<int> edge_cols;
  for (int k = 1; k < cols; ++k) {
    if (std::abs(strength[static_cast<std::size_t>(k)] -
                 strength[static_cast<std::size_t>(k - 1)]) > o.edge_step_neper)
      edge_cols.push_back(k);
  }
  // Merge edges closer than spike_columns (a mixed pixel makes two small steps).
  std::vector<int> merged;
  for (const int k : edge_cols) {
    if (!merged.empty() && k - merged.back() <= o.spike_columns) {
      merged.back() = k;
    } else {
      merged.push_back(k);
    }
  }
  std::vector<double> near_before, near_after;
  double abs_before = 0, abs_after = 0;
  for (std::size_t ei = 0; ei < merged.size(); ++ei) {
    const int k0 = merged[ei];
    const int k_end = ei + 1 < merged.size() ? merged[ei + 1] : cols;
    // Settled level: a straight line through the pure columns 4 to 12 time
    // constants after the edge (the memory has decayed to < 2 %), extrapolated
    // back to the edge: incidence angle and range drift slowly along a profile.
    const double t0 = time_s[static_cast<std::size_t>(k0)];
    auto settled_line = [&](const std::vector<double>& err) {
      std::vector<double> tt, ee;
      // Columns just before the next edge (a grazing face, a mixed pixel) stay out.
      for (int k = k0; k < k_end - 2 * o.spike_columns; ++k) {
        const double dt = time_s[static_cast<std::size_t>(k)] - t0;
        if (surfaces[static_cast<std::size_t>(k)] != 1 || dt < 4 * time_constant_s ||
            dt > 12 * time_constant_s || !std::isfinite(err[static_cast<std::size_t>(k)]))
          continue;
        tt.push_back(dt);
        ee.push_back(err[static_cast<std::size_t>(k)]);
      }
      if (tt.size() < 3) {  // short segment: its last third's mean
        for (int k = k0 + 2 * (k_end - k0) / 3; k < k_end; ++k) {
          if (surfaces[static_cast<std::size_t>(k)] != 1) continue;
          tt.push_back(0);
          ee.push_back(err[static_cast<std::size_t>(k)]);
        }
        return std::pair{mean_of(ee), 0.0};
      }
      const auto f = fit_line(tt, ee);
      return std::pair{f.intercept, f.slope};
    };
    const auto [settled_b0, slope_b] = settled_line(p.error_before_m);
    const auto [settled_a0, slope_a] = settled_line(p.error_after_m);
    auto settled_at = [&, sb0 = settled_b0, sa0 = settled_a0, sb = slope_b, sa = slope_a](
                          int k, bool after) {
      const double dt = time_s[static_cast<std::size_t>(k)] - t0;
      return after ? sa0 + sa * dt : sb0 + sb * dt;
    };
    EdgeSpike edge;
    edge.elevation_deg = p.elevation_deg[static_cast<std::size_t>(k0)];
    const int k_prev = std::max(0, k0 - o.spike_columns - 1);
    edge.rising =
        strength[static_cast<std::size_t>(k0)] > strength[static_cast<std::size_t>(k_prev)];
    double best_b = 0, best_a = 0;
    int seen = 0;
    // The first spike_columns columns with a reading: where the loop lost lock
    // after the edge (no echo on any revolution) the spike is where it re-locks.
    for (int k = k0; k < k_end && seen < o.spike_columns; ++k) {
      if (surfaces[static_cast<std::size_t>(k)] != 1 ||
          !std::isfinite(p.error_before_m[static_cast<std::size_t>(k)]))
        continue;
      ++seen;
      const double db = p.error_before_m[static_cast<std::size_t>(k)] - settled_at(k, false);
      const double da = p.error_after_m[static_cast<std::size_t>(k)] - settled_at(k, true);
      if (std::abs(db) > std::abs(best_b)) best_b = db;
      if (std::abs(da) > std::abs(best_a)) best_a = da;
    }
    edge.spike_before_m = best_b;
    edge.spike_after_m = best_a;
    abs_before += std::abs(best_b);
    abs_after += std::abs(best_a);
    p.edges.push_back(edge);
    for (int k = k0; k < k_end; ++k) {
      if (surfaces[static_cast<std::size_t>(k)] != 1) continue;
      const double db = p.error_before_m[static_cast<std::size_t>(k)] - settled_at(k, false);
      const double da = p.error_after_m[static_cast<std::size_t>(k)] - settled_at(k, true);
      if (time_s[static_cast<std::size_t>(k)] - t0 <= 5 * time_constant_s) {
        near_before.push_back(db);
        near_after.push_back(da);
      }
    }
  }
  if (!p.edges.empty()) {
    p.spike_before_m = abs_before / static_cast<double>(p.edges.size());
    p.spike_after_m = abs_after / static_cast<double>(p.edges.size());
  }
  p.rms_near_edges_before_m = calib::error_stats(near_before).rms_m;
  p.rms_near_edges_after_m = calib::error_stats(near_after).rms_m;
  return p;
}

/// Fig. 4.28 as the thesis's line scans are taken: a mid-grey area beside a
/// black one on a plane at the transition distance, one line from grey into black.
TransitionLine transition_line(const device::VirtualRangefinder& device, const MemoryScanOptions& o,
                               std::uint64_t seed) {
  const double a = o.transition_area_m;
  scan::Scene scene;
  for (const auto& [sign, grey] :
       {std::pair{1.0, o.transition_from_grey}, std::pair{-1.0, o.transition_to_grey}}) {
    scan::Primitive p;
    p.kind = scan::PrimitiveKind::kPlane;
    p.name = "transition chart";
    p.center_m = {o.transition_distance_m, sign * 0.5 * a, 0};
    p.normal = {-1, 0, 0};
    p.size_m = {a, 0.05};
    p.reflectance.value = grey_reflectance(grey);
    scene.primitives.push_back(p);
  }
  const scan::RayCaster caster(scene);
  const scan::Footprint footprint(device.config());
  // The stage's columns every millimetre from +a to -a (the line runs towards -y).
  scan::LineOptions lo;
  const int columns = static_cast<int>(std::round(2 * a / 1e-3));
  for (int c = 0; c < columns; ++c) lo.y_m.push_back(a - (c + 0.5) * 1e-3);
  lo.z_m = {0.0};
  lo.stage_speed_m_per_s = o.stage_speed_m_per_s;
  const auto pattern =
      scan::line_pattern(lo, o.line_shots / device.config().link.laser.repetition_hz);
  SequenceScanOptions so;
  so.seed = seed;
  so.shots = o.line_shots;
  so.conditions.ambient_c = o.ambient_c;
  const auto s = run_sequence_scan(caster, footprint, device, pattern, so);
  TransitionLine t;
  t.black_start_m = a;
  double lo_m = ranging::kNaN, hi_m = ranging::kNaN;
  for (const auto& b : s.result.beams) {
    const double position = a - b.beam.origin_m[1];
    t.position_m.push_back(position);
    t.truth_m.push_back(b.true_range_m);
    const double r = b.raw.has_echo() ? b.raw.distance_raw_m : ranging::kNaN;
    t.range_m.push_back(r);
    if (position < a || position > 1.5 * a) continue;  // the first half of the black area
    ++t.outputs_first_half;
    if (!std::isfinite(r)) {
      ++t.no_echo_first_half;
      continue;
    }
    lo_m = std::isnan(lo_m) ? r : std::min(lo_m, r);
    hi_m = std::isnan(hi_m) ? r : std::max(hi_m, r);
  }
  t.swing_m = hi_m - lo_m;
  return t;
}

}  // namespace

void MemoryScanOptions::validate() const {
  auto fail = [](const std::string& field, const std::string& why) {
    throw std::invalid_argument("memory scans: " + field + " " + why);
  };
  if (!(wall_distance_m > block_front_m + 0.02))
    fail("wall_distance_m", "must lie more than 2 cm behind block_front_m");
  if (!(block_front_m > 0)) fail("block_front_m", "must be positive");
  for (const double r : {wall_reflectance, block_reflectance})
    if (!(r > 0 && r <= 1)) fail("reflectance", "must be in (0, 1]");
  if (block_bottom_m.size() != block_top_m.size() || block_bottom_m.empty())
    fail("block_bottom_m", "and block_top_m must be non-empty and of equal length");
  for (std::size_t i = 0; i < block_bottom_m.size(); ++i)
    if (!(block_top_m[i] > block_bottom_m[i])) fail("block_top_m", "must exceed block_bottom_m");
  if (!(transition_distance_m > 0)) fail("transition_distance_m", "must be positive");
  if (transition_from_grey < 0 || transition_from_grey > 255 || transition_to_grey < 0 ||
      transition_to_grey > 255)
    fail("transition greys", "must be in 0..255");
  if (!(transition_area_m >= 0.005 && transition_area_m <= 1.0))
    fail("transition_area_m", "must be in 0.005..1 m");
  if (line_shots < 1) fail("line_shots", "must be >= 1");
  if (!(stage_speed_m_per_s > 0)) fail("stage_speed_m_per_s", "must be positive");
  if (!(elevation_step_deg > 0)) fail("elevation_step_deg", "must be positive");
  if (!(elevation_max_deg > elevation_min_deg) || elevation_min_deg < -60 || elevation_max_deg > 60)
    fail("elevation range", "must be increasing within -60..60 degrees");
  if (!(revolutions_per_s > 0)) fail("revolutions_per_s", "must be positive");
  if (revolutions < 2) fail("revolutions", "must be >= 2");
  if (shots < 0) fail("shots", "must be >= 0");
  if (!(edge_step_neper > 0)) fail("edge_step_neper", "must be positive");
  if (spike_columns < 1) fail("spike_columns", "must be >= 1");
  fit.validate();
}

MemoryScanResult run_memory_scans(const device::VirtualRangefinder& device,
                                  const MemoryScanOptions& options, std::uint64_t seed) {
  options.validate();
  MemoryScanResult result;
  result.options = options;
  const double z_lo = -0.5, z_hi = 0.5;

  // Step-edge calibration scan: one block's lower edge.
  scan::Scene calibration;
  calibration.primitives.push_back(
      wall(options.wall_distance_m, z_lo, z_hi, options.wall_reflectance));
  calibration.primitives.push_back(block(options, options.calibration_edge_m, z_hi));
  auto cal = mirror_scan(device, options, calibration, derive_seed(seed, kCalibrationSalt));
  {
    std::vector<ranging::RawMeasurement> raw;
    std::vector<double> truth;
    for (const auto& b : cal.result.beams) {
      raw.push_back(b.raw);
      // Mixed pixels are not memory: leave them out of the fit.
      truth.push_back(b.surfaces == 1 ? b.true_range_m : ranging::kNaN);
    }
    result.fit = calib::fit_memory_correction(cal.time_s, raw, truth, options.fit);
  }
  const double tau = result.fit.correction.time_constant_s;

  scan::Scene edges;
  edges.primitives.push_back(wall(options.wall_distance_m, z_lo, z_hi, options.wall_reflectance));
  for (std::size_t i = 0; i < options.block_bottom_m.size(); ++i)
    edges.primitives.push_back(block(options, options.block_bottom_m[i], options.block_top_m[i]));
  auto edge_scan = mirror_scan(device, options, edges, derive_seed(seed, kEdgesSalt));
  correct(edge_scan, result.fit.correction);
  result.mirror_edges = profile_of("mirror_edges", edge_scan, options, tau);
  result.mirror_records = records_of(edge_scan, options.ambient_c);

  scan::Scene transition;
  transition.primitives.push_back(wall(options.transition_distance_m, z_lo, 0.0,
                                       grey_reflectance(options.transition_from_grey)));
  transition.primitives.push_back(
      wall(options.transition_distance_m, 0.0, z_hi, grey_reflectance(options.transition_to_grey)));
  auto tr = mirror_scan(device, options, transition, derive_seed(seed, kTransitionSalt));
  correct(tr, result.fit.correction);
  result.color_transition = profile_of("color_transition", tr, options, tau);
  result.transition_records = records_of(tr, options.ambient_c);
  result.transition_line = transition_line(device, options, derive_seed(seed, kTransitionLineSalt));
  return result;
}

std::vector<Finding> MemoryScanResult::findings() const {
  std::vector<Finding> f;
  f.push_back({"fitted_time_constant_ms", 1e3 * fit.correction.time_constant_s, "ms"});
  f.push_back({"fitted_gain_mm_per_neper", 1e3 * fit.correction.gain_m_per_neper, "mm/Np"});
  for (const auto* p : {&mirror_edges, &color_transition}) {
    f.push_back({p->name + "_spike_mm_before", 1e3 * p->spike_before_m, "mm"});
    f.push_back({p->name + "_spike_mm_after", 1e3 * p->spike_after_m, "mm"});
    f.push_back({p->name + "_rms_near_edges_mm_before", 1e3 * p->rms_near_edges_before_m, "mm"});
    f.push_back({p->name + "_rms_near_edges_mm_after", 1e3 * p->rms_near_edges_after_m, "mm"});
  }
  f.push_back({"transition_line_swing_in", m_to_inches(transition_line.swing_m), "in"});
  return f;
}

std::vector<ResultTable> MemoryScanResult::tables() const {
  std::vector<ResultTable> out;
  ResultTable e{
      "edges", {"profile", "elevation_deg", "rising", "spike_before_m", "spike_after_m"}, {}};
  for (const auto* p : {&mirror_edges, &color_transition}) {
    for (const auto& x : p->edges) {
      e.rows.push_back({p == &mirror_edges ? 0.0 : 1.0, x.elevation_deg, x.rising ? 1.0 : 0.0,
                        x.spike_before_m, x.spike_after_m});
    }
  }
  out.push_back(e);
  for (const auto* p : {&mirror_edges, &color_transition}) {
    ResultTable t{p == &mirror_edges ? "mirror_profile" : "transition_profile",
                  {"elevation_deg", "truth_m", "error_before_m", "error_after_m", "single_before_m",
                   "single_after_m"},
                  {}};
    for (std::size_t k = 0; k < p->elevation_deg.size(); ++k) {
      t.rows.push_back({p->elevation_deg[k], p->truth_m[k], p->error_before_m[k],
                        p->error_after_m[k], p->single_before_m[k], p->single_after_m[k]});
    }
    out.push_back(t);
  }
  return out;
}

std::string MemoryScanResult::summary() const {
  std::string out;
  char line[256];
  std::snprintf(line, sizeof line,
                "memory correction fitted on a step-edge scan: time constant %.3f ms, gain %.2f "
                "mm per neper (%zu outputs)\n",
                1e3 * fit.correction.time_constant_s, 1e3 * fit.correction.gain_m_per_neper,
                fit.rows);
  out += line;
  std::snprintf(line, sizeof line,
                "  colour transition as a line scan (Fig. 4.28): on the first half of the black "
                "area the range swings %.2f in (%zu of %zu outputs without an echo)\n",
                m_to_inches(transition_line.swing_m), transition_line.no_echo_first_half,
                transition_line.outputs_first_half);
  out += line;
  for (const auto* p : {&mirror_edges, &color_transition}) {
    std::snprintf(line, sizeof line,
                  "  %s: %zu edges, mean |spike| %.2f mm -> %.2f mm, RMS near edges %.2f mm -> "
                  "%.2f mm\n",
                  p->name.c_str(), p->edges.size(), 1e3 * p->spike_before_m, 1e3 * p->spike_after_m,
                  1e3 * p->rms_near_edges_before_m, 1e3 * p->rms_near_edges_after_m);
    out += line;
    for (const auto& e : p->edges) {
      std::snprintf(line, sizeof line, "    edge at %6.2f deg (%s): spike %+7.2f mm -> %+6.2f mm\n",
                    e.elevation_deg, e.rising ? "strength up  " : "strength down",
                    1e3 * e.spike_before_m, 1e3 * e.spike_after_m);
      out += line;
    }
  }
  return out;
}

}  // namespace tofkit::experiments
