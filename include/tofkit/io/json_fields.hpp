#pragma once
/// \file Reading fields of a JSON model file with errors that name the place
/// ("model.json: steps[1].function.knots[0]: expected a number").

#include <algorithm>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <stdexcept>
#include <string>
#include <string_view>

#include "tofkit/io/input_file.hpp"

namespace tofkit::io::json_fields {

[[noreturn]] inline void fail(const std::string& where, const std::string& what) {
  throw std::runtime_error(where + ": " + what);
}

/// j[key], or an error naming `where` when j is not an object or lacks the key.
inline const nlohmann::json& field(const nlohmann::json& j, const char* key,
                                   const std::string& where) {
  if (!j.is_object()) fail(where, "expected an object");
  const auto it = j.find(key);
  if (it == j.end()) fail(where, std::string("missing field '") + key + "'");
  return *it;
}

inline double number(const nlohmann::json& j, const std::string& where) {
  if (!j.is_number()) fail(where, "expected a number");
  return j.get<double>();
}

inline double number(const nlohmann::json& j, const char* key, const std::string& where) {
  return number(field(j, key, where), where + "." + key);
}

/// "line L, column C" of byte `offset` of `text`.
inline std::string position(std::string_view text, std::size_t offset) {
  offset = std::min(offset, text.size());
  std::size_t line = 1, line_start = 0;
  for (std::size_t i = 0; i < offset; ++i) {
    if (text[i] == '\n') {
      ++line;
      line_start = i + 1;
    }
  }
  return std::to_string(line) + ":" + std::to_string(offset - line_start + 1);
}

/// Parse a JSON text; errors name `name`, line and column ("model.json:3:14:
/// number 1e999 is too large for a double").
inline nlohmann::json parse_text(std::string_view text, const std::string& name) {
  try {
    return nlohmann::json::parse(text);
  } catch (const nlohmann::json::parse_error& e) {
    const std::size_t byte = e.byte > 0 ? e.byte - 1 : 0;
    std::string what = e.what();
    const auto colon = what.find("syntax error");
    if (colon != std::string::npos) what = what.substr(colon);
    fail(name, "not valid JSON at line " + position(text, byte) + " (line:column): " + what);
  } catch (const nlohmann::json::out_of_range& e) {
    // number overflow parsing '<token>': find the token to give its place.
    const std::string what = e.what();
    const auto open = what.find('\'');
    const auto close = what.rfind('\'');
    std::string place = name;
    if (open != std::string::npos && close > open) {
      const std::string token = what.substr(open + 1, close - open - 1);
      const auto at = text.find(token);
      if (at != std::string_view::npos) place += ":" + position(text, at);
      fail(place, "number " + token + " is too large for a double");
    }
    fail(place, "not valid JSON: " + what);
  } catch (const nlohmann::json::exception& e) {
    fail(name, std::string("not valid JSON: ") + e.what());
  }
}

/// Read and parse a JSON file (read_text_file's checks, then parse_text).
inline nlohmann::json parse_file(const std::filesystem::path& path, std::string_view what) {
  return parse_text(read_text_file(path, what), path.string());
}

}  // namespace tofkit::io::json_fields
