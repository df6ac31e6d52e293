#include "tofkit/io/raw_csv.hpp"

#include <fmt/format.h>

#include <array>
#include <charconv>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <fstream>
#include <iterator>
#include <optional>
#include <sstream>
#include <stdexcept>
#include <string>

#include "tofkit/io/atomic_file.hpp"
#include "tofkit/io/input_file.hpp"
#include "tofkit/ranging/record_columns.hpp"

namespace tofkit::io {
namespace {

namespace fs = std::filesystem;
using ranging::Range;
using ranging::Record;

// Every column either table may have: the raw ones (ranging::kRecordColumns,
// indices ranging::record_column::k...), then the three the corrected table adds.
using namespace ranging::record_column;
constexpr std::size_t kRawColumnCount = ranging::record_column::kCount;
enum CorrectedColumn : std::size_t {
  kDistance = kRawColumnCount,
  kSigma,
  kCorrectionFlags,
  kTime,  // optional time_s (s since power-on), after the raw or corrected columns
  kColumnCount
};
constexpr std::size_t kCorrectedColumnCount = kTime;

constexpr std::array<std::string_view, kColumnCount> kColumnNames = [] {
  std::array<std::string_view, kColumnCount> names{};
  for (std::size_t c = 0; c < kRawColumnCount; ++c) names[c] = ranging::kRecordColumns[c].name;
  names[kDistance] = "distance_m";
  names[kSigma] = "sigma_m";
  names[kCorrectionFlags] = "correction_flags";
  names[kTime] = "time_s";
  return names;
}();

bool is_integer_column(std::size_t c) {
  return c < kRawColumnCount ? ranging::kRecordColumns[c].type == ranging::ColumnType::kUint32
                             : c == kCorrectionFlags;
}

// NaN is an empty field; everything else shortest round-trip ("{}").
void append_number(fmt::memory_buffer& out, double v) {
  if (!std::isnan(v)) fmt::format_to(std::back_inserter(out), "{}", v);
}

void append_record(fmt::memory_buffer& out, const Record& r) {
  const auto* bytes = reinterpret_cast<const std::byte*>(&r);
  for (std::size_t c = 0; c < kRawColumnCount; ++c) {
    const ranging::RecordColumn& column = ranging::kRecordColumns[c];
    if (c > 0) out.push_back(',');
    if (column.type == ranging::ColumnType::kUint32) {
      std::uint32_t v;
      std::memcpy(&v, bytes + column.offset, sizeof(v));
      fmt::format_to(std::back_inserter(out), "{}", v);
    } else {
      double v;
      std::memcpy(&v, bytes + column.offset, sizeof(v));
      append_number(out, v);
    }
  }
}

void append_header(fmt::memory_buffer& out, std::size_t columns, bool time = false) {
  for (std::size_t c = 0; c < columns; ++c) {
    if (c > 0) out.push_back(',');
    out.append(kColumnNames[c]);
  }
  if (time) {
    out.push_back(',');
    out.append(kColumnNames[kTime]);
  }
  out.push_back('\n');
}

void write_buffer(std::ostream& os, const fmt::memory_buffer& buffer) {
  os.write(buffer.data(), static_cast<std::streamsize>(buffer.size()));
}

std::string_view trim(std::string_view s) {
  while (!s.empty() && (s.front() == ' ' || s.front() == '\t')) s.remove_prefix(1);
  while (!s.empty() && (s.back() == ' ' || s.back() == '\t')) s.remove_suffix(1);
  return s;
}

void split_fields(std::string_view line, std::vector<std::string_view>& fields) {
  fields.clear();
  std::size_t start = 0;
  for (;;) {
    const std::size_t comma = line.find(',', start);
    fields.push_back(
        trim(line.substr(start, comma == std::string_view::npos ? comma : comma - start)));
    if (comma == std::string_view::npos) return;
    start = comma + 1;
  }
}

// One parsed row: every known column's value, NaN / nullopt where absent.
struct ParsedRow {
  std::array<double, kColumnCount> number{};
  std::array<std::uint32_t, kColumnCount> integer{};
};

class TableReader {
 public:
  TableReader(const fs::path& path, bool corrected) : path_(path), corrected_(corrected) {
    text_ = read_text_file(path, "CSV file");
  }

