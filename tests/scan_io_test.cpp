// Scan files read back by other code than the writers': Open3D (PLY, PCD),
// Pillow + NumPy (PNG + sidecar against .npy), and a LAS 1.2 header reader
// written here from the ASPRS specification. Also: bad scenes are refused with
// file and key named and nothing written; the CLI's output does not depend on
// the thread count.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <tuple>
#include <utility>
#include <vector>

#include "cli_runner.hpp"
#include "tofkit/io/scene_file.hpp"

namespace fs = std::filesystem;

using tofkit::test::read_file;

namespace {

const fs::path kScenes = fs::path(TOFKIT_REFERENCE_DIR).parent_path() / "examples" / "scenes";

fs::path fresh_dir(const std::string& name) {
  return tofkit::test::fresh_dir("tofkit_scan_io_", name);
}

int run(const std::string& command) {
  const int status = std::system((command + " 2>/dev/null").c_str());
  return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

std::string scan_command(const fs::path& out, int threads) {
  return std::string(TOFKIT_BINARY) + " --threads " + std::to_string(threads) + " scan --scene " +
         (kScenes / "blocks.toml").string() +
         " --pattern spherical --azimuth=-20:20:1 --elevation=-12:40:1.3 --shots 20 --seed 5"
         " --out " +
         out.string();
}

fs::path write_scene(const fs::path& dir, const std::string& text) {
  const fs::path p = dir / "scene.toml";
  std::ofstream(p) << text;
  return p;
}

std::string load_error(const fs::path& scene) {
  try {
    (void)tofkit::io::load_scene(scene);
  } catch (const tofkit::io::SceneError& e) {
    return e.what();
  }
  return "";
}

template <typename T>
T get(const std::string& bytes, std::size_t offset) {
  T v;
  std::memcpy(&v, bytes.data() + offset, sizeof v);
  return v;
}

}  // namespace

TEST(ScanIo, BadScenesNameFileAndKeyAndWriteNothing) {
  const fs::path dir = fresh_dir("bad");
  const std::string plane =
      "[[surface]]\nkind = \"plane\"\ncenter_m = [1, 0, 0]\nnormal = [-1, 0, 0]\nsize_m = [1, 1]\n";
  struct Case {
    std::string text, expect;
  } cases[] = {
      {plane + "reflectance = 0.5\ncolour = 3\n", "scene.toml:7: unknown key surface[0].colour"},
      {"[[surface]]\nkind = \"sphere\"\ncenter_m = [1, 0, 0]\nradius_m = 0\nreflectance = 0.5\n",
       "scene.toml:1: surface[0]: radius_m must be in [1e-06, 2e+05] m"},
      // Magnitudes Embree's float bounds or a pattern's int64 cell index
      // cannot hold (a 1e-300 sphere had been hit, a 1e-300 cell overflowed
      // the index) are refused like other degenerate primitives.
      {"[[surface]]\nkind = \"sphere\"\ncenter_m = [1, 0, 0]\nradius_m = 1e-300\nreflectance = "
       "0.5\n",
       "scene.toml:1: surface[0]: radius_m must be in [1e-06, 2e+05] m"},
      {"[[surface]]\nkind = \"sphere\"\ncenter_m = [1e300, 0, 0]\nradius_m = 1\nreflectance = "
       "0.5\n",
       "surface[0]: center_m must be finite, within 1e+05 m"},
      {"[[surface]]\nkind = \"cylinder\"\nbase_m = [2, 0, -1]\naxis = [0, 0, 1]\nradius_m = "
       "0.5\nheight_m = 1e30\nreflectance = 0.5\n",
       "surface[0]: height_m must be in [1e-06, 2e+05] m"},
      {"[[surface]]\nkind = \"box\"\nmin_m = [1, 0, 0]\nmax_m = [1.0000000001, 1, 1]\nreflectance "
       "= 0.5\n",
       "surface[0]: max_m must exceed min_m by at least 1e-06 m on every axis"},
      {plane + "pattern = \"checker\"\nvalues = [0.1, 0.5]\ncell_m = 1e-300\n",
       "surface[0]: cell_m must be in [1e-06, 2e+05] m"},
      {"[sensor]\npose_m = [0, 0, -1e200]\n" + plane + "reflectance = 0.5\n",
       "sensor: pose_m must be finite, within 1e+05 m"},
      {"[[surface]]\nkind = \"mesh\"\nfile = \"point.obj\"\nreflectance = 0.5\n",
       "scene.toml:1: surface[0]: mesh has no triangle of nonzero area"},
      {"[[surface]]\nkind = \"mesh\"\nfile = \"empty.ply\"\nreflectance = 0.5\n",
       "empty.ply: element 'vertex' has no properties"},
      {"[[surface]]\nkind = \"mesh\"\nfile = \"short.ply\"\nreflectance = 0.5\n",
       "short.ply: the header's element counts need at least 12000 bytes of data, the file has 12"},
      {"[[surface]]\nkind = \"mesh\"\nfile = \"index.ply\"\nreflectance = 0.5\n",
       "index.ply: face 1 refers to vertex 7, but the file has 3"},
      {"[[surface]]\nkind = \"mesh\"\nfile = \"nowhere.ply\"\nreflectance = 0.5\n",
       "scene.toml:3: surface[0].file: "},
      {plane + "reflectance = 1.5\n", "surface[0]: reflectance must lie in [0, 1]"},
      {"[[surface]]\nkind = \"mesh\"\nfile = \"junk.obj\"\nreflectance = 0.5\n",
       "junk.obj:4: bad face index '3x'"},  // (had been read as 3)
      {"[[surface]]\nkind = \"mesh\"\nfile = \"nan.ply\"\nreflectance = 0.5\n",
       "nan.ply: 'nan' in the PLY data is not a number"},  // (had said "truncated")
      {plane + "pattern = \"checker\"\ncell_m = 0.01\nseed = -3\n",
       "surface[0].seed must be a whole number >= 0"},
      {plane + "pattern = \"checker\"\ncell_m = 0.01\nseed = 3\nrandom_min = 0.8\n"
               "random_max = 0.2\n",
       "surface[0]: random_min must not exceed random_max"},
      // A NaN or huge sensor angle had aborted on Embree's ray check; a 1e300
      // normal overflowed its length and the plane vanished (exit 0, no echo).
      {"[sensor]\nrpy_deg = [nan, 0, 0]\n" + plane + "reflectance = 0.5\n",
       "scene.toml:1: sensor: rpy_deg must be finite angles within +-360 degrees"},
      {"[[surface]]\nkind = \"plane\"\ncenter_m = [1, 0, 0]\nnormal = [-1e300, 0, 0]\n"
       "size_m = [1, 1]\nreflectance = 0.5\n",
       "surface[0]: normal must be a nonzero vector (length in [1e-12, 1e+12])"},
      {plane + "pattern = \"stripes\"\ncell_m = 0.01\n", "surface[0].values is missing"},
  };
  // Three vertices on one point: a mesh with no surface.
  std::ofstream(dir / "point.obj") << "v 1 0 0\nv 1 0 0\nv 1 0 0\nf 1 2 3\n";
  // Headers whose counts the data cannot hold (found by fuzz_mesh: 30 million
  // vertices of no property filled memory).
  std::ofstream(dir / "empty.ply") << "ply\nformat binary_little_endian 1.0\n"
                                      "element vertex 30000000\nend_header\n";
  std::ofstream(dir / "junk.obj") << "v 1 0 0\nv 1 1 0\nv 1 0 1\nf 1 2 3x\n";
  std::ofstream(dir / "nan.ply") << "ply\nformat ascii 1.0\nelement vertex 3\nproperty float "
                                    "x\nproperty float y\nproperty float z\nelement face 1\n"
                                    "property list uchar int vertex_indices\nend_header\n"
                                    "1 0 0\nnan 1 0\n1 0 1\n3 0 1 2\n";
  std::ofstream(dir / "index.ply") << "ply\nformat ascii 1.0\nelement vertex 3\nproperty float "
                                      "x\nproperty float y\nproperty float z\nelement face 2\n"
                                      "property list uchar int vertex_indices\nend_header\n"
                                      "1 0 0\n1 1 0\n1 0 1\n3 0 1 2\n3 0 1 7\n";
  std::ofstream(dir / "short.ply") << "ply\nformat binary_little_endian 1.0\nelement vertex "
                                      "1000\nproperty float x\nproperty float y\nproperty "
                                      "float z\nend_header\n0123456789ab";
  for (const auto& c : cases) {
    const fs::path scene = write_scene(dir, c.text);
    const std::string message = load_error(scene);
    EXPECT_NE(message.find(c.expect), std::string::npos) << message;
    const fs::path out = dir / "out";
    fs::remove_all(out);
    fs::create_directories(out);
    EXPECT_EQ(run(std::string(TOFKIT_BINARY) + " scan --scene " + scene.string() +
                  " --pattern spherical --azimuth=0 --elevation=0 --out " + out.string()),
              1);
    EXPECT_TRUE(fs::is_empty(out)) << c.expect;
  }
  // Scene and mesh files are read as every input is (io::read_text_file): a
  // directory or a device is named as such (both had been "not found"), and
  // a mesh over --max-input-mb is refused before it is parsed.
  EXPECT_NE(load_error(dir).find(dir.string() + ": is a directory, expected a scene file"),
            std::string::npos);
  EXPECT_NE(load_error("/dev/null").find("/dev/null: is not a regular file, expected a scene file"),
            std::string::npos);
  {
    std::ofstream big(dir / "big.obj");
    for (int i = 0; i < 200000; ++i) big << "v 1 " << i * 1e-4 << " " << i % 2 << "\n";
    big << "f 1 2 3\n";
  }
  const fs::path big_scene =
      write_scene(dir, "[[surface]]\nkind = \"mesh\"\nfile = \"big.obj\"\nreflectance = 0.5\n");
  const fs::path out = dir / "out";
  fs::remove_all(out);
  fs::create_directories(out);
  const std::string limited = std::string(TOFKIT_BINARY) + " --max-input-mb 1 scan --scene " +
                              big_scene.string() +
                              " --pattern spherical --azimuth=0 --elevation=0 --out " +
                              out.string() + " 2> " + (dir / "err.txt").string();
  const int status = std::system(limited.c_str());
  EXPECT_TRUE(WIFEXITED(status) && WEXITSTATUS(status) == 1);
  std::ifstream err(dir / "err.txt");
  const std::string said((std::istreambuf_iterator<char>(err)), std::istreambuf_iterator<char>());
  EXPECT_NE(said.find("big.obj: "), std::string::npos) << said;
  EXPECT_NE(said.find("is larger than the input limit of 1048576 bytes"), std::string::npos)
      << said;
  EXPECT_TRUE(fs::is_empty(out));
  EXPECT_EQ(
      run(std::string(TOFKIT_BINARY) + " scan --scene " + big_scene.string() +
          " --pattern spherical --azimuth=0 --elevation=0 --out " + out.string() + " > /dev/null"),
      0);
  fs::remove_all(dir);
}

// An OBJ file that starts with a UTF-8 byte-order mark is the same mesh (the
// mark had hidden the first vertex's tag: the faces pointed one vertex off).
TEST(ScanIo, AnObjWithAByteOrderMarkIsTheSameMesh) {
  const fs::path dir = fresh_dir("bom");
  const std::string obj = "v 1 0 0\nv 1 1 0\nv 1 0 1\nv 1 1 1\nf 1 2 3\nf 2 4 3\n";
  std::ofstream(dir / "plain.obj") << obj;
  std::ofstream(dir / "marked.obj") << "\xEF\xBB\xBF" << obj;
  auto mesh = [&](const char* file) {
    const fs::path scene = dir / (std::string(file) + ".toml");
    std::ofstream(scene) << "[[surface]]\nkind = \"mesh\"\nfile = \"" << file
                         << "\"\nreflectance = 0.5\n";
    return tofkit::io::load_scene(scene).primitives.at(0);
  };
  const auto plain = mesh("plain.obj"), marked = mesh("marked.obj");
  EXPECT_EQ(marked.vertices, plain.vertices);
  EXPECT_EQ(marked.triangles, plain.triangles);
  EXPECT_EQ(plain.vertices.size(), 4u);
  fs::remove_all(dir);
}

TEST(ScanIo, ExampleScenesLoad) {
  for (const char* name : {"blocks.toml", "grey_stripes.toml", "random_checker.toml"}) {
    EXPECT_NO_THROW((void)tofkit::io::load_scene(kScenes / name)) << name;
  }
  const auto blocks = tofkit::io::load_scene(kScenes / "blocks.toml");
  bool mesh = false;
  for (const auto& p : blocks.primitives) {
    if (p.kind == tofkit::scan::PrimitiveKind::kMesh) {
      mesh = true;
      EXPECT_EQ(p.triangles.size(), 5u);  // two quads fanned into two triangles each + a cap
    }
  }
  EXPECT_TRUE(mesh);
}

// The command in each example scene's header comment runs as written (two
// had a list the parser refuses, 0.08:-0.08:0.002, unnoticed).
TEST(ScanIo, ExampleScenesRunTheCommandsInTheirComments) {
  const fs::path out = fresh_dir("examples");
  for (const char* name : {"blocks.toml", "grey_stripes.toml", "random_checker.toml"}) {
    std::ifstream in(kScenes / name);
    std::string line, command;
    while (std::getline(in, line) && line.rfind('#', 0) == 0) {
      const auto at = line.find("tofkit scan");
      if (command.empty() && at == std::string::npos) continue;
      std::string part = line.substr(command.empty() ? at + 6 : 1);  // after "tofkit"
      if (!part.empty() && part.back() == '\\') part.pop_back();
      command += part;
      if (line.find("--out DIR") != std::string::npos) break;
    }
    ASSERT_NE(command.find("--out DIR"), std::string::npos) << name;
    command.replace(command.find("--out DIR"), 9, "--write npy --out " + out.string());
    fs::remove_all(out);
    fs::create_directories(out);
    EXPECT_EQ(run("cd " + kScenes.string() + " && " + TOFKIT_BINARY + command + " > /dev/null"), 0)
        << name << ":" << command;
    EXPECT_TRUE(fs::exists(out / "range.npy")) << name;
  }
  fs::remove_all(out);
}

// Every scan output goes through the one writer (io/atomic_file.hpp): a
// target that is the scene, a link or a directory is refused naming it, and
// nothing else is written. scan had its own writer that replaced its scene,
// links and FIFOs, and left the files before a failing one behind.
TEST(ScanIo, OutputsThatAreInputsLinksOrDirectoriesAreRefusedWritingNothing) {
  const fs::path dir = fresh_dir("outputs");
  const std::string plane =
      "[[surface]]\nkind = \"plane\"\ncenter_m = [2, 0, 0]\nnormal = [-1, 0, 0]\n"
      "size_m = [1, 1]\nreflectance = 0.5\n";
  const fs::path out = dir / "out";
  auto scan = [&](const fs::path& scene, const std::string& shots) {
    const std::string command = std::string(TOFKIT_BINARY) + " scan --scene " + scene.string() +
                                " --pattern raster --y 0,0.1 --z 0 " + shots + " --out " +
                                out.string() + " 2> " + (dir / "err.txt").string();
    const int status = std::system(command.c_str());
    return std::pair{WIFEXITED(status) ? WEXITSTATUS(status) : -1, read_file(dir / "err.txt")};
  };
  auto only = [&](const std::string& name) {
    std::vector<std::string> names;
    for (const auto& e : fs::directory_iterator(out)) names.push_back(e.path().filename());
    return names == std::vector<std::string>{name};
  };
  fs::create_directories(out);
  std::ofstream(out / "scan.csv") << plane;  // the scene, where scan.csv goes
  auto [status, said] = scan(out / "scan.csv", "--shots 10");
  EXPECT_EQ(status, 1);
  EXPECT_NE(said.find("scan.csv': it is the input file"), std::string::npos) << said;
  EXPECT_EQ(read_file(out / "scan.csv"), plane);
  EXPECT_TRUE(only("scan.csv"));

  const fs::path scene = write_scene(dir, plane);
  fs::remove_all(out);
  fs::create_directories(out);
  fs::create_symlink(dir / "elsewhere.csv", out / "scan.csv");
  std::tie(status, said) = scan(scene, "--shots 10");
  EXPECT_EQ(status, 1);
  EXPECT_NE(said.find("scan.csv': it is a symbolic link"), std::string::npos) << said;
  EXPECT_TRUE(fs::is_symlink(out / "scan.csv"));
  EXPECT_TRUE(only("scan.csv"));

  fs::remove_all(out);
  fs::create_directories(out / "points.ply");  // written after scan.csv, the images
  std::tie(status, said) = scan(scene, "--shots 10");
  EXPECT_EQ(status, 1);
  EXPECT_NE(said.find("points.ply': it is a directory"), std::string::npos) << said;
  EXPECT_TRUE(only("points.ply"));

  // A raster's samples times its shots are the shots of one output, bounded
  // as --shots is (65536 x 65536 had wrapped to 0 and scanned with the config's).
  fs::remove_all(out);
  fs::create_directories(out);
  std::tie(status, said) = scan(scene, "--samples 65536 --shots 65536");
  EXPECT_EQ(status, 1);
  EXPECT_NE(said.find("65536 samples x 65536 shots = 4294967296 shots per point is over the "
                      "limit of 10000000"),
            std::string::npos)
      << said;
  EXPECT_TRUE(fs::is_empty(out));
  fs::remove_all(dir);
}

TEST(ScanIo, SameBytesOnOneAndTwoThreads) {
  const fs::path a = fresh_dir("t1"), b = fresh_dir("t2");
  ASSERT_EQ(run(scan_command(a, 1)), 0);
  ASSERT_EQ(run(scan_command(b, 2)), 0);
  std::size_t files = 0;
  for (const auto& entry : fs::directory_iterator(a)) {
    ++files;
    EXPECT_EQ(read_file(entry.path()), read_file(b / entry.path().filename()))
        << entry.path().filename();
  }
  EXPECT_EQ(files, 14u);  // csv, 3 x (png, json, npy) (sigma: calibrated), ply, pcd, las, view
  fs::remove_all(a);
  fs::remove_all(b);
}

TEST(ScanIo, CloudsOpenInOpen3dAndPngMatchesNpyAndLasHeaderChecks) {
  const fs::path dir = fresh_dir("readers");
  ASSERT_EQ(run(scan_command(dir, 2)), 0);

  // Points: one per beam with an echo = finite pixels of range.npy (a 1:1
  // pattern); the scan looks above the wall, so some beams miss (REP-117).
  const std::string script = R"PY(
import sys, json, numpy as np, open3d as o3d
from PIL import Image
d = sys.argv[1]
rng = np.load(d + '/range.npy')
valid = np.isfinite(rng)
assert 0 < valid.sum() < rng.size, (valid.sum(), rng.size)
n = int(valid.sum())
for name in ('points.ply', 'points.pcd'):
    pc = o3d.t.io.read_point_cloud(d + '/' + name)
    for field in ('intensity', 'range', 'sigma', 'row', 'column', 'time', 'flags'):
        assert field in pc.point, (name, field)
    pos = pc.point.positions.numpy().astype(np.float64)
    assert len(pos) == n, (name, len(pos), n)
    r = pc.point.range.numpy()[:, 0]
    # Sensor at the origin: |point| is the range; rows/columns index range.npy.
    assert np.allclose(np.linalg.norm(pos, axis=1), r, atol=2e-6 * r.max()), name
    rows = pc.point.row.numpy()[:, 0]; cols = pc.point.column.numpy()[:, 0]
    assert np.allclose(rng[rows, cols], r, rtol=1e-6), name
    assert len(o3d.io.read_point_cloud(d + '/' + name).points) == n, name
for q in ('range', 'intensity'):
    side = json.load(open(d + '/' + q + '.json'))
    png = np.array(Image.open(d + '/' + q + '.png')).astype(np.float64)
    ref = np.load(d + '/' + q + '.npy')
    assert png.shape == ref.shape and side['invalid_value'] == 0
    assert ((png == 0) == ~np.isfinite(ref)).all(), q
    dec = side['offset'] + side['scale'] * png
    ok = np.isfinite(ref)
    err = np.abs(dec[ok] - ref[ok]).max()
    assert err <= side['scale'], (q, err, side['scale'])
print(n)
)PY";
  std::ofstream(dir / "check.py") << script;
  const std::string cmd = "/usr/bin/python3 " + (dir / "check.py").string() + " " + dir.string() +
                          " > " + (dir / "count.txt").string();
  ASSERT_EQ(std::system(cmd.c_str()), 0) << "Open3D / Pillow check failed";
  const long n = std::stol(read_file(dir / "count.txt"));

