#pragma once
/// \file The model file of a ranging pipeline (JSON):
///
///   {"kind": "tofkit.pipeline", "version": 1,
///    "time_to_distance": {"wavelength_nm", "air": {"temperature_c", "pressure_hpa",
///                         "relative_humidity_pct"}, "metres_per_ns" (informational)},
///    "steps": [{"kind": "offset", "offset_m"},
///              {"kind": "grayvalue" | "temperature", "input": "pulse_width_ns" | "temperature_c",
///               "function": {"x0", "intercept", "slope0", "knots": [], "slopes": []},
///               "domain": {"min", "max"}},
///              {"kind": "surface", "surface": io::surface_to_json(...)},
///              {"kind": "walk", "input": "pulse_width_ns",
///               "shape": {"pulse_sigma_ns", "pole_time_constant_ns",
///                         "saturation_log_overdrive" (null: no clipping seen),
///                         "recovery_ns_per_neper"},
///               "reference_pulse_width_ns", "domain": {"min", "max"}}],
///    each step with "fit": {"rows", "residual_rms_m"},
///    "confidence": io::confidence_to_json(...)  (absent without a confidence model),
///    "residual_rms_m": ..., "fit": {...}  (free-form fit statistics, optional),
///    "uncertainty_budget": {"components": [{"name", "step", "type": "A" | "B",
///        "default_specification", "scope": "always" | "same_power_on" | "other_power_on",
///        "axis": "none" | "log_amplitude" | "time_since_calibration_s" | "temperature_c"
///        | "lost_shot_share" | "false_stop_rate_per_m", "node": [], "variance_m2": []}],
///        "unobserved": [...], "calibration_time_s" (optional: s after power-on),
///        "shots" (optional: shots per measurement, for the two lost-shot axes)}  (optional: models
///        written before the budget have none, and read as before)}
///
/// Non-finite numbers are written as null (an open domain bound, an unknown RMS).
/// A walk step's objects are read strictly: an unknown key is an error naming it.

#include <filesystem>
#include <nlohmann/json.hpp>
#include <string>

#include "tofkit/ranging/pipeline.hpp"
#include "tofkit/ranging/uncertainty_budget.hpp"

namespace tofkit::calib {
struct ModelFitSummary;
}  // namespace tofkit::calib

namespace tofkit::io {

/// `fit` (may be null) is stored under "fit": fit statistics for the reader.
[[nodiscard]] nlohmann::json pipeline_to_json(const ranging::Pipeline& pipeline,
                                              const nlohmann::json& fit = nullptr);
/// Throws std::runtime_error naming `context` and the bad field
/// ("model.json: steps[1].function.knots[0]: expected a number").
[[nodiscard]] ranging::Pipeline pipeline_from_json(const nlohmann::json& j,
                                                   const std::string& context);

/// The "fit" object of a model file written by `tofkit fit` or the Python
/// fitters: rows, chain / surface / confidence statistics; `input` names the data.
[[nodiscard]] nlohmann::json fit_summary_json(const calib::ModelFitSummary& summary,
                                              const std::string& input);

/// Writes the model file atomically (no half-written file on failure).
void save_pipeline(const std::filesystem::path& path, const ranging::Pipeline& pipeline,
                   const nlohmann::json& fit = nullptr,
                   const ranging::UncertaintyBudget* budget = nullptr);
/// Reads a model file; errors name the file and the field.
[[nodiscard]] ranging::Pipeline load_pipeline(const std::filesystem::path& path);

[[nodiscard]] nlohmann::json budget_to_json(const ranging::UncertaintyBudget& budget);
/// Throws std::runtime_error naming `context` and the bad field.
[[nodiscard]] ranging::UncertaintyBudget budget_from_json(const nlohmann::json& j,
                                                          const std::string& context);
/// The model file's "uncertainty_budget" (empty when the file has none).
[[nodiscard]] ranging::UncertaintyBudget load_budget(const std::filesystem::path& path);

}  // namespace tofkit::io
