#pragma once
/// \file Closest-hit ray casting with Embree 3. Planes (rectangles), boxes,
/// spheres and capped cylinders are exact surfaces (Embree user geometry whose
/// intersection is computed in double); meshes are Embree triangles. Every hit
/// is refined in double on the original (double) ray, so the distance to an
/// analytic primitive is its closed-form intersection, and a mesh's is exact
/// for its (double) vertices.

#include <embree3/rtcore.h>

#include <cstdint>
#include <limits>
#include <memory>
#include <span>

#include "tofkit/scan/scene.hpp"

namespace tofkit::scan {

struct Hit {
  double distance_m = std::numeric_limits<double>::quiet_NaN();  ///< along the unit direction
  Vec3 normal{0, 0, 0};         ///< unit surface normal, facing the ray
  double reflectance = 0;       ///< at the hit point
  std::uint32_t primitive = 0;  ///< index into Scene::primitives
  std::uint32_t part = 0;       ///< face of a box / cylinder, triangle of a mesh
  [[nodiscard]] bool hit() const { return distance_m == distance_m; }
};

class RayCaster {
 public:
  /// Builds the Embree scene; throws std::invalid_argument with
  /// Scene::validate()'s messages if the scene is invalid.
  explicit RayCaster(Scene scene);
  ~RayCaster();
  RayCaster(const RayCaster&) = delete;
  RayCaster& operator=(const RayCaster&) = delete;

  /// Closest hit of the ray origin + t direction, t > 0 (direction: unit).
  [[nodiscard]] Hit cast(const Vec3& origin, const Vec3& direction) const;
  /// The closest hits of many rays, each the hit cast() gives: traced as
  /// Embree packets of up to 16 rays (coherent rays, such as a beam's
  /// footprint, trace faster so). Throws std::invalid_argument when the
  /// spans' sizes differ.
  void cast(std::span<const Vec3> origins, std::span<const Vec3> directions,
            std::span<Hit> hits) const;

  [[nodiscard]] const Scene& scene() const;
  /// The committed Embree scene (for baselines that cast the same rays bare).
  [[nodiscard]] RTCScene embree_scene() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

/// Closed-form closest intersection of a ray with an analytic primitive (not
/// a mesh) in (t_min, t_max); false if none. Exposed for tests.
bool intersect_primitive(const Primitive& p, const Vec3& origin, const Vec3& direction,
                         double t_min, double t_max, double& t, Vec3& normal, std::uint32_t& part);

}  // namespace tofkit::scan
