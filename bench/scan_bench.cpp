// Beams per second of a 1-megabeam spherical scan (1024 x 1024) of a mesh
// scene (a 131k-triangle sphere in a 12-triangle room), with 1 and 16 rays per
// beam, on 1 and 2 threads, beside the baseline measured in the same run: bare
// Embree casting the same rays (rtcIntersect1 on the same scene, no
// refinement, no footprint grouping). Stages:
//   EmbreeBare/R     the R rays of every beam, bare Embree
//   CastSingle/R     tofkit's casts of a footprint's rays (the axis and the R
//                    sub-rays), one RayCaster::cast each (float traversal + double
//                    refinement), as the footprint traced them before packets
//   CastPacket/R     the same rays through RayCaster::cast over spans (Embree
//                    packets of up to 16): the same hits; its ratio to CastSingle
//                    is the packets' gain
//   EmbreePacket/R   the CastPacket rays as bare Embree packets (rtcIntersect16,
//                    the rest one by one; no refinement): the packets' baseline
//   Footprint/R      tofkit casting + double refinement + grouping into a Target
//   Measured/R       footprint + the device's measurement (analytic, 1 shot), a block
//                    of beams' targets measured in one call as the scanner does (single
//                    shots run in lanes), results discarded (the scan without its output)
//   Scan/R           the full scan: footprint + device measurement (analytic, 1 shot),
//                    into a fresh ScanResult (a one-off scan: the kernel clears its pages)
//   ScanFrames/R     the same, frame after frame into one ScanResult (a real-time
//                    scanner: its results' storage is reused)
//   ResultBytes/F    the baseline of the results' share: memcpy of a frame's
//                    bytes (sizeof(BeamResult) per beam, from a buffer of the same
//                    size) in the scanner's blocks, into fresh memory (F = 1: the
//                    kernel maps and clears its pages, as for Scan) or into one
//                    buffer frame after frame (F = 0, as for ScanFrames)
// The second argument is the thread count. With 1 thread the CPU column is
// the whole cost (useful on a shared machine, where real time includes waits).
#include <benchmark/benchmark.h>
#include <tbb/global_control.h>
#include <tbb/parallel_for.h>

#include <cmath>
#include <cstring>
#include <memory>
#include <numbers>
#include <vector>

#include "tofkit/device/virtual_rangefinder.hpp"
#include "tofkit/scan/footprint.hpp"
#include "tofkit/scan/pattern.hpp"
#include "tofkit/scan/scanner.hpp"

using namespace tofkit;
using namespace tofkit::scan;

