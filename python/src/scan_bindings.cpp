// Bindings of scanning: a scene file scanned by a pattern through the virtual
// rangefinder (`tofkit scan`), returned as NumPy images, points and the
// per-beam table instead of files.

#include <fmt/format.h>
#include <pybind11/stl.h>
#include <pybind11/stl/filesystem.h>

#include <cmath>
#include <cstdint>
#include <optional>
#include <set>
#include <string>
#include <utility>
#include <vector>

#include "bindings.hpp"
#include "tofkit/device/device_config.hpp"
#include "tofkit/device/virtual_rangefinder.hpp"
#include "tofkit/io/scan_output.hpp"
#include "tofkit/io/scene_file.hpp"
#include "tofkit/io/value_list.hpp"
#include "tofkit/scan/scanner.hpp"

namespace tofkit::python {
namespace {

namespace fs = std::filesystem;

/// `tofkit scan`'s options (the CLI's defaults are the Python defaults).
struct ScanArgs {
  std::string pattern;
  py::object y = py::none(), z = py::none(), azimuth = py::none(), elevation = py::none();
  int samples = 1, revolutions = 1, shots = 0;
  double speed_m_per_s = 0.05, turnaround_s = 0.5, rate_hz = 10, azimuth_step_deg = 0.2;
  double ambient_c = device::Conditions{}.ambient_c;
  std::uint64_t seed = 1;
  std::string mode = "analytic";
  std::uint64_t shard_index = 0, shard_count = 1;  ///< shard=(k, n): beams [k n/N, (k+1) n/N)
};

/// One row of the per-beam table (BEAM_DTYPE): scan.csv's columns plus the
/// surfaces in the footprint.
struct BeamRow {
  std::int32_t row, column;
  double time_s, position_m;
  double origin_x_m, origin_y_m, origin_z_m, dir_x, dir_y, dir_z;
  double distance_true_m;
  std::int32_t surfaces;
  double reflectance, angle_deg;
  double tof_ns, distance_raw_m, pulse_width_ns, amplitude, temperature_c;
  std::uint32_t shots_valid, flags;
  double distance_m, sigma_m;
  std::uint32_t correction_flags;
};

/// The point cloud's columns (the CLI's PLY/PCD fields, in their order).
constexpr const char* kPointColumns[] = {"x",     "y",   "z",      "intensity", "range",
                                         "sigma", "row", "column", "time_s",    "flags"};
constexpr std::size_t kPointColumnCount = std::size(kPointColumns);

/// A scan's value list: the CLI's text ("a,b,c" or "start:stop:step") or numbers.
std::vector<double> value_list(const py::object& value, const std::string& name,
                               const std::string& pattern) {
  if (value.is_none()) throw std::invalid_argument("pattern " + pattern + " needs " + name);
  if (py::isinstance<py::str>(value)) {
    return io::parse_value_list(value.cast<std::string>(), name);
  }
  // c_style: a strided or reversed view is copied in order (its data() is not
  // the values one after another).
  const auto values = py::array_t<double, py::array::c_style | py::array::forcecast>::ensure(value);
  if (!values || values.ndim() > 1) {
    throw std::invalid_argument(name +
                                ": expected a number, a 1-D list or a string \"a,b,c\" / "
                                "\"start:stop:step\"");
  }
  return {values.data(), values.data() + values.size()};
}

scan::BeamPattern make_pattern(const ScanArgs& a, double period_s) {
  const scan::PatternSettings settings{a.samples,      a.revolutions, a.speed_m_per_s,
                                       a.turnaround_s, a.rate_hz,     a.azimuth_step_deg};
  const py::object* values[] = {&a.y, &a.z, &a.azimuth, &a.elevation};  // PatternListName order
  const auto lists = [&](scan::PatternListName l) {
    return value_list(*values[static_cast<std::size_t>(l)], scan::pattern_list_name(l), a.pattern);
  };
  return scan::make_pattern(a.pattern, settings, lists, period_s);
}

/// The CLI's option checks (CLI11 ranges), named after the Python arguments.
void check_range(double value, double lo, double hi, const char* name) {
  if (!(value >= lo && value <= hi)) {
    throw std::invalid_argument(fmt::format("{}: {} is not in [{}, {}]", name, value, lo, hi));
  }
}

void validate(const ScanArgs& a) {
  if (a.mode != "analytic" && a.mode != "waveform") {
    throw std::invalid_argument("mode: '" + a.mode + "' is not analytic or waveform");
  }
  check_range(a.samples, 1, 100000, "samples");
  check_range(a.speed_m_per_s, 0, 100, "speed_m_per_s");
  check_range(a.turnaround_s, 0, 1e4, "turnaround_s");
  check_range(a.rate_hz, 1e-6, 1e5, "rate_hz");
  check_range(a.revolutions, 1, 1e6, "revolutions");
  check_range(a.azimuth_step_deg, 1e-4, 360, "azimuth_step_deg");
  if (a.shots != 0) check_range(a.shots, 1, 1e7, "shots");
  check_range(a.ambient_c, -60, 150, "ambient_c");
  if (a.shard_count < 1 || a.shard_count > 1000000 || a.shard_index >= a.shard_count)
    throw std::invalid_argument("shard: (k, n) needs n = 1 .. 1000000 and k = 0 .. n - 1");
}

/// A NumPy array over a vector's memory (moved, not copied; freed with the array).
template <typename T>
py::array adopt(std::vector<T>&& values, std::vector<py::ssize_t> shape,
                const py::dtype& dtype = py::dtype::of<T>()) {
  auto* heap = new std::vector<T>(std::move(values));
  const py::capsule owner(heap, [](void* p) { delete static_cast<std::vector<T>*>(p); });
  return py::array(dtype, std::move(shape), {}, heap->data(), owner);
}

py::array image_array(scan::Image&& image) {
  return adopt(std::move(image.values), {image.rows, image.columns});
}

py::dtype beam_dtype() {
  struct Field {
    const char* name;
    const char* format;
    std::size_t offset;
  };
  const Field fields[] = {{"row", "<i4", offsetof(BeamRow, row)},
                          {"column", "<i4", offsetof(BeamRow, column)},
                          {"time_s", "<f8", offsetof(BeamRow, time_s)},
                          {"position_m", "<f8", offsetof(BeamRow, position_m)},
                          {"origin_x_m", "<f8", offsetof(BeamRow, origin_x_m)},
                          {"origin_y_m", "<f8", offsetof(BeamRow, origin_y_m)},
                          {"origin_z_m", "<f8", offsetof(BeamRow, origin_z_m)},
                          {"dir_x", "<f8", offsetof(BeamRow, dir_x)},
                          {"dir_y", "<f8", offsetof(BeamRow, dir_y)},
                          {"dir_z", "<f8", offsetof(BeamRow, dir_z)},
                          {"distance_true_m", "<f8", offsetof(BeamRow, distance_true_m)},
                          {"surfaces", "<i4", offsetof(BeamRow, surfaces)},
                          {"reflectance", "<f8", offsetof(BeamRow, reflectance)},
                          {"angle_deg", "<f8", offsetof(BeamRow, angle_deg)},
                          {"tof_ns", "<f8", offsetof(BeamRow, tof_ns)},
                          {"distance_raw_m", "<f8", offsetof(BeamRow, distance_raw_m)},
                          {"pulse_width_ns", "<f8", offsetof(BeamRow, pulse_width_ns)},
                          {"amplitude", "<f8", offsetof(BeamRow, amplitude)},
                          {"temperature_c", "<f8", offsetof(BeamRow, temperature_c)},
                          {"shots_valid", "<u4", offsetof(BeamRow, shots_valid)},
                          {"flags", "<u4", offsetof(BeamRow, flags)},
                          {"distance_m", "<f8", offsetof(BeamRow, distance_m)},
                          {"sigma_m", "<f8", offsetof(BeamRow, sigma_m)},
                          {"correction_flags", "<u4", offsetof(BeamRow, correction_flags)}};
  py::list names, formats, offsets;
  for (const Field& f : fields) {
    names.append(f.name);
    formats.append(f.format);
    offsets.append(f.offset);
  }
  return struct_dtype(names, formats, offsets, sizeof(BeamRow));
}

std::vector<BeamRow> beam_rows(const scan::ScanResult& r) {
  std::vector<BeamRow> rows;
  rows.reserve(r.beams.size());
  for (const auto& b : r.beams) {
    const auto& m = b.raw;
    rows.push_back({b.beam.row,
                    b.beam.column,
                    b.beam.time_s,
                    b.beam.position_m,
                    b.beam.origin_m[0],
                    b.beam.origin_m[1],
                    b.beam.origin_m[2],
                    b.beam.direction[0],
                    b.beam.direction[1],
                    b.beam.direction[2],
                    b.true_range_m,
                    b.surfaces,
                    b.reflectance,
                    device::incidence_angle_deg(b.cos_incidence),
                    m.tof_ns,
                    m.distance_raw_m,
                    m.pulse_width_ns,
                    m.amplitude,
                    m.temperature_c,
                    m.shots_valid,
                    m.flags,
                    b.range.distance_m,
                    b.range.sigma_m,
                    b.range.correction_flags});
  }
  return rows;
}

/// The cloud as an (N, 10) float64 array in kPointColumns' order.
std::vector<double> point_table(const std::vector<io::CloudPoint>& points) {
  std::vector<double> table;
  table.reserve(points.size() * kPointColumnCount);
  for (const auto& p : points) {
    for (const double v :
         {p.x, p.y, p.z, static_cast<double>(p.intensity), static_cast<double>(p.range),
          static_cast<double>(p.sigma), static_cast<double>(p.row), static_cast<double>(p.column),
          p.time_s, static_cast<double>(p.flags)}) {
      table.push_back(v);
    }
  }
  return table;
}

py::dict run(const device::DeviceConfig& config, const fs::path& scene_path, const ScanArgs& args,
             const py::object& model) {
  validate(args);
  const ranging::Pipeline* pipeline = model.is_none() ? nullptr : &pipeline_of(model);
  scan::Scene scene;
  try {
    scene = io::load_scene(scene_path);
  } catch (const std::exception& e) {
    rethrow_for_file(scene_path, e);
  }
  const int shots = args.shots > 0 ? args.shots : config.measurement.shots;
  const double period_s = shots / config.link.laser.repetition_hz;
  const scan::BeamPattern pattern = make_pattern(args, period_s);  // at most kMaxPatternBeams

  scan::ScanResult result;
  scan::ScanImages images;
  std::vector<io::CloudPoint> points;
  {
    py::gil_scoped_release release;
    const auto mode = args.mode == "waveform" ? device::SimulationMode::kWaveform
                                              : device::SimulationMode::kAnalytic;
    scan::ScanOptions options;
    options.seed = args.seed;
    options.shots = shots;
    options.conditions.ambient_c = args.ambient_c;
    if (args.shard_count <= 1) {
      result = scan::run_scan(scene, config, mode, pattern, options);
    } else {
      // A shard: its range of beams, the same values as in the whole scan
      // (beam i on random stream i); images hold its pixels only.
      const std::uint64_t n = pattern.size(), k = args.shard_index, count = args.shard_count;
      const auto at = [&](std::uint64_t j) { return n / count * j + n % count * j / count; };
      const device::VirtualRangefinder rangefinder(config, mode);
      const scan::RayCaster caster(scene);
      result = scan::describe_scan(pattern, scene);
      result.beams.reserve(at(k + 1) - at(k));
      scan::run_scan_blocks(caster, scan::Footprint(config), rangefinder, pattern, options, at(k),
                            at(k + 1), 1 << 15,
                            [&](std::size_t, std::span<scan::BeamResult> beams) {
                              result.beams.insert(result.beams.end(), beams.begin(), beams.end());
                            });
    }
    if (pipeline != nullptr) scan::apply_pipeline(*pipeline, result);
    images = scan::make_images(result);
    points = io::cloud_points(result);
  }

  py::dict out;
  out["range"] = image_array(std::move(images.range));
  out["intensity"] = image_array(std::move(images.intensity));
  out["sigma"] = image_array(std::move(images.sigma));
  out["truth"] = image_array(std::move(images.truth));
  const auto n_points = static_cast<py::ssize_t>(points.size());
  out["points"] =
      adopt(point_table(points), {n_points, static_cast<py::ssize_t>(kPointColumnCount)});
  const auto n_beams = static_cast<py::ssize_t>(result.beams.size());
  out["beams"] = adopt(beam_rows(result), {n_beams}, beam_dtype());
  out["pattern"] = result.pattern.name;
  out["rows"] = result.pattern.rows;
  out["columns"] = result.pattern.columns;
  out["shots"] = scan::shots_per_beam(config, shots, result.pattern);
  out["has_model"] = result.has_model;
  out["sensor_position_m"] = result.sensor.position_m;
  out["sensor_rpy_deg"] = result.sensor.rpy_deg;
  return out;
}

}  // namespace

void bind_scan(py::module_& m) {
  py::class_<ScanArgs>(m, "_ScanArgs")
      .def(py::init<>())
      .def_readwrite("pattern", &ScanArgs::pattern)
      .def_readwrite("y", &ScanArgs::y)
      .def_readwrite("z", &ScanArgs::z)
      .def_readwrite("azimuth", &ScanArgs::azimuth)
      .def_readwrite("elevation", &ScanArgs::elevation)
      .def_readwrite("samples", &ScanArgs::samples)
      .def_readwrite("revolutions", &ScanArgs::revolutions)
      .def_readwrite("shots", &ScanArgs::shots)
      .def_readwrite("speed_m_per_s", &ScanArgs::speed_m_per_s)
      .def_readwrite("turnaround_s", &ScanArgs::turnaround_s)
      .def_readwrite("rate_hz", &ScanArgs::rate_hz)
      .def_readwrite("azimuth_step_deg", &ScanArgs::azimuth_step_deg)
      .def_readwrite("ambient_c", &ScanArgs::ambient_c)
      .def_readwrite("seed", &ScanArgs::seed)
      .def_readwrite("mode", &ScanArgs::mode)
      .def_readwrite("shard_index", &ScanArgs::shard_index)
      .def_readwrite("shard_count", &ScanArgs::shard_count);
  m.def("_scan", &run, py::arg("config"), py::arg("scene"), py::arg("args"), py::arg("model"));
  m.attr("BEAM_DTYPE") = beam_dtype();
  py::tuple columns(kPointColumnCount);
  for (std::size_t i = 0; i < kPointColumnCount; ++i) columns[i] = kPointColumns[i];
  m.attr("POINT_COLUMNS") = columns;
}

}  // namespace tofkit::python
