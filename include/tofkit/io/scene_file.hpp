#pragma once
/// \file Scene files (TOML) and the meshes they name (PLY, OBJ).
///
///     [sensor]
///     pose_m = [0, 0, 0]          # sensor position
///     rpy_deg = [0, 0, 0]         # roll, pitch, yaw
///     [[surface]]
///     kind = "plane"              # plane | box | sphere | cylinder | mesh
///     center_m = [0.5, 0, 0]
///     normal = [-1, 0, 0]
///     size_m = [0.3, 0.2]         # width, height of the rectangle
///     reflectance = 0.5           # or: pattern = "stripes" | "checker",
///                                 #     values = [...], cell_m = 0.02, seed = 1
///
/// sphere: center_m, radius_m; box: min_m, max_m; cylinder: base_m, axis,
/// radius_m, height_m; mesh: file = "part.ply" | "part.obj" (relative to the
/// scene file), optional offset_m and scale. A checker with `seed` draws each
/// cell at random from `values` (or from [random_min, random_max] without
/// values). An unknown key, a wrong type, a degenerate primitive or a missing
/// mesh is a SceneError naming the file, line and key.

#include <filesystem>
#include <stdexcept>

#include "tofkit/scan/scene.hpp"

namespace tofkit::io {

class SceneError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

[[nodiscard]] scan::Scene load_scene(const std::filesystem::path& file);

/// Triangles of an OBJ (v / f, polygons fanned) or PLY (ascii or binary
/// little-endian; float or double vertices; face index lists) file.
void load_mesh(const std::filesystem::path& file, scan::Primitive& mesh);

}  // namespace tofkit::io
