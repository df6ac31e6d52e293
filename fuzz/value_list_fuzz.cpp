// The value-list parser of command-line options ("a,b,c", "start:stop:step")
// on arbitrary text: std::invalid_argument naming the option, or finite values
// within the row limit.
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <stdexcept>
#include <string>
#include <string_view>

#include "tofkit/io/input_file.hpp"
#include "tofkit/io/value_list.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace tofkit;
  const std::string_view text(reinterpret_cast<const char*>(data), size);
  try {
    const auto values = io::parse_value_list(text, "--x");
    if (values.empty() || values.size() > io::resource_limits().max_rows) std::abort();
    for (const double v : values) {
      if (!std::isfinite(v)) std::abort();
    }
  } catch (const std::invalid_argument& e) {
    if (std::string(e.what()).rfind("--x: ", 0) != 0) std::abort();
  }
  return 0;
}
