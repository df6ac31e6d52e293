#include <nlohmann/json.hpp>

#include "demo_report.hpp"
#include "tofkit/io/atomic_file.hpp"
#include "tofkit/io/firmware_export.hpp"
#include "tofkit/io/model_json.hpp"

namespace tofkit::app {

void write_demo_model(const std::filesystem::path& dir,
                      const experiments::PaperStudyResult& result) {
  const auto& fit = result.fit;
  nlohmann::json stats = {{"rows", fit.rows},
                          {"rows_skipped", fit.rows_skipped},
                          {"rows_downweighted", fit.rows_downweighted},
                          {"residual_rms_m", fit.after.rms_m},
                          {"max_abs_residual_m", fit.after.max_abs_m},
                          {"uncorrected_rms_m", fit.before.rms_m}};
  io::save_pipeline(dir / "model.json", fit.pipeline, stats);
  const ranging::FixedPointChain chain(result.fixed_point);
  io::create_output_directories(dir / "firmware");
  io::save_fixed_point_json(dir / "firmware" / "coefficients.json", chain);
  io::save_fixed_point_header(dir / "firmware" / "tofkit_coefficients.h", chain);
}

}  // namespace tofkit::app
