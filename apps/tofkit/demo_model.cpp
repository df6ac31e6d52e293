#include "demo_report.hpp"

namespace tofkit::app {

void write_demo_model(const std::filesystem::path&, const experiments::PaperStudyResult&) {}

}  // namespace tofkit::app
