// tofkit._tofkit: thin bindings over the core batch APIs (kiss-icp's pattern:
// a C++ core, thin bindings, a small Python package on top).

#include <stdexcept>
#include <string>

#include "bindings.hpp"
#include "tofkit/io/config_file.hpp"
#include "tofkit/ranging/raw_measurement.hpp"
#include "tofkit/ranging/record_columns.hpp"

namespace tofkit::python {

py::dtype struct_dtype(const py::list& names, const py::list& formats, const py::list& offsets,
                       std::size_t itemsize) {
  py::dict spec;
  spec["names"] = names;
  spec["formats"] = formats;
  spec["offsets"] = offsets;
  spec["itemsize"] = itemsize;
  return py::dtype::from_args(spec);
}

namespace {

/// ranging::kRecordColumns (all of them, or the device's only) as a dtype.
py::dtype columns_dtype(bool raw_only) {
  using ranging::ColumnType;
  static_assert(sizeof(ranging::RawMeasurement) == 48 && sizeof(ranging::Record) == 80,
                "unexpected record layout");
  py::list names, formats, offsets;
  for (const ranging::RecordColumn& c : ranging::kRecordColumns) {
    if (raw_only && !c.is_raw()) continue;
    names.append(py::str(c.name.data(), c.name.size()));
    formats.append(c.type == ColumnType::kFloat64 ? "<f8" : "<u4");
    offsets.append(raw_only ? c.raw_offset() : c.offset);
  }
  return struct_dtype(names, formats, offsets,
                      raw_only ? sizeof(ranging::RawMeasurement) : sizeof(ranging::Record));
}

}  // namespace

py::dtype record_dtype() {
  return columns_dtype(false);
}

py::dtype raw_dtype() {
  return columns_dtype(true);
}

py::dtype range_dtype() {
  using ranging::Range;
  py::list names, formats, offsets;
  names.append("distance_m"), formats.append("<f8"), offsets.append(offsetof(Range, distance_m));
  names.append("sigma_m"), formats.append("<f8"), offsets.append(offsetof(Range, sigma_m));
  names.append("correction_flags"), formats.append("<u4"),
      offsets.append(offsetof(Range, correction_flags));
  return struct_dtype(names, formats, offsets, sizeof(Range));
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
  tp::bind_scan(m);
  tp::bind_sweep(m);
}
