// `tofkit demo`: the main job. Runs the paper's Section 5 end to end on the
// built-in virtual rangefinder, prints a Table 2-style comparison, and writes
// summary.json, the CSVs, model.json, plots and report.html.
#include <fmt/format.h>
#include <unistd.h>

#include <CLI/CLI.hpp>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <string>

#include "app.hpp"
#include "demo_report.hpp"
#include "demo_thesis.hpp"
#include "demo_thesis_scan.hpp"
#include "html.hpp"
#include "tofkit/calib/uncertainty_budget.hpp"
#include "tofkit/device/accurange_preset.hpp"
#include "tofkit/device/virtual_rangefinder.hpp"
#include "tofkit/experiments/paper_reference.hpp"
#include "tofkit/experiments/paper_study.hpp"
#include "tofkit/io/atomic_file.hpp"
#include "tofkit/io/raw_csv.hpp"
#include "tofkit/io/validation_matrix.hpp"
#include "validate_run.hpp"

namespace tofkit::app {
namespace {

struct DemoOptions {
  std::filesystem::path out = "demo-out";
  std::uint64_t seed = 2022;
  bool plots = true;
};

/// A one-line progress indicator on a terminal; silent when stderr is a file.
class Progress {
 public:
  Progress() : tty_(::isatty(STDERR_FILENO) != 0) {}
  void operator()(std::string_view stage, double done) {
    if (!tty_) return;
    std::fprintf(stderr, "\r  [%-30.*s] %3.0f %%", static_cast<int>(stage.size()), stage.data(),
                 100.0 * done);
    std::fflush(stderr);
    if (done >= 1.0) std::fprintf(stderr, "\n");
  }

