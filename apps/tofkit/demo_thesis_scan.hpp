#pragma once
/// \file The thesis's scanning results in `tofkit demo` (AccuRange-like preset):
/// the line-by-line model (Figs. 4.23-4.24), the checkerboard (Fig. 4.27),
/// confidence images (Figs. 4.32-4.33), mirror-edge spikes and the colour
/// transition (Figs. 3.4-3.5, 4.28) with tofkit's memory correction. Pictures
/// go to <dir>/plots, the section's HTML is returned for report.html.

#include <cstdint>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <string>

#include "tofkit/experiments/scan_memory.hpp"
#include "tofkit/experiments/thesis_line_scan.hpp"

namespace tofkit::app {

struct ThesisScanDemo {
  experiments::LineScanResult line;
  experiments::MemoryScanResult memory;
};

/// Runs both experiments on the accurange preset.
[[nodiscard]] ThesisScanDemo run_thesis_scan_demo(std::uint64_t seed);

/// Adds "thesis_line", "thesis_checker" and "memory_correction" to summary.json.
void add_thesis_scan_summary(nlohmann::json& summary, const ThesisScanDemo& demo);

/// Writes the pictures and returns the report section (HTML tables and figures).
[[nodiscard]] std::string write_thesis_scan_section(const std::filesystem::path& dir,
                                                    const ThesisScanDemo& demo, bool render);

}  // namespace tofkit::app
