#pragma once
/// \file Writing output files all-or-nothing: the content goes to a temporary
/// file in the same directory, which is renamed over the target only once it
/// is complete. A failure (an exception from the writer, a full disk) leaves no
/// file behind and an existing target untouched.

#include <filesystem>
#include <functional>
#include <ostream>
#include <string_view>

namespace tofkit::io {

/// Write `path` through `write`, atomically. Throws std::runtime_error naming
/// the path if the directory does not exist or the file cannot be written;
/// rethrows whatever `write` throws, after removing the temporary file.
void write_file_atomically(const std::filesystem::path& path,
                           const std::function<void(std::ostream&)>& write);

/// Write `contents` to `path`, atomically.
void write_file_atomically(const std::filesystem::path& path, std::string_view contents);

}  // namespace tofkit::io