 private:
  bool tty_;
};

// "yes" only when every row has a finite deviation within the limit and the
// chain has every step: a row without a measurement (NaN) fails the verdict
// instead of being skipped, and so does a step the calibration could not fit.
std::string verdict(double worst, std::size_t missing, std::size_t rows, double limit_mm,
                    std::size_t steps_not_fitted) {
  std::string why;
  if (missing > 0) why = fmt::format("{} of {} rows without a measurement", missing, rows);
  if (steps_not_fitted > 0) {
    why += fmt::format("{}{} chain step(s) not fitted", why.empty() ? "" : "; ", steps_not_fitted);
  }
  if (!why.empty()) return "NO (" + why + ")";
  return worst <= limit_mm ? "yes" : "NO";
}

// Every accuracy figure told apart: noise of one measurement (repeatability)
// and the error of the mean of the repeats (what a better correction could remove).
void print_split_table(const experiments::PaperStudyResult& r) {
  const auto& v = r.verification_rows;
  const int repeats = v.empty() ? 0 : v.front().repeats;
  fmt::print(
      "\nnoise vs systematic residual ({} repeats of each condition; error = corrected - true)\n",
      repeats);
  fmt::print("{:<24} {:>10} {:>12} {:>14} {:>14} {:>14}\n", "test set", "conditions", "noise (mm)",
             "syst. RMS (mm)", "syst. max (mm)", "noise of mean");
  for (const auto& [name, s] : split_lines(r)) {
    fmt::print("{:<24} {:>10} {:>12.2f} {:>14.2f} {:>14.2f} {:>14.2f}\n", name, s->groups,
               1e3 * s->noise_m, 1e3 * s->systematic_rms_m, 1e3 * s->systematic_max_abs_m,
               1e3 * s->noise_of_mean_m);
  }
  fmt::print(
      "(noise: std of one measurement about its condition's mean; syst.: error of that mean, "
      "RMS with the mean's own noise removed)\n");
}

void print_table(const experiments::PaperStudyResult& r) {
  namespace paper = experiments::paper;
  fmt::print("tofkit demo: the paper's Section 5 on the virtual rangefinder\n\n");
  fmt::print("{:<44} {:>12} {:>12}\n", "figure", "paper", "tofkit");
  fmt::print("{:<44} {:>12} {:>12.2f}\n", "range at SNR = 10, rho 0.1, sunlit (m)", "~10",
             r.range_at_snr10_m);
  fmt::print("{:<44} {:>12.2f} {:>12.2f}\n", "longest achievable distance, rho 0.1 (m)",
             paper::kLongestDistance_m, r.max_range_m);
  fmt::print("{:<44} {:>12.2f} {:>12.2f}\n", "gray-value at 2.355 m: std (mm)",
             paper::kGrayvalueStd_mm, r.grayvalue.std_mm);
  fmt::print("{:<44} {:>12} {:>12.2f}\n", "gray-value at 2.355 m: accuracy +- (mm)",
             fmt::format("{:.0f}", paper::kGrayvalueAccuracy_mm), r.grayvalue.accuracy_mm);
  fmt::print("{:<44} {:>12.2f} {:>12.2f}\n", "temperature at 2.402 m: std (mm)",
             paper::kTemperatureStd_mm, r.temperature.std_mm);
  fmt::print("{:<44} {:>12} {:>12.2f}\n", "temperature at 2.402 m: accuracy +- (mm)",
             fmt::format("{:.0f}", paper::kTemperatureAccuracy_mm), r.temperature.accuracy_mm);
  fmt::print("\nTable 2 (black foam plate, rho 0.1); deviation = actual - measured\n");
  fmt::print("{:>10} {:>14} {:>14} {:>14} {:>14} {:>14}\n", "actual (m)", "paper meas.",
             "paper dev (mm)", "tofkit meas.", "tofkit dev (mm)", "noise 1s (mm)");
  double worst = 0;
  std::size_t missing = 0;
  for (const auto& row : r.verification_rows) {
    if (!std::isfinite(row.deviation_mm)) ++missing;
    fmt::print("{:>10.3f} {:>14.3f} {:>14.1f} {:>14.4f} {:>14.2f} {:>14.2f}\n", row.actual_m,
               row.paper_measured_m, row.paper_deviation_mm, row.measured_m, row.deviation_mm,
               row.noise_mm);
    worst = std::max(worst, std::abs(row.deviation_mm));
  }
  fmt::print("{:>10} {:>14} {:>14} {:>14} {:>14.2f}\n", "worst", "", "+-11", "", worst);
  fmt::print(
      "\nheld out ({} rows: 0.5-9 m x rho 0.05-0.9 x 5-40 C; {} without a reliable echo): "
      "max |error| {:.2f} mm, RMS {:.2f} mm (uncorrected RMS {:.1f} mm)\n",
      r.holdout_stats.rows, r.holdout_rows_without_echo, 1e3 * r.holdout_stats.max_abs_m,
      1e3 * r.holdout_stats.rms_m, 1e3 * r.holdout_raw_stats.rms_m);
  print_split_table(r);
  fmt::print("fixed point vs floating point: max difference {:.3f} mm\n",
             r.fixed_vs_float_max_diff_mm);
  for (const std::string& step : r.steps_not_fitted)
    fmt::print("chain step not fitted (left out of the correction): {}\n", step);
  const std::size_t rows = r.verification_rows.size();
  const std::size_t not_fitted = r.steps_not_fitted.size();
  fmt::print(
      "every verification row within +-11 mm: {} (the paper's band); within +-3 mm, stricter than "
      "the paper, for comparison: {}\n",
      verdict(worst, missing, rows, 11.0, not_fitted),
      verdict(worst, missing, rows, 3.0, not_fitted));
}

nlohmann::json split_json(const calib::RepeatabilitySplit& s) {
  return {{"conditions", s.groups},
          {"rows", s.rows},
          {"noise_mm", 1e3 * s.noise_m},
          {"systematic_rms_mm", 1e3 * s.systematic_rms_m},
          {"systematic_max_abs_mm", 1e3 * s.systematic_max_abs_m},
          {"noise_of_mean_mm", 1e3 * s.noise_of_mean_m}};
}

nlohmann::json summary_json(const experiments::PaperStudyResult& r) {
  nlohmann::json j;
  j["link_budget"] = {{"range_at_snr10_m", r.range_at_snr10_m}};
  j["max_range_m"] = r.max_range_m;
  j["grayvalue"] = {{"distance_m", r.grayvalue.distance_m},
                    {"std_mm", r.grayvalue.std_mm},
                    {"accuracy_mm", r.grayvalue.accuracy_mm},
                    {"raw_spread_mm", r.grayvalue.raw_spread_mm},
                    {"rows", r.grayvalue.rows},
                    {"split", split_json(r.grayvalue.split)}};
  j["temperature"] = {{"distance_m", r.temperature.distance_m},
                      {"std_mm", r.temperature.std_mm},
                      {"accuracy_mm", r.temperature.accuracy_mm},
                      {"rows", r.temperature.rows},
                      {"split", split_json(r.temperature.split)}};
  j["verification"] = nlohmann::json::array();
  for (const auto& row : r.verification_rows)
    j["verification"].push_back({{"actual_m", row.actual_m},
                                 {"measured_m", row.measured_m},
                                 {"deviation_mm", row.deviation_mm},
                                 {"noise_mm", row.noise_mm},
                                 {"repeats", row.repeats},
                                 {"paper_measured_m", row.paper_measured_m},
                                 {"paper_deviation_mm", row.paper_deviation_mm}});
  j["holdout"] = {{"max_abs_error_mm", 1e3 * r.holdout_stats.max_abs_m},
                  {"rms_mm", 1e3 * r.holdout_stats.rms_m},
                  {"bias_mm", 1e3 * r.holdout_stats.bias_m},
                  {"rows", r.holdout_stats.rows},
                  {"rows_without_reliable_echo", r.holdout_rows_without_echo},
                  {"uncorrected_rms_mm", 1e3 * r.holdout_raw_stats.rms_m},
                  {"split", split_json(r.holdout_split)}};
  j["verification_split"] = split_json(r.verification_split);
  j["fixed_point"] = {{"max_abs_difference_to_float_mm", r.fixed_vs_float_max_diff_mm}};
  nlohmann::json knots = nlohmann::json::object();
  if (r.fit.grayvalue) knots["grayvalue_ns"] = r.fit.grayvalue->knots;
  if (r.fit.temperature) knots["temperature_c"] = r.fit.temperature->knots;
  j["fit"] = {{"offset_mm", 1e3 * r.fit.offset_m},
              {"knots", knots},
              {"rows", r.fit.rows},
              {"residual_rms_mm", 1e3 * r.fit.after.rms_m}};
  if (!r.steps_not_fitted.empty()) j["fit"]["steps_not_fitted"] = r.steps_not_fitted;
  return j;
}

/// The calibration certificate of the paper's protocol: the chain refitted
/// with cross-fitting on the demo's calibration rows and its uncertainty
/// budget (calib/uncertainty_budget.hpp); the steps the paper did not take
/// (stability record, other power-ons) are type B terms, named.
std::string budget_section_html(const experiments::PaperStudyResult& result,
                                const device::DeviceConfig& config) {
  std::string text;
  try {
    calib::ModelFitOptions options;
    options.time_to_distance = device::nominal_time_to_distance(config);
    options.chain = calib::parse_chain_steps("offset,grayvalue,temperature");
    options.extrapolation_refit = true;  // the budget's extrapolation term
    const calib::ModelFitResult fit = calib::fit_model(result.calibration, options);
    calib::ProtocolSteps steps;
    steps.tdc_period_ns = 1e3 / config.tdc.coarse_clock_mhz;
    text = calib::fit_model_budget(result.calibration, fit, steps, {}).report;
  } catch (const std::invalid_argument& e) {
    text = std::string("no budget: ") + e.what();
  }
  return "<h2>Calibration certificate: the uncertainty budget of the paper's protocol</h2>\n"
         "<p>The chain fitted on the calibration rows with cross-fitting; each component from "
         "the step that observed it (type A) or a default specification (type B*). "
         "<code>tofkit plan</code> prints a protocol that observes every cause.</p><pre>" +
         html_escape(text) + "</pre>\n";
}

void run_demo(const DemoOptions& options, const AppContext& ctx) {
  const auto start = std::chrono::steady_clock::now();
  const auto config = ctx.load_config();
  io::create_output_directories(options.out);
  Progress progress;
  experiments::PaperStudyOptions study_options;
  study_options.seed = options.seed;
  study_options.progress = [&](std::string_view stage, double done) {
    progress(stage, 0.7 * done);
  };
  const auto result =
      experiments::run_paper_study(config, study_options, experiments::paper::kTable2);

  // The thesis's protocol on its own device (AccuRange-like preset).
  progress("thesis protocol", 0.72);
  const device::VirtualRangefinder accurange(device::accurange_preset());
  const auto thesis = experiments::run_thesis_protocol(accurange, {}, options.seed);

  progress("thesis scanning", 0.8);
  const auto thesis_scan = run_thesis_scan_demo(options.seed);

  // The validation matrix (the same runner as `tofkit validate`), for its summary.
  // The demo's devices: its own (--preset/--config/--set) for the rows of the
  // preset it starts from, the built-in presets for the others (as the thesis
  // parts above use the built-in accurange). A matrix that cannot be found or
  // run leaves the summary's entry with the reason; the demo goes on.
  progress("validation matrix", 0.88);
  const std::string matrix_name = "reference/validation_matrix.csv";
  std::optional<experiments::ValidationResult> validation;
  std::string validation_error;
  try {
    const auto demo_devices = [&config](const std::string& preset) {
      return std::optional<device::DeviceConfig>(preset == config.name ? config
                                                                       : device::preset(preset));
    };
    experiments::ValidationOptions validation_options;
    validation_options.seed = options.seed;
    validation = experiments::run_validation(
        io::read_validation_matrix(default_validation_matrix()), demo_devices, validation_options);
  } catch (const std::exception& e) {
    validation_error = e.what();
  }

  progress("writing results", 0.92);
  const auto& out = options.out;
  io::write_raw_csv(out / "calibration.csv", result.calibration);
  io::write_corrected_csv(out / "grayvalue_test.csv", result.grayvalue_test,
                          result.grayvalue_corrected);
  io::write_corrected_csv(out / "temperature_test.csv", result.temperature_test,
                          result.temperature_corrected);
  io::write_corrected_csv(out / "verification.csv", result.verification,
                          result.verification_corrected);
  io::write_corrected_csv(out / "holdout.csv", result.holdout, result.holdout_corrected);
  io::write_raw_csv(out / "max_range.csv", result.max_range_scan);
  write_demo_model(out, result);
  io::write_raw_csv(out / "thesis.csv", thesis.all_records());
  auto summary = summary_json(result);
  summary["thesis"] = thesis_summary_json(thesis);
  add_thesis_scan_summary(summary, thesis_scan);
  summary["validation"] = validation ? validation_demo_json(*validation, matrix_name)
                                     : nlohmann::json{{"error", validation_error}};
  const double seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  summary["seconds"] = seconds;
  summary["seed"] = options.seed;
  summary["device"] = config.name;
  auto figures = write_demo_plots(out, result, options.plots);
  const auto thesis_figures = write_thesis_plots(out, thesis, options.plots);
  figures.insert(figures.end(), thesis_figures.begin(), thesis_figures.end());
  write_demo_report(out, result, summary, figures, thesis.summary(),
                    budget_section_html(result, config) +
                        write_thesis_scan_section(out, thesis_scan, options.plots) +
                        (validation ? validation_section_html(*validation, matrix_name) : ""));
  io::write_file_atomically(out / "summary.json", summary.dump(2) + "\n");
  progress("done", 1.0);
  print_table(result);
  fmt::print("\nthe thesis's protocol (AccuRange-like preset, grey chart, test at 19 in):\n{}",
             thesis.summary());
  fmt::print("\nthe thesis's scanning results (AccuRange-like preset):\n{}{}",
             thesis_scan.line.summary(), thesis_scan.memory.summary());
  if (validation)
    fmt::print("\nthe validation matrix ({}; tofkit validate prints every row):\n{}", matrix_name,
               validation->summary_text());
  else
    fmt::print("\nthe validation matrix was not run: {}\n", validation_error);
  fmt::print(
      "\nwrote {} (summary.json, CSVs, model.json, firmware/, plots/, report.html) in {:.1f} s\n",
      out.string(), seconds);
}

const bool registered = register_command("demo", [](CLI::App& sub, AppContext& ctx) {
  sub.description(
      "the main job: calibrate and verify the built-in virtual rangefinder as the paper does "
      "(Section 5), and write a report");
  auto options = std::make_shared<DemoOptions>();
  sub.add_option("--out", options->out, "output directory")->capture_default_str();
  add_seed_option(sub, options->seed, "random seed of the whole study");
  sub.add_flag("!--no-plots", options->plots, "skip rendering PNG plots");
  sub.callback([options, &ctx] { run_demo(*options, ctx); });
});

}  // namespace
}  // namespace tofkit::app
