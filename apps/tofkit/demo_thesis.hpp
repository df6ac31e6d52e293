#pragma once
/// \file The thesis part of `tofkit demo`: summary, plots (thesis Figs. 4.15,
/// 4.19, 4.30-4.31) and the report section.

#include <filesystem>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "demo_report.hpp"
#include "tofkit/experiments/thesis_protocol.hpp"

namespace tofkit::app {

[[nodiscard]] nlohmann::json thesis_summary_json(const experiments::ThesisProtocolResult& result);

[[nodiscard]] std::vector<Figure> write_thesis_plots(
    const std::filesystem::path& dir, const experiments::ThesisProtocolResult& result, bool render);

}  // namespace tofkit::app
