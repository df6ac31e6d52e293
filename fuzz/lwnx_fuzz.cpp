// libFuzzer target: the lwnx link decoder (see link_fuzz_common.hpp).
#include "link_fuzz_common.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  return tofkit::link::fuzz::decode_both_ways(tofkit::link::Format::kLwnx, data, size);
}
