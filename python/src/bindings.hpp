#pragma once
/// \file Shared pieces of the tofkit Python extension: the NumPy dtypes that
/// mirror the C++ records byte for byte, and the error conversions.

#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>

#include <exception>
#include <filesystem>

#include "tofkit/ranging/pipeline.hpp"

namespace tofkit::python {

namespace py = pybind11;

/// A structured dtype of the given fields at their byte offsets.
[[nodiscard]] py::dtype struct_dtype(const py::list& names, const py::list& formats,
                                     const py::list& offsets, std::size_t itemsize);
/// The raw CSV columns in ranging::Record's layout (80 bytes a row): a
/// measure() result is the C++ records themselves.
[[nodiscard]] py::dtype record_dtype();
/// The device's columns only, in ranging::RawMeasurement's layout (48 bytes a
/// row): Model.apply hands such an array to the C++ batch as it is.
[[nodiscard]] py::dtype raw_dtype();
/// distance_m, sigma_m, correction_flags in ranging::Range's layout.
[[nodiscard]] py::dtype range_dtype();

/// Raises FileNotFoundError with `error`'s message (the CLI's) when `path`
/// does not exist, else rethrows `error` (translated as usual).
[[noreturn]] void rethrow_for_file(const std::filesystem::path& path, const std::exception& error);

/// The ranging pipeline of a tofkit._tofkit._Model (TypeError otherwise).
[[nodiscard]] const ranging::Pipeline& pipeline_of(const py::handle& model);

void bind_device(py::module_& m);
void bind_model(py::module_& m);
void bind_scan(py::module_& m);
void bind_sweep(py::module_& m);

}  // namespace tofkit::python
