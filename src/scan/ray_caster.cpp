#include "tofkit/scan/ray_caster.hpp"

#include <cmath>
#include <new>
#include <stdexcept>
#include <string>
#include <vector>

namespace tofkit::scan {
namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();

Vec3 facing(const Vec3& n, const Vec3& d) {
  return dot(n, d) > 0 ? -1.0 * n : n;
}

// Smaller root of a t^2 + 2 b t + c = 0 above t_min (numerically stable form).
bool quadratic_root(double a, double b, double c, double t_min, double t_max, double& t) {
  const double disc = b * b - a * c;
  if (disc < 0 || a == 0) return false;
  const double s = std::sqrt(disc);
  const double q = b > 0 ? -(b + s) : -(b - s);
  double t0 = q / a, t1 = q != 0 ? c / q : t0;
  if (t0 > t1) std::swap(t0, t1);
  if (t0 > t_min && t0 < t_max) {
    t = t0;
    return true;
  }
  if (t1 > t_min && t1 < t_max) {
    t = t1;
    return true;
  }
  return false;
}

bool intersect_rectangle(const Vec3& center, const Vec3& n_in, double width, double height,
                         const Vec3& o, const Vec3& d, double t_min, double t_max, double& t,
                         Vec3& normal) {
  const Vec3 n = normalized(n_in);
  const double dn = dot(d, n);
  if (dn == 0) return false;
  const double tt = dot(center - o, n) / dn;
  if (!(tt > t_min && tt < t_max)) return false;
  Vec3 u, v;
  plane_axes(n, u, v);
  const Vec3 rel = o + tt * d - center;
  if (std::abs(dot(rel, u)) > 0.5 * width || std::abs(dot(rel, v)) > 0.5 * height) return false;
  t = tt;
  normal = facing(n, d);
  return true;
}

bool intersect_disk(const Vec3& center, const Vec3& n, double radius, const Vec3& o, const Vec3& d,
                    double t_min, double t_max, double& t) {
  const double dn = dot(d, n);
  if (dn == 0) return false;
  const double tt = dot(center - o, n) / dn;
  if (!(tt > t_min && tt < t_max)) return false;
  const Vec3 rel = o + tt * d - center;
  if (dot(rel, rel) > radius * radius) return false;
  t = tt;
  return true;
}

/// A mesh triangle as its double refinement reads it: one vertex, the two
/// edges from it and the unit normal, together (96 bytes: the hit's one or two
/// cache lines instead of its index triple and three scattered vertices).
struct alignas(32) RefineTriangle {
  Vec3 a, e1, e2, unit_normal;
};

RefineTriangle refine_triangle(const Vec3& a, const Vec3& b, const Vec3& c) {
  const Vec3 e1 = b - a, e2 = c - a;
  return {a, e1, e2, normalized(cross(e1, e2))};
}

bool intersect_triangle(const RefineTriangle& tri, const Vec3& o, const Vec3& d, double& t,
                        Vec3& normal) {
  // Moller-Trumbore in double.
  const Vec3& e1 = tri.e1;
  const Vec3& e2 = tri.e2;
  const Vec3 p = cross(d, e2);
  const double det = dot(e1, p);
  if (det == 0) return false;
  const double inv = 1.0 / det;
  const Vec3 s = o - tri.a;
  const double u = dot(s, p) * inv;
  if (u < 0 || u > 1) return false;
  const Vec3 q = cross(s, e1);
  const double v = dot(d, q) * inv;
  if (v < 0 || u + v > 1) return false;
  t = dot(e2, q) * inv;
  normal = facing(tri.unit_normal, d);
  return t > 0;
}

}  // namespace

