#pragma once
/// \file Text into HTML for the reports (demo, thesis scans, validate).

#include <string>

namespace tofkit::app {

/// `s` with HTML's special characters escaped, for element text and
/// attribute values.
inline std::string html_escape(const std::string& s) {
  std::string out;
  out.reserve(s.size());
  for (const char c : s) {
    switch (c) {
      case '<':
        out += "&lt;";
        break;
      case '>':
        out += "&gt;";
        break;
      case '&':
        out += "&amp;";
        break;
      case '"':
        out += "&quot;";
        break;
      default:
        out += c;
    }
  }
  return out;
}

}  // namespace tofkit::app