  std::vector<CorrectedRow> read() {
    std::vector<CorrectedRow> rows;
    std::string_view rest = text_;
    if (rest.substr(0, 3) == "\xEF\xBB\xBF") rest.remove_prefix(3);  // UTF-8 BOM
    std::size_t line_number = 0;
    bool have_header = false;
    std::vector<std::string_view> fields;
    const std::uint64_t max_rows = resource_limits().max_rows;
    while (!rest.empty()) {
      // Lines end in LF, CR LF or a lone CR (old Mac files).
      const std::size_t end = rest.find_first_of("\r\n");
      const std::string_view line = rest.substr(0, end);
      std::size_t skip = end == std::string_view::npos ? rest.size() : end + 1;
      if (end != std::string_view::npos && rest[end] == '\r' && end + 1 < rest.size() &&
          rest[end + 1] == '\n') {
        ++skip;
      }
      rest.remove_prefix(skip);
      ++line_number;
      line_ = line.data();
      if (trim(line).empty()) continue;
      split_fields(line, fields);
      if (!have_header) {
        read_header(fields, line_number);
        have_header = true;
        continue;
      }
      if (rows.size() >= max_rows) {
        fail(line_number,
             fmt::format("more than {} data rows (raise the limit with --max-rows)", max_rows));
      }
      rows.push_back(read_row(fields, line_number));
    }
    if (!have_header) throw std::runtime_error(path_.string() + ": empty file (no header row)");
    return rows;
  }

 private:
  [[noreturn]] void fail(std::size_t line, const std::string& what) const {
    throw std::runtime_error(path_.string() + ":" + std::to_string(line) + ": " + what);
  }

  void read_header(const std::vector<std::string_view>& names, std::size_t line) {
    header_size_ = names.size();
    index_.fill(std::nullopt);
    for (std::size_t i = 0; i < names.size(); ++i) {
      for (std::size_t c = 0; c < kColumnCount; ++c) {
        if (names[i] != kColumnNames[c]) continue;
        if (index_[c]) {
          fail(line, fmt::format("column '{}' appears twice (columns {} and {})", names[i],
                                 *index_[c] + 1, i + 1));
        }
        index_[c] = i;
      }
    }
    if (!index_[kTof] && !index_[kDistanceRaw]) {
      // One field holding ';' or tabs: a spreadsheet's export in another separator.
      const bool other_separator =
          names.size() == 1 && names[0].find_first_of(";\t") != std::string_view::npos;
      fail(line, std::string("header has neither 'tof_ns' nor 'distance_raw_m'") +
                     (other_separator ? " (its fields are not separated by commas: tofkit reads "
                                        "comma-separated values)"
                                      : ""));
    }
    if (corrected_ && !index_[kDistance]) fail(line, "header has no 'distance_m' column");
  }

  // "file:line:column: column 5 (tof_ns): '1e999' is too large for a double"; long
  // fields are shortened in the message.
  [[noreturn]] void fail_field(std::string_view field, std::size_t line, std::size_t column,
                               const std::string& why) const {
    const std::size_t character = static_cast<std::size_t>(field.data() - line_) + 1;
    // Control bytes are shown as \xNN: a NUL had ended the message (what()
    // is a C string) before the reason.
    std::string shown;
    for (const char c : field.substr(0, 40)) {
      const auto byte = static_cast<unsigned char>(c);
      shown += byte < 0x20 || byte == 0x7F ? fmt::format("\\x{:02X}", byte) : std::string(1, c);
    }
    if (field.size() > 40) shown += "...";
    throw std::runtime_error(fmt::format("{}:{}:{}: column {} ({}): '{}' {}", path_.string(), line,
                                         character, column + 1, column_name(column), shown, why));
  }

  double parse_double(std::string_view field, std::size_t line, std::size_t column) const {
    if (field.empty()) return ranging::kNaN;
    double v = 0;
    if (const auto why = parse_number(field, v)) fail_field(field, line, column, *why);
    return v;
  }

  std::uint32_t parse_uint(std::string_view field, std::size_t line, std::size_t column) const {
    std::uint32_t v = 0;
    const auto [ptr, ec] = std::from_chars(field.data(), field.data() + field.size(), v);
    if (field.empty() || ec != std::errc() || ptr != field.data() + field.size()) {
      fail_field(field, line, column, "is not a non-negative 32-bit integer");
    }
    return v;
  }

  std::string_view column_name(std::size_t file_column) const {
    for (std::size_t c = 0; c < kColumnCount; ++c) {
      if (index_[c] == file_column) return kColumnNames[c];
    }
    return "?";
  }

