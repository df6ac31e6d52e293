#include "tofkit/io/validation_matrix.hpp"

#include <algorithm>
#include <map>
#include <optional>
#include <stdexcept>

#include "tofkit/io/input_file.hpp"

namespace tofkit::io {
namespace {

using experiments::ValidationMatrixError;
using experiments::ValidationMethod;
using experiments::ValidationRole;
using experiments::ValidationRow;

struct CsvRecord {
  std::size_t line = 0;  ///< where the record starts
  std::vector<std::string> fields;
};

/// RFC 4180 fields; '#' at the start of a line (outside quotes) is a comment,
/// blank lines are skipped. Throws ValidationMatrixError (column "") on an
/// unterminated quote or text after a closing quote.
std::vector<CsvRecord> split_csv(std::string_view text) {
  std::vector<CsvRecord> records;
  std::size_t i = 0, line = 1;
  if (text.starts_with("\xEF\xBB\xBF")) i = 3;  // UTF-8 byte order mark
  while (i < text.size()) {
    // Skip blank and comment lines.
    if (text[i] == '\n' || text[i] == '\r' || text[i] == '#') {
      if (text[i] == '#') i = std::min(text.find('\n', i), text.size());
      if (i < text.size() && text[i] == '\r') ++i;
      if (i < text.size() && text[i] == '\n') {
        ++i;
        ++line;
      }
      continue;
    }
    CsvRecord rec;
    rec.line = line;
    std::string field;
    bool done = false;
    while (!done) {
      if (i < text.size() && text[i] == '"') {
        ++i;
        for (;;) {
          if (i >= text.size())
            throw ValidationMatrixError(rec.line, "", "a quoted field is not closed");
          if (text[i] == '"') {
            if (i + 1 < text.size() && text[i + 1] == '"') {
              field += '"';
              i += 2;
              continue;
            }
            ++i;
            break;
          }
          if (text[i] == '\n') ++line;
          if (text[i] == '\0') throw ValidationMatrixError(line, "", "a NUL byte in the file");
          field += text[i++];
        }
        if (i < text.size() && text[i] != ',' && text[i] != '\n' && text[i] != '\r')
          throw ValidationMatrixError(line, "", "text after a closing quote");
      } else {
        while (i < text.size() && text[i] != ',' && text[i] != '\n' && text[i] != '\r') {
          if (text[i] == '\0') throw ValidationMatrixError(line, "", "a NUL byte in the file");
          field += text[i++];
        }
      }
      rec.fields.push_back(std::move(field));
      field.clear();
      if (i < text.size() && text[i] == ',') {
        ++i;
        continue;
      }
      if (i < text.size() && text[i] == '\r') ++i;
      if (i < text.size() && text[i] == '\n') {
        ++i;
        ++line;
      }
      done = true;
    }
    records.push_back(std::move(rec));
  }
  return records;
}

std::string trim(const std::string& s) {
  const auto b = s.find_first_not_of(" \t");
  if (b == std::string::npos) return {};
  return s.substr(b, s.find_last_not_of(" \t") - b + 1);
}

}  // namespace

const std::vector<std::string>& validation_matrix_required_columns() {
  static const std::vector<std::string> c{"id",         "document", "figure", "quantity",
                                          "conditions", "value",    "band",   "band_reason",
                                          "preset",     "role"};
  return c;
}

const std::vector<std::string>& validation_matrix_optional_columns() {
  static const std::vector<std::string> c{"unit", "method", "note"};
  return c;
}

std::vector<ValidationRow> parse_validation_matrix(std::string_view text,
                                                   const std::string& source) {
  auto where = [&](std::size_t line, const std::string& column) {
    return source + ":" + std::to_string(line) +
           (column.empty() ? "" : ": column '" + column + "'");
  };
  try {
    const auto records = split_csv(text);
    if (records.empty()) throw ValidationMatrixError(1, "", "no header row (the file is empty)");
    const auto& header = records.front();
    std::map<std::string, std::size_t> index;
    const auto& required = validation_matrix_required_columns();
    const auto& optional = validation_matrix_optional_columns();
    for (std::size_t k = 0; k < header.fields.size(); ++k) {
      const std::string name = trim(header.fields[k]);
      if (std::find(required.begin(), required.end(), name) == required.end() &&
          std::find(optional.begin(), optional.end(), name) == optional.end())
        throw ValidationMatrixError(header.line, name, "unknown column (see docs/validation.md)");
      if (!index.emplace(name, k).second)
        throw ValidationMatrixError(header.line, name, "the column appears twice");
    }
    for (const auto& name : required)
      if (!index.contains(name))
        throw ValidationMatrixError(header.line, name, "the header has no such column");

    std::vector<ValidationRow> rows;
    const std::size_t max_rows = resource_limits().max_rows;
    for (std::size_t r = 1; r < records.size(); ++r) {
      const auto& rec = records[r];
      if (rows.size() >= max_rows)
        throw ValidationMatrixError(rec.line, "", "more rows than --max-rows");
      if (rec.fields.size() != header.fields.size())
        throw ValidationMatrixError(rec.line, "",
                                    std::to_string(rec.fields.size()) + " fields, the header has " +
                                        std::to_string(header.fields.size()));
      auto get = [&](const std::string& name) -> std::string {
        const auto it = index.find(name);
        return it == index.end() ? std::string() : trim(rec.fields[it->second]);
      };
      auto number = [&](const std::string& name, const std::string& s) {
        double v = 0;
        if (const auto why = parse_number(s, v))
          throw ValidationMatrixError(rec.line, name, "'" + s + "' " + *why);
        return v;
      };
      ValidationRow row;
      row.line = rec.line;
      row.id = get("id");
      row.document = get("document");
      row.figure = get("figure");
      row.quantity = get("quantity");
      row.conditions = get("conditions");
      try {
        row.parameters = experiments::parse_conditions(row.conditions);
      } catch (const std::invalid_argument& e) {
        throw ValidationMatrixError(rec.line, "conditions", e.what());
      }
      row.value = number("value", get("value"));
      std::string band = get("band");
      if (band.ends_with('%')) {
        row.band_relative = true;
        band = trim(band.substr(0, band.size() - 1));
      }
      row.band = number("band", band);
      row.band_reason = get("band_reason");
      if (row.band_reason.empty())
        throw ValidationMatrixError(rec.line, "band_reason", "a band needs its reason");
      row.unit = get("unit");
      row.preset = get("preset");
      const std::string role = get("role");
      if (role == "calibration")
        row.role = ValidationRole::kCalibration;
      else if (role == "held_out")
        row.role = ValidationRole::kHeldOut;
      else
        throw ValidationMatrixError(rec.line, "role",
                                    "'" + role + "' is not calibration or held_out");
      const std::string method = get("method");
      if (method.empty() || method == "document")
        row.method = ValidationMethod::kDocument;
      else if (method == "tofkit")
        row.method = ValidationMethod::kTofkit;
      else
        throw ValidationMatrixError(rec.line, "method",
                                    "'" + method + "' is not document or tofkit");
      row.note = get("note");
      rows.push_back(std::move(row));
    }
    experiments::check_validation_rows(rows);
    return rows;
  } catch (const ValidationMatrixError& e) {
    throw std::runtime_error(where(e.line(), e.column()) + ": " + e.what());
  }
}

std::vector<ValidationRow> read_validation_matrix(const std::filesystem::path& path) {
  return parse_validation_matrix(read_text_file(path, "validation matrix"), path.string());
}

}  // namespace tofkit::io
