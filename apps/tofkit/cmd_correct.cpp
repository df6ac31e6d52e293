// tofkit correct: apply a model file's ranging pipeline to a raw CSV and write
// the corrected CSV (distance_m, sigma_m, correction_flags added).

#include <fmt/format.h>

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
  const std::vector<ranging::Record> records = io::read_raw_csv(o.in);
  std::vector<ranging::Range> ranges(records.size());
  pipeline.apply(ranging::RawColumns::of(records), ranges);  // read in place
  // With a budget in the model, sigma_m is its combined standard uncertainty
  // at each row's amplitude and the time since calibration.
  const ranging::UncertaintyBudget budget = io::load_budget(o.model);
  if (!budget.empty()) {
    const double since[1] = {o.since_calibration_s};
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
                 "(a model with an uncertainty budget: its drift term); default: unknown, "
                 "another power-on (its power-on term)")
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
