// The raw and corrected CSV readers on arbitrary bytes: an error (an
// exception naming file:line:column) or rows, never a crash; rows that are
// read write back and read again to the same values.
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <stdexcept>
#include <vector>

#include "fuzz_common.hpp"
#include "tofkit/io/raw_csv.hpp"

namespace {

bool same(double a, double b) {
  return (std::isnan(a) && std::isnan(b)) || a == b;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace tofkit;
  const auto path = fuzz::scratch_file(".csv", data, size);
  try {
    (void)io::read_corrected_csv(path);
  } catch (const std::runtime_error&) {
  }
  std::vector<ranging::Record> records;
  try {
    records = io::read_raw_csv(path);
  } catch (const std::runtime_error&) {
    return 0;
  }
  // Round trip: what was read is written and read back bit-exactly.
  const auto copy = fuzz::scratch_file(".copy.csv", nullptr, 0);
  io::write_raw_csv(copy, records);
  const auto again = io::read_raw_csv(copy);
  if (again.size() != records.size()) std::abort();
  for (std::size_t i = 0; i < records.size(); ++i) {
    const auto& a = records[i].raw;
    const auto& b = again[i].raw;
    if (!same(a.tof_ns, b.tof_ns) || !same(a.amplitude, b.amplitude) ||
        !same(records[i].truth.distance_m, again[i].truth.distance_m) || a.flags != b.flags) {
      std::abort();
    }
  }
  return 0;
}