  CorrectedRow read_row(const std::vector<std::string_view>& fields, std::size_t line) const {
    if (fields.size() != header_size_) {
      fail(line, fmt::format("expected {} fields (as in the header), got {}", header_size_,
                             fields.size()));
    }
    ParsedRow p;
    for (std::size_t c = 0; c < kColumnCount; ++c) {
      p.number[c] = ranging::kNaN;
      if (!index_[c]) continue;
      const std::size_t i = *index_[c];
      if (is_integer_column(c)) {
        p.integer[c] = parse_uint(fields[i], line, i);
      } else {
        p.number[c] = parse_double(fields[i], line, i);
      }
    }
    CorrectedRow row;
    auto* bytes = reinterpret_cast<std::byte*>(&row.record);
    for (std::size_t c = 0; c < kRawColumnCount; ++c) {
      const ranging::RecordColumn& column = ranging::kRecordColumns[c];
      if (column.type == ranging::ColumnType::kFloat64) {
        std::memcpy(bytes + column.offset, &p.number[c], sizeof(double));
      } else if (index_[c]) {
        std::memcpy(bytes + column.offset, &p.integer[c], sizeof(std::uint32_t));
      }
    }
    auto& m = row.record.raw;
    const bool has_distance = !std::isnan(m.tof_ns) || !std::isnan(m.distance_raw_m);
    if (!index_[kShotsValid]) m.shots_valid = has_distance ? 1u : 0u;
    if (!index_[kFlags]) m.flags = has_distance ? 0u : ranging::kRawNoEcho;
    row.range.distance_m = p.number[kDistance];
    row.range.sigma_m = p.number[kSigma];
    row.range.correction_flags = index_[kCorrectionFlags] ? p.integer[kCorrectionFlags] : 0u;
    row.time_s = p.number[kTime];
    // Seconds since power-on: a negative one would give the drift term a
    // time before the device ran.
    if (row.time_s < 0) {
      const std::size_t i = *index_[kTime];
      fail_field(fields[i], line, i, "is negative (time_s is seconds since power-on)");
    }
    return row;
  }

  fs::path path_;
  bool corrected_;
  std::string text_;
  const char* line_ = nullptr;  // start of the line being read (for columns in messages)
  std::size_t header_size_ = 0;
  std::array<std::optional<std::size_t>, kColumnCount> index_{};
};

}  // namespace

std::span<const std::string_view> raw_csv_columns() {
  return std::span<const std::string_view>(kColumnNames.data(), kRawColumnCount);
}

std::span<const std::string_view> corrected_csv_columns() {
  return std::span<const std::string_view>(kColumnNames.data() + kRawColumnCount,
                                           kCorrectedColumnCount - kRawColumnCount);
}

void write_raw_csv(std::ostream& os, std::span<const Record> records,
                   std::span<const double> time_s) {
  if (!time_s.empty() && time_s.size() != records.size()) {
    throw std::invalid_argument(
        fmt::format("write_raw_csv: {} records but {} times", records.size(), time_s.size()));
  }
  fmt::memory_buffer buffer;
  append_header(buffer, kRawColumnCount, !time_s.empty());
  for (std::size_t i = 0; i < records.size(); ++i) {
    append_record(buffer, records[i]);
    if (!time_s.empty()) {
      buffer.push_back(',');
      append_number(buffer, time_s[i]);
    }
    buffer.push_back('\n');
    if (buffer.size() > (1u << 20)) {  // flush in ~1 MB chunks
      write_buffer(os, buffer);
      buffer.clear();
    }
  }
  write_buffer(os, buffer);
}

void write_raw_csv(const fs::path& path, std::span<const Record> records,
                   std::span<const double> time_s) {
  write_file_atomically(path, [&](std::ostream& os) { write_raw_csv(os, records, time_s); });
}

std::vector<Record> read_raw_csv(const fs::path& path, std::vector<double>* time_s) {
  std::vector<CorrectedRow> rows = TableReader(path, false).read();
  std::vector<Record> records;
  records.reserve(rows.size());
  if (time_s) time_s->clear();
  for (const auto& row : rows) {
    records.push_back(row.record);
    if (time_s) time_s->push_back(row.time_s);
  }
  return records;
}

void write_corrected_csv(std::ostream& os, std::span<const Record> records,
                         std::span<const Range> ranges) {
  if (records.size() != ranges.size()) {
    throw std::invalid_argument(fmt::format("write_corrected_csv: {} records but {} ranges",
                                            records.size(), ranges.size()));
  }
  fmt::memory_buffer buffer;
  append_header(buffer, kCorrectedColumnCount);
  for (std::size_t i = 0; i < records.size(); ++i) {
    append_record(buffer, records[i]);
    buffer.push_back(',');
    append_number(buffer, ranges[i].distance_m);
    buffer.push_back(',');
    append_number(buffer, ranges[i].sigma_m);
    fmt::format_to(std::back_inserter(buffer), ",{}\n", ranges[i].correction_flags);
    if (buffer.size() > (1u << 20)) {
      write_buffer(os, buffer);
      buffer.clear();
    }
  }
  write_buffer(os, buffer);
}

void write_corrected_csv(const fs::path& path, std::span<const Record> records,
                         std::span<const Range> ranges) {
  if (records.size() != ranges.size()) {
    throw std::invalid_argument(fmt::format("write_corrected_csv({}): {} records but {} ranges",
                                            path.string(), records.size(), ranges.size()));
  }
  write_file_atomically(path, [&](std::ostream& os) { write_corrected_csv(os, records, ranges); });
}

std::vector<CorrectedRow> read_corrected_csv(const fs::path& path) {
  return TableReader(path, true).read();
}

}  // namespace tofkit::io
