#pragma once
/// \file Reading a validation matrix (reference/validation_matrix.csv; the
/// format is in docs/validation.md): CSV with a header row, fields quoted when
/// they hold commas, '#' lines are comments. Every problem is an error naming
/// the file, the line and the column.

#include <filesystem>
#include <string>
#include <string_view>
#include <vector>

#include "tofkit/experiments/validation.hpp"

namespace tofkit::io {

/// The columns a matrix must have, then those it may have.
[[nodiscard]] const std::vector<std::string>& validation_matrix_required_columns();
[[nodiscard]] const std::vector<std::string>& validation_matrix_optional_columns();

/// Parses matrix text; `source` names it in messages ("file.csv:12: column
/// 'band': ..."). Checks every row against the quantity registry
/// (experiments::check_validation_rows). Throws std::runtime_error.
[[nodiscard]] std::vector<experiments::ValidationRow> parse_validation_matrix(
    std::string_view text, const std::string& source);

/// Reads and parses a matrix file (read_text_file's limits apply).
[[nodiscard]] std::vector<experiments::ValidationRow> read_validation_matrix(
    const std::filesystem::path& path);

}  // namespace tofkit::io