bool intersect_primitive(const Primitive& p, const Vec3& o, const Vec3& d, double t_min,
                         double t_max, double& t, Vec3& normal, std::uint32_t& part) {
  switch (p.kind) {
    case PrimitiveKind::kPlane:
      part = 0;
      return intersect_rectangle(p.center_m, p.normal, p.size_m[0], p.size_m[1], o, d, t_min, t_max,
                                 t, normal);
    case PrimitiveKind::kSphere: {
      const Vec3 oc = o - p.center_m;
      if (!quadratic_root(dot(d, d), dot(oc, d), dot(oc, oc) - p.radius_m * p.radius_m, t_min,
                          t_max, t)) {
        return false;
      }
      normal = facing(normalized(o + t * d - p.center_m), d);
      part = 0;
      return true;
    }
    case PrimitiveKind::kBox: {
      // Slabs: the entry face is where the last slab is entered.
      double t0 = -kInf, t1 = kInf;
      int axis0 = -1, axis1 = -1;
      for (int k = 0; k < 3; ++k) {
        if (d[k] == 0) {
          if (o[k] < p.min_m[k] || o[k] > p.max_m[k]) return false;
          continue;
        }
        double a = (p.min_m[k] - o[k]) / d[k], b = (p.max_m[k] - o[k]) / d[k];
        if (a > b) std::swap(a, b);
        if (a > t0) t0 = a, axis0 = k;
        if (b < t1) t1 = b, axis1 = k;
      }
      if (t0 > t1) return false;
      int axis = -1;
      if (t0 > t_min && t0 < t_max) {
        t = t0, axis = axis0;
      } else if (t1 > t_min && t1 < t_max) {
        t = t1, axis = axis1;
      } else {
        return false;
      }
      Vec3 n{0, 0, 0};
      n[static_cast<std::size_t>(axis)] = 1;
      normal = facing(n, d);
      part = static_cast<std::uint32_t>(2 * axis + (normal[static_cast<std::size_t>(axis)] > 0));
      return true;
    }
    case PrimitiveKind::kCylinder: {
      const Vec3 a = normalized(p.axis);
      const Vec3 ob = o - p.base_m;
      const Vec3 dp = d - dot(d, a) * a, op = ob - dot(ob, a) * a;
      bool found = false;
      double best = t_max, tt = 0;
      // Side: both roots in order (the nearer may lie beyond the height).
      const double qa = dot(dp, dp), qb = dot(op, dp), qc = dot(op, op) - p.radius_m * p.radius_m;
      const double disc = qb * qb - qa * qc;
      if (qa > 0 && disc >= 0) {
        const double s = std::sqrt(disc);
        for (const double root : {(-qb - s) / qa, (-qb + s) / qa}) {
          if (!(root > t_min && root < best)) continue;
          const double h = dot(ob + root * d, a);
          if (h < 0 || h > p.height_m) continue;
          found = true;
          best = root;
          normal = facing(normalized(ob + root * d - h * a), d);
          part = 0;
          break;
        }
      }
      for (std::uint32_t cap = 1; cap <= 2; ++cap) {
        const Vec3 c = cap == 1 ? p.base_m : p.base_m + p.height_m * a;
        if (intersect_disk(c, a, p.radius_m, o, d, t_min, best, tt)) {
          found = true;
          best = tt;
          normal = facing(a, d);
          part = cap;
        }
      }
      if (found) t = best;
      return found;
    }
    case PrimitiveKind::kMesh:
      return false;
  }
  return false;
}

struct RayCaster::Impl {
  Scene scene;
  RTCDevice device = nullptr;
  RTCScene rtc_scene = nullptr;
  /// Per primitive: its triangles for the double refinement (empty unless a mesh).
  std::vector<std::vector<RefineTriangle>> refine;

  ~Impl() {
    if (rtc_scene != nullptr) rtcReleaseScene(rtc_scene);
    if (device != nullptr) rtcReleaseDevice(device);
  }
};