namespace {

/// One bare Embree ray (single precision, every mask bit, no hit yet).
RTCRayHit embree_ray(const Vec3& o, const Vec3& d) {
  RTCRayHit rh{};
  rh.ray.org_x = static_cast<float>(o[0]), rh.ray.org_y = static_cast<float>(o[1]);
  rh.ray.org_z = static_cast<float>(o[2]);
  rh.ray.dir_x = static_cast<float>(d[0]), rh.ray.dir_y = static_cast<float>(d[1]);
  rh.ray.dir_z = static_cast<float>(d[2]);
  rh.ray.tfar = std::numeric_limits<float>::infinity();
  rh.ray.mask = 0xFFFFFFFFu;
  rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
  return rh;
}

constexpr int kSide = 1024;  // 1024 x 1024 = 1 M beams

Scene mesh_scene() {
  Scene s;
  Primitive sphere;
  sphere.kind = PrimitiveKind::kMesh;
  sphere.name = "sphere";
  sphere.reflectance.value = 0.5;
  const int n_lat = 256, n_lon = 256;  // 2 x 256 x 255 triangles
  const Vec3 c{3.0, 0.0, 0.0};
  for (int i = 0; i <= n_lat; ++i) {
    for (int j = 0; j < n_lon; ++j) {
      const double th = std::numbers::pi * i / n_lat, ph = 2 * std::numbers::pi * j / n_lon;
      sphere.vertices.push_back({c[0] + std::sin(th) * std::cos(ph),
                                 c[1] + std::sin(th) * std::sin(ph), c[2] + std::cos(th)});
    }
  }
  for (int i = 0; i < n_lat; ++i) {
    for (int j = 0; j < n_lon; ++j) {
      const auto a = static_cast<std::uint32_t>(i * n_lon + j),
                 b = static_cast<std::uint32_t>(i * n_lon + (j + 1) % n_lon);
      const auto d = a + n_lon, e = b + n_lon;
      if (i > 0) sphere.triangles.push_back({a, b, e});
      if (i < n_lat - 1) sphere.triangles.push_back({a, e, d});
    }
  }
  s.primitives.push_back(sphere);
  Primitive room;
  room.kind = PrimitiveKind::kMesh;
  room.name = "room";
  room.reflectance.value = 0.3;
  for (int k = 0; k < 8; ++k)
    room.vertices.push_back({k & 1 ? 6.0 : -6.0, k & 2 ? 6.0 : -6.0, k & 4 ? 4.0 : -2.0});
  const std::uint32_t faces[6][4] = {{0, 2, 6, 4}, {1, 5, 7, 3}, {0, 4, 5, 1},
                                     {2, 3, 7, 6}, {0, 1, 3, 2}, {4, 6, 7, 5}};
  for (const auto& f : faces) {
    room.triangles.push_back({f[0], f[1], f[2]});
    room.triangles.push_back({f[0], f[2], f[3]});
  }
  s.primitives.push_back(room);
  return s;
}

struct Fixture {
  RayCaster caster{mesh_scene()};
  BeamPattern pattern;
  Fixture() {
    std::vector<double> az, el;
    for (int k = 0; k < kSide; ++k) {
      az.push_back(-60.0 + 120.0 * k / (kSide - 1));
      el.push_back(-40.0 + 80.0 * k / (kSide - 1));
    }
    pattern = spherical_pattern({az, el, 10});
  }
};

Fixture& fixture() {
  static Fixture f;
  return f;
}

device::DeviceConfig config_with(int rays) {
  device::DeviceConfig c;
  c.scan.rays_per_beam = rays;
  return c;
}

void BM_EmbreeBare(benchmark::State& state) {
  const int rays = static_cast<int>(state.range(0));
  tbb::global_control limit(tbb::global_control::max_allowed_parallelism,
                            static_cast<std::size_t>(state.range(1)));
  auto& f = fixture();
  const Footprint fp(config_with(rays));
  const RTCScene scene = f.caster.embree_scene();
  for (auto _ : state) {
    tbb::parallel_for(
        tbb::blocked_range<std::size_t>(0, f.pattern.beams.size(), 256), [&](const auto& block) {
          RTCIntersectContext context;
          rtcInitIntersectContext(&context);
          float sum = 0;
          for (std::size_t i = block.begin(); i != block.end(); ++i) {
            const Vec3& axis = f.pattern.beams[i].direction;
            Vec3 e1, e2;
            plane_axes(axis, e1, e2);
            // The same rays as Footprint::trace (the axis alone for one ray).
            for (const auto& s : fp.sub_rays()) {
              const Vec3 o = (fp.exit_radius_m() * s.x) * e1 + (fp.exit_radius_m() * s.y) * e2;
              const Vec3 d = rays == 1
                                 ? axis
                                 : normalized(axis + std::tan(fp.half_divergence_rad() * s.x) * e1 +
                                              std::tan(fp.half_divergence_rad() * s.y) * e2);
              RTCRayHit rh = embree_ray(o, d);
              rtcIntersect1(scene, &context, &rh);
              sum += rh.ray.tfar;
            }
          }
          benchmark::DoNotOptimize(sum);
        });
  }
  state.SetItemsProcessed(state.iterations() * static_cast<std::int64_t>(f.pattern.beams.size()));
}

// Every beam of the fixture's pattern through `per_beam(i, footprint_result)`,
// in parallel blocks as the scanner runs them; the values are summed so that
// the work is not optimized away.
template <class PerBeam>
void over_beams(benchmark::State& state, PerBeam per_beam) {
  const auto& f = fixture();
  for (auto _ : state) {
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, f.pattern.beams.size(), 256),
                      [&](const auto& block) {
                        Footprint::Result r;
                        double sum = 0;
                        for (std::size_t i = block.begin(); i != block.end(); ++i)
                          sum += per_beam(i, r);
                        benchmark::DoNotOptimize(sum);
                      });
  }
  state.SetItemsProcessed(state.iterations() * static_cast<std::int64_t>(f.pattern.beams.size()));
}

// The rays Footprint::trace casts for beam i: its axis, then (R > 1) the R sub-rays.
void footprint_rays(const Footprint& fp, const Beam& beam, std::vector<Vec3>& origins,
                    std::vector<Vec3>& directions) {
  origins.assign(1, beam.origin_m);
  directions.assign(1, beam.direction);
  if (fp.sub_rays().size() == 1) return;
  Vec3 e1, e2;
  plane_axes(beam.direction, e1, e2);
  for (const auto& s : fp.sub_rays()) {
    origins.push_back(beam.origin_m + (fp.exit_radius_m() * s.x) * e1 +
                      (fp.exit_radius_m() * s.y) * e2);
    directions.push_back(normalized(beam.direction + std::tan(fp.half_divergence_rad() * s.x) * e1 +
                                    std::tan(fp.half_divergence_rad() * s.y) * e2));
  }
}

