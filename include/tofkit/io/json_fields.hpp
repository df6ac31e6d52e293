#pragma once
/// \file Reading fields of a JSON model file with errors that name the place
/// ("model.json: steps[1].function.knots[0]: expected a number").

#include <nlohmann/json.hpp>
#include <stdexcept>
#include <string>

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

}  // namespace tofkit::io::json_fields