namespace {

void bounds_callback(const RTCBoundsFunctionArguments* args) {
  const auto& p = *static_cast<const Primitive*>(args->geometryUserPtr);
  Vec3 lo, hi;
  switch (p.kind) {
    case PrimitiveKind::kPlane: {
      Vec3 u, v;
      plane_axes(p.normal, u, v);
      const Vec3 eu = 0.5 * p.size_m[0] * u, ev = 0.5 * p.size_m[1] * v;
      for (int k = 0; k < 3; ++k) {
        const double e = std::abs(eu[k]) + std::abs(ev[k]);
        lo[k] = p.center_m[k] - e;
        hi[k] = p.center_m[k] + e;
      }
      break;
    }
    case PrimitiveKind::kSphere:
      for (int k = 0; k < 3; ++k) {
        lo[k] = p.center_m[k] - p.radius_m;
        hi[k] = p.center_m[k] + p.radius_m;
      }
      break;
    case PrimitiveKind::kBox:
      lo = p.min_m;
      hi = p.max_m;
      break;
    case PrimitiveKind::kCylinder: {
      const Vec3 top = p.base_m + p.height_m * normalized(p.axis);
      for (int k = 0; k < 3; ++k) {
        lo[k] = std::min(p.base_m[k], top[k]) - p.radius_m;
        hi[k] = std::max(p.base_m[k], top[k]) + p.radius_m;
      }
      break;
    }
    case PrimitiveKind::kMesh:
      break;
  }
  // Pad by a relative float ulp so float traversal never culls an exact hit.
  auto* b = args->bounds_o;
  auto pad = [](double x) { return 1e-6 * (1.0 + std::abs(x)); };
  b->lower_x = static_cast<float>(lo[0] - pad(lo[0]));
  b->lower_y = static_cast<float>(lo[1] - pad(lo[1]));
  b->lower_z = static_cast<float>(lo[2] - pad(lo[2]));
  b->upper_x = static_cast<float>(hi[0] + pad(hi[0]));
  b->upper_y = static_cast<float>(hi[1] + pad(hi[1]));
  b->upper_z = static_cast<float>(hi[2] + pad(hi[2]));
}

void intersect_callback(const RTCIntersectFunctionNArguments* args) {
  const auto& p = *static_cast<const Primitive*>(args->geometryUserPtr);
  auto* rayhit = args->rayhit;
  RTCRayN* ray = RTCRayHitN_RayN(rayhit, args->N);
  RTCHitN* hit = RTCRayHitN_HitN(rayhit, args->N);
  for (unsigned i = 0; i < args->N; ++i) {
    if (args->valid[i] == 0) continue;
    const Vec3 o{RTCRayN_org_x(ray, args->N, i), RTCRayN_org_y(ray, args->N, i),
                 RTCRayN_org_z(ray, args->N, i)};
    const Vec3 d{RTCRayN_dir_x(ray, args->N, i), RTCRayN_dir_y(ray, args->N, i),
                 RTCRayN_dir_z(ray, args->N, i)};
    double t = 0;
    Vec3 n;
    std::uint32_t part = 0;
    if (!intersect_primitive(p, o, d, RTCRayN_tnear(ray, args->N, i), RTCRayN_tfar(ray, args->N, i),
                             t, n, part)) {
      continue;
    }
    RTCRayN_tfar(ray, args->N, i) = static_cast<float>(t);
    RTCHitN_Ng_x(hit, args->N, i) = static_cast<float>(n[0]);
    RTCHitN_Ng_y(hit, args->N, i) = static_cast<float>(n[1]);
    RTCHitN_Ng_z(hit, args->N, i) = static_cast<float>(n[2]);
    RTCHitN_u(hit, args->N, i) = 0;
    RTCHitN_v(hit, args->N, i) = 0;
    RTCHitN_primID(hit, args->N, i) = part;
    RTCHitN_geomID(hit, args->N, i) = args->geomID;
    RTCHitN_instID(hit, args->N, i, 0) = args->context->instID[0];
  }
}

/// Throws on an Embree error: std::bad_alloc when it ran out of memory (a
/// mesh's acceleration structure can take hundreds of times its file's
/// size), else std::runtime_error. Without the check an Embree that failed
/// to build a mesh left it out of the scene (its beams: no echo, exit 0).
void check_embree(RTCDevice device, const char* what) {
  const RTCError error = rtcGetDeviceError(device);
  if (error == RTC_ERROR_NONE) return;
  if (error == RTC_ERROR_OUT_OF_MEMORY) throw std::bad_alloc();
  throw std::runtime_error(std::string("Embree: ") + what + " failed (error " +
                           std::to_string(static_cast<int>(error)) + ")");
}

}  // namespace

