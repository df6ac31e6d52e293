#pragma once
/// \file What a scanner sees: primitives (rectangle, box, sphere, capped
/// cylinder, triangle mesh) with a reflectance each, or a reflectance pattern
/// (stripes, checker) on planes, and the sensor's pose. Frames follow ROS
/// REP-103: right-handed, metres, the sensor looks along +x with z up.

#include <array>
#include <cmath>
#include <cstdint>
#include <string>
#include <vector>

namespace tofkit::scan {

using Vec3 = std::array<double, 3>;

/// A scene, and the sensor moving through it, lie within 100 km of the origin
/// (the farthest distance a device measures): beyond it Embree's
/// single-precision bounds lose the scene.
inline constexpr double kSceneExtentM = 1e5;

/// Reflectance over a surface: uniform, stripes, or a checkerboard.
struct Reflectance {
  enum class Kind { kUniform, kStripes, kChecker };
  Kind kind = Kind::kUniform;
  double value = 0.5;          ///< kUniform: Lambertian reflectance rho
  std::vector<double> values;  ///< kStripes / kChecker: listed values (cycled)
  double cell_m = 0.02;        ///< stripe width / checker cell size
  bool random = false;         ///< kChecker: each cell draws from `values` (or, if empty, uniformly
                               ///< from [random_min, random_max]) with the seed
  std::uint64_t seed = 1;      ///< kChecker with random = true
  double random_min = 0.02;    ///< range of random checker values
  double random_max = 0.9;

  /// Reflectance at plane coordinates (u, v), metres from the plane's corner.
  [[nodiscard]] double at(double u_m, double v_m) const;
};

enum class PrimitiveKind { kPlane, kBox, kSphere, kCylinder, kMesh };

/// One surface of the scene. Which fields apply depends on `kind`.
struct Primitive {
  PrimitiveKind kind = PrimitiveKind::kPlane;
  Reflectance reflectance;
  std::string name;  ///< for messages ("surface[3]")
  // kPlane: a rectangle
  Vec3 center_m{0, 0, 0};
  Vec3 normal{-1, 0, 0};
  std::array<double, 2> size_m{1, 1};  ///< width (along u), height (along v)
  // kBox: axis-aligned
  Vec3 min_m{0, 0, 0};
  Vec3 max_m{1, 1, 1};
  // kSphere: center_m, radius_m; kCylinder: base_m, axis, radius_m, height_m (capped)
  double radius_m = 0.1;
  Vec3 base_m{0, 0, 0};
  Vec3 axis{0, 0, 1};
  double height_m = 0.1;
  // kMesh: triangles (vertex triples)
  std::vector<Vec3> vertices;
  std::vector<std::array<std::uint32_t, 3>> triangles;
};

/// Rigid pose: position and roll/pitch/yaw (applied z-y'-x'', REP-103).
/// A pose as a rotation matrix (by columns) and a translation, worked out once
/// for many points.
struct RigidTransform {
  std::array<Vec3, 3> columns{};
  Vec3 translation{0, 0, 0};
  [[nodiscard]] Vec3 rotate(const Vec3& v) const {
    const auto& c = columns;
    return {c[0][0] * v[0] + c[1][0] * v[1] + c[2][0] * v[2],
            c[0][1] * v[0] + c[1][1] * v[1] + c[2][1] * v[2],
            c[0][2] * v[0] + c[1][2] * v[1] + c[2][2] * v[2]};
  }
  [[nodiscard]] Vec3 transform(const Vec3& p) const {
    const Vec3 r = rotate(p);
    return {r[0] + translation[0], r[1] + translation[1], r[2] + translation[2]};
  }
};

struct Pose {
  Vec3 position_m{0, 0, 0};
  Vec3 rpy_deg{0, 0, 0};
  /// The sensor frame's rotation and origin in the world frame (a scan works
  /// it out once: rotate() and transform() below take six sines and cosines).
  [[nodiscard]] RigidTransform to_world() const;
  /// A direction or offset from the sensor frame into the world frame.
  [[nodiscard]] Vec3 rotate(const Vec3& v) const { return to_world().rotate(v); }
  /// A point from the sensor frame into the world frame.
  [[nodiscard]] Vec3 transform(const Vec3& p) const { return to_world().transform(p); }
};

struct Scene {
  Pose sensor;
  std::vector<Primitive> primitives;

  /// Messages naming the primitive and the field of each problem (degenerate
  /// sizes, zero normals, reflectance outside [0, 1], empty meshes, ...).
  [[nodiscard]] std::vector<std::string> validate() const;
};

/// The in-plane axes (u, v) of a rectangle with this normal: v is the world
/// up direction projected on the plane (z, or x when the normal is vertical),
/// u = v x n, so (u, v, n) is right-handed.
void plane_axes(const Vec3& normal, Vec3& u, Vec3& v);

// Small vector helpers shared by scan/.
inline Vec3 operator+(const Vec3& a, const Vec3& b) {
  return {a[0] + b[0], a[1] + b[1], a[2] + b[2]};
}
inline Vec3 operator-(const Vec3& a, const Vec3& b) {
  return {a[0] - b[0], a[1] - b[1], a[2] - b[2]};
}
inline Vec3 operator*(double s, const Vec3& a) {
  return {s * a[0], s * a[1], s * a[2]};
}
inline double dot(const Vec3& a, const Vec3& b) {
  return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}
inline Vec3 cross(const Vec3& a, const Vec3& b) {
  return {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]};
}
inline Vec3 normalized(const Vec3& a) {
  const double inv = 1.0 / std::sqrt(dot(a, a));
  return {a[0] * inv, a[1] * inv, a[2] * inv};
}

}  // namespace tofkit::scan
