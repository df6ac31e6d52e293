// tofkit characterize line-scan | checkerboard | mirror-edges | color-transition:
// the thesis's scanning results (reference/characterization_thesis.md,
// Sections 3 and 4.7-4.8) on the virtual rangefinder with memory.

#include <stdexcept>

#include "characterize_registry.hpp"
#include "tofkit/experiments/scan_memory.hpp"
#include "tofkit/experiments/thesis_line_scan.hpp"

namespace tofkit::app {

namespace {
std::map<std::string, CharacterizeRunner>& registry() {
  static std::map<std::string, CharacterizeRunner> map;
  return map;
}
}  // namespace

bool register_characterization(std::string name, CharacterizeRunner runner) {
  if (!registry().emplace(name, std::move(runner)).second)
    throw std::logic_error("characterize: experiment '" + name + "' registered twice");
  return true;
}

const std::map<std::string, CharacterizeRunner>& registered_characterizations() {
  return registry();
}

namespace {

/// Only the named part of a result's findings and tables.
template <typename Result>
CharacterizeOutcome part_of(const Result& r, const std::string& prefix,
                            const std::vector<std::string>& table_names) {
  CharacterizeOutcome o;
  for (const auto& f : r.findings())
    if (f.name.rfind(prefix, 0) == 0 || prefix.empty()) o.findings.push_back(f);
  for (const auto& t : r.tables())
    for (const auto& n : table_names)
      if (t.name == n) o.tables.push_back(t);
  o.summary = r.summary();
  return o;
}

const bool registered_line = register_characterization(
    "line-scan", [](const device::VirtualRangefinder& d, std::uint64_t seed) {
      const auto r = experiments::run_line_scan(d, {}, seed);
      auto o = part_of(r, "", {"line_models", "per_grey", "coverage"});
      o.records.assign(r.records.begin(),
                       r.records.begin() + static_cast<std::ptrdiff_t>(r.line_test_records));
      std::erase_if(o.findings, [](const auto& f) { return f.name.rfind("checker", 0) == 0; });
      return o;
    });
const bool registered_checker = register_characterization(
    "checkerboard", [](const device::VirtualRangefinder& d, std::uint64_t seed) {
      const auto r = experiments::run_line_scan(d, {}, seed);
      auto o = part_of(r, "checker", {"checker_models", "coverage"});
      o.records.assign(r.records.begin() + static_cast<std::ptrdiff_t>(r.line_test_records),
                       r.records.end());
      return o;
    });
const bool registered_edges = register_characterization(
    "mirror-edges", [](const device::VirtualRangefinder& d, std::uint64_t seed) {
      const auto r = experiments::run_memory_scans(d, {}, seed);
      auto o = part_of(r, "", {"edges", "mirror_profile"});
      o.records = r.mirror_records;
      std::erase_if(o.findings, [](const auto& f) {
        return f.name.rfind("color", 0) == 0 || f.name.rfind("transition", 0) == 0;
      });
      return o;
    });
const bool registered_transition = register_characterization(
    "color-transition", [](const device::VirtualRangefinder& d, std::uint64_t seed) {
      const auto r = experiments::run_memory_scans(d, {}, seed);
      auto o = part_of(r, "", {"edges", "transition_profile"});
      o.records = r.transition_records;
      std::erase_if(o.findings, [](const auto& f) { return f.name.rfind("mirror", 0) == 0; });
      return o;
    });

}  // namespace
}  // namespace tofkit::app
