#include "tofkit/io/scene_file.hpp"

#include <fmt/format.h>
#include <toml++/toml.h>

#include <algorithm>
#include <charconv>
#include <cstring>
#include <set>
#include <sstream>
#include <string>
#include <string_view>
#include <vector>

#include "tofkit/io/input_file.hpp"

namespace tofkit::io {
namespace {

namespace fs = std::filesystem;
using scan::Primitive;
using scan::PrimitiveKind;
using scan::Reflectance;
using scan::Vec3;

// Collects every problem, then throws them all at once.
struct Problems {
  std::vector<std::string> lines;
  void add(const std::string& where, const std::string& what) {
    lines.push_back(where + ": " + what);
  }
  void throw_if_any() const {
    if (lines.empty()) return;
    std::string text;
    for (const auto& l : lines) text += (text.empty() ? "" : "\n") + l;
    throw SceneError(text);
  }
};

/// A file's whole text through io::read_text_file (its checks and
/// --max-input-mb), its errors as SceneErrors.
std::string read_input(const fs::path& file, std::string_view what) {
  try {
    return read_text_file(file, what);
  } catch (const std::runtime_error& e) {
    throw SceneError(e.what());
  }
}

/// An input stream over a text already read, without copying it (seekable:
/// the PLY reader measures the data after its header).
class TextBuffer : public std::streambuf {
 public:
  explicit TextBuffer(std::string& text) {
    setg(text.data(), text.data(), text.data() + text.size());
  }

 protected:
  pos_type seekoff(off_type off, std::ios_base::seekdir dir, std::ios_base::openmode) override {
    char* base = dir == std::ios_base::beg ? eback() : dir == std::ios_base::cur ? gptr() : egptr();
    if (off < eback() - base || off > egptr() - base) return pos_type(off_type(-1));
    setg(eback(), base + off, egptr());
    return pos_type(gptr() - eback());
  }
  pos_type seekpos(pos_type pos, std::ios_base::openmode which) override {
    return seekoff(off_type(pos), std::ios_base::beg, which);
  }
};

class Reader {
 public:
  Reader(std::string file, Problems& problems) : file_(std::move(file)), problems_(problems) {}

  std::string where(const toml::node& node) const {
    return file_ + ":" + std::to_string(node.source().begin.line);
  }

  bool number(const toml::table& t, const std::string& prefix, const char* key, double& out) {
    const toml::node* n = t.get(key);
    if (n == nullptr) return false;
    if (auto v = n->value<double>()) {
      out = *v;
      return true;
    }
    problems_.add(where(*n), prefix + key + " must be a number");
    return false;
  }

  bool integer(const toml::table& t, const std::string& prefix, const char* key,
               std::int64_t& out) {
    const toml::node* n = t.get(key);
    if (n == nullptr) return false;
    if (auto v = n->value_exact<std::int64_t>()) {
      out = *v;
      return true;
    }
    problems_.add(where(*n), prefix + key + " must be an integer");
    return false;
  }

  bool string(const toml::table& t, const std::string& prefix, const char* key, std::string& out) {
    const toml::node* n = t.get(key);
    if (n == nullptr) return false;
    if (auto v = n->value<std::string>()) {
      out = *v;
      return true;
    }
    problems_.add(where(*n), prefix + key + " must be a string");
    return false;
  }

  bool numbers(const toml::table& t, const std::string& prefix, const char* key,
               std::vector<double>& out, std::size_t exact_size) {
    const toml::node* n = t.get(key);
    if (n == nullptr) return false;
    const auto* arr = n->as_array();
    bool ok = arr != nullptr && (exact_size == 0 || arr->size() == exact_size) && !arr->empty();
    out.clear();
    if (ok) {
      for (const auto& e : *arr) {
        const auto v = e.value<double>();
        if (!v) {
          ok = false;
          break;
        }
        out.push_back(*v);
      }
    }
    if (!ok) {
      problems_.add(where(*n), exact_size > 0 ? fmt::format("{}{} must be an array of {} numbers",
                                                            prefix, key, exact_size)
                                              : prefix + key + " must be an array of numbers");
    }
    return ok;
  }

