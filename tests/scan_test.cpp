// Scanning against oracles: closed-form intersections of every primitive,
// the geometric split of a footprint across a step edge, the cos(phi) law and
// echo stretching of a tilted plate, the stripe chart's intensity order,
// pattern timing, line resampling, and thread-count independence.
#include <gtest/gtest.h>
#include <tbb/task_arena.h>

#include <cmath>
#include <cstring>
#include <numbers>
#include <vector>

#include "tofkit/device/virtual_rangefinder.hpp"
#include "tofkit/experiments/scan_sequence.hpp"
#include "tofkit/scan/footprint.hpp"
#include "tofkit/scan/pattern.hpp"
#include "tofkit/scan/ray_caster.hpp"
#include "tofkit/scan/scanner.hpp"

using namespace tofkit;
using namespace tofkit::scan;

namespace {

using LD = long double;

Primitive plane(Vec3 c, Vec3 n, double w, double h, double rho) {
  Primitive p;
  p.kind = PrimitiveKind::kPlane;
  p.center_m = c;
  p.normal = n;
  p.size_m = {w, h};
  p.reflectance.value = rho;
  p.name = "plane";
  return p;
}

Scene single(Primitive p) {
  Scene s;
  s.primitives.push_back(std::move(p));
  return s;
}

// The same bytes (NaNs included).
template <class T>
bool same(const T& x, const T& y) {
  return std::memcmp(&x, &y, sizeof x) == 0;
}

// Two results of beam i with the same beam (world frame) and footprint.
void expect_same_trace(const BeamResult& a, const BeamResult& b, std::size_t i) {
  EXPECT_TRUE(same(a.beam.time_s, b.beam.time_s) && same(a.beam.origin_m, b.beam.origin_m) &&
              same(a.beam.direction, b.beam.direction) && a.beam.row == b.beam.row &&
              a.beam.column == b.beam.column)
      << i;
  EXPECT_TRUE(same(a.true_range_m, b.true_range_m) && a.surfaces == b.surfaces &&
              same(a.reflectance, b.reflectance) && same(a.cos_incidence, b.cos_incidence))
      << i;
}

// Deterministic ray origins and directions that are not float-representable.
Vec3 origin(int i) {
  return {0.1 + 0.0123456789 * i, -0.03 + 0.00731 * i, 0.017 * std::sin(i)};
}

}  // namespace

TEST(ScanRayCaster, SphereMatchesClosedFormToAMicrometre) {
  Primitive p;
  p.kind = PrimitiveKind::kSphere;
  p.center_m = {12.3456789, 0.4321, -0.2468};
  p.radius_m = 1.23456789;
  p.name = "sphere";
  const RayCaster caster(single(p));
  for (int i = 0; i < 50; ++i) {
    const Vec3 o = origin(i);
    const Vec3 target = p.center_m + Vec3{-0.5, 0.6 * std::sin(0.3 * i), 0.6 * std::cos(0.7 * i)};
    const Vec3 d = normalized(target - o);
    // t = d.(c-o) - sqrt(r^2 - |(c-o) - (d.(c-o)) d|^2), in long double.
    LD co[3], dd[3], b = 0;
    for (int k = 0; k < 3; ++k)
      co[k] = LD(p.center_m[k]) - LD(o[k]), dd[k] = d[k], b += dd[k] * co[k];
    LD perp2 = 0;
    for (int k = 0; k < 3; ++k) perp2 += (co[k] - b * dd[k]) * (co[k] - b * dd[k]);
    const LD expected = b - std::sqrt(LD(p.radius_m) * LD(p.radius_m) - perp2);
    const Hit hit = caster.cast(o, d);
    ASSERT_TRUE(hit.hit()) << i;
    EXPECT_NEAR(hit.distance_m, static_cast<double>(expected), 1e-6) << i;
  }
}

TEST(ScanRayCaster, TiltedRectangleMatchesClosedForm) {
  const Vec3 n = normalized({-1, 0.3, 0.2});
  const Primitive p = plane({9.87654321, 0.1, 0.05}, n, 4, 3, 0.5);
  const RayCaster caster(single(p));
  for (int i = 0; i < 50; ++i) {
    const Vec3 o = origin(i);
    const Vec3 d = normalized(Vec3{1, 0.05 * std::sin(i), 0.04 * std::cos(i)});
    LD num = 0, den = 0;
    for (int k = 0; k < 3; ++k) {
      num += (LD(p.center_m[k]) - LD(o[k])) * LD(n[k]);
      den += LD(d[k]) * LD(n[k]);
    }
    const Hit hit = caster.cast(o, d);
    ASSERT_TRUE(hit.hit());
    EXPECT_NEAR(hit.distance_m, static_cast<double>(num / den), 1e-6);
    EXPECT_NEAR(std::abs(dot(hit.normal, n)), 1.0, 1e-12);
  }
  // Outside the rectangle: no hit (REP-117: nothing invented).
  EXPECT_FALSE(caster.cast({0, 0, 0}, normalized({1, 0.5, 0})).hit());
}

