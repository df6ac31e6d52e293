#include "tofkit/scan/footprint.hpp"

#include <cmath>
#include <limits>
#include <numbers>

namespace tofkit::scan {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

/// Sub-ray hits that form one surface: one primitive, one reflectance, and
/// no crease or step between them. `point` and `normal` are its first hit's.
struct Group {
  std::uint32_t primitive;
  double reflectance;
  Vec3 point, normal;
  double weight = 0, distance_sum = 0;
  Vec3 normal_sum{0, 0, 0};
};

}  // namespace

Footprint::Footprint(const device::DeviceConfig& config)
    : Footprint(config.link.laser.exit_beam_diameter_mm * 1e-3,
                config.link.laser.beam_divergence_mrad * 1e-3, config.scan.rays_per_beam,
                config.scan.crease_angle_deg) {}

Footprint::Footprint(double exit_diameter_m, double divergence_rad, int rays_per_beam,
                     double crease_angle_deg)
    : exit_radius_m_(0.5 * exit_diameter_m),
      half_divergence_rad_(0.5 * divergence_rad),
      cos_crease_(std::cos(crease_angle_deg * std::numbers::pi / 180.0)),
      sin_crease_(std::sin(crease_angle_deg * std::numbers::pi / 180.0)) {
  const int n = rays_per_beam < 1 ? 1 : rays_per_beam;
  if (n == 1) {
    sub_rays_.push_back({0, 0, 1});
    tilts_.push_back({0, 0});
    return;
  }
  // Vogel's sunflower: sample k sits at radius sqrt((k + 1/2) / n), so every
  // sample stands for an equal area of the (top-hat) disk.
  const double golden = std::numbers::pi * (3.0 - std::sqrt(5.0));
  for (int k = 0; k < n; ++k) {
    const double r = std::sqrt((k + 0.5) / n);
    const double a = golden * k;
    const double x = r * std::cos(a), y = r * std::sin(a);
    sub_rays_.push_back({x, y, 1.0 / n});
    tilts_.push_back({std::tan(half_divergence_rad_ * x), std::tan(half_divergence_rad_ * y)});
  }
}

void Footprint::trace(const RayCaster& caster, const Vec3& origin, const Vec3& axis,
                      Result& result) const {
  auto& surfaces = result.target.surfaces;
  surfaces.clear();
  if (sub_rays_.size() == 1) {
    const Hit h = caster.cast(origin, axis);
    result.true_range_m = h.distance_m;
    if (h.hit()) {
      const double cos_phi = std::min(1.0, std::abs(dot(h.normal, axis)));
      surfaces.push_back({1.0, h.distance_m, h.reflectance, cos_phi});
    }
    return;
  }
  // The axis and the sub-rays, traced together as packets (the hits of
  // single casts; coherent rays trace faster so).
  const std::size_t rays = sub_rays_.size();
  thread_local std::vector<Vec3> origins, directions;
  thread_local std::vector<Hit> hits;
  origins.resize(rays + 1);
  directions.resize(rays + 1);
  hits.resize(rays + 1);
  // Cross-section axes of the beam.
  Vec3 e1, e2;
  plane_axes(axis, e1, e2);
  origins[0] = origin;
  directions[0] = axis;
  for (std::size_t k = 0; k < rays; ++k) {
    const SubRay& s = sub_rays_[k];
    origins[k + 1] = origin + (exit_radius_m_ * s.x) * e1 + (exit_radius_m_ * s.y) * e2;
    directions[k + 1] = normalized(axis + tilts_[k].x * e1 + tilts_[k].y * e2);
  }
  caster.cast(origins, directions, hits);
  result.true_range_m = hits[0].distance_m;
  Group groups[16];
  std::vector<Group> more;
  std::size_t count = 0;
  const double tan_half_divergence = std::tan(half_divergence_rad_);
  for (std::size_t k = 0; k < rays; ++k) {
    const SubRay& s = sub_rays_[k];
    const Vec3& o = origins[k + 1];
    const Vec3& d = directions[k + 1];
    const Hit& h = hits[k + 1];
    if (!h.hit()) continue;
    const Vec3 point = o + h.distance_m * d;
    const double along_axis = dot(point - origin, axis);
    // A continuous surface deviates from its tangent plane at the first hit by
    // no more than the footprint's diameter times the sine of its crease angle;
    // a larger step (or a sharper crease) is another surface: a mixed pixel.
    const double diameter_m = 2.0 * (exit_radius_m_ + along_axis * tan_half_divergence);
    Group* g = nullptr;
    for (std::size_t i = 0; i < count; ++i) {
      Group& c = i < 16 ? groups[i] : more[i - 16];
      if (c.primitive == h.primitive && c.reflectance == h.reflectance &&
          dot(c.normal, h.normal) >= cos_crease_ &&
          std::abs(dot(point - c.point, c.normal)) <= diameter_m * sin_crease_) {
        g = &c;
        break;
      }
    }
    if (g == nullptr) {
      const Group fresh{h.primitive, h.reflectance, point, h.normal};
      if (count < 16) {
        groups[count] = fresh;
        g = &groups[count];
      } else {
        more.push_back(fresh);
        g = &more.back();
      }
      ++count;
    }
    g->weight += s.weight;
    g->distance_sum += s.weight * along_axis;
    g->normal_sum = g->normal_sum + s.weight * h.normal;
  }
  for (std::size_t i = 0; i < count; ++i) {
    const Group& g = i < 16 ? groups[i] : more[i - 16];
    const Vec3 n = normalized(g.normal_sum);
    const double cos_phi = std::min(1.0, std::abs(dot(n, axis)));
    surfaces.push_back({g.weight, g.distance_sum / g.weight, g.reflectance, cos_phi});
  }
  (void)kNaN;
}

}  // namespace tofkit::scan