RayCaster::RayCaster(Scene scene) : impl_(std::make_unique<Impl>()) {
  const auto problems = scene.validate();
  if (!problems.empty()) {
    std::string text;
    for (const auto& m : problems) text += (text.empty() ? "" : "\n") + m;
    throw std::invalid_argument(text);
  }
  impl_->scene = std::move(scene);
  impl_->device = rtcNewDevice(nullptr);
  if (impl_->device == nullptr) throw std::runtime_error("Embree: cannot create a device");
  impl_->rtc_scene = rtcNewScene(impl_->device);
  rtcSetSceneFlags(impl_->rtc_scene, RTC_SCENE_FLAG_ROBUST);
  rtcSetSceneBuildQuality(impl_->rtc_scene, RTC_BUILD_QUALITY_HIGH);
  auto& prims = impl_->scene.primitives;
  impl_->refine.resize(prims.size());
  for (std::size_t i = 0; i < prims.size(); ++i) {
    auto& p = prims[i];
    RTCGeometry g = nullptr;
    if (p.kind == PrimitiveKind::kMesh) {
      g = rtcNewGeometry(impl_->device, RTC_GEOMETRY_TYPE_TRIANGLE);
      auto* v = static_cast<float*>(rtcSetNewGeometryBuffer(
          g, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, 3 * sizeof(float), p.vertices.size()));
      if (v == nullptr) {
        rtcReleaseGeometry(g);
        check_embree(impl_->device, "a mesh's vertices");
        throw std::bad_alloc();  // (no buffer without an error)
      }
      for (std::size_t k = 0; k < p.vertices.size(); ++k) {
        for (std::size_t c = 0; c < 3; ++c) v[3 * k + c] = static_cast<float>(p.vertices[k][c]);
      }
      auto* t = static_cast<unsigned*>(rtcSetNewGeometryBuffer(
          g, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, 3 * sizeof(unsigned), p.triangles.size()));
      if (t == nullptr) {
        rtcReleaseGeometry(g);
        check_embree(impl_->device, "a mesh's triangles");
        throw std::bad_alloc();  // (no buffer without an error)
      }
      for (std::size_t k = 0; k < p.triangles.size(); ++k) {
        for (std::size_t c = 0; c < 3; ++c) t[3 * k + c] = p.triangles[k][c];
      }
      auto& refine = impl_->refine[i];
      refine.reserve(p.triangles.size());
      for (const auto& tri : p.triangles)
        refine.push_back(
            refine_triangle(p.vertices[tri[0]], p.vertices[tri[1]], p.vertices[tri[2]]));
    } else {
      g = rtcNewGeometry(impl_->device, RTC_GEOMETRY_TYPE_USER);
      rtcSetGeometryUserPrimitiveCount(g, 1);
      rtcSetGeometryUserData(g, &p);
      rtcSetGeometryBoundsFunction(g, bounds_callback, nullptr);
      rtcSetGeometryIntersectFunction(g, intersect_callback);
    }
    rtcCommitGeometry(g);
    rtcAttachGeometryByID(impl_->rtc_scene, g, static_cast<unsigned>(i));
    rtcReleaseGeometry(g);
  }
  rtcCommitScene(impl_->rtc_scene);
  check_embree(impl_->device, "building the scene");
}

RayCaster::~RayCaster() = default;

const Scene& RayCaster::scene() const {
  return impl_->scene;
}
RTCScene RayCaster::embree_scene() const {
  return impl_->rtc_scene;
}

namespace {

using RefineTables = std::vector<std::vector<RefineTriangle>>;

// A closest hit as Embree's float traversal found it, refined on the double
// ray: the closed form for analytic primitives, double Moller-Trumbore for
// the hit triangle (float traversal chose which one).
Hit refined_hit(const Scene& scene, const RefineTables& refine, unsigned geom_id, unsigned prim_id,
                float tfar, const Vec3& float_normal, const Vec3& o, const Vec3& d) {
  Hit hit;
  if (geom_id == RTC_INVALID_GEOMETRY_ID) return hit;
  const auto& p = scene.primitives[geom_id];
  hit.primitive = geom_id;
  hit.part = prim_id;
  double t = 0;
  Vec3 n;
  bool refined = false;
  if (p.kind == PrimitiveKind::kMesh) {
    refined = intersect_triangle(refine[geom_id][prim_id], o, d, t, n);
  } else {
    std::uint32_t part = 0;
    refined = intersect_primitive(p, o, d, 0.0, kInf, t, n, part);
    if (refined) hit.part = part;
  }
  if (!refined) {  // the float hit, where the double ray just misses
    t = tfar;
    n = normalized(facing(float_normal, d));
  }
  hit.distance_m = t;
  hit.normal = n;
  hit.reflectance = p.reflectance.value;
  if (p.kind == PrimitiveKind::kPlane && p.reflectance.kind != Reflectance::Kind::kUniform) {
    Vec3 u, v;
    plane_axes(p.normal, u, v);
    const Vec3 rel = o + t * d - p.center_m;
    hit.reflectance =
        p.reflectance.at(dot(rel, u) + 0.5 * p.size_m[0], dot(rel, v) + 0.5 * p.size_m[1]);
  }
  return hit;
}

// Up to W rays as one Embree packet (RTCRayHit4/8/16), the lanes past n
// invalid: the same hits as W single casts (the same float ray per lane,
// the same closest-hit traversal and triangle test, the same refinement).
template <int W, class RayHitW, class IntersectW>
void cast_packet(const Scene& scene, const RefineTables& refine, RTCScene rtc_scene, const Vec3* o,
                 const Vec3* d, std::size_t n, Hit* out, IntersectW intersect) {
  alignas(64) int valid[W];
  alignas(64) RayHitW rh;
  for (int i = 0; i < W; ++i) {
    const auto lane = static_cast<std::size_t>(i);
    const std::size_t k = lane < n ? lane : 0;
    valid[i] = lane < n ? -1 : 0;
    rh.ray.org_x[i] = static_cast<float>(o[k][0]);
    rh.ray.org_y[i] = static_cast<float>(o[k][1]);
    rh.ray.org_z[i] = static_cast<float>(o[k][2]);
    rh.ray.dir_x[i] = static_cast<float>(d[k][0]);
    rh.ray.dir_y[i] = static_cast<float>(d[k][1]);
    rh.ray.dir_z[i] = static_cast<float>(d[k][2]);
    rh.ray.tnear[i] = 0;
    rh.ray.tfar[i] = std::numeric_limits<float>::infinity();
    rh.ray.mask[i] = 0xFFFFFFFFu;
    rh.ray.time[i] = 0;
    rh.ray.flags[i] = 0;
    rh.hit.geomID[i] = RTC_INVALID_GEOMETRY_ID;
    rh.hit.instID[0][i] = RTC_INVALID_GEOMETRY_ID;
  }
  RTCIntersectContext context;
  rtcInitIntersectContext(&context);
  intersect(valid, rtc_scene, &context, &rh);
  for (std::size_t i = 0; i < n; ++i) {
    out[i] = refined_hit(scene, refine, rh.hit.geomID[i], rh.hit.primID[i], rh.ray.tfar[i],
                         {rh.hit.Ng_x[i], rh.hit.Ng_y[i], rh.hit.Ng_z[i]}, o[i], d[i]);
  }
}

}  // namespace

