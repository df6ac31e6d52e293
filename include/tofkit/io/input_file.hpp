#pragma once
/// \file Reading input files and numbers from them, with limits: the one place
/// where tofkit turns bytes from a user into text and numbers.
///
/// - read_text_file: the whole file or an error naming it (not a regular
///   file, larger than the limit, out of memory, short read); the file is
///   recorded as an input (note_input) so no output replaces it.
/// - parse_number: a decimal number; rejects garbage, overflow ("1e999"),
///   "inf"/"nan" and over-long fields instead of reading a wrong value.
/// - resource_limits(): the row and size limits every reader and command
///   checks before it allocates (the CLI's --max-rows and --max-input-mb).

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>
#include <string_view>

namespace tofkit::io {

/// Limits on what one command may read or build. Commands check them before
/// the work; messages name the option that raises them.
struct ResourceLimits {
  std::uint64_t max_input_bytes = 256ull << 20;  ///< --max-input-mb (256 MB)
  std::uint64_t max_rows = 1'000'000;            ///< --max-rows: CSV rows, grid rows, list values
};

/// The process-wide limits (mutable: the CLI sets them from its options).
[[nodiscard]] ResourceLimits& resource_limits();

/// The longest numeric field parse_number accepts, characters.
constexpr std::size_t kMaxNumberLength = 400;

/// Parse `text` (no surrounding blanks; an optional leading '+') as a finite
/// double. Returns std::nullopt on success (value in `out`), else why it is
/// not one: "is not a number", "is too large for a double", ... Underflow
/// rounds to the nearest representable value (0 or subnormal), as strtod does.
[[nodiscard]] std::optional<std::string> parse_number(std::string_view text, double& out);

/// The whole content of a text file. Throws std::runtime_error starting with
/// the path ("model.json: is a directory", "data.csv: 300 MB is larger than
/// the --max-input-mb limit of 256 MB") when it is missing, not a regular
/// file, too large, unreadable or shorter than its size; `what` names the
/// kind of file in messages ("config file", "model file").
[[nodiscard]] std::string read_text_file(const std::filesystem::path& path, std::string_view what);

}  // namespace tofkit::io
