#include "tofkit/io/input_file.hpp"

#include <fmt/format.h>

#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <new>
#include <stdexcept>
#include <string>
#include <system_error>

#include "tofkit/io/atomic_file.hpp"

namespace tofkit::io {

ResourceLimits& resource_limits() {
  static ResourceLimits limits;
  return limits;
}

std::optional<std::string> parse_number(std::string_view text, double& out) {
  if (text.empty()) return "is empty";
  if (text.size() > kMaxNumberLength) {
    return fmt::format("is {} characters long, more than a number may have ({})", text.size(),
                       kMaxNumberLength);
  }
  const std::string_view digits = text.front() == '+' ? text.substr(1) : text;
  if (digits.empty() || digits.front() == '+' || (digits.front() == '-' && text.front() == '+')) {
    return std::string("is not a number");
  }
  double value = 0;
  const auto [ptr, ec] = std::from_chars(digits.data(), digits.data() + digits.size(), value,
                                         std::chars_format::general);
  if (ptr != digits.data() + digits.size() ||
      (ec != std::errc() && ec != std::errc::result_out_of_range)) {
    return std::string("is not a number");
  }
  if (ec == std::errc::result_out_of_range) {
    // Overflow or underflow: strtod tells them apart (HUGE_VAL vs tiny).
    const std::string copy(digits);
    errno = 0;
    value = std::strtod(copy.c_str(), nullptr);
    if (std::isinf(value)) return std::string("is too large for a double (beyond 1.8e308)");
  }
  if (!std::isfinite(value)) return std::string("is not a finite number");
  out = value;
  return std::nullopt;
}

std::string read_text_file(const std::filesystem::path& path, std::string_view what) {
  namespace fs = std::filesystem;
  const std::string name = path.string();
  std::error_code ec;
  const fs::file_status status = fs::status(path, ec);
  if (!fs::exists(status)) throw std::runtime_error(name + ": " + std::string(what) + " not found");
  if (fs::is_directory(status)) {
    throw std::runtime_error(name + ": is a directory, expected a " + std::string(what));
  }
  if (!fs::is_regular_file(status)) {
    throw std::runtime_error(name + ": is not a regular file, expected a " + std::string(what));
  }
  const std::uintmax_t size = fs::file_size(path, ec);
  if (ec)
    throw std::runtime_error(name + ": cannot read the " + std::string(what) + ": " + ec.message());
  const std::uint64_t limit = resource_limits().max_input_bytes;
  if (size > limit) {
    throw std::runtime_error(
        fmt::format("{}: {} bytes is larger than the input limit of {} bytes ({:.4g} MB; raise it "
                    "with --max-input-mb)",
                    name, size, limit, static_cast<double>(limit) / 1048576.0));
  }
  std::FILE* file = std::fopen(name.c_str(), "rb");
  if (file == nullptr) {
    throw std::runtime_error(name + ": cannot open the " + std::string(what) + ": " +
                             std::strerror(errno));
  }
  std::string text;
  try {
    text.resize(static_cast<std::size_t>(size));
  } catch (const std::bad_alloc&) {
    std::fclose(file);
    throw std::runtime_error(fmt::format("{}: not enough memory to read its {} bytes", name, size));
  }
  const std::size_t got = text.empty() ? 0 : std::fread(text.data(), 1, text.size(), file);
  const bool error = std::ferror(file) != 0;
  const bool more = std::fgetc(file) != EOF;  // the file grew while being read
  std::fclose(file);
  if (error || got != text.size()) {
    throw std::runtime_error(
        fmt::format("{}: read only {} of its {} bytes (read error)", name, got, size));
  }
  if (more) throw std::runtime_error(name + ": the file changed while it was read");
  note_input(path);
  return text;
}

}  // namespace tofkit::io
