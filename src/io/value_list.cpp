#include "tofkit/io/value_list.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <charconv>
#include <cmath>
#include <stdexcept>
#include <string>

#include "tofkit/io/input_file.hpp"

namespace tofkit::io {
namespace {

std::string_view trim(std::string_view s) {
  while (!s.empty() && (s.front() == ' ' || s.front() == '\t')) s.remove_prefix(1);
  while (!s.empty() && (s.back() == ' ' || s.back() == '\t')) s.remove_suffix(1);
  return s;
}

[[noreturn]] void fail(std::string_view option, const std::string& what) {
  throw std::invalid_argument(std::string(option) + ": " + what);
}

double parse_number(std::string_view text, std::string_view option) {
  const std::string_view t = trim(text);
  if (t.empty()) fail(option, "empty value in list");
  double value = 0;
  if (const auto why = io::parse_number(t, value)) {
    const std::string shown = t.size() > 40 ? std::string(t.substr(0, 40)) + "..." : std::string(t);
    fail(option, "'" + shown + "' " + *why);
  }
  return value;
}

std::vector<double> parse_range(std::string_view text, std::string_view option) {
  std::vector<std::string_view> parts;
  std::size_t start = 0;
  for (;;) {
    const std::size_t colon = text.find(':', start);
    parts.push_back(text.substr(start, colon == std::string_view::npos ? colon : colon - start));
    if (colon == std::string_view::npos) break;
    start = colon + 1;
  }
  if (parts.size() != 3) {
    fail(option, "'" + std::string(text) + "' is not a range start:stop:step");
  }
  const double first = parse_number(parts[0], option);
  const double stop = parse_number(parts[1], option);
  const double step = parse_number(parts[2], option);
  if (step == 0) fail(option, "step of '" + std::string(text) + "' is zero");
  const double steps = (stop - first) / step;
  // Tolerance relative to one step so that 0.1:0.3:0.1 includes 0.3.
  constexpr double kTolerance = 1e-9;
  if (steps < -kTolerance) {
    fail(option, "step of '" + std::string(text) + "' points away from stop");
  }
  const double count = std::floor(steps + kTolerance) + 1.0;
  const auto max_values = static_cast<double>(resource_limits().max_rows);
  if (!(count <= max_values)) {
    fail(option, fmt::format("'{}' has {:.0f} values, more than the limit of {:.0f} (raise it with "
                             "--max-rows)",
                             text, count, max_values));
  }
  const auto n = static_cast<std::size_t>(count);
  std::vector<double> values;
  values.reserve(n);
  // first + i step (not repeated addition) so that rounding does not accumulate.
  for (std::size_t i = 0; i < n; ++i) values.push_back(first + static_cast<double>(i) * step);
  if (std::abs(values.back() - stop) <= kTolerance * std::abs(step)) values.back() = stop;
  return values;
}

}  // namespace

std::vector<double> parse_value_list(std::string_view text, std::string_view option) {
  const std::string_view t = trim(text);
  if (t.empty()) fail(option, "empty list");
  if (t.find(':') != std::string_view::npos) {
    if (t.find(',') != std::string_view::npos) {
      fail(option, "'" + std::string(t) + "' mixes a list (,) and a range (:)");
    }
    return parse_range(t, option);
  }
  const std::size_t count = static_cast<std::size_t>(std::count(t.begin(), t.end(), ',')) + 1;
  if (count > resource_limits().max_rows) {
    fail(option, fmt::format("the list has {} values, more than the limit of {} (raise it with "
                             "--max-rows)",
                             count, resource_limits().max_rows));
  }
  std::vector<double> values;
  values.reserve(count);
  std::size_t start = 0;
  for (;;) {
    const std::size_t comma = t.find(',', start);
    values.push_back(parse_number(
        t.substr(start, comma == std::string_view::npos ? comma : comma - start), option));
    if (comma == std::string_view::npos) break;
    start = comma + 1;
  }
  return values;
}

}  // namespace tofkit::io
