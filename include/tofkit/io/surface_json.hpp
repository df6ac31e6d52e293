#pragma once
/// \file JSON form of correction surfaces and confidence models (parts of a
/// model file: kind, version, parameters, input domain, fit statistics).

#include <memory>
#include <nlohmann/json.hpp>
#include <string>

#include "tofkit/calib/confidence_model.hpp"
#include "tofkit/calib/correction_surface.hpp"

namespace tofkit::io {

[[nodiscard]] nlohmann::json surface_to_json(const calib::CorrectionSurface& surface);
/// Throws std::runtime_error naming `context` (e.g. "model.json: steps[1]") on bad input.
[[nodiscard]] std::shared_ptr<const calib::CorrectionSurface> surface_from_json(
    const nlohmann::json& j, const std::string& context);

[[nodiscard]] nlohmann::json confidence_to_json(const calib::ConfidenceModel& model);
[[nodiscard]] std::shared_ptr<const calib::ConfidenceModel> confidence_from_json(
    const nlohmann::json& j, const std::string& context);

}  // namespace tofkit::io