TEST(ScanRayCaster, BoxAndCubeMeshMatchClosedForm) {
  Primitive box;
  box.kind = PrimitiveKind::kBox;
  box.min_m = {7.1234567, -1, -1};
  box.max_m = {8.7654321, 1, 1};
  box.name = "box";
  // The same cube as 12 triangles.
  Primitive mesh;
  mesh.kind = PrimitiveKind::kMesh;
  mesh.name = "mesh";
  for (int k = 0; k < 8; ++k) {
    mesh.vertices.push_back(
        {k & 1 ? box.max_m[0] : box.min_m[0], k & 2 ? 1.0 : -1.0, k & 4 ? 1.0 : -1.0});
  }
  const std::uint32_t faces[6][4] = {{0, 2, 6, 4}, {1, 5, 7, 3}, {0, 4, 5, 1},
                                     {2, 3, 7, 6}, {0, 1, 3, 2}, {4, 6, 7, 5}};
  for (const auto& f : faces) {
    mesh.triangles.push_back({f[0], f[1], f[2]});
    mesh.triangles.push_back({f[0], f[2], f[3]});
  }
  const RayCaster box_caster(single(box)), mesh_caster(single(mesh));
  for (int i = 0; i < 50; ++i) {
    const Vec3 o = origin(i);
    const Vec3 d = normalized(Vec3{1, 0.08 * std::sin(i), 0.08 * std::cos(i)});
    const double expected = static_cast<double>((LD(box.min_m[0]) - LD(o[0])) / LD(d[0]));
    const Hit a = box_caster.cast(o, d), b = mesh_caster.cast(o, d);
    ASSERT_TRUE(a.hit() && b.hit());
    EXPECT_NEAR(a.distance_m, expected, 1e-6);
    EXPECT_NEAR(b.distance_m, expected, 1e-6);
    EXPECT_NEAR(a.normal[0], -1.0, 1e-12);
  }
}

TEST(ScanRayCaster, PacketsGiveTheHitsOfSingleCasts) {
  // A scene of every kind: a ground of 2 x 24 x 24 triangles sharing edges
  // and vertices, a box, a sphere, a capped cylinder, a plane with stripes.
  Scene scene;
  Primitive ground;
  ground.kind = PrimitiveKind::kMesh;
  ground.name = "ground";
  ground.reflectance.value = 0.3;
  constexpr int kGrid = 25;
  for (int i = 0; i < kGrid; ++i)
    for (int j = 0; j < kGrid; ++j)
      ground.vertices.push_back({-2.0 + 0.5 * i, -6.0 + 0.5 * j, -1.7 + 0.01 * std::sin(i * j)});
  for (std::uint32_t i = 0; i + 1 < kGrid; ++i) {
    for (std::uint32_t j = 0; j + 1 < kGrid; ++j) {
      const std::uint32_t a = i * kGrid + j, b = a + 1, c = a + kGrid, d = c + 1;
      ground.triangles.push_back({a, c, d});
      ground.triangles.push_back({a, d, b});
    }
  }
  scene.primitives.push_back(ground);
  Primitive box;
  box.kind = PrimitiveKind::kBox;
  box.name = "box";
  box.min_m = {4.0, -1.0, -1.7};
  box.max_m = {5.0, 0.5, -0.2};
  scene.primitives.push_back(box);
  Primitive sphere;
  sphere.kind = PrimitiveKind::kSphere;
  sphere.name = "sphere";
  sphere.center_m = {6.0, 2.0, -0.5};
  sphere.radius_m = 0.7;
  scene.primitives.push_back(sphere);
  Primitive cylinder;
  cylinder.kind = PrimitiveKind::kCylinder;
  cylinder.name = "cylinder";
  cylinder.base_m = {3.0, 3.0, -1.7};
  cylinder.radius_m = 0.4;
  cylinder.height_m = 1.5;
  scene.primitives.push_back(cylinder);
  Primitive wall = plane({9.0, 0, 0}, {-1, 0, 0}, 12.0, 4.0, 0.5);
  wall.reflectance.kind = Reflectance::Kind::kStripes;
  wall.reflectance.values = {0.1, 0.9};
  wall.reflectance.cell_m = 0.3;
  scene.primitives.push_back(wall);
  ASSERT_TRUE(scene.validate().empty());
  const RayCaster caster(scene);

  // Rays from near the sensor to every vertex, every edge's midpoint and
  // every triangle's centroid of the ground (ties between triangles), to the
  // analytic primitives' edges, and beams' footprints (20 coherent rays).
  std::vector<Vec3> origins, directions;
  const auto aim = [&](const Vec3& o, const Vec3& at) {
    origins.push_back(o);
    directions.push_back(normalized(at - o));
  };
  for (std::size_t k = 0; k < ground.vertices.size(); ++k)
    aim(origin(int(k % 7)), ground.vertices[k]);
  for (const auto& t : ground.triangles) {
    const Vec3 &a = ground.vertices[t[0]], &b = ground.vertices[t[1]], &c = ground.vertices[t[2]];
    aim({0, 0, 0}, 0.5 * (a + b));
    aim({0, 0, 0}, 0.5 * (b + c));
    aim({0, 0, 0}, 0.5 * (c + a));
    aim({0, 0.01, 0}, (1.0 / 3.0) * (a + b + c));
  }
  for (int i = 0; i < 400; ++i) {
    const double y = -1.0 + 1.5 * i / 399.0;
    aim({0, 0, 0}, {4.0, y, -0.2});  // the box's top edge
    aim({0, 0, 0}, {4.0, y, -1.7});  // where the box meets the ground
    aim({0, 0, 0}, {6.0, 2.0 + 0.7 * std::cos(i), -0.5 + 0.7 * std::sin(i)});  // sphere's rim
  }
  const Footprint footprint(3e-3, 20e-3, 19);
  for (int i = 0; i < 300; ++i) {
    const double az = -0.7 + 1.4 * i / 299.0, el = -0.35 + 0.5 * std::sin(3.0 * i);
    const Vec3 axis{std::cos(el) * std::cos(az), std::cos(el) * std::sin(az), std::sin(el)};
    Vec3 e1, e2;
    plane_axes(axis, e1, e2);
    origins.push_back({0, 0, 0});
    directions.push_back(axis);
    for (const auto& s : footprint.sub_rays()) {
      origins.push_back((footprint.exit_radius_m() * s.x) * e1 +
                        (footprint.exit_radius_m() * s.y) * e2);
      directions.push_back(normalized(axis + std::tan(footprint.half_divergence_rad() * s.x) * e1 +
                                      std::tan(footprint.half_divergence_rad() * s.y) * e2));
    }
  }
  std::vector<Hit> single(origins.size());
  std::size_t hits = 0;
  for (std::size_t i = 0; i < origins.size(); ++i) {
    single[i] = caster.cast(origins[i], directions[i]);
    hits += single[i].hit() ? 1 : 0;
  }
  EXPECT_GT(hits, origins.size() * 3 / 4);
  EXPECT_LT(hits, origins.size());  // some miss
  // In batches of every size from 1 to 40 (packets of 16, 8, 4 and single rays).
  for (std::size_t size = 1; size <= 40; ++size) {
    std::vector<Hit> packed(origins.size());
    for (std::size_t first = 0; first < origins.size(); first += size) {
      const std::size_t n = std::min(size, origins.size() - first);
      caster.cast(std::span(origins).subspan(first, n), std::span(directions).subspan(first, n),
                  std::span(packed).subspan(first, n));
    }
    std::size_t differ = 0;
    for (std::size_t i = 0; i < origins.size(); ++i) {
      const Hit &a = single[i], &b = packed[i];
      if (!(same(a.distance_m, b.distance_m) && same(a.normal, b.normal) &&
            same(a.reflectance, b.reflectance) && a.primitive == b.primitive && a.part == b.part)) {
        if (++differ < 5)
          ADD_FAILURE() << "batch " << size << ", ray " << i << ": single " << a.distance_m
                        << " (primitive " << a.primitive << " part " << a.part << "), packet "
                        << b.distance_m << " (primitive " << b.primitive << " part " << b.part
                        << ")";
      }
    }
    EXPECT_EQ(differ, 0u) << "batch " << size;
  }
  std::vector<Hit> wrong(3);
  EXPECT_THROW(caster.cast(std::span(origins).first(2), std::span(directions).first(2), wrong),
               std::invalid_argument);
}

