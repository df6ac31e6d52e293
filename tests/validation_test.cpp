// The validation matrix and `tofkit validate`: the reference matrix parses and
// names only known quantities; its document values agree with reference/*.csv
// read here independently; a user's matrix runs end to end; bad matrices exit 1
// naming file, line and column; one row against the paper's closed form.

#include "tofkit/experiments/validation.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <fstream>
#include <map>
#include <nlohmann/json.hpp>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include "cli_runner.hpp"
#include "tofkit/device/device_config.hpp"
#include "tofkit/experiments/paper_method.hpp"
#include "tofkit/io/validation_matrix.hpp"

namespace {

using tofkit::experiments::ValidationMethod;
using tofkit::experiments::ValidationRow;

const std::string kMatrix = std::string(TOFKIT_REFERENCE_DIR) + "/validation_matrix.csv";

/// A plain CSV of numbers and words (the reference tables have no quotes), by header name.
std::vector<std::map<std::string, std::string>> read_plain_csv(const std::string& file) {
  std::ifstream in(std::string(TOFKIT_REFERENCE_DIR) + "/" + file);
  std::string line;
  std::getline(in, line);
  auto split = [](const std::string& s) {
    std::vector<std::string> out;
    std::stringstream ss(s);
    std::string f;
    while (std::getline(ss, f, ',')) out.push_back(f);
    return out;
  };
  const auto header = split(line);
  std::vector<std::map<std::string, std::string>> rows;
  while (std::getline(in, line)) {
    if (line.empty()) continue;
    const auto f = split(line);
    std::map<std::string, std::string> row;
    for (std::size_t k = 0; k < header.size() && k < f.size(); ++k) row[header[k]] = f[k];
    rows.push_back(row);
  }
  return rows;
}

std::map<std::string, ValidationRow> by_id(const std::vector<ValidationRow>& rows) {
  std::map<std::string, ValidationRow> m;
  for (const auto& r : rows) m[r.id] = r;
  return m;
}

TEST(ValidationMatrix, ReferenceParsesAndNamesKnownQuantities) {
  const auto rows = tofkit::io::read_validation_matrix(kMatrix);
  ASSERT_GE(rows.size(), 100u);
  std::set<std::string> known;
  for (const auto& q : tofkit::experiments::validation_quantities()) known.insert(q.id);
  std::set<std::string> figures, presets;
  for (const auto& r : rows) {
    EXPECT_TRUE(known.contains(r.quantity)) << r.id;
    EXPECT_FALSE(r.band_reason.empty()) << r.id;
    EXPECT_GT(r.band_width(), 0) << r.id;
    figures.insert(r.document + " " + r.figure);
    presets.insert(r.preset);
    // Every preset a row names is a built-in device.
    EXPECT_NO_THROW((void)tofkit::device::preset(r.preset)) << r.id;
  }
  for (const char* f :
       {"paper Fig. 3", "paper Fig. 6", "paper Fig. 7", "paper Fig. 8", "paper Fig. 9",
        "paper Table 2", "thesis Fig. 4.4", "thesis Fig. 4.9", "thesis Fig. 4.18",
        "thesis Fig. 4.23", "thesis Fig. 4.27", "thesis Fig. 4.28", "thesis Section 4.8",
        "thesis Fig. 4.32", "thesis Fig. 4.33"})
    EXPECT_TRUE(figures.contains(f)) << f;
  EXPECT_EQ(presets, (std::set<std::string>{"paper", "accurange"}));
}

TEST(ValidationMatrix, DocumentValuesAgreeWithTheReferenceTables) {
  const auto m = by_id(tofkit::io::read_validation_matrix(kMatrix));
  auto value = [&](const std::string& id) {
    EXPECT_TRUE(m.contains(id)) << id;
    return m.contains(id) ? m.at(id).value : NAN;
  };
  // Table 2: deviation (m) per actual distance.
  const auto t2 = read_plain_csv("table2_accuracy.csv");
  ASSERT_EQ(t2.size(), 8u);
  for (const auto& r : t2) {
    const long d = std::lround(std::stod(r.at("actual_value_m")));
    const double dev_mm = 1e3 * std::stod(r.at("deviation_m"));
    EXPECT_NEAR(value("paper.table2." + std::to_string(d) + "m"), dev_mm, 1e-9);
    EXPECT_NEAR(value("paper.table2." + std::to_string(d) + "m.tofkit"), dev_mm, 1e-9);
  }
  // Fig. 4.4: one row per setting, 2^3 .. 2^11 shots.
  const auto f44 = read_plain_csv("fig4_4_sampling.csv");
  ASSERT_EQ(f44.size(), 9u);
  for (std::size_t k = 0; k < f44.size(); ++k) {
    const std::string n = ".n" + std::to_string(3 + k);
    // The setting's exponent gives the thesis's rate: 312,500 / 2^N.
    EXPECT_NEAR(std::stod(f44[k].at("sampling_rate_hz")), 312500.0 / double(1 << (3 + k)), 0.01);
    EXPECT_DOUBLE_EQ(value("thesis.fig4_4.resolution" + n),
                     std::stod(f44[k].at("resolution_mm_per_count")));
    EXPECT_DOUBLE_EQ(value("thesis.fig4_4.variance" + n), std::stod(f44[k].at("variance_in2")));
    EXPECT_DOUBLE_EQ(value("thesis.fig4_4.mean" + n), std::stod(f44[k].at("mean_in")));
  }
  // Figs. 4.18, 4.23, 4.27: every model row's bias, variance, RMS and improvement.
  for (const auto& [file, prefix] : {std::pair{"fig4_18_point_fit.csv", "thesis.fig4_18."},
                                     std::pair{"fig4_23_line_fit.csv", "thesis.fig4_23."},
                                     std::pair{"fig4_27_checker_fit.csv", "thesis.fig4_27."}}) {
    for (const auto& r : read_plain_csv(file)) {
      const std::string model = r.at("order") == "raw" ? "raw" : "poly" + r.at("order");
      const std::string base = std::string(prefix) + model;
      EXPECT_DOUBLE_EQ(value(base + ".bias"), std::stod(r.at("bias_in")));
      EXPECT_DOUBLE_EQ(value(base + ".variance"), std::stod(r.at("variance_in")));
      EXPECT_DOUBLE_EQ(value(base + ".rms"), std::stod(r.at("rms_in")));
      if (model != "raw")
        EXPECT_DOUBLE_EQ(value(base + ".improvement"), std::stod(r.at("rms_improvement_pct")));
    }
  }
  // The figures quoted in the documents' text (reference/*.md).
  EXPECT_DOUBLE_EQ(value("paper.fig7.std"), 4.60);
  EXPECT_DOUBLE_EQ(value("paper.fig7.accuracy"), 9.0);
  EXPECT_DOUBLE_EQ(value("paper.fig9.std"), 4.70);
  EXPECT_DOUBLE_EQ(value("paper.fig9.accuracy"), 10.0);
  EXPECT_DOUBLE_EQ(value("paper.fig8.slope_above"), 3.8);
  EXPECT_DOUBLE_EQ(value("paper.sec5_3.longest"), 8.08);
  EXPECT_DOUBLE_EQ(value("paper.fig6.knee"), 6.5);
  EXPECT_DOUBLE_EQ(value("thesis.fig4_9.rms_grey102up"), 0.2281);
  EXPECT_DOUBLE_EQ(value("thesis.fig4_9.rms_all"), 1.0693);
  EXPECT_DOUBLE_EQ(value("thesis.fig4_9.slope"), 0.9804);
  EXPECT_DOUBLE_EQ(value("thesis.fig4_9.intercept"), -0.6732);
  EXPECT_NEAR(value("thesis.fig4_9.offset_20in"), 0.9804 * 20 - 0.6732 - 20, 1e-9);
  // Ranges stated as "a-b" are the band around their middle.
  auto range_of = [&](const std::string& id) {
    const auto& r = m.at(id);
    return std::pair{r.value - r.band_width(), r.value + r.band_width()};
  };
  EXPECT_EQ(range_of("thesis.warmup.settle"), (std::pair{25.0, 35.0}));
  const auto t = range_of("thesis.temperature.slope");
  EXPECT_NEAR(t.first, -0.60, 1e-12);
  EXPECT_NEAR(t.second, -0.25, 1e-12);
  EXPECT_NEAR(value("thesis.fig4_28.swing"), 23.91 - 15.65, 1e-9);
  const double rel[] = {0.0117, 0.0077, 0.0070, 0.0046};
  const int at_in[] = {15, 17, 20, 22};
  for (int k = 0; k < 4; ++k)
    EXPECT_DOUBLE_EQ(value("thesis.relative_error." + std::to_string(at_in[k]) + "in"), rel[k]);
  EXPECT_DOUBLE_EQ(value("thesis.confidence.stripes_min"), 0.076);
  EXPECT_DOUBLE_EQ(value("thesis.confidence.stripes_max"), 0.401);
  EXPECT_DOUBLE_EQ(value("thesis.confidence.checker_min"), 0.005);
  EXPECT_DOUBLE_EQ(value("thesis.confidence.checker_max"), 0.513);
  // tofkit's rows are marked as such and the document's are not.
  for (const auto& [id, r] : m)
    EXPECT_EQ(id.ends_with(".tofkit") || id.find(".bspline.") != std::string::npos,
              r.method == ValidationMethod::kTofkit)
        << id;
}

/// Paper Eq. 6 and Eq. 8 with Table 1 (reference/ranging_paper.md), written out
/// here: the extended-target power, the multiplied shot noises (signal,
/// background by Eq. 9 as printed, dark), and the amplifier's NEP.
double closed_form_snr(double distance_m, double rho, const tofkit::device::DeviceConfig& c) {
  const double pi = 3.14159265358979323846, q = 1.602176634e-19;
  const auto& rx = c.link.receiver;
  const double ar = pi * std::pow(26e-3 / 2, 2);
  const double ta = 0.99, tt = 0.975, tr = 0.15;
  const double pr = 1.0 * ar * rho / (pi * distance_m * distance_m) * tt * tr * ta * ta;
  const double theta_r = 0.02, d_r = 26e-3, dlambda_um = 0.020, h = 748.5;
  const double pb = pi / 16 * tr * rho * theta_r * theta_r * d_r * d_r * dlambda_um *
                    (ta * rho * h * std::cos(44 * pi / 180));
  const double m = 100, f = 3, b = 150e6, r0 = 0.58;
  const double shot = 2 * q * m * m * f * b;
  const double noise2 = shot * r0 * pr + shot * r0 * pb + shot * rx.dark_current_na * 1e-9 +
                        std::pow(2e-14 * r0 * m * std::sqrt(b), 2);
  return r0 * m * pr / std::sqrt(noise2);
}

TEST(ValidationRunner, LinkBudgetRowMatchesTheClosedForm) {
  ValidationRow row;
  row.id = "snr";
  row.quantity = "paper.link_budget.snr";
  row.parameters = {{"distance_m", "10"}, {"reflectance", "0.1"}};
  row.value = 10;
  row.band = 2;
  row.band_reason = "test";
  row.preset = "paper";
  const auto config = tofkit::device::preset("paper");
  for (const double d : {2.0, 10.0}) {
    row.parameters["distance_m"] = std::to_string(d);
    const std::vector<ValidationRow> rows{row};
    const auto result = tofkit::experiments::run_validation(
        rows, [&](const std::string&) { return std::optional(config); });
    ASSERT_EQ(result.rows.size(), 1u);
    EXPECT_NEAR(result.rows[0].twin, closed_form_snr(d, 0.1, config),
                1e-3 * closed_form_snr(d, 0.1, config))
        << d << " m";
  }
  // Near SNR 10 at 10 m: the paper's Figure 3.
  EXPECT_NEAR(closed_form_snr(10, 0.1, config), 10, 1.0);
}

TEST(ValidationRunner, SharesAndBandsAreCounted) {
  // Two copies of one quantity whose value the test knows from a first run:
  // one band around it (in), one far away (outside twice), one tofkit row.
  ValidationRow r;
  r.quantity = "paper.link_budget.range_at_snr_m";
  r.parameters = {{"snr", "10"}};
  r.band_reason = "test";
  r.preset = "paper";
  r.band = 0.5;
  r.id = "a";
  r.value = 0;
  auto select = [](const std::string& p) { return std::optional(tofkit::device::preset(p)); };
  const double twin = tofkit::experiments::run_validation(std::vector{r}, select).rows[0].twin;
  ASSERT_TRUE(std::isfinite(twin));
  std::vector<ValidationRow> rows(2, r);
  rows[0].value = twin + 0.4;  // in band (0.5)
  rows[0].role = tofkit::experiments::ValidationRole::kCalibration;
  rows[1].id = "b";
  rows[1].value = twin + 1.2;  // beyond twice the band
  const auto result = tofkit::experiments::run_validation(rows, select);
  EXPECT_EQ(result.summary.rows, 2u);
  EXPECT_EQ(result.summary.in_band, 1u);
  EXPECT_EQ(result.summary.outside_twice, 1u);
  EXPECT_EQ(result.summary.held_out, 1u);
  EXPECT_EQ(result.summary.held_out_in_band, 0u);
  EXPECT_DOUBLE_EQ(result.summary.calibration_in_band_share(), 1.0);
  // A preset the selection does not run is reported, not run.
  const auto none = tofkit::experiments::run_validation(
      rows, [](const std::string&) { return std::optional<tofkit::device::DeviceConfig>(); });
  EXPECT_EQ(none.summary.rows, 0u);
  EXPECT_EQ(none.summary.not_run, 2u);
}

// The paper's correction, fitted on measurements whose offset is exactly the
// paper's shapes: a hinge at 6.5 ns in pulse width and a drift of 3.8 mm/C
// above 16 C, flat below. The fit must find those numbers, and the test sets
// (same shapes) must come out corrected to zero.
TEST(PaperMethod, RecoversThePapersShapesAndCorrectsThem) {
  using tofkit::ranging::Record;
  const double slope_below = -30, slope_above = 60, drift = 3.8;  // mm/ns, mm/ns, mm/C
  auto measured_minus_true_mm = [&](double width_ns, double sensor_c) {
    const double g =
        width_ns < 6.5 ? slope_below * (width_ns - 6.5) : slope_above * (width_ns - 6.5);
    return 12.0 + g + drift * std::max(0.0, sensor_c - 16.0);
  };
  auto record = [&](double distance_m, double ambient_c, double width_ns, double sensor_c) {
    Record r;
    r.truth.distance_m = distance_m;
    r.truth.reflectance = 0.5;
    r.truth.ambient_c = ambient_c;
    r.raw.shots_valid = 100;
    r.raw.pulse_width_ns = width_ns;
    r.raw.temperature_c = sensor_c;
    r.raw.distance_raw_m = distance_m + 1e-3 * measured_minus_true_mm(width_ns, sensor_c);
    return r;
  };
  tofkit::experiments::PaperStudyOptions options;
  options.test_repeats = 1;
  tofkit::experiments::PaperStudyResult study;
  for (double w = 3.0; w <= 10.0; w += 0.25) study.calibration.push_back(record(2.355, 20, w, 26));
  for (double t = 2; t <= 46; t += 2) study.calibration.push_back(record(2.402, t - 6, 5.0, t));
  for (double w = 3.1; w <= 10.0; w += 0.5)
    study.grayvalue_test.push_back(record(2.355, 20, w, 26));
  for (double t = 3; t <= 45; t += 3)
    study.temperature_test.push_back(record(2.402, t - 6, 5.0, t));
  for (int d = 1; d <= 8; ++d) study.verification.push_back(record(d, 20, 4.0 + 0.5 * d, 26));

  const auto m = tofkit::experiments::run_paper_method(study, options);
  EXPECT_NEAR(m.slope_below_knee_mm_per_ns, slope_below, 1e-6);
  EXPECT_NEAR(m.slope_above_knee_mm_per_ns, slope_above, 1e-6);
  EXPECT_NEAR(m.temperature_slope_above_mm_per_c, drift, 1e-6);
  EXPECT_NEAR(m.temperature_slope_below_mm_per_c, 0.0, 1e-6);
  EXPECT_NEAR(m.grayvalue.std_mm, 0.0, 1e-6);
  EXPECT_NEAR(m.grayvalue.accuracy_mm, 0.0, 1e-6);
  EXPECT_EQ(m.grayvalue.rows, study.grayvalue_test.size());
  EXPECT_NEAR(m.temperature.accuracy_mm, 0.0, 1e-6);
  ASSERT_EQ(m.verification_rows.size(), 8u);
  for (const auto& row : m.verification_rows) EXPECT_NEAR(row.deviation_mm, 0.0, 1e-6);
  // Plates that stay on one side of the knee cannot place it: refused.
  tofkit::experiments::PaperStudyResult narrow = study;
  narrow.calibration.clear();
  for (double w = 3.0; w <= 6.0; w += 0.25) narrow.calibration.push_back(record(2.355, 20, w, 26));
  EXPECT_THROW((void)tofkit::experiments::run_paper_method(narrow, options), std::runtime_error);
}

class ValidateCli : public tofkit::test::CliFixture {
 protected:
  ValidateCli() : CliFixture("tofkit_validate_") {}
  static constexpr const char* kHeader =
      "id,document,figure,quantity,conditions,value,band,band_reason,unit,preset,role\n";
};

TEST_F(ValidateCli, UserMatrixRunsEndToEndAndTheJsonReadsBack) {
  write("mine.csv", std::string("# my device\n") + kHeader +
                        "my.snr,mine,budget,paper.link_budget.snr,distance_m=5,40,25%,\"my "
                        "spec, +-25 %\",,paper,held_out\n"
                        "my.rmax,mine,budget,paper.link_budget.range_at_snr_m,snr=10,9.5,1,spec,"
                        "m,paper,calibration\n");
  const auto r = run("validate --matrix mine.csv --out out --no-plots");
  ASSERT_EQ(r.status, 0) << read("stderr.txt");
  EXPECT_NE(r.out.find("my.snr"), std::string::npos);
  EXPECT_NE(r.out.find("held-out rows in band"), std::string::npos);
  const auto j = nlohmann::json::parse(read("out/validation.json"));
  ASSERT_EQ(j["rows"].size(), 2u);
  const auto config = tofkit::device::preset("paper");
  EXPECT_NEAR(j["rows"][0]["twin"].get<double>(), closed_form_snr(5, 0.1, config),
              1e-3 * closed_form_snr(5, 0.1, config));
  EXPECT_DOUBLE_EQ(j["rows"][0]["band"].get<double>(), 10.0);  // 25 % of 40
  // Signal shot noise dominates: SNR ~ 1/R, about 19 at 5 m, outside twice the band.
  EXPECT_TRUE(j["rows"][0]["outside_twice_band"].get<bool>());
  for (const auto& row : j["rows"]) {
    const double off = std::abs(row["twin"].get<double>() - row["value"].get<double>());
    EXPECT_EQ(row["in_band"].get<bool>(), off <= row["band"].get<double>()) << row["id"];
  }
  EXPECT_EQ(j["summary"]["rows"].get<int>(), 2);
  EXPECT_EQ(j["summary"]["held_out_rows"].get<int>(), 1);
  EXPECT_FALSE(read("out/validation.csv").empty());
  EXPECT_NE(read("out/validation.html").find("my.rmax"), std::string::npos);
  // --only runs a subset; a --preset that no row names runs nothing: an error.
  const auto only = run("validate --matrix mine.csv --only my.rmax");
  EXPECT_EQ(only.status, 0);
  EXPECT_EQ(only.out.find("my.snr "), std::string::npos);
  EXPECT_EQ(run("--preset accurange validate --matrix mine.csv").status, 1);
  // --require-in-band: status 3 when a row is outside; the outputs are still written.
  EXPECT_EQ(run("validate --matrix mine.csv --require-in-band --out out2 --no-plots").status, 3);
  EXPECT_TRUE(std::filesystem::exists(dir_ / "out2" / "validation.json"));
}

TEST_F(ValidateCli, BadMatricesExitOneNamingLineAndColumn) {
  struct Case {
    std::string body;  // after the header (line 1)
    std::string expected;
  };
  const std::vector<Case> cases{
      {"a,p,f,no.such.quantity,,1,1,r,,paper,held_out\n", "bad.csv:2: column 'quantity'"},
      {"a,p,f,paper.link_budget.snr,distance_m=10,1,x,r,,paper,held_out\n",
       "bad.csv:2: column 'band'"},
      {"a,p,f,paper.link_budget.snr,distance_m=10,1,1,r,,paper,maybe\n",
       "bad.csv:2: column 'role'"},
      {"a,p,f,paper.link_budget.snr,\n", "bad.csv:2: 5 fields"},
      {"a,p,f,paper.link_budget.snr,distance_m=10,1,1,r,,paper,held_out\n"
       "b,p,f,paper.link_budget.snr,colour=red,1,1,r,,paper,held_out\n",
       "bad.csv:3: column 'conditions'"},
      {"a,p,f,paper.link_budget.snr,distance_m=10,1,1,,,paper,held_out\n",
       "bad.csv:2: column 'band_reason'"},
      {"a,p,f,paper.grayvalue.std_mm,distance_m=3,1,1,r,,paper,held_out\n",
       "bad.csv:2: column 'conditions'"},
      {"a,p,f,paper.link_budget.snr,\"distance_m=10,1,1,r,,paper,held_out\n",
       "a quoted field is not closed"},
  };
  for (const auto& c : cases) {
    write("bad.csv", kHeader + c.body);
    const auto r = run("validate --matrix bad.csv --out out");
    EXPECT_EQ(r.status, 1) << c.body;
    EXPECT_NE(read("stderr.txt").find(c.expected), std::string::npos) << c.body << "\n"
                                                                      << read("stderr.txt");
    EXPECT_FALSE(std::filesystem::exists(dir_ / "out" / "validation.json")) << c.body;
  }
  write("bad.csv", "id,document,figure\n");
  EXPECT_EQ(run("validate --matrix bad.csv").status, 1);
  EXPECT_NE(read("stderr.txt").find("bad.csv:1: column 'quantity'"), std::string::npos);
  // The unknown quantity is named.
  write("bad.csv", std::string(kHeader) + "a,p,f,paper.snr,,1,1,r,,paper,held_out\n");
  EXPECT_EQ(run("validate --matrix bad.csv").status, 1);
  EXPECT_NE(read("stderr.txt").find("unknown quantity 'paper.snr'"), std::string::npos);
}

TEST_F(ValidateCli, AnExperimentThatRefusesLeavesItsRowsWithTheReasonNotAFailure) {
  // No plate echoes with a 100 V threshold: the paper's method cannot be fitted.
  const auto r =
      run("--preset paper --set discriminator.threshold_v=100 validate --only paper.fig7 --out out "
          "--no-plots");
  ASSERT_EQ(r.status, 0) << read("stderr.txt");
  const auto j = nlohmann::json::parse(read("out/validation.json"));
  for (const auto& row : j["rows"]) {
    if (!row["run"].get<bool>()) continue;
    EXPECT_TRUE(row["twin"].is_null()) << row["id"];  // not 0
    EXPECT_FALSE(row["in_band"].get<bool>()) << row["id"];
    if (row["method"] == "document")
      EXPECT_NE(row["error"].get<std::string>().find("paper method"), std::string::npos);
  }
  EXPECT_EQ(j["summary"]["in_band"].get<int>(), 0);
}

TEST_F(ValidateCli, FindsTheReferenceMatrixByItself) {
  const auto r = run("validate --only paper.fig3 --out out --no-plots");
  ASSERT_EQ(r.status, 0) << read("stderr.txt");
  EXPECT_NE(r.out.find("validation_matrix.csv"), std::string::npos);
  const auto j = nlohmann::json::parse(read("out/validation.json"));
  EXPECT_EQ(j["summary"]["rows"].get<int>(), 2);
}

}  // namespace
