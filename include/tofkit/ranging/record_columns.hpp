#pragma once
/// \file The raw measurement table's columns (DESIGN.md), in file order, each
/// a field of ranging::Record: the one list from which the raw CSV reader and
/// writer and the Python package's NumPy dtypes take their names, types and
/// layout.

#include <array>
#include <cstddef>
#include <cstdint>
#include <string_view>

#include "tofkit/ranging/raw_measurement.hpp"

namespace tofkit::ranging {

enum class ColumnType : std::uint8_t { kFloat64, kUint32 };

struct RecordColumn {
  std::string_view name;
  std::size_t offset;  ///< bytes from the start of a ranging::Record
  ColumnType type;

  /// A field of the device's RawMeasurement (else of the GroundTruth).
  [[nodiscard]] constexpr bool is_raw() const { return offset >= offsetof(Record, raw); }
  /// Bytes from the start of a RawMeasurement (is_raw() columns only).
  [[nodiscard]] constexpr std::size_t raw_offset() const { return offset - offsetof(Record, raw); }
};

/// Indices into kRecordColumns.
namespace record_column {
enum Index : std::size_t {
  kDistanceTrue,
  kReflectance,
  kAngle,
  kAmbient,
  kTof,
  kDistanceRaw,
  kPulseWidth,
  kAmplitude,
  kTemperature,
  kShotsValid,
  kFlags,
  kCount
};
}  // namespace record_column

namespace detail {
constexpr std::size_t truth(std::size_t member) {
  return offsetof(Record, truth) + member;
}
constexpr std::size_t raw(std::size_t member) {
  return offsetof(Record, raw) + member;
}
}  // namespace detail

inline constexpr std::array<RecordColumn, record_column::kCount> kRecordColumns = {{
    {"distance_true_m", detail::truth(offsetof(GroundTruth, distance_m)), ColumnType::kFloat64},
    {"reflectance", detail::truth(offsetof(GroundTruth, reflectance)), ColumnType::kFloat64},
    {"angle_deg", detail::truth(offsetof(GroundTruth, angle_deg)), ColumnType::kFloat64},
    {"ambient_c", detail::truth(offsetof(GroundTruth, ambient_c)), ColumnType::kFloat64},
    {"tof_ns", detail::raw(offsetof(RawMeasurement, tof_ns)), ColumnType::kFloat64},
    {"distance_raw_m", detail::raw(offsetof(RawMeasurement, distance_raw_m)), ColumnType::kFloat64},
    {"pulse_width_ns", detail::raw(offsetof(RawMeasurement, pulse_width_ns)), ColumnType::kFloat64},
    {"amplitude", detail::raw(offsetof(RawMeasurement, amplitude)), ColumnType::kFloat64},
    {"temperature_c", detail::raw(offsetof(RawMeasurement, temperature_c)), ColumnType::kFloat64},
    {"shots_valid", detail::raw(offsetof(RawMeasurement, shots_valid)), ColumnType::kUint32},
    {"flags", detail::raw(offsetof(RawMeasurement, flags)), ColumnType::kUint32},
}};

}  // namespace tofkit::ranging
