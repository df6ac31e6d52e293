#include "tofkit/scan/scene.hpp"

#include <Random123/philox.h>

#include <algorithm>
#include <cmath>
#include <numbers>

namespace tofkit::scan {
namespace {

double deg(double d) {
  return d * std::numbers::pi / 180.0;
}

// A uniform number in [0, 1) for checker cell (i, j): counter-based, so the
// board does not depend on the order cells are looked up in.
double cell_uniform(std::uint64_t seed, std::int64_t i, std::int64_t j) {
  r123::Philox2x64 rng;
  const r123::Philox2x64::ctr_type ctr{
      {static_cast<std::uint64_t>(i), static_cast<std::uint64_t>(j)}};
  const r123::Philox2x64::key_type key{{seed}};
  const auto out = rng(ctr, key);
  return static_cast<double>(out[0] >> 11) * 0x1.0p-53;
}

bool finite(const Vec3& v) {
  return std::isfinite(v[0]) && std::isfinite(v[1]) && std::isfinite(v[2]);
}
/// A scene lies within kSceneExtentM of the origin and has no feature under
/// 1 um (far below any beam's footprint): beyond either, Embree's
/// single-precision bounds and a pattern's cell index (an int64 of coordinate
/// / cell) would overflow or collapse.
constexpr double kSmallestFeatureM = 1e-6;
/// Finite and within the scene's extent.
bool in_extent(const Vec3& v) {
  return finite(v) && std::abs(v[0]) <= kSceneExtentM && std::abs(v[1]) <= kSceneExtentM &&
         std::abs(v[2]) <= kSceneExtentM;
}
/// A length the scene can hold: at least a micrometre, at most its extent.
bool feature_size(double v) {
  return v >= kSmallestFeatureM && v <= 2 * kSceneExtentM;
}
double norm(const Vec3& v) {
  return std::sqrt(dot(v, v));
}
/// A direction the ray caster can normalize (a 1e300 component overflowed
/// its length to inf and made the surface vanish).
bool direction(const Vec3& v) {
  const double n = norm(v);
  return n >= 1e-12 && n <= 1e12;
}

}  // namespace

double Reflectance::at(double u_m, double v_m) const {
  switch (kind) {
    case Kind::kUniform:
      return value;
    case Kind::kStripes: {
      // Vertical stripes across u (the thesis's grey chart).
      const auto i = static_cast<std::int64_t>(std::floor(u_m / cell_m));
      const auto n = static_cast<std::int64_t>(values.size());
      return values[static_cast<std::size_t>(((i % n) + n) % n)];
    }
    case Kind::kChecker: {
      const auto i = static_cast<std::int64_t>(std::floor(u_m / cell_m));
      const auto j = static_cast<std::int64_t>(std::floor(v_m / cell_m));
      if (random) {
        const double x = cell_uniform(seed, i, j);
        if (values.empty()) return random_min + (random_max - random_min) * x;
        return values[std::min(values.size() - 1,
                               static_cast<std::size_t>(x * static_cast<double>(values.size())))];
      }
      const auto n = static_cast<std::int64_t>(values.size());
      return values[static_cast<std::size_t>((((i + j) % n) + n) % n)];
    }
  }
  return value;
}

RigidTransform Pose::to_world() const {
  // R = Rz(yaw) Ry(pitch) Rx(roll) (REP-103 fixed-axis roll, pitch, yaw),
  // applied to the unit vectors for its columns.
  const double cr = std::cos(deg(rpy_deg[0])), sr = std::sin(deg(rpy_deg[0]));
  const double cp = std::cos(deg(rpy_deg[1])), sp = std::sin(deg(rpy_deg[1]));
  const double cy = std::cos(deg(rpy_deg[2])), sy = std::sin(deg(rpy_deg[2]));
  auto rotate = [&](const Vec3& v) -> Vec3 {
    const Vec3 a{v[0], cr * v[1] - sr * v[2], sr * v[1] + cr * v[2]};
    const Vec3 b{cp * a[0] + sp * a[2], a[1], -sp * a[0] + cp * a[2]};
    return {cy * b[0] - sy * b[1], sy * b[0] + cy * b[1], b[2]};
  };
  return {{rotate({1, 0, 0}), rotate({0, 1, 0}), rotate({0, 0, 1})}, position_m};
}

void plane_axes(const Vec3& normal, Vec3& u, Vec3& v) {
  const Vec3 n = normalized(normal);
  Vec3 up{0, 0, 1};
  if (std::abs(n[2]) > 0.999) up = {1, 0, 0};
  v = normalized(up - dot(up, n) * n);
  u = cross(v, n);
}

std::vector<std::string> Scene::validate() const {
  std::vector<std::string> messages;
  auto bad = [&](const Primitive& p, const std::string& what) {
    messages.push_back(p.name + ": " + what);
  };
  if (!in_extent(sensor.position_m))
    messages.push_back("sensor: pose_m must be finite, within 1e+05 m");
  for (const double a : sensor.rpy_deg) {
    if (!(std::abs(a) <= 360.0)) {
      messages.push_back("sensor: rpy_deg must be finite angles within +-360 degrees");
      break;
    }
  }
  for (const auto& p : primitives) {
    const auto& r = p.reflectance;
    auto check_rho = [&](double rho, const char* key) {
      if (!(rho >= 0.0 && rho <= 1.0)) bad(p, std::string(key) + " must lie in [0, 1]");
    };
    if (r.kind == Reflectance::Kind::kUniform) check_rho(r.value, "reflectance");
    for (const double rho : r.values) check_rho(rho, "values");
    if (r.kind != Reflectance::Kind::kUniform) {
      if (!feature_size(r.cell_m)) bad(p, "cell_m must be in [1e-06, 2e+05] m");
      if (!r.random && r.values.empty()) bad(p, "values must list at least one reflectance");
      if (r.random) {
        check_rho(r.random_min, "random_min");
        check_rho(r.random_max, "random_max");
        if (r.random_min > r.random_max) bad(p, "random_min must not exceed random_max");
      }
      if (p.kind != PrimitiveKind::kPlane) bad(p, "pattern is only allowed on kind = \"plane\"");
    }
    switch (p.kind) {
      case PrimitiveKind::kPlane:
        if (!in_extent(p.center_m)) bad(p, "center_m must be finite, within 1e+05 m");
        if (!direction(p.normal))
          bad(p, "normal must be a nonzero vector (length in [1e-12, 1e+12])");
        if (!feature_size(p.size_m[0]) || !feature_size(p.size_m[1]))
          bad(p, "size_m must be two sizes in [1e-06, 2e+05] m");
        break;
      case PrimitiveKind::kBox:
        if (!in_extent(p.min_m) || !in_extent(p.max_m))
          bad(p, "min_m and max_m must be finite, within 1e+05 m");
        for (int k = 0; k < 3; ++k) {
          if (!(p.max_m[k] - p.min_m[k] >= kSmallestFeatureM)) {
            bad(p, "max_m must exceed min_m by at least 1e-06 m on every axis (degenerate box)");
            break;
          }
        }
        break;
      case PrimitiveKind::kSphere:
        if (!in_extent(p.center_m)) bad(p, "center_m must be finite, within 1e+05 m");
        if (!feature_size(p.radius_m)) bad(p, "radius_m must be in [1e-06, 2e+05] m");
        break;
      case PrimitiveKind::kCylinder:
        if (!in_extent(p.base_m)) bad(p, "base_m must be finite, within 1e+05 m");
        if (!direction(p.axis)) bad(p, "axis must be a nonzero vector (length in [1e-12, 1e+12])");
        if (!feature_size(p.radius_m)) bad(p, "radius_m must be in [1e-06, 2e+05] m");
        if (!feature_size(p.height_m)) bad(p, "height_m must be in [1e-06, 2e+05] m");
        break;
      case PrimitiveKind::kMesh: {
        if (p.triangles.empty()) bad(p, "mesh has no triangles");
        bool ok = true;
        for (const auto& t : p.triangles) {
          for (const auto i : t) ok = ok && i < p.vertices.size();
        }
        if (!ok) {
          bad(p, "mesh triangle refers to a missing vertex");
          break;
        }
        for (const auto& v : p.vertices) ok = ok && in_extent(v);
        if (!ok) {
          bad(p, "mesh vertices must be finite, within 1e+05 m");
          break;
        }
        // A mesh of zero-area triangles only (points or lines) has no surface
        // to hit: degenerate, like a zero radius.
        bool area = false;
        for (const auto& t : p.triangles) {
          const Vec3 n =
              cross(p.vertices[t[1]] - p.vertices[t[0]], p.vertices[t[2]] - p.vertices[t[0]]);
          area = area || norm(n) > 0;
        }
        if (!p.triangles.empty() && !area) bad(p, "mesh has no triangle of nonzero area");
        break;
      }
    }
  }
  return messages;
}

}  // namespace tofkit::scan
