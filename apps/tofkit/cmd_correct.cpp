// tofkit correct: apply a model file's ranging pipeline to a raw CSV and write
// the corrected CSV (distance_m, sigma_m, correction_flags added).

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <iostream>
#include <memory>
#include <string>
#include <vector>

#include "app.hpp"
#include "tofkit/io/model_json.hpp"
#include "tofkit/io/raw_csv.hpp"
#include "tofkit/ranging/pipeline.hpp"
#include "tofkit/ranging/uncertainty_budget.hpp"

namespace tofkit::app {
namespace {

struct CorrectOptions {
  std::string model;
  std::string in;
  std::string out;
  double since_calibration_s = ranging::kNaN;  // NaN: unknown (another power-on)
};

void run_correct(const CorrectOptions& o) {
  if (o.out != "-") require_output_directory(o.out, "--out");
  const ranging::Pipeline pipeline = io::load_pipeline(o.model);
  std::vector<double> time_s;  // the rows' time since power-on, where the file has it
  const std::vector<ranging::Record> records = io::read_raw_csv(o.in, &time_s);
  std::vector<ranging::Range> ranges(records.size());
  pipeline.apply(ranging::RawColumns::of(records), ranges);  // read in place
  // With a budget in the model, sigma_m is its combined standard uncertainty
  // at each row's amplitude and the time since calibration.
  const ranging::UncertaintyBudget budget = io::load_budget(o.model);
  if (!budget.empty()) {
    // The time since calibration: --since-calibration, else each row's
    // time_s less the calibration's (rows with a time are on its power-on),
    // else unknown (another power-on).
    std::vector<double> since = {o.since_calibration_s};
    const bool timed =
        std::isfinite(budget.calibration_time_s) &&
        std::any_of(time_s.begin(), time_s.end(), [](double t) { return std::isfinite(t); });
    if (!std::isfinite(o.since_calibration_s) && timed) {
      since.assign(time_s.size(), ranging::kNaN);
      for (std::size_t i = 0; i < time_s.size(); ++i)
        since[i] = time_s[i] - budget.calibration_time_s;
    }
    ranging::apply_budget(budget, pipeline, ranging::RawColumns::of(records), since, ranges);
  }
  if (o.out == "-") {
    io::write_corrected_csv(std::cout, records, ranges);
    std::cout.flush();
  } else {
    io::write_corrected_csv(o.out, records, ranges);
  }

  std::size_t no_echo = 0, out_of_domain = 0, non_finite = 0;
  for (const auto& r : ranges) {
    no_echo += (r.correction_flags & ranging::kCorrNoEcho) != 0 ? 1 : 0;
    out_of_domain += (r.correction_flags & ranging::kCorrOutOfDomain) != 0 ? 1 : 0;
    non_finite += (r.correction_flags & ranging::kCorrNonFinite) != 0 ? 1 : 0;
  }
  fmt::print(stderr,
             "tofkit correct: {} rows ({} without echo, {} outside the model's domain, {} with a "
             "missing input) -> {}\n",
             ranges.size(), no_echo, out_of_domain, non_finite, o.out == "-" ? "stdout" : o.out);
}

const bool registered = register_command("correct", [](CLI::App& sub, AppContext& ctx) {
  sub.description("apply a model (from tofkit fit) to a raw CSV and write the corrected CSV");
  auto o = std::make_shared<CorrectOptions>();
  sub.add_option("--model", o->model, "model file (JSON, from tofkit fit)")->required();
  sub.add_option("--in", o->in, "raw CSV")->required();
  sub.add_option("--out", o->out, "corrected CSV to write (- for stdout); its directory is made")
      ->required();
  sub.add_option("--since-calibration", o->since_calibration_s,
                 "seconds from the calibration to these rows on the calibration's power-on "
                 "(a model with an uncertainty budget: its drift term); default: each row's "
                 "time_s (time since power-on, from measure --start-s / --every) less the "
                 "calibration's, else unknown: another power-on (its power-on term)")
      ->check(CLI::Range(0.0, 1e9));
  sub.callback([o, &ctx] {
    // The model / table carry everything the command uses; --config, --set
    // and --preset are still checked, so a bad key is an error, not ignored.
    (void)ctx.load_config();
    run_correct(*o);
  });
});

}  // namespace
}  // namespace tofkit::app