  bool vec3(const toml::table& t, const std::string& prefix, const char* key, Vec3& out) {
    std::vector<double> v;
    if (!numbers(t, prefix, key, v, 3)) return false;
    out = {v[0], v[1], v[2]};
    return true;
  }

  void require(const toml::table& t, const std::string& prefix, const char* key) {
    if (t.get(key) == nullptr) problems_.add(where(t), prefix + key + " is missing");
  }

  void unknown_keys(const toml::table& t, const std::string& prefix,
                    const std::set<std::string>& known) {
    for (const auto& [k, v] : t) {
      if (known.count(std::string(k.str())) == 0) {
        problems_.add(where(v), "unknown key " + prefix + std::string(k.str()));
      }
    }
  }

 private:
  std::string file_;
  Problems& problems_;
};

toml::table parse(const fs::path& file) {
  const std::string text = read_input(file, "scene file");
  try {
    return toml::parse(text, file.string());
  } catch (const toml::parse_error& e) {
    throw SceneError(fmt::format("{}:{}:{}: TOML syntax error: {}", file.string(),
                                 e.source().begin.line, e.source().begin.column, e.description()));
  }
}

// ---- meshes ----

void load_obj(const fs::path& file, Primitive& mesh) {
  std::string text = read_input(file, "mesh file");
  // A UTF-8 byte-order mark (some editors write one) is not part of line 1's
  // tag: left in, the first vertex was skipped and every face shifted.
  if (text.starts_with("\xEF\xBB\xBF")) text.erase(0, 3);
  TextBuffer buffer(text);
  std::istream in(&buffer);
  std::string line;
  int line_no = 0;
  while (std::getline(in, line)) {
    ++line_no;
    std::istringstream ls(line);
    std::string tag;
    ls >> tag;
    if (tag == "v") {
      Vec3 v;
      if (!(ls >> v[0] >> v[1] >> v[2])) {
        throw SceneError(fmt::format("{}:{}: bad vertex", file.string(), line_no));
      }
      mesh.vertices.push_back(v);
    } else if (tag == "f") {
      std::vector<std::uint32_t> idx;
      std::string token;
      while (ls >> token) {
        // The vertex index, up to a '/' (texture and normal indices follow), whole:
        // '3x' or '3.9' had been read as 3.
        const std::string_view index(token.data(), std::min(token.find('/'), token.size()));
        long i = 0;
        const auto [end, error] = std::from_chars(index.data(), index.data() + index.size(), i);
        if (error != std::errc() || end != index.data() + index.size()) {
          throw SceneError(
              fmt::format("{}:{}: bad face index '{}'", file.string(), line_no, token));
        }
        const long n = static_cast<long>(mesh.vertices.size());
        const long k = i > 0 ? i - 1 : n + i;  // negative: relative to the end
        if (k < 0 || k >= n) {
          throw SceneError(
              fmt::format("{}:{}: face index {} out of range", file.string(), line_no, i));
        }
        idx.push_back(static_cast<std::uint32_t>(k));
      }
      if (idx.size() < 3)
        throw SceneError(
            fmt::format("{}:{}: face with fewer than 3 vertices", file.string(), line_no));
      for (std::size_t k = 1; k + 1 < idx.size(); ++k)
        mesh.triangles.push_back({idx[0], idx[k], idx[k + 1]});
    }
  }
}

struct PlyProperty {
  std::string name, type, count_type;  // count_type non-empty for lists
};
struct PlyElement {
  std::string name;
  std::size_t count = 0;
  std::vector<PlyProperty> properties;
};

std::size_t ply_type_size(const std::string& t) {
  if (t == "char" || t == "uchar" || t == "int8" || t == "uint8") return 1;
  if (t == "short" || t == "ushort" || t == "int16" || t == "uint16") return 2;
  if (t == "int" || t == "uint" || t == "int32" || t == "uint32" || t == "float" || t == "float32")
    return 4;
  if (t == "double" || t == "float64") return 8;
  return 0;
}

/// Memory a PLY's mesh may take per byte of the file (a vertex of three
/// uchar coordinates is the smallest: 3 bytes for a 24-byte Vec3).
constexpr double kPlyMemoryPerInputByte = 8;

double ply_read_binary(const char* p, const std::string& t) {
  auto get = [&](auto v) {
    std::memcpy(&v, p, sizeof v);
    return static_cast<double>(v);
  };
  if (t == "char" || t == "int8") return get(std::int8_t{});
  if (t == "uchar" || t == "uint8") return get(std::uint8_t{});
  if (t == "short" || t == "int16") return get(std::int16_t{});
  if (t == "ushort" || t == "uint16") return get(std::uint16_t{});
  if (t == "int" || t == "int32") return get(std::int32_t{});
  if (t == "uint" || t == "uint32") return get(std::uint32_t{});
  if (t == "float" || t == "float32") return get(float{});
  return get(double{});
}

void load_ply(const fs::path& file, Primitive& mesh) {
  std::string text = read_input(file, "mesh file");
  TextBuffer buffer(text);
  std::istream in(&buffer);
  const std::string name = file.string();
  std::string line;
  std::getline(in, line);
  if (line.rfind("ply", 0) != 0) throw SceneError(name + ": not a PLY file");
  std::string format;
  std::vector<PlyElement> elements;
  while (std::getline(in, line)) {
    if (!line.empty() && line.back() == '\r') line.pop_back();
    std::istringstream ls(line);
    std::string tag;
    ls >> tag;
    if (tag == "format") {
      ls >> format;
    } else if (tag == "element") {
      PlyElement e;
      ls >> e.name >> e.count;
      if (e.count > (1u << 28)) throw SceneError(name + ": element count too large");
      elements.push_back(e);
    } else if (tag == "property") {
      if (elements.empty()) throw SceneError(name + ": property before element");
      PlyProperty p;
      ls >> p.type;
      if (p.type == "list") ls >> p.count_type >> p.type;
      ls >> p.name;
      if (ply_type_size(p.type) == 0 ||
          (!p.count_type.empty() && ply_type_size(p.count_type) == 0)) {
        throw SceneError(name + ": unknown PLY property type in '" + line + "'");
      }
      elements.back().properties.push_back(p);
    } else if (tag == "end_header") {
      break;
    }
  }
  const bool ascii = format == "ascii";
  if (!ascii && format != "binary_little_endian") {
    throw SceneError(name + ": PLY format '" + format +
                     "' is not supported (ascii, binary_little_endian)");
  }
  // Every instance of an element holds at least one value: the counts the
  // header declares must fit in the data that follows it (a header promising
  // 30 million vertices in 100 bytes had filled memory).
  const auto header_end = in.tellg();
  in.seekg(0, std::ios::end);
  const double data_bytes = static_cast<double>(in.tellg() - header_end);
  in.seekg(header_end);
  double least_bytes = 0;
  for (const auto& e : elements) {
    if (e.properties.empty() && e.count > 0)
      throw SceneError(name + ": element '" + e.name + "' has no properties");
    double instance = 0;  // ascii: a digit and a separator per value at least
    for (const auto& p : e.properties)
      instance +=
          ascii ? 2.0
                : static_cast<double>(ply_type_size(p.count_type.empty() ? p.type : p.count_type));
    least_bytes += static_cast<double>(e.count) * instance;
  }
  if (least_bytes > data_bytes + 1) {
    throw SceneError(
        fmt::format("{}: the header's element counts need at least {:.0f} bytes of "
                    "data, the file has {:.0f} (truncated PLY data)",
                    name, least_bytes, data_bytes));
  }
  // Memory bounded by a small multiple of the input: a vertex takes a Vec3
  // (24 bytes) whatever its properties, so a vertex element must hold x, y
  // and z, and the vertices with the triangles their faces can make must fit
  // in kPlyMemoryPerInputByte times the file (1e8 one-byte vertices of a
  // 100 MB file had taken 3.25 GB before being refused).
  std::size_t vertex_count = 0;
  double triangle_bound = 0;
  for (const auto& e : elements) {
    if (e.name == "vertex") {
      vertex_count = e.count;
      for (const char* axis : {"x", "y", "z"}) {
        if (std::none_of(e.properties.begin(), e.properties.end(),
                         [&](const PlyProperty& p) { return p.name == axis; })) {
          throw SceneError(name + ": the vertex element has no property '" + axis + "'");
        }
      }
    }
    if (e.name == "face") {
      // A list of n indices makes n - 2 triangles: at most one per index in
      // the data the other elements leave.
      for (const auto& p : e.properties) {
        if (!p.count_type.empty())
          triangle_bound += ascii ? 0.5 : 1.0 / static_cast<double>(ply_type_size(p.type));
      }
    }
  }
  double other_bytes = 0;  // the least the elements other than faces take
  for (const auto& e : elements) {
    if (e.name == "face") continue;
    for (const auto& p : e.properties) {
      other_bytes +=
          static_cast<double>(e.count) *
          (ascii
               ? 2.0
               : static_cast<double>(ply_type_size(p.count_type.empty() ? p.type : p.count_type)));
    }
  }
  triangle_bound *= std::max(0.0, data_bytes - other_bytes);
  const double memory_bytes =
      static_cast<double>(vertex_count) * sizeof(Vec3) + triangle_bound * sizeof(mesh.triangles[0]);
  const double file_bytes = data_bytes + static_cast<double>(header_end);
  if (memory_bytes > kPlyMemoryPerInputByte * file_bytes + 4096) {
    throw SceneError(fmt::format(
        "{}: {} vertices would take {:.0f} MB, more than {:.0f} times the file's {:.0f} MB (the "
        "vertex element's properties are too small to be coordinates)",
        name, vertex_count, memory_bytes / 1e6, kPlyMemoryPerInputByte, file_bytes / 1e6));
  }
  mesh.vertices.reserve(mesh.vertices.size() + vertex_count);
  auto read_value = [&](const std::string& type) -> double {
    if (ascii) {
      double v = 0;
      if (!(in >> v)) {
        if (in.eof()) throw SceneError(name + ": truncated PLY data");
        in.clear();
        std::string token;
        in >> token;
        throw SceneError(name + ": '" + token + "' in the PLY data is not a number");
      }
      return v;
    }
    char bytes[8];
    if (!in.read(bytes, static_cast<std::streamsize>(ply_type_size(type)))) {
      throw SceneError(name + ": truncated PLY data");
    }
    return ply_read_binary(bytes, type);
  };
  // A face's indices are checked against the header's vertex count (the
  // vertex element may follow the faces), so the message can name the face.
  for (const auto& e : elements) {
    for (std::size_t i = 0; i < e.count; ++i) {
      Vec3 v{0, 0, 0};
      for (const auto& p : e.properties) {
        if (!p.count_type.empty()) {
          const double n = read_value(p.count_type);
          if (!(n >= 0 && n < 1e6)) throw SceneError(name + ": bad list length");
          std::vector<std::uint32_t> idx;
          for (int k = 0; k < static_cast<int>(n); ++k) {
            const double x = read_value(p.type);
            if (!(x >= 0 && x < 4e9 && x == std::floor(x))) {
              // (a float index 1.5 had been truncated to 1)
              throw SceneError(fmt::format("{}: bad face index {} in {} {}", name, x, e.name, i));
            }
            idx.push_back(static_cast<std::uint32_t>(x));
          }
          if (e.name == "face" && (p.name == "vertex_indices" || p.name == "vertex_index")) {
            for (const auto index : idx) {
              if (index >= vertex_count) {
                throw SceneError(fmt::format("{}: face {} refers to vertex {}, but the file has {}",
                                             name, i, index, vertex_count));
              }
            }
            for (std::size_t k = 1; k + 1 < idx.size(); ++k)
              mesh.triangles.push_back({idx[0], idx[k], idx[k + 1]});
          }
          continue;
        }
        const double x = read_value(p.type);
        if (e.name == "vertex") {
          if (p.name == "x") v[0] = x;
          if (p.name == "y") v[1] = x;
          if (p.name == "z") v[2] = x;
        }
      }
      if (e.name == "vertex") mesh.vertices.push_back(v);
    }
  }
}

Reflectance read_reflectance(Reader& r, Problems& problems, const toml::table& t,
                             const std::string& prefix) {
  Reflectance refl;
  std::string pattern;
  const bool has_pattern = r.string(t, prefix, "pattern", pattern);
  double value = 0;
  const bool has_value = r.number(t, prefix, "reflectance", value);
  if (has_pattern && has_value) {
    problems.add(r.where(*t.get("pattern")),
                 prefix + "pattern and " + prefix + "reflectance exclude each other");
  }
  if (has_value) refl.value = value;
  if (!has_pattern) {
    if (!has_value) r.require(t, prefix, "reflectance");
    for (const char* key : {"values", "cell_m", "seed", "random_min", "random_max"}) {
      if (t.get(key) != nullptr)
        problems.add(r.where(*t.get(key)), prefix + key + " needs a pattern");
    }
    return refl;
  }
  if (pattern == "stripes") {
    refl.kind = Reflectance::Kind::kStripes;
  } else if (pattern == "checker") {
    refl.kind = Reflectance::Kind::kChecker;
  } else {
    problems.add(r.where(*t.get("pattern")), prefix + "pattern must be \"stripes\" or \"checker\"");
  }
  r.numbers(t, prefix, "values", refl.values, 0);
  r.number(t, prefix, "cell_m", refl.cell_m);
  r.require(t, prefix, "cell_m");
  std::int64_t seed = 0;
  if (r.integer(t, prefix, "seed", seed)) {
    if (refl.kind != Reflectance::Kind::kChecker) {
      problems.add(r.where(*t.get("seed")), prefix + "seed applies to pattern = \"checker\" only");
    }
    if (seed < 0) {  // (TOML integers are signed: -3 had become 2^64 - 3)
      problems.add(r.where(*t.get("seed")), prefix + "seed must be a whole number >= 0");
    }
    refl.random = true;
    refl.seed = static_cast<std::uint64_t>(seed);
  }
  r.number(t, prefix, "random_min", refl.random_min);
  r.number(t, prefix, "random_max", refl.random_max);
  if (!refl.random && t.get("values") == nullptr) r.require(t, prefix, "values");
  return refl;
}

}  // namespace

void load_mesh(const fs::path& file, Primitive& mesh) {
  const auto ext = file.extension().string();
  if (ext == ".obj" || ext == ".OBJ") {
    load_obj(file, mesh);
  } else if (ext == ".ply" || ext == ".PLY") {
    load_ply(file, mesh);
  } else {
    throw SceneError(file.string() + ": mesh files must be .ply or .obj");
  }
}

scan::Scene load_scene(const fs::path& file) {
  const toml::table root = parse(file);
  Problems problems;
  Reader r(file.string(), problems);
  scan::Scene scene;
  r.unknown_keys(root, "", {"sensor", "surface"});
  std::string sensor_where = r.where(root);  // the [sensor] table, else the file's start
  if (const toml::node* s = root.get("sensor")) {
    sensor_where = r.where(*s);
    if (const auto* t = s->as_table()) {
      r.unknown_keys(*t, "sensor.", {"pose_m", "rpy_deg"});
      r.vec3(*t, "sensor.", "pose_m", scene.sensor.position_m);
      r.vec3(*t, "sensor.", "rpy_deg", scene.sensor.rpy_deg);
    } else {
      problems.add(r.where(*s), "sensor must be a table");
    }
  }
  const toml::node* surfaces = root.get("surface");
  const auto* arr = surfaces != nullptr ? surfaces->as_array() : nullptr;
  if (surfaces != nullptr && (arr == nullptr || !arr->is_array_of_tables())) {
    problems.add(r.where(*surfaces), "surface must be an array of tables ([[surface]])");
  }
  if (arr == nullptr || arr->empty()) problems.add(file.string(), "the scene has no [[surface]]");
  std::vector<std::string> surface_where;
  if (arr != nullptr && arr->is_array_of_tables()) {
    for (std::size_t i = 0; i < arr->size(); ++i) {
      const auto& t = *arr->get(i)->as_table();
      const std::string prefix = fmt::format("surface[{}].", i);
      Primitive p;
      p.name = fmt::format("surface[{}]", i);
      std::string kind;
      r.string(t, prefix, "kind", kind);
      std::set<std::string> known = {"kind",   "reflectance", "pattern",    "values",
                                     "cell_m", "seed",        "random_min", "random_max"};
      if (kind == "plane") {
        p.kind = PrimitiveKind::kPlane;
        known.insert({"center_m", "normal", "size_m"});
        for (const char* k : {"center_m", "normal", "size_m"}) r.require(t, prefix, k);
        r.vec3(t, prefix, "center_m", p.center_m);
        r.vec3(t, prefix, "normal", p.normal);
        std::vector<double> size;
        if (r.numbers(t, prefix, "size_m", size, 2)) p.size_m = {size[0], size[1]};
      } else if (kind == "sphere") {
        p.kind = PrimitiveKind::kSphere;
        known.insert({"center_m", "radius_m"});
        for (const char* k : {"center_m", "radius_m"}) r.require(t, prefix, k);
        r.vec3(t, prefix, "center_m", p.center_m);
        r.number(t, prefix, "radius_m", p.radius_m);
      } else if (kind == "box") {
        p.kind = PrimitiveKind::kBox;
        known.insert({"min_m", "max_m"});
        for (const char* k : {"min_m", "max_m"}) r.require(t, prefix, k);
        r.vec3(t, prefix, "min_m", p.min_m);
        r.vec3(t, prefix, "max_m", p.max_m);
      } else if (kind == "cylinder") {
        p.kind = PrimitiveKind::kCylinder;
        known.insert({"base_m", "axis", "radius_m", "height_m"});
        for (const char* k : {"base_m", "axis", "radius_m", "height_m"}) r.require(t, prefix, k);
        r.vec3(t, prefix, "base_m", p.base_m);
        r.vec3(t, prefix, "axis", p.axis);
        r.number(t, prefix, "radius_m", p.radius_m);
        r.number(t, prefix, "height_m", p.height_m);
      } else if (kind == "mesh") {
        p.kind = PrimitiveKind::kMesh;
        known.insert({"file", "offset_m", "scale"});
        std::string mesh_file;
        Vec3 offset{0, 0, 0};
        double scale = 1;
        r.vec3(t, prefix, "offset_m", offset);
        r.number(t, prefix, "scale", scale);
        if (r.string(t, prefix, "file", mesh_file)) {
          const fs::path path = file.parent_path() / mesh_file;
          try {
            load_mesh(path, p);
          } catch (const SceneError& e) {
            problems.add(r.where(*t.get("file")), prefix + "file: " + e.what());
          }
          for (auto& v : p.vertices) v = scan::operator+(scan::operator*(scale, v), offset);
        } else {
          r.require(t, prefix, "file");
        }
      } else if (t.get("kind") != nullptr) {
        problems.add(
            r.where(*t.get("kind")),
            prefix + "kind must be plane, box, sphere, cylinder or mesh (got \"" + kind + "\")");
      } else {
        r.require(t, prefix, "kind");
      }
      r.unknown_keys(t, prefix, known);
      p.reflectance = read_reflectance(r, problems, t, prefix);
      surface_where.push_back(r.where(t));
      scene.primitives.push_back(std::move(p));
    }
  }
  problems.throw_if_any();
  // Geometry checks (degenerate primitives), located at their [[surface]].
  const std::string surface = "surface[";
  for (const auto& message : scene.validate()) {
    if (message.rfind(surface, 0) != 0) {  // the sensor's
      problems.add(sensor_where, message);
      continue;
    }
    const auto index = static_cast<std::size_t>(std::stoul(message.substr(surface.size())));
    problems.add(surface_where[index], message);
  }
  problems.throw_if_any();
  return scene;
}

}  // namespace tofkit::io