Hit RayCaster::cast(const Vec3& o, const Vec3& d) const {
  RTCIntersectContext context;
  rtcInitIntersectContext(&context);
  RTCRayHit rh;
  rh.ray.org_x = static_cast<float>(o[0]);
  rh.ray.org_y = static_cast<float>(o[1]);
  rh.ray.org_z = static_cast<float>(o[2]);
  rh.ray.dir_x = static_cast<float>(d[0]);
  rh.ray.dir_y = static_cast<float>(d[1]);
  rh.ray.dir_z = static_cast<float>(d[2]);
  rh.ray.tnear = 0;
  rh.ray.tfar = std::numeric_limits<float>::infinity();
  rh.ray.mask = 0xFFFFFFFFu;
  rh.ray.time = 0;
  rh.ray.flags = 0;
  rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
  rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
  rtcIntersect1(impl_->rtc_scene, &context, &rh);
  return refined_hit(impl_->scene, impl_->refine, rh.hit.geomID, rh.hit.primID, rh.ray.tfar,
                     {rh.hit.Ng_x, rh.hit.Ng_y, rh.hit.Ng_z}, o, d);
}

void RayCaster::cast(std::span<const Vec3> origins, std::span<const Vec3> directions,
                     std::span<Hit> hits) const {
  if (origins.size() != directions.size() || origins.size() != hits.size())
    throw std::invalid_argument("RayCaster::cast: origins, directions and hits differ in size");
  const Scene& scene = impl_->scene;
  const RefineTables& refine = impl_->refine;
  const RTCScene rtc_scene = impl_->rtc_scene;
  for (std::size_t first = 0; first < hits.size();) {
    const std::size_t n = std::min<std::size_t>(hits.size() - first, 16);
    const Vec3* o = origins.data() + first;
    const Vec3* d = directions.data() + first;
    Hit* out = hits.data() + first;
    if (n > 8) {
      cast_packet<16, RTCRayHit16>(scene, refine, rtc_scene, o, d, n, out,
                                   [](const int* v, RTCScene s, RTCIntersectContext* c,
                                      RTCRayHit16* r) { rtcIntersect16(v, s, c, r); });
    } else if (n > 4) {
      cast_packet<8, RTCRayHit8>(scene, refine, rtc_scene, o, d, n, out,
                                 [](const int* v, RTCScene s, RTCIntersectContext* c,
                                    RTCRayHit8* r) { rtcIntersect8(v, s, c, r); });
    } else if (n > 1) {
      cast_packet<4, RTCRayHit4>(scene, refine, rtc_scene, o, d, n, out,
                                 [](const int* v, RTCScene s, RTCIntersectContext* c,
                                    RTCRayHit4* r) { rtcIntersect4(v, s, c, r); });
    } else {
      out[0] = cast(o[0], d[0]);
    }
    first += n;
  }
}

}  // namespace tofkit::scan
