// Bindings of the correction side: the ranging pipeline ("Model": load/save
// the CLI's JSON, batch apply over NumPy columns without copying them), and
// the chain and surface fitters.

#include <pybind11/stl.h>
#include <pybind11/stl/filesystem.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstring>
#include <fstream>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <vector>

#include "bindings.hpp"
#include "columns.hpp"
#include "tofkit/calib/model_fit.hpp"
#include "tofkit/device/device_config.hpp"
#include "tofkit/io/model_json.hpp"
#include "tofkit/ranging/pipeline.hpp"
#include "tofkit/ranging/uncertainty_budget.hpp"

namespace tofkit::python {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

/// Rows handed to Pipeline::apply at a time when the input must be gathered
/// (Pipeline::apply's own block: 12 kB of RawMeasurements, stays in L1).
constexpr std::size_t kChunk = 256;

/// A pipeline with the fit statistics the CLI stores beside it.
struct Model {
  ranging::Pipeline pipeline;
  json fit;                           ///< "fit" object of the model file (null: none)
  std::string report;                 ///< the fitter's summary (empty for a loaded model)
  ranging::UncertaintyBudget budget;  ///< the model file's (empty: none)
};

Model load_model(const fs::path& path) {
  Model model;
  try {
    model.pipeline = io::load_pipeline(path);
    model.budget = io::load_budget(path);
  } catch (const std::exception& e) {
    rethrow_for_file(path, e);
  }
  // The free-form fit statistics, kept so that save() writes the same file.
  std::ifstream in(path);
  const json j = json::parse(in, nullptr, false);
  if (j.is_object() && j.contains("fit")) model.fit = j["fit"];
  return model;
}

/// `out` if given (checked: RANGE_DTYPE, C-contiguous, writable, n rows),
/// else a new RANGE_DTYPE array of n rows.
py::array output_array(const std::optional<py::array>& out, std::size_t n) {
  if (!out) return py::array(range_dtype(), static_cast<py::ssize_t>(n));
  const py::array& a = *out;
  if (!a.dtype().equal(range_dtype()) || a.ndim() != 1 || !(a.flags() & py::array::c_style) ||
      !a.writeable()) {
    throw py::type_error("out: expected a writable, contiguous 1-D array of RANGE_DTYPE");
  }
  if (static_cast<std::size_t>(a.shape(0)) != n) {
    throw py::value_error("out: " + std::to_string(a.shape(0)) + " rows for " + std::to_string(n) +
                          " measurements");
  }
  return a;
}

/// Corrected ranges into `out` or one new allocation (RANGE_DTYPE); the
/// input is read in place, the GIL released while correcting.
py::array apply(const Model& model, const py::tuple& columns,
                const std::optional<py::array>& out_arg, double since_calibration_s) {
  const ColumnSet input(columns);
  const std::size_t n = input.rows();
  py::array out = output_array(out_arg, n);
  auto* ranges = static_cast<ranging::Range*>(out.mutable_data());
  const std::optional<ranging::RawColumns> columns_in_place = input.raw_columns();
  const ranging::Pipeline& pipeline = model.pipeline;
  py::gil_scoped_release release;
  if (columns_in_place) {
    // RawMeasurement's fields at any stride (RAW_DTYPE, measure()'s records,
    // a dict of float64/uint32 columns): one call over all of it.
    pipeline.apply(*columns_in_place, std::span(ranges, n));
    // With a budget, sigma_m is its combined standard uncertainty.
    if (!model.budget.empty())
      ranging::apply_budget(model.budget, pipeline, *columns_in_place,
                            std::span(&since_calibration_s, 1), std::span(ranges, n));
    return out;
  }
  // Other dtypes or absent columns: gathered a block at a time, with the raw
  // CSV reader's defaults.
  std::vector<ranging::RawMeasurement> chunk(kChunk);
  for (std::size_t begin = 0; begin < n; begin += kChunk) {
    const std::size_t count = std::min(kChunk, n - begin);
    const std::span<ranging::RawMeasurement> block(chunk.data(), count);
    // The next block's reads overlap this block's compute.
    if (begin + count < n) input.prefetch_raw(begin + count, std::min(kChunk, n - begin - count));
    input.gather_raw(begin, block);
    pipeline.apply(block, std::span(ranges + begin, count));
    if (!model.budget.empty())
      ranging::apply_budget(model.budget, pipeline, ranging::RawColumns::of(block),
                            std::span(&since_calibration_s, 1), std::span(ranges + begin, count));
  }
  return out;
}

std::vector<ranging::Record> records_of(const py::tuple& columns) {
  const ColumnSet input(columns);
  std::vector<ranging::Record> records(input.rows());
  input.gather_records(0, records);
  return records;
}

/// calib::fit_model on the records, as `tofkit fit` runs it; the GIL is released meanwhile.
Model fit_model(const std::vector<ranging::Record>& records, const calib::ModelFitOptions& options,
                const json& base_fit) {
  std::optional<calib::ModelFitResult> fit;
  {
    py::gil_scoped_release release;
    fit = calib::fit_model(records, options);
  }
  Model model{std::move(fit->pipeline),
              io::fit_summary_json(fit->summary, "python"),
              std::move(fit->report),
              {}};
  // A surface fitted on a chain Model keeps the chain's statistics.
  if (base_fit.is_object() && base_fit.contains("chain") && !model.fit.contains("chain")) {
    model.fit["chain"] = base_fit["chain"];
  }
  return model;
}

calib::ConfidenceKind confidence_kind(const std::string& confidence) {
  return calib::parse_confidence_kind(confidence);
}

Model fit_chain(const py::tuple& columns, const std::string& steps_text,
                const device::DeviceConfig& config, const std::string& confidence,
                bool refine_walk) {
  calib::ModelFitOptions options;
  try {
    options.chain = calib::parse_chain_steps(steps_text);
  } catch (const std::invalid_argument& e) {
    throw std::invalid_argument("steps " + steps_text + ": " + e.what());
  }
  if (refine_walk && !options.chain->grayvalue) {
    throw std::invalid_argument(
        "refine_walk refines the chain's grayvalue step: steps needs "
        "grayvalue");
  }
  options.refine_walk = refine_walk;
  options.time_to_distance = device::nominal_time_to_distance(config);
  options.confidence = confidence_kind(confidence);
  options.confidence_required = true;
  return fit_model(records_of(columns), options, nullptr);
}

/// A surface over (range, amplitude[, temperature]) on the residual of `base`
/// (or alone for `config`), as `tofkit fit [--chain ...] --surface SPEC` does.
Model fit_surface(const std::optional<Model>& base, const device::DeviceConfig& config,
                  const py::tuple& columns, const std::string& spec, bool temperature,
                  std::optional<double> rcond, const std::string& confidence) {
  calib::ModelFitOptions options;
  try {
    options.surface = calib::parse_surface_spec(spec);
  } catch (const std::invalid_argument& e) {
    throw std::invalid_argument("surface " + spec + ": " + e.what());
  }
  if (rcond && options.surface.kind != calib::SurfaceKind::polynomial) {
    throw std::invalid_argument("rcond applies to surface poly:N only");
  }
  if (rcond) options.polynomial.rcond = *rcond;
  options.surface_temperature = temperature;
  options.time_to_distance =
      base ? base->pipeline.time_to_distance() : device::nominal_time_to_distance(config);
  if (base) options.base = base->pipeline;
  options.confidence = confidence_kind(confidence);
  options.confidence_required = true;
  return fit_model(records_of(columns), options, base ? base->fit : json());
}

/// The C++ batch baselines of the benchmark script: Pipeline::apply over a
/// std::vector of the same rows (copied from the input once, not timed),
/// either RawMeasurements (48 B, the span form) or Records (80 B, measure()'s
/// layout, read through RawColumns as `tofkit correct` does), into a reused
/// output vector or (`allocate`) a new one per call as `tofkit correct` does.
/// run() returns one call's wall time in seconds.
class CppBaseline {
 public:
  CppBaseline(const Model& model, const py::tuple& columns) : pipeline_(model.pipeline) {
    const ColumnSet input(columns);
    records_.resize(input.rows());
    input.gather_records(0, records_);
    raw_.resize(records_.size());
    for (std::size_t i = 0; i < records_.size(); ++i) raw_[i] = records_[i].raw;
    reused_.resize(raw_.size());
  }

