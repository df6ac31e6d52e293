#pragma once
/// \file Running a validation matrix from the command line (`tofkit validate`
/// and the demo's summary): where the reference matrix is, which device each
/// row's preset stands for, and the JSON, CSV and HTML outputs.

#include <cstdint>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "app.hpp"
#include "tofkit/experiments/validation.hpp"

namespace tofkit::app {

/// reference/validation_matrix.csv of this tofkit: next to the binary (../reference,
/// as in a build directory inside the checkout), else the source tree it was
/// built from. Throws std::runtime_error naming where it looked.
[[nodiscard]] std::filesystem::path default_validation_matrix();

/// Without --preset / --config every row runs on its own preset (with the --set
/// overrides); with them, the device they give runs the rows whose preset is
/// the one it starts from, and the other rows are not run.
[[nodiscard]] experiments::DeviceForPreset device_selection(const AppContext& ctx);

/// validation.json's content: the summary and every row.
[[nodiscard]] nlohmann::json validation_json(const experiments::ValidationResult& result,
                                             const std::string& matrix, std::uint64_t seed);
/// The summary alone (shares as fractions, null without rows).
[[nodiscard]] nlohmann::json validation_summary_json(const experiments::ValidationSummary& s);

/// The demo's entry: the matrix, the summary over every row and one per preset.
[[nodiscard]] nlohmann::json validation_demo_json(const experiments::ValidationResult& result,
                                                  const std::string& matrix);
/// The demo report's section: the summary per preset, as an HTML table.
[[nodiscard]] std::string validation_section_html(const experiments::ValidationResult& result,
                                                  const std::string& matrix);

/// validation.json, validation.csv, validation.html and plots/validation_*.{gp,dat,png} in dir.
void write_validation_outputs(const std::filesystem::path& dir,
                              const experiments::ValidationResult& result,
                              const std::string& matrix, std::uint64_t seed, bool render);

}  // namespace tofkit::app
