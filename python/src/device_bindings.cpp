// Bindings of the device side: DeviceConfig (presets, TOML files, overrides,
// dump), the virtual rangefinder over the measure grid, the link budget, and
// the raw CSV reader.

#include <pybind11/stl.h>
#include <pybind11/stl/filesystem.h>

#include <cstdint>
#include <cstring>
#include <limits>
#include <optional>
#include <string>
#include <vector>

#include "bindings.hpp"
#include "tofkit/device/device_config.hpp"
#include "tofkit/device/virtual_rangefinder.hpp"
#include "tofkit/experiments/plate_grid.hpp"
#include "tofkit/io/config_file.hpp"
#include "tofkit/io/input_file.hpp"
#include "tofkit/io/raw_csv.hpp"
#include "tofkit/physics/link_budget.hpp"

namespace tofkit::python {
namespace {

namespace fs = std::filesystem;

/// Overrides as "section.key=value" strings from a dict, a list or one string.
std::vector<std::string> overrides_of(const py::object& set) {
  std::vector<std::string> out;
  if (set.is_none()) return out;
  if (py::isinstance<py::str>(set)) return {set.cast<std::string>()};
  if (py::isinstance<py::dict>(set)) {
    for (const auto& [key, value] : set.cast<py::dict>()) {
      const std::string text = py::isinstance<py::bool_>(value)
                                   ? (value.cast<bool>() ? "true" : "false")
                                   : py::str(value).cast<std::string>();
      out.push_back(py::str(key).cast<std::string>() + "=" + text);
    }
    return out;
  }
  for (const auto& item : set) out.push_back(py::str(item).cast<std::string>());
  return out;
}

device::DeviceConfig load_config(const std::optional<std::string>& preset,
                                 const std::optional<fs::path>& file, const py::object& set) {
  const std::vector<std::string> overrides = overrides_of(set);
  try {
    return io::load_device_config(preset.value_or(""), file, overrides);
  } catch (const io::ConfigError& e) {
    if (file) rethrow_for_file(*file, e);
    throw;
  }
}

py::object field_object(const device::ConfigField& field) {
  if (const auto* b = std::get_if<bool*>(&field.value)) return py::bool_(**b);
  if (const auto* i = std::get_if<int*>(&field.value)) return py::int_(**i);
  return py::float_(*std::get<double*>(field.value));
}

py::object config_value(device::DeviceConfig config, const std::string& key) {
  for (const auto& f : device::config_fields(config)) {
    if (f.key == key) return field_object(f);
  }
  throw py::key_error("unknown key '" + key + "'");
}

py::dict config_dict(device::DeviceConfig config) {
  py::dict d;
  for (const auto& f : device::config_fields(config)) d[py::str(f.key)] = field_object(f);
  return d;
}

/// Records in measure-grid order; one NumPy allocation for the result.
py::array measure(const device::DeviceConfig& config, const experiments::PlateGrid& grid,
                  std::uint64_t seed, const std::string& mode_name) {
  if (mode_name != "analytic" && mode_name != "waveform") {
    throw std::invalid_argument("mode: '" + mode_name + "' is not analytic or waveform");
  }
  // The CLI's row limit (--max-rows): a grid past it is a ValueError, not an
  // allocation that aborts the interpreter (1e7 rows had, under 4 GB).
  std::vector<experiments::PlannedMeasurement> plan;
  try {
    plan = experiments::plate_grid_plan(grid, static_cast<double>(io::resource_limits().max_rows));
  } catch (const std::invalid_argument& e) {
    const std::string what = e.what();
    if (what.find(" rows, more than ") == std::string::npos) throw;
    throw std::invalid_argument(what + " (the row limit of the CLI's --max-rows)");
  }
  const auto mode = mode_name == "waveform" ? device::SimulationMode::kWaveform
                                            : device::SimulationMode::kAnalytic;
  const device::VirtualRangefinder rangefinder(config, mode);
  py::array out(record_dtype(), static_cast<py::ssize_t>(plan.size()));
  auto* records = static_cast<ranging::Record*>(out.mutable_data());
  {
    py::gil_scoped_release release;
    experiments::run(rangefinder, plan, seed, {records, plan.size()});
  }
  return out;
}

py::dict link_budget(const device::DeviceConfig& config,
                     const py::array_t<double, py::array::forcecast>& distances_m,
                     double reflectance, double angle_deg, std::optional<double> temperature_c) {
  const physics::LinkConfig& link = config.link;
  const double t = temperature_c.value_or(link.receiver.nominal_temperature_c);
  const auto d = distances_m.unchecked<1>();
  const auto n = d.shape(0);
  {
    // The ranges `measure` takes (a negative distance had given a positive
    // power, a NaN or 0 m a NaN or infinite SNR, without a word).
    experiments::PlateGrid grid;
    for (py::ssize_t i = 0; i < n; ++i) grid.distances_m.push_back(d(i));
    grid.reflectances = {reflectance};
    grid.angles_deg = {angle_deg};
    grid.ambient_c = {t};
    std::string message;
    for (const auto& p : grid.problems(std::numeric_limits<double>::infinity()))
      message += (message.empty() ? "" : "\n") + p;
    if (!message.empty()) throw std::invalid_argument(message);
  }
  py::array_t<double> received(n), background(n), signal(n), snr(n), signal_shot(n),
      background_shot(n), dark_shot(n), thermal(n), total(n);
  for (py::ssize_t i = 0; i < n; ++i) {
    const physics::LinkBudgetPoint p =
        physics::link_budget_at(link, d(i), reflectance, angle_deg, t);
    received.mutable_at(i) = p.received_power_w;
    background.mutable_at(i) = p.background_power_w;
    signal.mutable_at(i) = p.signal_current_a;
    snr.mutable_at(i) = p.snr;
    signal_shot.mutable_at(i) = p.noise.signal_shot_a;
    background_shot.mutable_at(i) = p.noise.background_shot_a;
    dark_shot.mutable_at(i) = p.noise.dark_shot_a;
    thermal.mutable_at(i) = p.noise.thermal_a;
    total.mutable_at(i) = p.noise.total_a;
  }
  py::dict out;
  out["distance_m"] = py::array_t<double>(distances_m);
  out["received_power_w"] = received;
  out["background_power_w"] = background;
  out["signal_current_a"] = signal;
  out["noise_signal_shot_a"] = signal_shot;
  out["noise_background_shot_a"] = background_shot;
  out["noise_dark_shot_a"] = dark_shot;
  out["noise_thermal_a"] = thermal;
  out["noise_total_a"] = total;
  out["snr"] = snr;
  return out;
}

py::array read_raw(const fs::path& path) {
  std::vector<ranging::Record> records;
  try {
    records = io::read_raw_csv(path);
  } catch (const std::exception& e) {
    rethrow_for_file(path, e);
  }
  py::array out(record_dtype(), static_cast<py::ssize_t>(records.size()));
  if (!records.empty()) {
    std::memcpy(out.mutable_data(), records.data(), records.size() * sizeof(ranging::Record));
  }
  return out;
}

}  // namespace

void bind_device(py::module_& m) {
  py::class_<device::DeviceConfig>(m, "DeviceConfig",
                                   "A device configuration (the CLI's --preset, --config, --set)")
      .def(py::init(&load_config), py::arg("preset") = py::none(), py::arg("file") = py::none(),
           py::arg("set") = py::none(),
           "As the CLI's --preset, --config and --set: start from `preset` (None: the file's, "
           "else paper), apply the TOML `file`, then the overrides `set` (a dict {key: value} "
           "or 'section.key=value' strings). Raises ValueError (FileNotFoundError for a missing "
           "file) with the CLI's message.")
      .def_property_readonly("name", [](const device::DeviceConfig& c) { return c.name; })
      .def("dump", &io::dump_device_config, "The full configuration as TOML (tofkit config --dump)")
      .def("__getitem__", &config_value, py::arg("key"))
      .def("to_dict", &config_dict, "Every key and its value")
      .def("__repr__",
           [](const device::DeviceConfig& c) { return "<tofkit.DeviceConfig " + c.name + ">"; })
      .def_static("presets", &device::preset_names);

  py::class_<experiments::PlateGrid>(m, "_PlateGrid")
      .def(py::init<>())
      .def_readwrite("distances_m", &experiments::PlateGrid::distances_m)
      .def_readwrite("reflectances", &experiments::PlateGrid::reflectances)
      .def_readwrite("angles_deg", &experiments::PlateGrid::angles_deg)
      .def_readwrite("ambient_c", &experiments::PlateGrid::ambient_c)
      .def_readwrite("count", &experiments::PlateGrid::count)
      .def_readwrite("shots", &experiments::PlateGrid::shots);

  m.def(
      "set_max_rows",
      [](std::uint64_t rows) {
        if (rows < 1) throw std::invalid_argument("max_rows: must be at least 1");
        const std::uint64_t before = io::resource_limits().max_rows;
        io::resource_limits().max_rows = rows;
        return before;
      },
      py::arg("rows"),
      "The row limit of measure(), read_raw() and scan lists, as the CLI's --max-rows (default "
      "1e6); returns the previous one.");
  m.def("_measure", &measure, py::arg("config"), py::arg("grid"), py::arg("seed"), py::arg("mode"));
  m.def("_link_budget", &link_budget, py::arg("config"), py::arg("distance_m"),
        py::arg("reflectance"), py::arg("angle_deg"), py::arg("temperature_c"));
  m.def("read_raw", &read_raw, py::arg("path"),
        "Read a raw CSV (tofkit measure's output) into a structured array");
}

}  // namespace tofkit::python