  double run(bool allocate, bool records) {
    py::gil_scoped_release release;
    std::vector<ranging::Range> fresh;
    const auto start = std::chrono::steady_clock::now();
    if (allocate) fresh.resize(raw_.size());
    std::vector<ranging::Range>& out = allocate ? fresh : reused_;
    if (records) {
      pipeline_.apply(ranging::RawColumns::of(records_), out);
    } else {
      pipeline_.apply(raw_, out);
    }
    const auto stop = std::chrono::steady_clock::now();
    return std::chrono::duration<double>(stop - start).count();
  }  // `fresh` is freed after the clock stops, as Python frees its result later

 private:
  ranging::Pipeline pipeline_;
  std::vector<ranging::Record> records_;
  std::vector<ranging::RawMeasurement> raw_;
  std::vector<ranging::Range> reused_;
};

}  // namespace

const ranging::Pipeline& pipeline_of(const py::handle& model) {
  return model.cast<const Model&>().pipeline;
}

void bind_model(py::module_& m) {
  py::class_<Model>(m, "_Model")
      .def_static("load", &load_model, py::arg("path"))
      .def(
          "save",
          [](const Model& model, const fs::path& path) {
            io::save_pipeline(path, model.pipeline, model.fit,
                              model.budget.empty() ? nullptr : &model.budget);
          },
          py::arg("path"))
      .def("to_json",
           [](const Model& model) {
             json j = io::pipeline_to_json(model.pipeline, model.fit);
             if (!model.budget.empty()) j["uncertainty_budget"] = io::budget_to_json(model.budget);
             return j.dump();
           })
      .def("summary", [](const Model& model) { return model.pipeline.summary(); })
      .def_readonly("report", &Model::report)
      .def_property_readonly("fit_json", [](const Model& model) { return model.fit.dump(); })
      .def_property_readonly("residual_rms_m",
                             [](const Model& model) { return model.pipeline.residual_rms_m(); })
      .def_property_readonly("budget_json",
                             [](const Model& model) {
                               return model.budget.empty()
                                          ? std::string("null")
                                          : io::budget_to_json(model.budget).dump();
                             })
      .def("apply", &apply, py::arg("columns"), py::arg("out") = py::none(),
           py::arg("since_calibration_s") = ranging::kNaN);
  m.def("_fit_chain", &fit_chain, py::arg("columns"), py::arg("steps"), py::arg("config"),
        py::arg("confidence"), py::arg("refine_walk"));
  m.def("_fit_surface", &fit_surface, py::arg("base"), py::arg("config"), py::arg("columns"),
        py::arg("spec"), py::arg("temperature"), py::arg("rcond"), py::arg("confidence"));
  py::class_<CppBaseline>(m, "_CppBaseline")
      .def(py::init<const Model&, const py::tuple&>(), py::arg("model"), py::arg("columns"))
      .def("run", &CppBaseline::run, py::arg("allocate"), py::arg("records") = false);
}

}  // namespace tofkit::python
