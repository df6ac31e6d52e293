#pragma once
/// \file Levenshtein edit distance, for "did you mean" suggestions (configuration
/// keys, subcommands and options).

#include <cstddef>
#include <string_view>

namespace tofkit::io {

/// The number of single-character insertions, deletions and substitutions
/// that turn `a` into `b`; costs |a| x |b|.
[[nodiscard]] std::size_t edit_distance(std::string_view a, std::string_view b);

}  // namespace tofkit::io
