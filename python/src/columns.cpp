#include "columns.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <string>
#include <type_traits>

namespace tofkit::python {
namespace {

bool native_byte_order(const py::dtype& dtype) {
  const char order = dtype.byteorder();
  return order == '=' || order == '|' || (order == '<' && PY_LITTLE_ENDIAN) ||
         (order == '>' && !PY_LITTLE_ENDIAN);
}

/// A count or a bit set from any number: NaN and negatives -> 0, saturating.
template <typename Src>
std::uint32_t to_uint32(Src v) {
  constexpr auto max = std::numeric_limits<std::uint32_t>::max();
  if constexpr (std::is_floating_point_v<Src>) {
    if (!(v >= 0)) return 0;
    return v >= static_cast<Src>(4294967296.0) ? max : static_cast<std::uint32_t>(v);
  } else if constexpr (std::is_same_v<Src, bool>) {
    return v ? 1u : 0u;
  } else {
    if constexpr (std::is_signed_v<Src>) {
      if (v < 0) return 0;
    }
    return static_cast<std::uint64_t>(v) > max ? max : static_cast<std::uint32_t>(v);
  }
}

template <typename Src, typename Dst>
void convert(const Column& c, std::size_t begin, std::size_t n, char* dst,
             std::size_t dst_stride_arg) {
  const char* src = c.data + static_cast<py::ssize_t>(begin) * c.stride;
  const auto copy = [&](py::ssize_t src_stride, std::size_t dst_stride) {
    for (std::size_t i = 0; i < n; ++i) {
      Src v;
      std::memcpy(&v, src + static_cast<py::ssize_t>(i) * src_stride, sizeof(Src));
      Dst d;
      if constexpr (std::is_same_v<Dst, double>) {
        d = static_cast<double>(v);
      } else {
        d = to_uint32(v);
      }
      std::memcpy(dst + i * dst_stride, &d, sizeof(Dst));
    }
  };
  // A contiguous column (the common case) with a constant stride the compiler can see.
  constexpr auto raw_stride = sizeof(ranging::RawMeasurement);
  if (c.stride == static_cast<py::ssize_t>(sizeof(Src)) && dst_stride_arg == raw_stride) {
    copy(static_cast<py::ssize_t>(sizeof(Src)), raw_stride);
  } else {
    copy(c.stride, dst_stride_arg);
  }
}

/// Reads column `c` into the Dst fields at dst, dst + dst_stride, ...
template <typename Dst>
void read_column(const Column& c, std::size_t begin, std::size_t n, char* dst,
                 std::size_t dst_stride) {
  switch (c.kind) {
    case 'f':
      if (c.itemsize == 8) return convert<double, Dst>(c, begin, n, dst, dst_stride);
      if (c.itemsize == 4) return convert<float, Dst>(c, begin, n, dst, dst_stride);
      break;
    case 'i':
      if (c.itemsize == 8) return convert<std::int64_t, Dst>(c, begin, n, dst, dst_stride);
      if (c.itemsize == 4) return convert<std::int32_t, Dst>(c, begin, n, dst, dst_stride);
      if (c.itemsize == 2) return convert<std::int16_t, Dst>(c, begin, n, dst, dst_stride);
      if (c.itemsize == 1) return convert<std::int8_t, Dst>(c, begin, n, dst, dst_stride);
      break;
    case 'u':
      if (c.itemsize == 8) return convert<std::uint64_t, Dst>(c, begin, n, dst, dst_stride);
      if (c.itemsize == 4) return convert<std::uint32_t, Dst>(c, begin, n, dst, dst_stride);
      if (c.itemsize == 2) return convert<std::uint16_t, Dst>(c, begin, n, dst, dst_stride);
      if (c.itemsize == 1) return convert<std::uint8_t, Dst>(c, begin, n, dst, dst_stride);
      break;
    case 'b':
      return convert<bool, Dst>(c, begin, n, dst, dst_stride);
  }
}

/// A count or bit-set column holds integers in [0, 2^32 - 1] (NaN: missing);
/// a negative, fractional or larger value is refused by name (-1 had read
/// as 0, 2**40 as 2**32 - 1).
void require_uint32(const py::array& a, const std::string& name) {
  const char kind = a.dtype().kind();
  if (kind == 'b' || (kind == 'u' && a.dtype().itemsize() <= 4)) return;
  const py::array_t<double> values = py::array_t<double, py::array::forcecast>::ensure(a);
  if (!values) throw py::type_error(name + ": expected a numeric column");
  const auto v = values.unchecked<1>();
  for (py::ssize_t i = 0; i < v.shape(0); ++i) {
    const double x = v(i);
    if (std::isnan(x)) continue;
    if (!(x >= 0 && x <= 4294967295.0 && x == std::floor(x))) {
      throw py::value_error(name + ": " + py::repr(py::float_(x)).cast<std::string>() + " in row " +
                            std::to_string(i) + " is not an integer in [0, 2**32 - 1]");
    }
  }
}

template <typename Dst>
void fill(Dst value, std::size_t n, char* dst, std::size_t dst_stride) {
  for (std::size_t i = 0; i < n; ++i) std::memcpy(dst + i * dst_stride, &value, sizeof(Dst));
}

}  // namespace

ColumnSet::ColumnSet(const py::tuple& columns) {
  if (columns.size() != kColumnCount) {
    throw py::value_error("expected " + std::to_string(kColumnCount) + " columns");
  }
  bool have_rows = false;
  for (std::size_t k = 0; k < kColumnCount; ++k) {
    const py::handle obj = columns[k];
    if (obj.is_none()) continue;
    const std::string name(ranging::kRecordColumns[k].name);
    py::array a = py::array::ensure(obj);
    if (!a) throw py::type_error(name + ": expected an array");
    if (a.ndim() != 1) {
      throw py::value_error(name + ": expected a 1-D column, got " + std::to_string(a.ndim()) +
                            " dimensions");
    }
    const char given = a.dtype().kind();
    if ((given == 'f' || given == 'i' || given == 'u') &&
        (!native_byte_order(a.dtype()) ||
         (given == 'f' && a.dtype().itemsize() != 4 && a.dtype().itemsize() != 8))) {
      // float16, long double or the other byte order: one copy as float64
      // (every other numeric column is read in place).
      a = py::array(a.attr("astype")("float64"));
    }
    const py::dtype dtype = a.dtype();
    const char kind = dtype.kind();
    if (kind != 'f' && kind != 'i' && kind != 'u' && kind != 'b') {
      throw py::type_error(name + ": expected a numeric column, got dtype " +
                           py::str(static_cast<py::object>(dtype)).cast<std::string>());
    }
    const auto n = static_cast<std::size_t>(a.shape(0));
    if (have_rows && n != rows_) {
      throw py::value_error(name + ": " + std::to_string(n) + " rows, but " +
                            std::to_string(rows_) + " in the columns before it");
    }
    rows_ = n;
    have_rows = true;
    if (k == kShotsValid || k == kFlags) require_uint32(a, name);
    columns_[k] = Column{static_cast<const char*>(a.data()), a.strides(0), kind, dtype.itemsize()};
    arrays_.push_back(std::move(a));
  }
  if (!columns_[kTof].present() && !columns_[kDistanceRaw].present()) {
    throw py::value_error("the raw data needs tof_ns or distance_raw_m");
  }
}

void ColumnSet::gather_raw(std::size_t begin, std::span<ranging::RawMeasurement> out) const {
  using ranging::RawMeasurement;
  const std::size_t n = out.size();
  char* base = reinterpret_cast<char*>(out.data());
  constexpr std::size_t stride = sizeof(RawMeasurement);
  for (std::size_t k = kTof; k <= kTemperature; ++k) {
    const Column& c = columns_[k];
    char* dst = base + ranging::kRecordColumns[k].raw_offset();
    if (c.present()) {
      read_column<double>(c, begin, n, dst, stride);
    } else {
      fill<double>(ranging::kNaN, n, dst, stride);
    }
  }
  const Column& shots = columns_[kShotsValid];
  const Column& flags = columns_[kFlags];
  if (shots.present())
    read_column<std::uint32_t>(shots, begin, n,
                               base + ranging::kRecordColumns[kShotsValid].raw_offset(), stride);
  if (flags.present())
    read_column<std::uint32_t>(flags, begin, n, base + ranging::kRecordColumns[kFlags].raw_offset(),
                               stride);
  if (!shots.present() || !flags.present()) {
    // The raw CSV reader's defaults (io/raw_csv.hpp).
    for (RawMeasurement& m : out) {
      const bool has_distance = std::isfinite(m.tof_ns) || std::isfinite(m.distance_raw_m);
      if (!shots.present()) m.shots_valid = has_distance ? 1u : 0u;
      if (!flags.present()) m.flags = has_distance ? 0u : ranging::kRawNoEcho;
    }
  }
}

void ColumnSet::gather_records(std::size_t begin, std::span<ranging::Record> out) const {
  using ranging::Record;
  std::vector<ranging::RawMeasurement> raw(out.size());
  gather_raw(begin, raw);
  char* base = reinterpret_cast<char*>(out.data());
  for (std::size_t k = kDistanceTrue; k <= kAmbient; ++k) {
    const Column& c = columns_[k];
    char* dst = base + ranging::kRecordColumns[k].offset;
    if (c.present()) {
      read_column<double>(c, begin, out.size(), dst, sizeof(Record));
    } else {
      fill<double>(ranging::kNaN, out.size(), dst, sizeof(Record));
    }
  }
  for (std::size_t i = 0; i < out.size(); ++i) out[i].raw = raw[i];
}

void ColumnSet::prefetch_raw(std::size_t begin, std::size_t n) const {
  constexpr py::ssize_t kLine = 64;
  for (std::size_t k = kTof; k <= kFlags; ++k) {
    const Column& c = columns_[k];
    if (!c.present() || n == 0) continue;
    const char* first = c.data + static_cast<py::ssize_t>(begin) * c.stride;
    const char* last = first + static_cast<py::ssize_t>(n - 1) * c.stride;
    const char* lo = std::min(first, last);
    const char* hi = std::max(first, last) + c.itemsize;
    // Columns of one structured array share their lines: fetch them once.
    if (k > kTof && columns_[kTof].present() && c.stride == columns_[kTof].stride &&
        std::abs(c.data - columns_[kTof].data) < c.stride) {
      continue;
    }
    for (const char* p = lo; p < hi; p += kLine) __builtin_prefetch(p);
  }
}

std::optional<ranging::RawColumns> ColumnSet::raw_columns() const {
  const auto column = [this]<typename T>(std::size_t k, T, ranging::StridedColumn<T>& out) {
    const Column& c = columns_[k];
    const char kind = std::is_floating_point_v<T> ? 'f' : 'u';
    if (!c.present() || c.kind != kind || c.itemsize != static_cast<py::ssize_t>(sizeof(T))) {
      return false;
    }
    out = {reinterpret_cast<const std::byte*>(c.data), c.stride};
    return true;
  };
  ranging::RawColumns raw;
  raw.size = rows_;
  if (column(kTof, 0.0, raw.tof_ns) && column(kDistanceRaw, 0.0, raw.distance_raw_m) &&
      column(kPulseWidth, 0.0, raw.pulse_width_ns) && column(kAmplitude, 0.0, raw.amplitude) &&
      column(kTemperature, 0.0, raw.temperature_c) &&
      column(kShotsValid, std::uint32_t{}, raw.shots_valid) &&
      column(kFlags, std::uint32_t{}, raw.flags)) {
    return raw;
  }
  return std::nullopt;
}

}  // namespace tofkit::python
