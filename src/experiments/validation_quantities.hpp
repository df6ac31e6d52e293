#pragma once
// The registry behind experiments/validation.hpp (private to the core): a
// quantity id maps to a function of a context that runs each experiment once.

#include <functional>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "tofkit/experiments/validation.hpp"

namespace tofkit::experiments::validation_detail {

using Parameters = std::map<std::string, std::string>;

/// Runs each experiment at most once for one device and seed (lazily).
class QuantityContext {
 public:
  QuantityContext(device::DeviceConfig config, std::uint64_t seed);
  ~QuantityContext();
  QuantityContext(const QuantityContext&) = delete;
  QuantityContext& operator=(const QuantityContext&) = delete;
  struct Runs;
  Runs& runs() { return *runs_; }

 private:
  std::unique_ptr<Runs> runs_;
};

using QuantityFunction =
    std::function<double(QuantityContext&, const Parameters&, ValidationMethod)>;

struct Quantity {
  QuantityInfo info;
  QuantityFunction compute;
  /// Extra checks of a row's conditions beyond the keys (throws ValidationMatrixError).
  std::function<void(const ValidationRow&)> check;
};

[[nodiscard]] const std::map<std::string, Quantity>& quantities();

}  // namespace tofkit::experiments::validation_detail
