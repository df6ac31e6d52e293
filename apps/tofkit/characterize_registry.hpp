#pragma once
/// \file Extra `tofkit characterize` experiments, registered from their own
/// files (like subcommands): the scanning results of the thesis live in
/// characterize_scan.cpp.

#include <cstdint>
#include <functional>
#include <map>
#include <string>
#include <vector>

#include "tofkit/device/virtual_rangefinder.hpp"
#include "tofkit/experiments/characterization_common.hpp"
#include "tofkit/ranging/raw_measurement.hpp"

namespace tofkit::app {

/// What every protocol hands back, whatever its result type.
struct CharacterizeOutcome {
  std::vector<ranging::Record> records;
  std::vector<experiments::Finding> findings;
  std::vector<experiments::ResultTable> tables;
  std::string summary;
};

using CharacterizeRunner =
    std::function<CharacterizeOutcome(const device::VirtualRangefinder&, std::uint64_t)>;

/// Registers an experiment; call from a namespace-scope static initializer.
/// Throws std::logic_error on a duplicate name.
bool register_characterization(std::string name, CharacterizeRunner runner);

/// Experiments registered so far, by name.
[[nodiscard]] const std::map<std::string, CharacterizeRunner>& registered_characterizations();

/// Every experiment `tofkit characterize` runs (the built-in protocols and the
/// registered ones), by name.
[[nodiscard]] const std::map<std::string, CharacterizeRunner>& characterize_experiments();

}  // namespace tofkit::app