TEST(ScanRayCaster, CylinderSideAndCapMatchClosedForm) {
  Primitive c;
  c.kind = PrimitiveKind::kCylinder;
  c.base_m = {6.54321, 0.0123, -0.5};
  c.axis = {0, 0, 1};
  c.radius_m = 0.4321;
  c.height_m = 1.0;
  c.name = "cylinder";
  const RayCaster caster(single(c));
  for (int i = 0; i < 50; ++i) {
    const Vec3 o{0.01 * i, 0.002 * i, 0.01 * std::sin(i)};
    const Vec3 d = normalized(Vec3{1, 0.03 * std::sin(0.5 * i), 0.02 * std::cos(i)});
    // Horizontal circle in x-y: |o + t d - b|_xy = r.
    const LD ox = LD(o[0]) - c.base_m[0], oy = LD(o[1]) - c.base_m[1];
    const LD a = LD(d[0]) * d[0] + LD(d[1]) * d[1], b = ox * d[0] + oy * d[1];
    const LD cc = ox * ox + oy * oy - LD(c.radius_m) * c.radius_m;
    const LD t = (-b - std::sqrt(b * b - a * cc)) / a;
    const Hit hit = caster.cast(o, d);
    ASSERT_TRUE(hit.hit());
    EXPECT_NEAR(hit.distance_m, static_cast<double>(t), 1e-6);
    EXPECT_EQ(hit.part, 0u);
  }
  // Looking down on the top cap.
  const Hit top = caster.cast({6.6, 0.0, 3.0}, {0, 0, -1});
  ASSERT_TRUE(top.hit());
  EXPECT_NEAR(top.distance_m, 2.5, 1e-9);
  EXPECT_EQ(top.part, 2u);
}

TEST(ScanScene, DegeneratePrimitivesAreRefusedByName) {
  Scene s;
  Primitive box;
  box.kind = PrimitiveKind::kBox;
  box.min_m = {1, 0, 0};
  box.max_m = {1, 1, 1};
  box.name = "surface[0]";
  s.primitives.push_back(box);
  const auto problems = s.validate();
  ASSERT_EQ(problems.size(), 1u);
  EXPECT_NE(problems[0].find("surface[0]"), std::string::npos);
  EXPECT_THROW(RayCaster{s}, std::invalid_argument);
}

