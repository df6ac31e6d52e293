#pragma once
/// \file Raw and corrected measurement tables (CSV with a header row).
///
/// Raw columns, in this order (DESIGN.md): distance_true_m, reflectance,
/// angle_deg, ambient_c, tof_ns, distance_raw_m, pulse_width_ns, amplitude,
/// temperature_c, shots_valid, flags. The corrected table adds distance_m,
/// sigma_m, correction_flags. NaN is an empty field (a measurement with no echo
/// keeps its row with an empty distance). Numbers are written in shortest
/// round-trip form, so files are byte-reproducible and read back bit-exactly.
///
/// Readers go by the header: columns may come in any order and unknown columns
/// are ignored. Missing truth columns read as NaN; at least one of tof_ns and
/// distance_raw_m must be present (the other then reads as NaN). A missing
/// shots_valid reads as 1 when the row has a distance and 0 otherwise; a
/// missing flags column as kRawNoEcho for rows without a distance, else 0.
/// An optional last column `time_s` gives each row's time since power-on, s
/// (`measure --start-s` / `--every` write it; empty or absent: unknown).
/// Errors (std::runtime_error) name the file, line and column.

#include <filesystem>
#include <ostream>
#include <span>
#include <string_view>
#include <vector>

#include "tofkit/ranging/raw_measurement.hpp"

namespace tofkit::io {

/// The raw columns, in file order.
[[nodiscard]] std::span<const std::string_view> raw_csv_columns();

/// The three columns the corrected table adds after the raw ones.
[[nodiscard]] std::span<const std::string_view> corrected_csv_columns();

/// The raw CSV (header and a row per record) into a stream (`measure --out -`:
/// stdout); with `time_s` (one per record) a last column time_s.
void write_raw_csv(std::ostream& os, std::span<const ranging::Record> records,
                   std::span<const double> time_s = {});
/// Write records atomically (temporary file + rename).
void write_raw_csv(const std::filesystem::path& path, std::span<const ranging::Record> records,
                   std::span<const double> time_s = {});

/// The records; with `time_s`, each row's time since power-on too (NaN where
/// the file has none).
[[nodiscard]] std::vector<ranging::Record> read_raw_csv(const std::filesystem::path& path,
                                                        std::vector<double>* time_s = nullptr);

/// One row of the corrected table.
struct CorrectedRow {
  ranging::Record record;
  ranging::Range range;
  double time_s = ranging::kNaN;  ///< time since power-on (the optional time_s column)
};

/// The corrected CSV into a stream (`tofkit correct --out -`: stdout).
void write_corrected_csv(std::ostream& os, std::span<const ranging::Record> records,
                         std::span<const ranging::Range> ranges);
/// Write records with their corrected ranges (same length; throws
/// std::invalid_argument otherwise), atomically.
void write_corrected_csv(const std::filesystem::path& path,
                         std::span<const ranging::Record> records,
                         std::span<const ranging::Range> ranges);

/// Read a corrected table; distance_m is required, sigma_m (NaN) and
/// correction_flags (0) are optional.
[[nodiscard]] std::vector<CorrectedRow> read_corrected_csv(const std::filesystem::path& path);

}  // namespace tofkit::io