void cast_rays(benchmark::State& state, bool packets) {
  tbb::global_control limit(tbb::global_control::max_allowed_parallelism,
                            static_cast<std::size_t>(state.range(1)));
  auto& f = fixture();
  const Footprint fp(config_with(static_cast<int>(state.range(0))));
  over_beams(state, [&](std::size_t i, Footprint::Result&) {
    thread_local std::vector<Vec3> origins, directions;
    thread_local std::vector<Hit> hits;
    footprint_rays(fp, f.pattern.beams[i], origins, directions);
    hits.resize(origins.size());
    if (packets) {
      f.caster.cast(origins, directions, hits);
    } else {
      for (std::size_t k = 0; k < hits.size(); ++k)
        hits[k] = f.caster.cast(origins[k], directions[k]);
    }
    double sum = 0;
    for (const auto& h : hits) sum += h.hit() ? h.distance_m : 0.0;
    return sum;
  });
}

void BM_EmbreePacket(benchmark::State& state) {
  tbb::global_control limit(tbb::global_control::max_allowed_parallelism,
                            static_cast<std::size_t>(state.range(1)));
  auto& f = fixture();
  const Footprint fp(config_with(static_cast<int>(state.range(0))));
  const RTCScene scene = f.caster.embree_scene();
  over_beams(state, [&](std::size_t i, Footprint::Result&) {
    thread_local std::vector<Vec3> origins, directions;
    footprint_rays(fp, f.pattern.beams[i], origins, directions);
    RTCIntersectContext context;
    rtcInitIntersectContext(&context);
    double sum = 0;
    std::size_t first = 0;
    for (; origins.size() - first >= 16; first += 16) {
      alignas(64) int valid[16];
      alignas(64) RTCRayHit16 rh{};
      for (int k = 0; k < 16; ++k) {
        const auto& o = origins[first + static_cast<std::size_t>(k)];
        const auto& d = directions[first + static_cast<std::size_t>(k)];
        valid[k] = -1;
        rh.ray.org_x[k] = static_cast<float>(o[0]), rh.ray.org_y[k] = static_cast<float>(o[1]);
        rh.ray.org_z[k] = static_cast<float>(o[2]);
        rh.ray.dir_x[k] = static_cast<float>(d[0]), rh.ray.dir_y[k] = static_cast<float>(d[1]);
        rh.ray.dir_z[k] = static_cast<float>(d[2]);
        rh.ray.tfar[k] = std::numeric_limits<float>::infinity();
        rh.ray.mask[k] = 0xFFFFFFFFu;
        rh.hit.geomID[k] = RTC_INVALID_GEOMETRY_ID;
      }
      rtcIntersect16(valid, scene, &context, &rh);
      for (int k = 0; k < 16; ++k) sum += rh.ray.tfar[k];
    }
    for (; first < origins.size(); ++first) {
      RTCRayHit rh = embree_ray(origins[first], directions[first]);
      rtcIntersect1(scene, &context, &rh);
      sum += rh.ray.tfar;
    }
    return sum;
  });
}

void BM_CastSingle(benchmark::State& state) {
  cast_rays(state, false);
}

void BM_CastPacket(benchmark::State& state) {
  cast_rays(state, true);
}

void BM_Footprint(benchmark::State& state) {
  tbb::global_control limit(tbb::global_control::max_allowed_parallelism,
                            static_cast<std::size_t>(state.range(1)));
  auto& f = fixture();
  const Footprint fp(config_with(static_cast<int>(state.range(0))));
  over_beams(state, [&](std::size_t i, Footprint::Result& r) {
    fp.trace(f.caster, f.pattern.beams[i].origin_m, f.pattern.beams[i].direction, r);
    return r.true_range_m + static_cast<double>(r.target.surfaces.size());
  });
}

void BM_Measured(benchmark::State& state) {
  tbb::global_control limit(tbb::global_control::max_allowed_parallelism,
                            static_cast<std::size_t>(state.range(1)));
  auto& f = fixture();
  const auto config = config_with(static_cast<int>(state.range(0)));
  const Footprint fp(config);
  const device::VirtualRangefinder dev(config, device::SimulationMode::kAnalytic);
  // As the scanner: a block's footprints, then their measurements in one call.
  struct Block {
    std::vector<device::Target> targets;
    std::vector<device::Conditions> conditions;
    std::vector<ranging::RawMeasurement> raw;
  };
  for (auto _ : state) {
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, f.pattern.beams.size(), 256),
                      [&](const auto& block) {
                        thread_local Block b;
                        const std::size_t n = block.size();
                        b.targets.resize(std::max(b.targets.size(), n));
                        b.conditions.resize(std::max(b.conditions.size(), n));
                        b.raw.resize(std::max(b.raw.size(), n));
                        Footprint::Result r;
                        for (std::size_t k = 0; k < n; ++k) {
                          const auto& beam = f.pattern.beams[block.begin() + k];
                          fp.trace(f.caster, beam.origin_m, beam.direction, r);
                          std::swap(b.targets[k].surfaces, r.target.surfaces);
                        }
                        dev.measure({b.targets.data(), n}, {b.conditions.data(), n}, 1,
                                    block.begin(), 1, {b.raw.data(), n});
                        double sum = 0;
                        for (std::size_t k = 0; k < n; ++k) sum += b.raw[k].tof_ns;
                        benchmark::DoNotOptimize(sum);
                      });
  }
  state.SetItemsProcessed(state.iterations() * static_cast<std::int64_t>(f.pattern.beams.size()));
}