TEST(ScanFootprint, StepEdgeSplitsByTheGeometricFraction) {
  // Near plate covers y < 0 at 2 m, far plate behind at 2.5 m.
  Scene s;
  s.primitives.push_back(plane({2.0, 0.5, 0}, {-1, 0, 0}, 1.0, 1.0, 0.3));
  s.primitives.push_back(plane({2.5, 0, 0}, {-1, 0, 0}, 4.0, 4.0, 0.6));
  const RayCaster caster(s);
  const double exit_d = 3e-3, div = 3e-3;
  const Footprint fp(exit_d, div, 1024);
  const double r = 0.5 * (exit_d + 2.0 * div);  // footprint radius at the edge
  for (const double offset : {-0.8, -0.3, 0.0, 0.4, 0.9}) {
    Footprint::Result res;
    fp.trace(caster, {0, offset * r, 0}, {1, 0, 0}, res);
    // Share of the disk at y > 0 (on the near plate): circular segment.
    const double h = -offset;
    const double expected = (std::acos(h) - h * std::sqrt(1 - h * h)) / std::numbers::pi;
    ASSERT_EQ(res.target.surfaces.size(), 2u) << offset;
    double near = 0, total = 0;
    for (const auto& surf : res.target.surfaces) {
      total += surf.fraction;
      if (surf.distance_m < 2.2) {
        near = surf.fraction;
        EXPECT_NEAR(surf.distance_m, 2.0, 1e-9);
        EXPECT_EQ(surf.reflectance, 0.3);
      } else {
        EXPECT_NEAR(surf.distance_m, 2.5, 1e-9);
      }
    }
    EXPECT_NEAR(total, 1.0, 1e-12);
    EXPECT_NEAR(1.0 - near, 1.0 - expected, 0.01) << offset;
  }
}

// Mesh triangles are one surface unless a crease sharper than
// scan.crease_angle_deg (30 deg) or a step deeper than the footprint's
// diameter times its sine parts them. The beam (footprint 9 mm at 2 m) hits
// the shared edge of two triangles at y = 0, each a half of the disk.
TEST(ScanFootprint, MeshTrianglesSplitOnlyAtCreasesAndSteps) {
  const double exit_d = 3e-3, div = 3e-3;
  const Footprint fp(exit_d, div, 1024);
  // Two triangles meeting along the z axis at x = 2: the half at y > 0 is
  // turned by `crease_deg` about that edge and moved back by `step_m`.
  auto split_count = [&](double crease_deg, double step_m) {
    Primitive m;
    m.kind = PrimitiveKind::kMesh;
    m.name = "mesh";
    m.reflectance.value = 0.4;
    const double a = crease_deg * std::numbers::pi / 180.0;
    m.vertices = {{2.0, -1.0, -1.0},        {2.0, 0.0, -1.0},
                  {2.0, 0.0, 1.0},          {2.0 + step_m, 0.0, -1.0},
                  {2.0 + step_m, 0.0, 1.0}, {2.0 + step_m + std::sin(a), std::cos(a), 0.0}};
    m.triangles = {{0, 1, 2}, {3, 4, 5}};
    const RayCaster caster(single(m));
    Footprint::Result res;
    fp.trace(caster, {0, 0, 0}, {1, 0, 0}, res);
    double total = 0;
    for (const auto& surf : res.target.surfaces) total += surf.fraction;
    EXPECT_NEAR(total, 1.0, 1e-9) << crease_deg << " " << step_m;
    return res.target.surfaces.size();
  };
  EXPECT_EQ(split_count(0.0, 0.0), 1u);    // coplanar: one surface, whatever the triangles
  EXPECT_EQ(split_count(10.0, 0.0), 1u);   // a shallow crease of a smooth mesh
  EXPECT_EQ(split_count(45.0, 0.0), 2u);   // a roof-like crease
  EXPECT_EQ(split_count(0.0, 0.001), 1u);  // 1 mm step: within 9 mm x sin 30 deg
  EXPECT_EQ(split_count(0.0, 0.02), 2u);   // 20 mm step: a mixed pixel
  // A sharper crease setting keeps the shallow one apart too.
  const Footprint strict(exit_d, div, 1024, 5.0);
  Primitive m;
  m.kind = PrimitiveKind::kMesh;
  m.name = "mesh";
  m.reflectance.value = 0.4;
  const double a = 10.0 * std::numbers::pi / 180.0;
  m.vertices = {
      {2.0, -1.0, -1.0}, {2.0, 0.0, -1.0}, {2.0, 0.0, 1.0}, {2.0 + std::sin(a), std::cos(a), 0.0}};
  m.triangles = {{0, 1, 2}, {1, 2, 3}};
  const RayCaster caster(single(m));
  Footprint::Result res;
  strict.trace(caster, {0, 0, 0}, {1, 0, 0}, res);
  EXPECT_EQ(res.target.surfaces.size(), 2u);
}

