// Mesh files on arbitrary bytes (the first byte picks PLY or OBJ, the rest is
// the file): an error naming the file, or triangles that Scene::validate
// judges; a valid mesh is put into a ray caster and cast on, so what the
// readers let through is what Embree and the double refinement take.
#include <unistd.h>

#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <stdexcept>
#include <string>

#include "tofkit/io/scene_file.hpp"
#include "tofkit/scan/ray_caster.hpp"

namespace {

std::filesystem::path mesh_file(bool ply, const std::uint8_t* data, std::size_t size) {
  const std::string stem = "tofkit_fuzz_mesh_" + std::to_string(::getpid());
  static const auto dir = std::filesystem::temp_directory_path();
  const auto path = dir / (stem + (ply ? ".ply" : ".obj"));
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out.write(reinterpret_cast<const char*>(data), static_cast<std::streamsize>(size));
  return path;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace tofkit;
  if (size == 0) return 0;
  const auto path = mesh_file((data[0] & 1) != 0, data + 1, size - 1);
  scan::Primitive mesh;
  mesh.kind = scan::PrimitiveKind::kMesh;
  mesh.name = "surface[0]";
  mesh.reflectance.value = 0.5;
  try {
    io::load_mesh(path, mesh);
  } catch (const std::runtime_error& e) {
    if (std::string(e.what()).find(path.filename().string()) == std::string::npos) std::abort();
    return 0;
  }
  scan::Scene scene;
  scene.primitives.push_back(mesh);
  if (!scene.validate().empty()) return 0;
  const scan::RayCaster caster{scene};
  // Rays from outside the mesh's box towards its vertices.
  for (std::size_t i = 0; i < mesh.vertices.size() && i < 8; ++i) {
    const scan::Vec3& v = mesh.vertices[i];
    const scan::Vec3 origin{v[0] - 1.0, v[1] - 0.5, v[2] + 0.25};
    const double n = std::sqrt(1.0 + 0.25 + 0.0625);
    const scan::Hit h = caster.cast(origin, {1.0 / n, 0.5 / n, -0.25 / n});
    if (h.hit() && !(h.distance_m >= 0 && std::isfinite(h.distance_m))) std::abort();
  }
  return 0;
}
