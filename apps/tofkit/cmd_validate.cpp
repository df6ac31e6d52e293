// `tofkit validate`: runs a validation matrix (default reference/validation_matrix.csv)
// on the virtual rangefinder, prints id / figure / document / twin / band / in band
// and the summary, and writes validation.json, validation.csv, validation.html and
// plots into --out. Exit 0 when it ran (in-band shares are results); with
// --require-in-band, 3 when a counted row is outside its band.

#include <fmt/format.h>
#include <unistd.h>

#include <CLI/CLI.hpp>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <string>

#include "app.hpp"
#include "tofkit/io/validation_matrix.hpp"
#include "validate_run.hpp"

namespace tofkit::app {
namespace {

struct ValidateOptions {
  std::string matrix;  ///< empty: the reference matrix
  std::string out;     ///< empty: print only
  std::string only;
  std::uint64_t seed = 2022;
  bool require_in_band = false;
  bool list = false;
  bool plots = true;
};

void list_quantities() {
  for (const auto& q : experiments::validation_quantities()) {
    std::string keys;
    for (const auto& k : q.parameters) keys += (keys.empty() ? "" : ", ") + k;
    fmt::print("{}  [{}]{}{}\n    {}\n", q.id, q.unit, keys.empty() ? "" : "  conditions: ", keys,
               q.description);
  }
}

void run_validate(const ValidateOptions& o, AppContext& ctx) {
  if (o.list) {
    list_quantities();
    return;
  }
  const std::filesystem::path matrix =
      o.matrix.empty() ? default_validation_matrix() : std::filesystem::path(o.matrix);
  const auto rows = io::read_validation_matrix(matrix);
  // Outputs name the reference matrix as the checkout does (the same bytes wherever it lives).
  const std::string name = o.matrix.empty() ? "reference/validation_matrix.csv" : o.matrix;
  const auto devices = device_selection(ctx);
  experiments::ValidationOptions options;
  options.seed = o.seed;
  options.only = o.only;
  const bool tty = ::isatty(STDERR_FILENO) != 0;
  options.progress = [tty](std::string_view stage, double done) {
    if (!tty) return;
    std::fprintf(stderr, "\r  [%-40.*s] %3.0f %%",
                 static_cast<int>(std::min<std::size_t>(stage.size(), 40)), stage.data(),
                 100.0 * done);
    std::fflush(stderr);
    if (done >= 1.0) std::fprintf(stderr, "\n");
  };
  const auto result = experiments::run_validation(rows, devices, options);
  if (result.summary.rows + result.summary.tofkit_rows == 0) {
    throw std::runtime_error("no row of " + matrix.string() + " was run" +
                             (o.only.empty() ? "" : " (--only " + o.only + ")") +
                             " with this device: rows run on the device whose preset they name");
  }
  if (!o.out.empty()) write_validation_outputs(o.out, result, name, o.seed, o.plots);
  fmt::print("tofkit validate: {} on {} (seed {})\n\n{}\n{}", name, fmt::join(result.devices, ", "),
             o.seed, result.table(), result.summary_text());
  if (!o.out.empty())
    fmt::print("wrote {} (validation.json, validation.csv, validation.html, plots/)\n", o.out);
  if (o.require_in_band && result.summary.in_band < result.summary.rows) {
    fmt::print(stderr, "tofkit validate: {} of {} rows outside their band (--require-in-band)\n",
               result.summary.rows - result.summary.in_band, result.summary.rows);
    ctx.exit_status = 3;
  }
}

const bool registered = register_command("validate", [](CLI::App& sub, AppContext& ctx) {
  sub.description(
      "run the validation matrix (the documents' figures) on the virtual rangefinder: document "
      "/ twin / band / in band, JSON, CSV and an HTML page");
  auto o = std::make_shared<ValidateOptions>();
  sub.add_option("--matrix", o->matrix,
                 "matrix file (CSV, docs/validation.md; default: reference/validation_matrix.csv)");
  sub.add_option("--out", o->out, "output directory (validation.json, .csv, .html, plots/)");
  sub.add_option("--only", o->only, "run only the rows whose id starts with this");
  add_seed_option(sub, o->seed, "random seed of every experiment run");
  sub.add_flag("--require-in-band", o->require_in_band,
               "exit with status 3 when a row (document's method) is outside its band");
  sub.add_flag("--list", o->list, "list the quantities a matrix row may name, and exit");
  sub.add_flag("!--no-plots", o->plots, "skip rendering PNG plots");
  sub.callback([o, &ctx] { run_validate(*o, ctx); });
});

}  // namespace
}  // namespace tofkit::app