TEST(ScanFootprint, TiltedPlateGivesCosineAmplitudeAndLongerEcho) {
  device::DeviceConfig config;
  config.scan.rays_per_beam = 64;
  const device::VirtualRangefinder dev(config);
  const Footprint fp(config);
  Footprint::Result flat;
  const double rho = 0.05, R = 3.0;
  const RayCaster flat_caster(single(plane({R, 0, 0}, {-1, 0, 0}, 2, 2, rho)));
  fp.trace(flat_caster, {0, 0, 0}, {1, 0, 0}, flat);
  const auto echo0 = dev.echo(flat.target, {});
  ASSERT_TRUE(echo0.detected && !echo0.saturated);
  for (const double phi : {20.0, 40.0, 60.0}) {
    const double a = phi * std::numbers::pi / 180;
    const RayCaster caster(single(plane({R, 0, 0}, {-std::cos(a), std::sin(a), 0}, 4, 2, rho)));
    Footprint::Result tilted;
    fp.trace(caster, {0, 0, 0}, {1, 0, 0}, tilted);
    ASSERT_EQ(tilted.target.surfaces.size(), 1u);
    EXPECT_NEAR(device::incidence_angle_deg(tilted.target.surfaces[0].cos_incidence), phi, 1e-6);
    EXPECT_NEAR(tilted.target.surfaces[0].distance_m, R, 1e-4);
    const auto echo = dev.echo(tilted.target, {});
    ASSERT_TRUE(echo.detected) << phi << " " << echo.peak_v << " " << echo0.peak_v;
    EXPECT_NEAR(echo.peak_v / echo0.peak_v, std::cos(a), 0.05 * std::cos(a)) << phi;
    const double width0 = echo0.fall_crossing_ns - echo0.rise_crossing_ns;
    const double width = echo.fall_crossing_ns - echo.rise_crossing_ns;
    // Longer echo than the same power would give at normal incidence: the
    // incidence angle stretches the pulse across the footprint's depth.
    device::Target same_power = flat.target;
    same_power.surfaces[0].reflectance = rho * echo.peak_v / echo0.peak_v;
    const auto ref = dev.echo(same_power, {});
    EXPECT_GT(width, ref.fall_crossing_ns - ref.rise_crossing_ns) << phi;
    (void)width0;
  }
}

TEST(ScanPatterns, TimeStampsIncreaseAndLinesVaryInSampleCount) {
  LineOptions lo;
  for (int k = 0; k < 20; ++k) lo.y_m.push_back(0.001 * k);
  lo.z_m = {0, 0.001, 0.002, 0.003, 0.004, 0.005};
  lo.stage_speed_m_per_s = 0.0113;
  lo.turnaround_s = 0.0137;
  const auto p = line_pattern(lo, 1e-3);
  std::vector<int> counts(lo.z_m.size());
  for (std::size_t i = 0; i < p.beams.size(); ++i) {
    if (i > 0) EXPECT_GT(p.beams[i].time_s, p.beams[i - 1].time_s);
    counts[static_cast<std::size_t>(p.beams[i].row)]++;
  }
  // 0.02 m at 11.3 mm/s (1.7699 s) sampled at 1 kHz: 1768 or 1769 whole samples.
  bool varies = false;
  for (const int c : counts) {
    EXPECT_GE(c, 1768);
    EXPECT_LE(c, 1769);
    varies = varies || c != counts[0];
  }
  EXPECT_TRUE(varies);

  SphericalOptions so{{-10, 0, 10}, {-5, 5}, 10};
  const auto s = spherical_pattern(so);
  ASSERT_EQ(s.beams.size(), 6u);
  for (std::size_t i = 1; i < s.beams.size(); ++i)
    EXPECT_GT(s.beams[i].time_s, s.beams[i - 1].time_s);
  // Row 0 column 0 is the top left: largest elevation and azimuth.
  for (const auto& b : s.beams) {
    if (b.row == 0 && b.column == 0) {
      EXPECT_NEAR(b.direction[1],
                  std::cos(5 * std::numbers::pi / 180) * std::sin(10 * std::numbers::pi / 180),
                  1e-12);
      EXPECT_GT(b.direction[2], 0);
    }
  }
}

