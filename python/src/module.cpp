// tofkit._tofkit: thin bindings over the core batch APIs (kiss-icp's pattern:
// a C++ core, thin bindings, a small Python package on top).

#include <stdexcept>
#include <string>

#include "bindings.hpp"
#include "tofkit/io/config_file.hpp"
#include "tofkit/ranging/raw_measurement.hpp"

namespace tofkit::python {

py::dtype record_dtype() {
  using ranging::RawMeasurement;
  using ranging::Record;
  static_assert(sizeof(RawMeasurement) == 48 && sizeof(Record) == 80, "unexpected record layout");
  const auto raw = [](std::size_t member) { return offsetof(Record, raw) + member; };
  py::list names, formats, offsets;
  const auto add = [&](const char* name, const char* format, std::size_t offset) {
    names.append(name);
    formats.append(format);
    offsets.append(offset);
  };
  add("distance_true_m", "<f8",
      offsetof(Record, truth) + offsetof(ranging::GroundTruth, distance_m));
  add("reflectance", "<f8", offsetof(Record, truth) + offsetof(ranging::GroundTruth, reflectance));
  add("angle_deg", "<f8", offsetof(Record, truth) + offsetof(ranging::GroundTruth, angle_deg));
  add("ambient_c", "<f8", offsetof(Record, truth) + offsetof(ranging::GroundTruth, ambient_c));
  add("tof_ns", "<f8", raw(offsetof(RawMeasurement, tof_ns)));
  add("distance_raw_m", "<f8", raw(offsetof(RawMeasurement, distance_raw_m)));
  add("pulse_width_ns", "<f8", raw(offsetof(RawMeasurement, pulse_width_ns)));
  add("amplitude", "<f8", raw(offsetof(RawMeasurement, amplitude)));
  add("temperature_c", "<f8", raw(offsetof(RawMeasurement, temperature_c)));
  add("shots_valid", "<u4", raw(offsetof(RawMeasurement, shots_valid)));
  add("flags", "<u4", raw(offsetof(RawMeasurement, flags)));
  py::dict spec;
  spec["names"] = names;
  spec["formats"] = formats;
  spec["offsets"] = offsets;
  spec["itemsize"] = sizeof(Record);
  return py::dtype::from_args(spec);
}

py::dtype raw_dtype() {
  using ranging::RawMeasurement;
  py::dict spec;
  spec["names"] = py::make_tuple("tof_ns", "distance_raw_m", "pulse_width_ns", "amplitude",
                                 "temperature_c", "shots_valid", "flags");
  spec["formats"] = py::make_tuple("<f8", "<f8", "<f8", "<f8", "<f8", "<u4", "<u4");
  spec["offsets"] =
      py::make_tuple(offsetof(RawMeasurement, tof_ns), offsetof(RawMeasurement, distance_raw_m),
                     offsetof(RawMeasurement, pulse_width_ns), offsetof(RawMeasurement, amplitude),
                     offsetof(RawMeasurement, temperature_c), offsetof(RawMeasurement, shots_valid),
                     offsetof(RawMeasurement, flags));
  spec["itemsize"] = sizeof(RawMeasurement);
  return py::dtype::from_args(spec);
}

py::dtype range_dtype() {
  using ranging::Range;
  py::dict spec;
  spec["names"] = py::make_tuple("distance_m", "sigma_m", "correction_flags");
  spec["formats"] = py::make_tuple("<f8", "<f8", "<u4");
  spec["offsets"] = py::make_tuple(offsetof(Range, distance_m), offsetof(Range, sigma_m),
                                   offsetof(Range, correction_flags));
  spec["itemsize"] = sizeof(Range);
  return py::dtype::from_args(spec);
}

void rethrow_for_file(const std::filesystem::path& path, const std::exception& error) {
  std::error_code ec;
  if (!std::filesystem::exists(path, ec)) {
    PyErr_SetString(PyExc_FileNotFoundError, error.what());
    throw py::error_already_set();
  }
  throw;
}

}  // namespace tofkit::python

PYBIND11_MODULE(_tofkit, m) {
  namespace tp = tofkit::python;
  m.doc() = "tofkit C++ core (pulsed time-of-flight rangefinders); use the `tofkit` package";
  // Bad keys, values and file contents are ValueError with the CLI's message
  // (std::invalid_argument already is); pybind11's own errors pass through.
  pybind11::register_exception_translator([](std::exception_ptr p) {
    try {
      if (p) std::rethrow_exception(p);
    } catch (const pybind11::builtin_exception&) {
      throw;
    } catch (const std::filesystem::filesystem_error& e) {
      PyErr_SetString(PyExc_OSError, e.what());
    } catch (const std::runtime_error& e) {
      PyErr_SetString(PyExc_ValueError, e.what());
    }
  });
  m.attr("RECORD_DTYPE") = tp::record_dtype();
  m.attr("RAW_DTYPE") = tp::raw_dtype();
  m.attr("RANGE_DTYPE") = tp::range_dtype();
  tp::bind_device(m);
  tp::bind_model(m);
}
