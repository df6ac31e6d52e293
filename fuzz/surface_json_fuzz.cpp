// Correction-surface and confidence-model JSON on arbitrary bytes: an error
// naming the place, or an object, never a crash.
#include <cstdint>
#include <stdexcept>
#include <string_view>

#include "tofkit/io/json_fields.hpp"
#include "tofkit/io/surface_json.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace tofkit;
  const std::string_view text(reinterpret_cast<const char*>(data), size);
  nlohmann::json j;
  try {
    j = io::json_fields::parse_text(text, "surface.json");
  } catch (const std::runtime_error&) {
    return 0;
  }
  try {
    (void)io::surface_from_json(j, "surface.json");
  } catch (const std::exception&) {
  }
  try {
    (void)io::confidence_from_json(j, "surface.json");
  } catch (const std::exception&) {
  }
  return 0;
}