TEST(ScanImages, LineResamplingAveragesByOverlapAndStripeChartOrdersIntensity) {
  // A stripe chart at 1.5 m: stripes 10 mm wide, six levels in shuffled order.
  const std::vector<double> levels = {0.45, 0.05, 0.85, 0.25, 0.65, 0.15};
  Primitive chart = plane({1.5, 0, 0}, {-1, 0, 0}, 0.06, 0.02, 0.5);
  chart.reflectance.kind = Reflectance::Kind::kStripes;
  chart.reflectance.values = levels;
  chart.reflectance.cell_m = 0.01;
  const RayCaster caster(single(chart));
  device::DeviceConfig config;
  config.measurement.shots = 10;
  config.discriminator.threshold_v = 0.02;
  const device::VirtualRangefinder dev(config);
  LineOptions lo;
  for (int k = 0; k < 60; ++k) lo.y_m.push_back(0.0295 - 0.001 * k);  // 1 mm columns
  lo.z_m = {0.0};
  lo.stage_speed_m_per_s = 0.37;  // 0.37 mm per 1 ms sample: 2.7 samples per column
  const double period = config.measurement.shots / config.link.laser.repetition_hz;
  const auto pattern = line_pattern(lo, period);
  ScanOptions options;
  const auto result = run_scan(caster, Footprint(config), dev, pattern, options);
  const auto images = make_images(result);
  ASSERT_EQ(images.range.columns, 60);
  // Truth resampled: every column on the plate at 1.5 m.
  for (int c = 0; c < 60; ++c) EXPECT_NEAR(images.truth.at(0, c), 1.5, 1e-9);
  // Stripe k covers columns 10k .. 10k + 9 from the left (+y): u grows towards
  // -y... stripe index from the plane's u axis; compare inner columns only.
  std::vector<double> mean(6, 0);
  std::vector<int> count(6, 0);
  Vec3 u, v;
  plane_axes(chart.normal, u, v);
  for (int c = 0; c < 60; ++c) {
    const double y = lo.y_m[static_cast<std::size_t>(c)];
    const double uu = y * u[1] + 0.03;
    const int stripe = static_cast<int>(std::floor(uu / 0.01));
    const double inside = uu / 0.01 - stripe;
    if (inside < 0.2 || inside > 0.8) continue;
    mean[static_cast<std::size_t>(stripe)] += images.intensity.at(0, c);
    ++count[static_cast<std::size_t>(stripe)];
  }
  for (std::size_t k = 0; k < 6; ++k) {
    ASSERT_GT(count[k], 0) << k;
    mean[k] /= count[k];
  }
  // The amplitude reading saturates at the peak detector's clip level: stripes
  // bright enough to clip read alike, so the order is strict only below it.
  const double clip = config.link.receiver.amplitude_clip_v;
  for (std::size_t a = 0; a < 6; ++a) {
    for (std::size_t b = 0; b < 6; ++b) {
      if (levels[a] >= levels[b]) continue;
      if (mean[a] < 0.99 * clip) {
        EXPECT_LT(mean[a], mean[b]) << a << " " << b;
      } else {
        EXPECT_NEAR(mean[b], clip, 1e-2 * clip) << a << " " << b;
      }
    }
  }
}

TEST(ScanScanner, SameBytesOnOneAndTwoThreads) {
  Scene s;
  s.primitives.push_back(plane({2.0, 0.5, 0}, {-1, 0, 0}, 1.0, 1.0, 0.3));
  Primitive sphere;
  sphere.kind = PrimitiveKind::kSphere;
  sphere.center_m = {1.5, -0.2, 0};
  sphere.radius_m = 0.2;
  sphere.name = "sphere";
  s.primitives.push_back(sphere);
  const RayCaster caster(s);
  device::DeviceConfig config;
  config.scan.rays_per_beam = 8;
  const device::VirtualRangefinder dev(config);
  std::vector<double> az, el;
  for (int k = -20; k <= 20; ++k) az.push_back(k);
  for (int k = -10; k <= 10; ++k) el.push_back(k);
  const auto pattern = spherical_pattern({az, el, 10});
  ScanOptions o;
  o.shots = 5;
  o.seed = 7;
  auto run = [&](int threads) {
    tbb::task_arena arena(threads);
    ScanResult r;
    arena.execute([&] { r = run_scan(caster, Footprint(config), dev, pattern, o); });
    return r;
  };
  const auto a = run(1), b = run(2);
  ASSERT_EQ(a.beams.size(), b.beams.size());
  int misses = 0;
  for (std::size_t i = 0; i < a.beams.size(); ++i) {
    EXPECT_EQ(std::memcmp(&a.beams[i].raw, &b.beams[i].raw, sizeof a.beams[i].raw), 0);
    if (a.beams[i].surfaces == 0) {
      ++misses;
      EXPECT_TRUE(std::isnan(a.beams[i].true_range_m));
      EXPECT_FALSE(a.beams[i].raw.has_echo());  // REP-117: a miss has no range
    }
  }
  EXPECT_GT(misses, 0);
}