void BM_Scan(benchmark::State& state) {
  const int rays = static_cast<int>(state.range(0));
  tbb::global_control limit(tbb::global_control::max_allowed_parallelism,
                            static_cast<std::size_t>(state.range(1)));
  auto& f = fixture();
  const auto config = config_with(rays);
  const device::VirtualRangefinder dev(config, device::SimulationMode::kAnalytic);
  ScanOptions o;
  o.shots = 1;
  for (auto _ : state) {
    const auto result = run_scan(f.caster, Footprint(config), dev, f.pattern, o);
    benchmark::DoNotOptimize(result.beams.data());
  }
  state.SetItemsProcessed(state.iterations() * static_cast<std::int64_t>(f.pattern.beams.size()));
}

void BM_ScanFrames(benchmark::State& state) {
  tbb::global_control limit(tbb::global_control::max_allowed_parallelism,
                            static_cast<std::size_t>(state.range(1)));
  auto& f = fixture();
  const auto config = config_with(static_cast<int>(state.range(0)));
  const device::VirtualRangefinder dev(config, device::SimulationMode::kAnalytic);
  const Footprint fp(config);
  ScanOptions o;
  o.shots = 1;
  ScanResult frame;
  run_scan(f.caster, fp, dev, f.pattern, o, frame);  // the storage, once
  for (auto _ : state) {
    run_scan(f.caster, fp, dev, f.pattern, o, frame);
    benchmark::DoNotOptimize(frame.beams.data());
  }
  state.SetItemsProcessed(state.iterations() * static_cast<std::int64_t>(f.pattern.beams.size()));
}

void BM_ResultBytes(benchmark::State& state) {
  const bool fresh = state.range(0) != 0;
  tbb::global_control limit(tbb::global_control::max_allowed_parallelism,
                            static_cast<std::size_t>(state.range(1)));
  const std::size_t beams = static_cast<std::size_t>(kSide) * kSide;
  constexpr std::size_t kBytes = sizeof(BeamResult);
  const auto source = std::make_unique<std::byte[]>(beams * kBytes);  // zeroed: its pages are in
  std::unique_ptr<std::byte[]> target;
  if (!fresh) target = std::make_unique<std::byte[]>(beams * kBytes);  // one buffer, mapped once
  for (auto _ : state) {
    if (fresh) target = std::make_unique_for_overwrite<std::byte[]>(beams * kBytes);
    std::byte* to = target.get();
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, beams, 256), [&](const auto& block) {
      std::memcpy(to + block.begin() * kBytes, source.get() + block.begin() * kBytes,
                  block.size() * kBytes);
    });
    benchmark::DoNotOptimize(to);
    benchmark::ClobberMemory();
  }
  state.SetItemsProcessed(state.iterations() * static_cast<std::int64_t>(beams));
  state.SetBytesProcessed(state.iterations() * static_cast<std::int64_t>(beams * kBytes));
}

}  // namespace

void rays_and_threads(benchmark::internal::Benchmark* b) {
  for (int rays : {1, 16})
    for (int threads : {1, 2}) b->Args({rays, threads});
  b->Unit(benchmark::kMillisecond)->UseRealTime()->MinTime(1.0);
}

BENCHMARK(BM_EmbreeBare)->Apply(rays_and_threads);
BENCHMARK(BM_EmbreePacket)->Apply(rays_and_threads);
BENCHMARK(BM_CastSingle)->Apply(rays_and_threads);
BENCHMARK(BM_CastPacket)->Apply(rays_and_threads);
BENCHMARK(BM_Footprint)->Apply(rays_and_threads);
BENCHMARK(BM_Measured)->Apply(rays_and_threads);
BENCHMARK(BM_Scan)->Apply(rays_and_threads);
BENCHMARK(BM_ScanFrames)->Apply(rays_and_threads);
BENCHMARK(BM_ResultBytes)
    ->ArgsProduct({{1, 0}, {1, 2}})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime()
    ->MinTime(1.0);
