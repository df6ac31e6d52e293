#pragma once
/// \file The demo's outputs beyond the table: model and firmware files, plots
/// (the paper's Figures 3, 6-10) and the HTML report.

#include <array>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <string>
#include <string_view>
#include <vector>

#include "tofkit/experiments/paper_study.hpp"

namespace tofkit::app {

/// One figure of the report.
struct Figure {
  std::string file;     ///< PNG (or the gnuplot script when not rendered), relative to the dir
  std::string caption;  ///< what it shows and which paper figure it mirrors
};

/// One row of the noise vs systematic table (text and HTML): a test set's name
/// and its split, in the demo's order.
struct SplitLine {
  std::string_view label;
  const calib::RepeatabilitySplit* split;
};
[[nodiscard]] std::array<SplitLine, 4> split_lines(const experiments::PaperStudyResult& r);

/// model.json and firmware/ (fixed-point coefficients as JSON and a C header).
void write_demo_model(const std::filesystem::path& dir,
                      const experiments::PaperStudyResult& result);

/// Gnuplot scripts and data for every figure, rendered to PNG when possible.
[[nodiscard]] std::vector<Figure> write_demo_plots(const std::filesystem::path& dir,
                                                   const experiments::PaperStudyResult& result,
                                                   bool render);

/// report.html: the tables and the figures, readable offline; `extra_html`
/// (sections of other parts of the demo) goes before the figures.
void write_demo_report(const std::filesystem::path& dir,
                       const experiments::PaperStudyResult& result, const nlohmann::json& summary,
                       const std::vector<Figure>& figures, const std::string& thesis_summary,
                       const std::string& extra_html = {});

}  // namespace tofkit::app
