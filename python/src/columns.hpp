#pragma once
/// \file NumPy columns -> C++ records without copying the input: each column
/// is read in place through its data pointer and byte stride (a field of a
/// structured array, or a plain 1-D array of any numeric dtype), one block of
/// rows at a time into a small buffer that stays in cache.

#include <cstddef>
#include <optional>
#include <span>
#include <vector>

#include "bindings.hpp"
#include "tofkit/ranging/pipeline.hpp"
#include "tofkit/ranging/raw_measurement.hpp"
#include "tofkit/ranging/record_columns.hpp"

namespace tofkit::python {

/// One input column, read in place.
struct Column {
  const char* data = nullptr;  ///< nullptr: the column is absent
  py::ssize_t stride = 0;      ///< bytes from one row to the next
  char kind = 0;               ///< NumPy kind: 'f', 'i', 'u' or 'b'
  py::ssize_t itemsize = 0;
  [[nodiscard]] bool present() const { return data != nullptr; }
};

/// Column k of a ColumnSet is ranging::kRecordColumns[k] (RECORD_DTYPE's field k).
using namespace ranging::record_column;
constexpr std::size_t kColumnCount = ranging::record_column::kCount;

/// All columns of a table; holds references to the arrays it reads.
class ColumnSet {
 public:
  /// `columns`: a tuple of kColumnCount entries, each a 1-D array or None.
  /// Throws TypeError / ValueError naming the column (wrong dtype, not 1-D,
  /// lengths differ) or when neither tof_ns nor distance_raw_m is given.
  explicit ColumnSet(const py::tuple& columns);

  [[nodiscard]] std::size_t rows() const { return rows_; }

  /// Rows [begin, begin + out.size()) as RawMeasurements, with the raw CSV
  /// reader's defaults for absent columns (NaN; shots_valid 1 / flags 0 for
  /// rows with a distance, else 0 / no-echo). Needs no GIL.
  void gather_raw(std::size_t begin, std::span<ranging::RawMeasurement> out) const;
  /// The same with the truth columns (NaN when absent).
  void gather_records(std::size_t begin, std::span<ranging::Record> out) const;

  /// Asks the CPU to fetch rows [begin, begin + n) of the raw columns into
  /// cache (the gather then overlaps memory with the previous block's compute).
  void prefetch_raw(std::size_t begin, std::size_t n) const;

  /// The raw columns as the pipeline reads them in place, when all seven are
  /// present with RawMeasurement's types (float64; uint32 shots_valid and
  /// flags) in native byte order, at any stride: a RAW_DTYPE or RECORD_DTYPE
  /// array, or a dict of such columns. std::nullopt otherwise (gather_raw).
  [[nodiscard]] std::optional<ranging::RawColumns> raw_columns() const;

 private:
  std::vector<py::array> arrays_;  // keeps the inputs alive
  Column columns_[kColumnCount];
  std::size_t rows_ = 0;
};

}  // namespace tofkit::python