// Scanning into a result that held another frame (more beams, every beam
// hit, ranges from a model) leaves the bytes of a fresh scan: nothing of the
// old frame survives, misses included.
TEST(ScanScanner, ReusedResultGivesTheBytesOfAFreshOne) {
  Scene s;
  s.primitives.push_back(plane({2.0, 0.0, 0}, {-1, 0, 0}, 1.0, 1.0, 0.3));
  const RayCaster caster(s);
  device::DeviceConfig config;
  config.scan.rays_per_beam = 4;
  const device::VirtualRangefinder dev(config);
  std::vector<double> az_wide, az_narrow, el;
  for (int k = -8; k <= 8; ++k) az_wide.push_back(k);         // all on the plate
  for (int k = -40; k <= 40; k += 8) az_narrow.push_back(k);  // some off it
  for (int k = -5; k <= 5; ++k) el.push_back(k);
  ScanOptions o;
  o.shots = 3;
  o.seed = 11;
  ScanResult reused;
  run_scan(caster, Footprint(config), dev, spherical_pattern({az_wide, el, 10}), o, reused);
  for (auto& b : reused.beams) b.range = {1.0, 0.01, 7u};
  reused.has_model = true;
  const auto pattern = spherical_pattern({az_narrow, el, 10});
  ASSERT_LT(pattern.beams.size(), reused.beams.size());
  run_scan(caster, Footprint(config), dev, pattern, o, reused);
  const ScanResult fresh = run_scan(caster, Footprint(config), dev, pattern, o);
  EXPECT_FALSE(reused.has_model);
  EXPECT_EQ(reused.pattern.rows, fresh.pattern.rows);
  EXPECT_EQ(reused.pattern.columns, fresh.pattern.columns);
  ASSERT_EQ(reused.beams.size(), fresh.beams.size());
  int misses = 0;
  for (std::size_t i = 0; i < fresh.beams.size(); ++i) {
    const BeamResult &a = reused.beams[i], &b = fresh.beams[i];
    misses += b.surfaces == 0;
    expect_same_trace(a, b, i);
    EXPECT_TRUE(same(a.raw, b.raw)) << i;
    EXPECT_TRUE(same(a.range.distance_m, b.range.distance_m) &&
                same(a.range.sigma_m, b.range.sigma_m) &&
                a.range.correction_flags == b.range.correction_flags)
        << i;
  }
  EXPECT_GT(misses, 0);
}

// A sequence scan with a still beam traces every beam as the scanner does:
// the same beams in the world frame (a posed sensor), true ranges, surface
// counts, and the largest surface's reflectance and incidence (NaN on a miss;
// the sequence scan had left them NaN on every beam).
TEST(ScanScanner, SequenceScanTracesBeamsAsTheScannerDoes) {
  Scene s;
  s.primitives.push_back(plane({2.0, 0.1, 0}, {-1, 0.2, 0}, 1.0, 1.0, 0.3));
  s.primitives.push_back(plane({2.5, -0.5, 0}, {-1, 0, 0}, 1.0, 1.0, 0.7));
  s.sensor.position_m = {0.1, -0.2, 0.05};
  s.sensor.rpy_deg = {2, -3, 5};
  const RayCaster caster(s);
  device::DeviceConfig config;
  config.scan.rays_per_beam = 7;
  const device::VirtualRangefinder dev(config);
  std::vector<double> az, el;
  for (int k = -40; k <= 40; k += 4) az.push_back(k);
  for (int k = -20; k <= 20; k += 5) el.push_back(k);
  const auto pattern = spherical_pattern({az, el, 10});
  ScanOptions o;
  o.shots = 2;
  const ScanResult plain = run_scan(caster, Footprint(config), dev, pattern, o);
  experiments::SequenceScanOptions so;
  so.shots = 2;
  so.window_points = 1;
  const auto seq = experiments::run_sequence_scan(caster, Footprint(config), dev, pattern, so);
  ASSERT_EQ(seq.result.beams.size(), plain.beams.size());
  int misses = 0, dark = 0, bright = 0;
  for (std::size_t i = 0; i < plain.beams.size(); ++i) {
    const BeamResult &a = seq.result.beams[i], &b = plain.beams[i];
    misses += b.surfaces == 0;
    dark += b.surfaces > 0 && b.reflectance == 0.3;
    bright += b.surfaces > 0 && b.reflectance == 0.7;
    expect_same_trace(a, b, i);
  }
  EXPECT_GT(misses, 0);
  EXPECT_GT(dark, 0);
  EXPECT_GT(bright, 0);
}

// A pattern's size is checked before its beams are made: a spinning step of
// 1e-30 degrees is refused (its firings per revolution had overflowed a
// long), and every pattern over its beam limit throws std::length_error
// naming the count, without allocating.
TEST(ScanPatterns, OversizedPatternsAreRefusedBeforeTheyAreBuilt) {
  std::vector<double> many(2000);
  for (std::size_t i = 0; i < many.size(); ++i) many[i] = 0.01 * static_cast<double>(i);
  EXPECT_THROW((void)spinning_pattern({{0.0}, 1e-30, 10, 1}), std::invalid_argument);
  EXPECT_THROW((void)spherical_pattern({many, many, 10}, 1000), std::length_error);
  EXPECT_THROW((void)raster_pattern({many, many, 1, 0.05}, 1e-3, 1000), std::length_error);
  EXPECT_THROW((void)line_pattern({{-1, 1}, many, 0.05, 0.5}, 1e-3, 1000), std::length_error);
  EXPECT_THROW((void)mirror_pattern({many, 2, 10, 0}, 1000), std::length_error);
  EXPECT_THROW((void)spinning_pattern({many, 0.2, 10, 1}, 1000), std::length_error);
  try {
    (void)spherical_pattern({many, many, 10}, 1000);
  } catch (const std::length_error& e) {
    EXPECT_NE(std::string(e.what()).find("spherical: the pattern has 4e+06 beams, more than the "
                                         "limit of 1000"),
              std::string::npos)
        << e.what();
  }
  // At the limit, built.
  EXPECT_EQ(spherical_pattern({{0, 1}, {0, 1, 2}, 10}, 6).beams.size(), 6u);
}

