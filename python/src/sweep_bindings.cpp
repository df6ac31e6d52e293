// tofkit.sweep: the CLI's sweep plans and table rows (io/sweep_plan.hpp), the
// same bytes as `tofkit sweep`; points computed in parallel, GIL released.

#include <pybind11/stl.h>
#include <tbb/parallel_for.h>

#include <string>
#include <vector>

#include "bindings.hpp"
#include "tofkit/io/sweep_plan.hpp"

namespace tofkit::python {

void bind_sweep(py::module_& m) {
  py::class_<io::SweepPlan>(m, "_SweepPlan")
      .def_property_readonly("points", &io::SweepPlan::points)
      .def_property_readonly("header", [](const io::SweepPlan& p) { return io::sweep_header(p); })
      .def_property_readonly("axes", [](const io::SweepPlan& p) {
        py::list axes;
        for (const auto& a : p.axes) axes.append(py::make_tuple(a.key, a.values));
        return axes;
      });
  m.def(
      "_sweep_plan",
      [](const std::string& file, const std::string& preset, const py::object& config_file,
         const std::vector<std::string>& overrides) {
        io::SweepBase base{preset, std::nullopt, overrides, {}, {}};
        if (!config_file.is_none()) base.config_file = py::str(config_file).cast<std::string>();
        return io::load_sweep_plan(file, base);
      },
      py::arg("file"), py::arg("preset"), py::arg("config_file"), py::arg("overrides"));
  m.def(
      "_sweep_rows",
      [](const io::SweepPlan& plan, const std::string& preset, const py::object& config_file,
         const std::vector<std::string>& overrides, const std::vector<std::uint64_t>& points) {
        io::SweepBase base{preset, std::nullopt, overrides, {}, {}};
        if (!config_file.is_none()) base.config_file = py::str(config_file).cast<std::string>();
        for (const auto p : points) {
          if (p >= plan.points())
            throw std::invalid_argument("point " + std::to_string(p) + " is beyond the plan's " +
                                        std::to_string(plan.points()));
        }
        std::vector<std::string> rows(points.size());
        {
          py::gil_scoped_release release;
          tbb::parallel_for(std::size_t{0}, points.size(),
                            [&](std::size_t k) { rows[k] = io::sweep_row(plan, base, points[k]); });
        }
        return rows;
      },
      py::arg("plan"), py::arg("preset"), py::arg("config_file"), py::arg("overrides"),
      py::arg("points"));
}

}  // namespace tofkit::python
