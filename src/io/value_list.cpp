#include "tofkit/io/value_list.hpp"

#include <charconv>
#include <cmath>
#include <stdexcept>
#include <string>

namespace tofkit::io {
namespace {

constexpr std::size_t kMaxValues = 10'000'000;

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
  // from_chars does not take a leading '+'; accept it for "+5".
  const std::string_view digits = t.front() == '+' ? t.substr(1) : t;
  double value = 0;
  const auto [ptr, ec] = std::from_chars(digits.data(), digits.data() + digits.size(), value);
  if (ec != std::errc() || ptr != digits.data() + digits.size()) {
    fail(option, "'" + std::string(t) + "' is not a number");
  }
  if (!std::isfinite(value)) fail(option, "'" + std::string(t) + "' is not a finite number");
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
  if (count > static_cast<double>(kMaxValues)) {
    fail(option, "'" + std::string(text) + "' has more than 1e7 values");
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
  std::vector<double> values;
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
