// The TOML config loader on arbitrary bytes: a ConfigError naming the file,
// or a config that passes validation and dumps to text that loads back to the
// same dump.
#include <cstdint>
#include <cstdlib>
#include <optional>
#include <string>
#include <vector>

#include "fuzz_common.hpp"
#include "tofkit/io/config_file.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace tofkit;
  const auto path = fuzz::scratch_file(".toml", data, size);
  const std::vector<std::string> none;
  device::DeviceConfig config;
  try {
    config = io::load_device_config("", path, none);
  } catch (const io::ConfigError& e) {
    if (std::string(e.what()).empty()) std::abort();
    return 0;
  }
  const std::string dump = io::dump_device_config(config);
  const auto again_path = fuzz::scratch_file(
      ".dump.toml", reinterpret_cast<const std::uint8_t*>(dump.data()), dump.size());
  const auto again = io::load_device_config("", again_path, none);
  if (io::dump_device_config(again) != dump) std::abort();
  return 0;
}
