// Model files (JSON) on arbitrary bytes: an error naming the file and field,
// or a pipeline that corrects a few measurements without crashing.
#include <cstdint>
#include <stdexcept>
#include <string_view>
#include <vector>

#include "tofkit/io/json_fields.hpp"
#include "tofkit/io/model_json.hpp"
#include "tofkit/ranging/pipeline.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace tofkit;
  const std::string_view text(reinterpret_cast<const char*>(data), size);
  try {
    const auto j = io::json_fields::parse_text(text, "model.json");
    const ranging::Pipeline pipeline = io::pipeline_from_json(j, "model.json");
    std::vector<ranging::RawMeasurement> raw(4);
    const double tofs[] = {0.0, 13.3, 66.7, -1.0};
    for (std::size_t i = 0; i < raw.size(); ++i) {
      raw[i].tof_ns = tofs[i];
      raw[i].pulse_width_ns = 3.0 + static_cast<double>(i);
      raw[i].amplitude = 0.5 * static_cast<double>(i);
      raw[i].temperature_c = 10.0 * static_cast<double>(i);
      raw[i].shots_valid = 1000;
    }
    std::vector<ranging::Range> out(raw.size());
    pipeline.apply(raw, out);
  } catch (const std::exception&) {
  }
  return 0;
}
