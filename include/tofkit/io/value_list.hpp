#pragma once
/// \file Value lists of command-line options: "a,b,c" or "start:stop:step".

#include <string_view>
#include <vector>

namespace tofkit::io {

/// Parse a comma-separated list ("0.5,1,2") or an inclusive range
/// ("start:stop:step", e.g. "0.5:15:0.5"; stop is included when it lies on the
/// grid within a relative tolerance of 1e-9 step, and is then returned exactly).
/// A negative step counts down. Throws std::invalid_argument whose message
/// starts with `option` (e.g. "--distance: 'x' is not a number").
[[nodiscard]] std::vector<double> parse_value_list(std::string_view text, std::string_view option);

}  // namespace tofkit::io
