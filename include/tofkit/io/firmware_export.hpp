#pragma once
/// \file Export of the fixed-point correction chain (ranging/fixed_point_chain.hpp)
/// for firmware: a JSON file that reads back bit-exactly, and a C header with
/// the integer coefficients (`static const int32_t` arrays) and a reference
/// `static inline` evaluation that reproduces FixedPointChain::apply.
///
/// JSON: {"kind": "tofkit.fixed_point_chain", "version": 1,
///        "format": {"tdc_lsb_ps", "pulse_width_lsb_ps", "temperature_lsb_c",
///                   "fraction_bits", "knot_fraction_bits"},
///        "constant_q", "tof_scale_q",
///        "grayvalue" / "temperature": {"enabled", "slope0_q", "knots_q": [], "slopes_q": [],
///                                      "domain_min_q", "domain_max_q"}}

#include <filesystem>
#include <nlohmann/json.hpp>
#include <string>
#include <string_view>

#include "tofkit/ranging/fixed_point_chain.hpp"

namespace tofkit::io {

[[nodiscard]] nlohmann::json fixed_point_to_json(const ranging::FixedPointChain& chain);
/// Throws std::runtime_error naming `context` and the bad field.
[[nodiscard]] ranging::FixedPointChain fixed_point_from_json(const nlohmann::json& j,
                                                             const std::string& context);

/// The C header text. `prefix` (a C identifier) starts every symbol.
[[nodiscard]] std::string fixed_point_c_header(const ranging::FixedPointChain& chain,
                                               std::string_view prefix = "tofkit");

/// Atomic writes; errors name the file.
void save_fixed_point_json(const std::filesystem::path& path,
                           const ranging::FixedPointChain& chain);
void save_fixed_point_header(const std::filesystem::path& path,
                             const ranging::FixedPointChain& chain,
                             std::string_view prefix = "tofkit");
[[nodiscard]] ranging::FixedPointChain load_fixed_point_json(const std::filesystem::path& path);

}  // namespace tofkit::io
