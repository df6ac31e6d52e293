// Scene files (TOML) on arbitrary bytes, beside two small meshes they may
// name (m.obj, m.ply): a SceneError naming the scene file, or a scene that
// passes validation, is put into a ray caster and cast on from its sensor.
#include <unistd.h>

#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string>

#include "tofkit/io/scene_file.hpp"
#include "tofkit/scan/ray_caster.hpp"

namespace {

std::filesystem::path scene_dir() {
  static const auto dir = [] {
    const auto d = std::filesystem::temp_directory_path() /
                   ("tofkit_fuzz_scene_" + std::to_string(::getpid()));
    std::filesystem::create_directories(d);
    std::ofstream(d / "m.obj") << "v 1 0 0\nv 1 1 0\nv 1 0 1\nf 1 2 3\n";
    std::ofstream(d / "m.ply") << "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\n"
                                  "property float y\nproperty float z\nelement face 1\n"
                                  "property list uchar int vertex_indices\nend_header\n"
                                  "2 0 0\n2 1 0\n2 0 1\n3 0 1 2\n";
    return d;
  }();
  return dir;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace tofkit;
  const auto path = scene_dir() / "scene.toml";
  {
    std::ofstream out(path, std::ios::binary | std::ios::trunc);
    out.write(reinterpret_cast<const char*>(data), static_cast<std::streamsize>(size));
  }
  scan::Scene scene;
  try {
    scene = io::load_scene(path);
  } catch (const io::SceneError& e) {
    if (std::string(e.what()).find("scene.toml") == std::string::npos) std::abort();
    return 0;
  }
  if (!scene.validate().empty()) std::abort();  // load_scene refuses what validate finds
  const scan::RayCaster caster{scene};
  const scan::RigidTransform pose = scene.sensor.to_world();
  for (int k = 0; k < 16; ++k) {
    const double az = -1.0 + 2.0 * k / 15.0, el = 0.3 * std::sin(3.0 * k);
    const scan::Vec3 d{std::cos(el) * std::cos(az), std::cos(el) * std::sin(az), std::sin(el)};
    const scan::Hit h = caster.cast(pose.transform({0, 0, 0}), pose.rotate(d));
    if (h.hit() && !(h.distance_m >= 0 && std::isfinite(h.distance_m))) std::abort();
    if (h.hit() && !(h.reflectance >= 0 && h.reflectance <= 1)) std::abort();
  }
  return 0;
}
