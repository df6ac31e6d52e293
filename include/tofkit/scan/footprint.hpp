#pragma once
/// \file A beam's footprint: the beam leaves the exit aperture with the
/// device's exit diameter and full-angle divergence (laser.exit_beam_diameter_mm,
/// laser.beam_divergence_mrad), so its footprint at range R has diameter
/// D0 + R theta (physics::footprint_diameter_m). It is sampled by
/// scan.rays_per_beam sub-rays at equal-area positions of a top-hat profile
/// (a Vogel sunflower: equal weights), and the sub-ray hits are grouped into
/// device::Surface's: fraction = share of the beam's power, distance along the
/// beam axis, reflectance, incidence angle. Hits on one primitive with one
/// reflectance are one surface unless a crease sharper than
/// scan.crease_angle_deg, or a step deeper than the footprint's diameter times
/// its sine, parts them: the triangles of a smooth mesh are one surface, a
/// box's faces or a roof edge are two. A footprint across an edge thus
/// becomes a mixed pixel; power that misses every surface is lost.

#include <span>
#include <vector>

#include "tofkit/device/device_config.hpp"
#include "tofkit/device/target.hpp"
#include "tofkit/scan/ray_caster.hpp"

namespace tofkit::scan {

/// One sub-ray of the footprint, relative to the beam: an offset of the origin
/// in the beam's cross-section (unit disk times the exit radius) and a tilt
/// (unit disk times the divergence half-angle), with its share of the power.
struct SubRay {
  double x = 0, y = 0;  ///< position in the unit disk
  double weight = 1;    ///< share of the beam's power (sums to 1)
};

/// The beam's footprint sampler for one device.
class Footprint {
 public:
  explicit Footprint(const device::DeviceConfig& config);
  Footprint(double exit_diameter_m, double divergence_rad, int rays_per_beam,
            double crease_angle_deg = 30.0);

  /// The target seen by a beam (origin, unit axis direction), and the true
  /// range of its axis (first hit, NaN on a miss; with one ray per beam the
  /// sub-ray is the axis). `scratch` avoids allocations in loops.
  struct Result {
    device::Target target;
    double true_range_m = 0;
  };
  void trace(const RayCaster& caster, const Vec3& origin, const Vec3& direction,
             Result& result) const;

  [[nodiscard]] std::span<const SubRay> sub_rays() const { return sub_rays_; }
  [[nodiscard]] double exit_radius_m() const { return exit_radius_m_; }
  [[nodiscard]] double half_divergence_rad() const { return half_divergence_rad_; }

 private:
  double exit_radius_m_ = 0;
  double half_divergence_rad_ = 0;
  double cos_crease_ = 1, sin_crease_ = 0;  ///< of scan.crease_angle_deg
  std::vector<SubRay> sub_rays_;
  struct Tilt {
    double x, y;  ///< tan of the sub-ray's tilt along the two cross-section axes
  };
  std::vector<Tilt> tilts_;
};

}  // namespace tofkit::scan