// Lists a stage or a mirror cannot follow are refused naming them: a line
// whose columns coincide had swept nothing (0 beams, exit 0), an uneven one put
// its columns where the images did not, and an azimuth of 1e300 degrees (or a
// stage position beyond the scene's 100 km) scanned.
TEST(ScanPatterns, ListsAStageOrAMirrorCannotFollowAreRefused) {
  const auto message = [](const auto& build) {
    try {
      (void)build();
    } catch (const std::invalid_argument& e) {
      return std::string(e.what());
    }
    return std::string("(built)");
  };
  for (const std::vector<double>& ys :
       {std::vector<double>{0, 0}, std::vector<double>{0, 0.01, 0.1}}) {
    EXPECT_NE(message([&] {
                return line_pattern({ys, {0}, 0.05, 0.5}, 1e-3);
              }).find("line y must be evenly spaced distinct positions"),
              std::string::npos);
  }
  std::vector<double> even;
  for (int k = 0; k <= 200; ++k) even.push_back(-0.1 + 0.001 * k);
  EXPECT_GT(line_pattern({even, {0}, 0.05, 0.5}, 1e-3).beams.size(), 0u);
  // A sweep shorter than one measurement holds no sample (0 beams, exit 0 before).
  EXPECT_NE(message([] {
              return line_pattern({{0, 1e-9}, {0}, 0.05, 0.5}, 1e-3);
            }).find("line: a sweep lasts 4e-08 s, less than one measurement (0.001 s of shots)"),
            std::string::npos);
  EXPECT_EQ(message([] {
              return spherical_pattern({{1e300}, {0}, 10});
            }),
            "spherical azimuth: 1e+300 is beyond +-360 degrees");
  EXPECT_EQ(message([] {
              return spinning_pattern({{-400}, 0.2, 10, 1});
            }),
            "spinning elevation: -400 is beyond +-360 degrees");
  EXPECT_EQ(message([] {
              return raster_pattern({{2e5}, {0}, 1, 0.05}, 1e-3);
            }),
            "raster y: 200000 is beyond +-100000 m");
  EXPECT_EQ(spherical_pattern({{-360, 360}, {-360, 360}, 10}).beams.size(), 4u);
}

TEST(ScanPatterns, RasterSerpentineMirrorAndSpinningGeometry) {
  // Raster: serpentine rows, every point once, time includes moves and dwell.
  const auto r = raster_pattern({{0.0, 0.01, 0.02}, {0.0, 0.01}, 4, 0.01}, 1e-3);
  ASSERT_EQ(r.beams.size(), 6u);
  EXPECT_EQ(r.shots_multiplier, 4);
  EXPECT_EQ(r.beams[0].column, 0);
  EXPECT_EQ(r.beams[2].column, 2);
  EXPECT_EQ(r.beams[3].column, 2);  // the second row runs back
  EXPECT_NEAR(r.beams[1].time_s - r.beams[0].time_s, 4e-3 + 0.01 / 0.01, 1e-12);
  EXPECT_NEAR(r.beams[0].origin_m[1], 0.02, 0);  // column 0 is the largest y (left)
  // Mirror: one profile per revolution, elevations in the x-z plane.
  const auto m = mirror_pattern({{-10, 0, 10}, 3, 20, 0});
  ASSERT_EQ(m.beams.size(), 9u);
  EXPECT_NEAR(m.beams[3].time_s - m.beams[0].time_s, 0.05, 1e-12);
  for (const auto& b : m.beams) EXPECT_EQ(b.direction[1], 0.0);
  // Spinning: all elevations fire together; 0.5 deg steps at 10 Hz.
  const auto s = spinning_pattern({{-15, -5, 5, 15}, 0.5, 10, 2});
  ASSERT_EQ(s.beams.size(), 4u * 720u * 2u);
  EXPECT_EQ(s.rows, 8);
  EXPECT_NEAR(s.beams.back().time_s, (2 * 720 - 1) / 7200.0, 1e-12);
  for (std::size_t i = 1; i < s.beams.size(); ++i)
    EXPECT_GE(s.beams[i].time_s, s.beams[i - 1].time_s);
  EXPECT_NEAR(std::asin(s.beams[0].direction[2]) * 180 / std::numbers::pi, 15.0, 1e-9);
}

TEST(ScanScene, SensorPoseRotatesBeamsRep103) {
  Pose pose;
  pose.position_m = {1, 2, 3};
  pose.rpy_deg = {0, 0, 90};  // yaw left: +x looks along world +y
  const Vec3 d = pose.rotate({1, 0, 0});
  EXPECT_NEAR(d[0], 0, 1e-15);
  EXPECT_NEAR(d[1], 1, 1e-15);
  pose.rpy_deg = {0, 90, 0};  // pitch +90 about y: +x turns to -z (looks down)
  const Vec3 down = pose.rotate({1, 0, 0});
  EXPECT_NEAR(down[2], -1, 1e-15);
  const Vec3 p = pose.transform({0, 0, 0});
  EXPECT_EQ(p[0], 1);
  EXPECT_EQ(p[2], 3);
  pose.rpy_deg = {90, 0, 0};  // roll about x: +y turns to +z
  EXPECT_NEAR(pose.rotate({0, 1, 0})[2], 1, 1e-15);
}