  // LAS 1.2 public header block, read at the specification's byte offsets.
  const std::string las = read_file(dir / "points.las");
  ASSERT_GE(las.size(), 227u);
  EXPECT_EQ(las.substr(0, 4), "LASF");
  EXPECT_EQ(las[24], 1);
  EXPECT_EQ(las[25], 2);
  EXPECT_EQ(get<std::uint16_t>(las, 94), 227);  // header size
  const auto data_offset = get<std::uint32_t>(las, 96);
  EXPECT_EQ(get<std::uint8_t>(las, 104), 1);  // point data format 1
  const auto record = get<std::uint16_t>(las, 105);
  EXPECT_EQ(record, 28);
  const auto count = get<std::uint32_t>(las, 107);
  EXPECT_EQ(static_cast<long>(count), n);
  EXPECT_EQ(las.size(), data_offset + static_cast<std::size_t>(count) * record);
  double scale[3], offset[3], max[3], min[3];
  for (int k = 0; k < 3; ++k) {
    scale[k] = get<double>(las, 131 + 8 * k);
    offset[k] = get<double>(las, 155 + 8 * k);
    max[k] = get<double>(las, 179 + 16 * k);
    min[k] = get<double>(las, 187 + 16 * k);
    EXPECT_EQ(scale[k], 1e-4);
  }
  // Every record lies in the header's bounds; the extremes reach them.
  double lo[3] = {1e300, 1e300, 1e300}, hi[3] = {-1e300, -1e300, -1e300};
  for (std::uint32_t i = 0; i < count; ++i) {
    const std::size_t at = data_offset + static_cast<std::size_t>(i) * record;
    for (int k = 0; k < 3; ++k) {
      const double v = get<std::int32_t>(las, at + 4 * k) * scale[k] + offset[k];
      lo[k] = std::min(lo[k], v);
      hi[k] = std::max(hi[k], v);
    }
    const double gps_time = get<double>(las, at + 20);
    EXPECT_GE(gps_time, 0.0);
  }
  for (int k = 0; k < 3; ++k) {
    EXPECT_NEAR(lo[k], min[k], scale[k]);
    EXPECT_NEAR(hi[k], max[k], scale[k]);
    EXPECT_LT(min[k], max[k]);
  }
  fs::remove_all(dir);
}
