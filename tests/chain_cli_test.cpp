// Round trip through the `tofkit` binary: fit -> correct -> evaluate on a
// synthetic calibration CSV generated here from a known hinge chain + noise.

#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <map>
#include <nlohmann/json.hpp>
#include <random>
#include <string>
#include <utility>
#include <vector>

#include "cli_runner.hpp"
#include "tofkit/calib/statistics.hpp"
#include "tofkit/io/firmware_export.hpp"
#include "tofkit/io/model_json.hpp"
#include "tofkit/io/raw_csv.hpp"
#include "tofkit/ranging/time_to_distance.hpp"

namespace tofkit {
namespace {

namespace fs = std::filesystem;

constexpr double kNoise_m = 0.001;

/// Known chain: e = true - c_air tof / 2 = -120 mm + g(pulse width) + h(temperature),
/// g: -36 mm/ns below the 6.5 ns inflection, +70 mm/ns above (paper Section 5.1);
/// h: 0 below 16 C, -3.8 mm/C above (Section 5.2).
double true_error_m(double pulse_width_ns, double temperature_c) {
  const double g = -0.036 * (pulse_width_ns - 6.5) + 0.106 * std::max(0.0, pulse_width_ns - 6.5);
  const double h = -0.0038 * std::max(0.0, temperature_c - 16.0);
  return -0.120 + g + h;
}

/// Plates of 10 reflectances (pulse width rises with reflectance) at 4 distances
/// and 9 temperatures, `count` measurements each.
std::vector<ranging::Record> synthetic_records(int count, unsigned seed) {
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> noise(0.0, kNoise_m), pw_noise(0.0, 0.02);
  const double k = ranging::metres_per_ns(ranging::TimeToDistance{});
  std::vector<ranging::Record> out;
  for (double d : {1.0, 2.0, 3.0, 4.0}) {
    for (int p = 0; p < 10; ++p) {
      const double rho = 0.02 + 0.1 * p;
      for (double t = 0; t <= 40; t += 5) {
        for (int i = 0; i < count; ++i) {
          ranging::Record r;
          r.truth = {d, rho, 0.0, t};
          r.raw.pulse_width_ns = 3.0 + 9.0 * std::sqrt(rho) + pw_noise(rng);
          r.raw.temperature_c = t + 2.0;  // sensor reads a little above ambient
          r.raw.amplitude = 0.05 + rho / (d * d);
          const double measured =
              d - true_error_m(r.raw.pulse_width_ns, r.raw.temperature_c) + noise(rng);
          r.raw.tof_ns = measured / k;
          r.raw.distance_raw_m = measured;
          r.raw.shots_valid = 100;
          out.push_back(r);
        }
      }
    }
  }
  return out;
}

class ChainCli : public test::CliFixture {
 protected:
  ChainCli() : CliFixture("tofkit_chain_cli_") {}
};

TEST_F(ChainCli, FitCorrectEvaluateRoundTrip) {
  io::write_raw_csv(path("calib.csv"), synthetic_records(3, 1));
  io::write_raw_csv(path("test.csv"), synthetic_records(1, 2));

  const test::CliResult fit = run("fit --in " + path("calib.csv") + " --out " + path("model.json") +
                                  " --chain offset,grayvalue,temperature");
  ASSERT_EQ(fit.status, 0) << fit.err;
  const ranging::Pipeline model = io::load_pipeline(path("model.json"));
  ASSERT_EQ(model.steps().size(), 3u);
  const auto& g = model.steps()[1].function;
  const auto& h = model.steps()[2].function;
  ASSERT_EQ(g.knots.size(), 1u) << model.summary();
  ASSERT_EQ(h.knots.size(), 1u) << model.summary();
  EXPECT_NEAR(g.knots[0], 6.5, 0.15);
  EXPECT_NEAR(h.knots[0], 16.0, 1.0);
  EXPECT_NEAR(g.segment_slopes()[0], -0.036, 1e-3);
  EXPECT_NEAR(g.segment_slopes()[1], 0.070, 1e-3);
  EXPECT_NEAR(h.segment_slopes()[1], -0.0038, 1e-4);

  const test::CliResult correct = run("correct --model " + path("model.json") + " --in " +
                                      path("test.csv") + " --out " + path("corrected.csv"));
  ASSERT_EQ(correct.status, 0) << correct.err;
  const auto rows = io::read_corrected_csv(path("corrected.csv"));
  ASSERT_EQ(rows.size(), 360u);
  double sum2 = 0;
  for (const auto& r : rows) {
    const double e = r.record.truth.distance_m - r.range.distance_m;
    sum2 += e * e;
  }
  const double rms = std::sqrt(sum2 / static_cast<double>(rows.size()));
  EXPECT_LT(rms, 1.3 * kNoise_m);  // corrected errors at the noise level
  EXPECT_GT(rms, 0.7 * kNoise_m);

  const test::CliResult eval =
      run("evaluate --in " + path("corrected.csv") + " --by reflectance --json");
  ASSERT_EQ(eval.status, 0) << eval.err;
  const nlohmann::json j = nlohmann::json::parse(eval.out);
  // Independent computation per reflectance: bias and RMS of true - distance_m.
  std::map<double, std::vector<double>> by_reflectance, raw_by_reflectance;
  for (const auto& r : rows) {
    by_reflectance[r.record.truth.reflectance].push_back(r.record.truth.distance_m -
                                                         r.range.distance_m);
    raw_by_reflectance[r.record.truth.reflectance].push_back(r.record.truth.distance_m -
                                                             r.record.raw.distance_raw_m);
  }
  ASSERT_EQ(j["groups"].size(), by_reflectance.size());
  std::size_t gi = 0;
  for (const auto& [rho, errors] : by_reflectance) {
    const auto& group = j["groups"][gi++];
    EXPECT_DOUBLE_EQ(group["key"].get<double>(), rho);
    double sum = 0, squares = 0;
    for (double e : errors) {
      sum += e;
      squares += e * e;
    }
    const double n = static_cast<double>(errors.size());
    EXPECT_EQ(group["rows"].get<std::size_t>(), errors.size());
    EXPECT_NEAR(group["corrected"]["bias_m"].get<double>(), sum / n, 1e-12);
    EXPECT_NEAR(group["corrected"]["rms_m"].get<double>(), std::sqrt(squares / n), 1e-12);
    double raw_squares = 0;
    for (double e : raw_by_reflectance[rho]) raw_squares += e * e;
    const double raw_rms = std::sqrt(raw_squares / n);
    EXPECT_NEAR(group["raw"]["rms_m"].get<double>(), raw_rms, 1e-12);
    EXPECT_NEAR(group["rms_improvement_pct"].get<double>(),
                100 * (raw_rms - std::sqrt(squares / n)) / raw_rms, 1e-9);
  }
  // Overall coverage: sigma is the fit's residual RMS, so about 68 % / 95 % of
  // Gaussian errors fall within 1 / 2 sigma.
  EXPECT_EQ(j["overall"]["rows"].get<std::size_t>(), rows.size());
  EXPECT_NEAR(j["overall"]["within_1_sigma"]["share"].get<double>(), 0.68, 0.08);
  EXPECT_NEAR(j["overall"]["within_2_sigma"]["share"].get<double>(), 0.95, 0.04);
  EXPECT_EQ(j["overall"]["within_2_sigma"]["amplitude_terciles"].size(), 3u);

  const test::CliResult text = run("evaluate --in " + path("corrected.csv"));
  ASSERT_EQ(text.status, 0) << text.err;
  EXPECT_NE(text.out.find("all"), std::string::npos);
}

TEST_F(ChainCli, ConfidenceAndFirmwareOutputs) {
  io::write_raw_csv(path("calib.csv"), synthetic_records(2, 3));
  const test::CliResult fit =
      run("fit --in " + path("calib.csv") + " --out " + path("model.json") +
          " --chain offset,grayvalue,temperature --confidence thesis --confidence-fraction 0.25"
          " --firmware " +
          path("fw"));
  ASSERT_EQ(fit.status, 0) << fit.err;
  const ranging::Pipeline model = io::load_pipeline(path("model.json"));
  ASSERT_TRUE(model.confidence());
  EXPECT_EQ(model.confidence()->kind(), "thesis");
  std::ifstream model_file(path("model.json"));
  const nlohmann::json j = nlohmann::json::parse(model_file);
  // Every 4th of the 360 truth groups is held out: 90 groups of 2 rows.
  EXPECT_EQ(j["fit"]["confidence"]["rows"].get<std::size_t>(), 180u);
  EXPECT_EQ(j["fit"]["rows_fit"].get<std::size_t>(), 540u);
  // The fixed-point export reproduces the float chain.
  const ranging::FixedPointChain fixed = io::load_fixed_point_json(path("fw.json"));
  EXPECT_TRUE(fs::exists(path("fw.h")));
  for (const auto& r : synthetic_records(1, 4)) {
    const auto out = fixed.apply(fixed.to_codes(r.raw));
    const auto codes_raw = fixed.to_raw(fixed.to_codes(r.raw));
    EXPECT_NEAR(out.distance_um * 1e-6, model.apply(codes_raw).distance_m, 0.5e-3);
  }
}

TEST_F(ChainCli, SmallCalibrationFitsWithResidualSigmaUnlessConfidenceIsAsked) {
  // A small calibration of another device in Table 1 sunlight: 4 distances x
  // 3 plates x 2 repeats, too few out-of-fold rows to calibrate a confidence.
  const std::string device =
      "--set receiver.bandwidth_mhz=80 --set laser.pulse_width_ns=2.5 "
      "--set environment.solar_irradiance_w_per_m2_um=748.5 ";
  ASSERT_EQ(run(device +
                "measure --distance 1,2,3,4 --reflectance 0.1,0.4,0.9 --count 2 "
                "--seed 3 --out " +
                path("cal.csv"))
                .status,
            0);
  for (const std::string spec : {"--chain offset,grayvalue", "--surface bspline"}) {
    const test::CliResult fit =
        run("fit --in " + path("cal.csv") + " --out " + path("model.json") + " " + spec);
    ASSERT_EQ(fit.status, 0) << spec << "\n" << fit.err;
    const ranging::Pipeline model = io::load_pipeline(path("model.json"));
    EXPECT_FALSE(model.confidence()) << spec;  // sigma: the residual RMS
    EXPECT_GT(model.residual_rms_m(), 0.0) << spec;
    EXPECT_NE((fit.out + fit.err).find("confidence: none"), std::string::npos) << fit.out;
    // Sigma is the error on held-out targets, not the (smaller) in-sample residual.
    EXPECT_NE((fit.out + fit.err).find("sigma = RMS of the"), std::string::npos) << fit.out;
  }
  // Asked for explicitly, a confidence that cannot be calibrated is an error.
  fs::remove(path("model.json"));
  const test::CliResult asked = run("fit --in " + path("cal.csv") + " --out " + path("model.json") +
                                    " --surface bspline --confidence calibrated");
  EXPECT_EQ(asked.status, 1);
  EXPECT_NE(asked.err.find("cal.csv"), std::string::npos) << asked.err;
  EXPECT_FALSE(fs::exists(path("model.json")));
  // Two plates: the correction fits, but each fold's refit sees one plate.
  // The message says so, instead of claiming the data have one target.
  ASSERT_EQ(
      run(device + "measure --distance 2 --reflectance 0.1,0.8 --count 12 --out " + path("two.csv"))
          .status,
      0);
  const test::CliResult two = run("fit --in " + path("two.csv") + " --out " + path("model.json") +
                                  " --chain offset,grayvalue --confidence calibrated");
  EXPECT_EQ(two.status, 1);
  EXPECT_NE(two.err.find("cross-fitting refits the correction without each of 2 folds of the 2 "
                         "truth groups, and a refit failed"),
            std::string::npos)
      << two.err;
  EXPECT_FALSE(fs::exists(path("model.json")));
}

TEST_F(ChainCli, DegenerateInputFailsWithoutWritingAModel) {
  const auto expect_failure = [&](const std::vector<ranging::Record>& records,
                                  const std::string& chain, const std::string& message) {
    io::write_raw_csv(path("bad.csv"), records);
    const test::CliResult r =
        run("fit --in " + path("bad.csv") + " --out " + path("model.json") + " --chain " + chain);
    EXPECT_NE(r.status, 0);
    EXPECT_NE(r.err.find(message), std::string::npos) << r.err;
    if (message.find("--chain") == std::string::npos) {
      EXPECT_NE(r.err.find("bad.csv: "), std::string::npos) << r.err;
    }
    EXPECT_FALSE(fs::exists(path("model.json")));
  };
  auto records = synthetic_records(1, 5);
  expect_failure({records.begin(), records.begin() + 7}, "offset", "too few rows: 7 usable");
  auto flat_pw = records;
  for (auto& r : flat_pw) r.raw.pulse_width_ns = 5.2;
  expect_failure(flat_pw, "offset,grayvalue,temperature",
                 "no spread in pulse_width_ns (all 5.20 ns): the grayvalue step needs plates of "
                 "different reflectance");
  auto flat_t = records;
  for (auto& r : flat_t) r.raw.temperature_c = 21.0;
  expect_failure(flat_t, "offset,grayvalue,temperature",
                 "no spread in temperature_c (all 21.00 C)");
  expect_failure(records, "offset,tilt", "--chain offset,tilt: unknown chain step \"tilt\"");
  expect_failure(records, "offset,grayvalue,walk",
                 "--chain offset,grayvalue,walk: chain steps grayvalue and walk both");

  // A model that cannot be read is named, and nothing is written.
  std::ofstream(path("broken.json")) << "{\"kind\": \"tofkit.pipeline\", \"version\": 1}";
  io::write_raw_csv(path("raw.csv"), records);
  const test::CliResult c = run("correct --model " + path("broken.json") + " --in " +
                                path("raw.csv") + " --out " + path("corrected.csv"));
  EXPECT_NE(c.status, 0);
  EXPECT_NE(c.err.find("broken.json: missing field 'time_to_distance'"), std::string::npos)
      << c.err;
  EXPECT_FALSE(fs::exists(path("corrected.csv")));
  const test::CliResult e = run("evaluate --in " + path("raw.csv") + " --by colour");
  EXPECT_NE(e.status, 0);
  EXPECT_NE(e.err.find("--by colour: no such column"), std::string::npos) << e.err;
}

// Bad-input check: 12 repeats of one plate (one distance, reflectance and
// ambient) on the virtual device. Their pulse widths (5.86-5.88 ns) and
// temperature readings (25.94-26.06 C) spread by noise only; fitted, they gave
// a walk at its pulse-sigma bound and a 1 mm/C temperature hinge. Each step
// that models such a column is refused, naming it, and nothing is written;
// plates of three reflectances at that one distance, and a temperature run of
// one plate at that distance, still fit.
TEST_F(ChainCli, OneTargetIsRefusedButOneDistanceCalibrationsFit) {
  const auto measure = [&](const std::string& grid, const std::string& file) {
    ASSERT_EQ(run("measure " + grid + " --shots 200 --out " + path(file)).status, 0) << grid;
  };
  const auto fit = [&](const std::string& file, const std::string& chain) {
    fs::remove(path("model.json"));
    return run("fit --in " + path(file) + " --out " + path("model.json") + " --chain " + chain);
  };
  measure("--distance 2 --reflectance 0.3 --temperature 20 --count 12", "one.csv");
  for (const auto& [chain, why] : std::vector<std::pair<std::string, std::string>>{
           {"offset,walk",
            "no spread in pulse_width_ns between targets (every usable row is one target, "
            "distance_true_m 2 m, reflectance 0.3, angle_deg 0 deg: "},
           {"offset,grayvalue", "no spread in pulse_width_ns between targets"},
           {"offset,temperature",
            "no spread in temperature_c between conditions (every usable row is at one "
            "ambient_c, 20 C: "}}) {
    const test::CliResult r = fit("one.csv", chain);
    EXPECT_EQ(r.status, 1) << chain << "\n" << r.out;
    EXPECT_NE(r.err.find("one.csv: " + why), std::string::npos) << chain << "\n" << r.err;
    EXPECT_NE(r.err.find(" is noise): the "), std::string::npos) << r.err;
    EXPECT_FALSE(fs::exists(path("model.json"))) << chain;
  }

  measure("--distance 2 --reflectance 0.05,0.2,0.9 --temperature 20 --count 4", "plates.csv");
  for (const std::string chain : {"offset,walk", "offset,grayvalue"}) {
    const test::CliResult r = fit("plates.csv", chain);
    ASSERT_EQ(r.status, 0) << chain << "\n" << r.err;
    const ranging::Pipeline model = io::load_pipeline(path("model.json"));
    ASSERT_EQ(model.steps().size(), 2u) << chain;
    EXPECT_EQ(model.steps()[1].kind,
              chain == "offset,walk" ? ranging::StepKind::kWalk : ranging::StepKind::kGrayvalue);
  }
  // The plates share one ambient: a temperature step on them is refused.
  EXPECT_EQ(fit("plates.csv", "offset,walk,temperature").status, 1);

  measure("--distance 2 --reflectance 0.3 --temperature 0,10,20,30,40 --count 3", "run.csv");
  const test::CliResult r = fit("run.csv", "offset,temperature");
  ASSERT_EQ(r.status, 0) << r.err;
  const ranging::Pipeline model = io::load_pipeline(path("model.json"));
  ASSERT_EQ(model.steps().size(), 2u);
  EXPECT_EQ(model.steps()[1].kind, ranging::StepKind::kTemperature);
}

// A walk curve that bends everywhere (a sine in pulse width): the hinge's
// three knots leave millimetres; --refine-walk (nodes and smoothing by grouped
// cross-validation) comes down to the noise on other rows, and says so in the
// model file. Without a grayvalue step the flag is refused, writing nothing.
TEST_F(ChainCli, RefineWalkFollowsACurvedWalk) {
  const double k = ranging::metres_per_ns(ranging::TimeToDistance{});
  const auto curved = [&](std::vector<ranging::Record> records) {
    for (auto& r : records) {
      const double pw = r.raw.pulse_width_ns, t = r.raw.temperature_c;
      const double curved_error =
          -0.120 + 0.010 * std::sin(2.5 * pw) + (true_error_m(pw, t) - true_error_m(pw, 0.0));
      const double delta = true_error_m(pw, t) - curved_error;  // measured = d - error + noise
      r.raw.distance_raw_m += delta;
      r.raw.tof_ns += delta / k;
    }
    return records;
  };
  io::write_raw_csv(path("calib.csv"), curved(synthetic_records(3, 11)));
  io::write_raw_csv(path("test.csv"), curved(synthetic_records(1, 12)));
  const auto test_rms = [&](const std::string& extra) {
    const test::CliResult fit =
        run("fit --confidence none --in " + path("calib.csv") + " --out " + path("model.json") +
            " --chain offset,grayvalue,temperature" + extra);
    EXPECT_EQ(fit.status, 0) << fit.err;
    const ranging::Pipeline model = io::load_pipeline(path("model.json"));
    double sum2 = 0;
    std::size_t n = 0;
    for (const auto& r : io::read_raw_csv(path("test.csv"))) {
      const double e = r.truth.distance_m - model.apply(r.raw).distance_m;
      if (!std::isfinite(e)) continue;
      sum2 += e * e;
      ++n;
    }
    return std::sqrt(sum2 / double(n));
  };
  const double hinge = test_rms("");
  const double refined = test_rms(" --refine-walk");
  std::ifstream in(path("model.json"));
  const auto j = nlohmann::json::parse(in);
  EXPECT_GT(j["fit"]["walk_refinement"]["nodes"].get<int>(), 0) << j["fit"].dump();
  EXPECT_GT(hinge, 2.0 * kNoise_m) << hinge;
  EXPECT_LT(refined, 1.3 * kNoise_m) << refined << " (hinge " << hinge << ")";
  std::printf("hinge %.3f mm, refined %.3f mm\n", hinge * 1e3, refined * 1e3);

  fs::remove(path("model.json"));
  const test::CliResult bad = run("fit --in " + path("calib.csv") + " --out " + path("model.json") +
                                  " --chain offset,temperature --refine-walk");
  EXPECT_NE(bad.status, 0);
  EXPECT_NE(bad.err.find("--refine-walk refines the chain's grayvalue step"), std::string::npos)
      << bad.err;
  EXPECT_FALSE(fs::exists(path("model.json")));
}

// A B-spline model file states its knots; `fit` reports them with the
// smoothing and the cross-validated RMS. Malformed knots in a model file are
// refused by `correct` with exit 1, a message naming the file and the key,
// and no output file.
TEST_F(ChainCli, BSplineKnotsAreReportedAndMalformedKnotsRefused) {
  io::write_raw_csv(path("calib.csv"), synthetic_records(2, 21));
  io::write_raw_csv(path("test.csv"), synthetic_records(1, 22));
  const test::CliResult fit = run("fit --confidence none --in " + path("calib.csv") + " --out " +
                                  path("model.json") + " --surface bspline");
  ASSERT_EQ(fit.status, 0) << fit.err;
  const std::string said = fit.out + fit.err;
  for (const char* needle : {"knots range ", "smoothing ", "cross-validated RMS "}) {
    EXPECT_NE(said.find(needle), std::string::npos) << needle << "\n" << said;
  }
  const nlohmann::json good = nlohmann::json::parse(test::read_file(path("model.json")));
  EXPECT_EQ(good["fit"]["surface"]["knots"].size(), 2u) << good["fit"].dump();
  std::size_t step = 0;
  while (step < good["steps"].size() && good["steps"][step]["kind"] != "surface") ++step;
  ASSERT_LT(step, good["steps"].size()) << good.dump();
  const std::string where = "steps[" + std::to_string(step) + "].surface.axes.";
  ASSERT_GE(good["steps"][step]["surface"]["axes"]["amplitude"]["knots"].size(), 3u);

  const auto expect_refused = [&](const nlohmann::json& model, const std::string& needle) {
    std::ofstream(path("bad.json")) << model.dump(2);
    fs::remove(path("corrected.csv"));
    const test::CliResult c = run("correct --model " + path("bad.json") + " --in " +
                                  path("test.csv") + " --out " + path("corrected.csv"));
    EXPECT_EQ(c.status, 1) << c.err;
    EXPECT_NE(c.err.find("bad.json"), std::string::npos) << c.err;
    EXPECT_NE(c.err.find(needle), std::string::npos) << needle << "\n" << c.err;
    EXPECT_FALSE(fs::exists(path("corrected.csv")));
  };
  nlohmann::json j = good;
  auto* knots = &j["steps"][step]["surface"]["axes"]["amplitude"]["knots"];
  (*knots)[2] = (*knots)[1];
  expect_refused(j, where + "amplitude.knots[2]: must be above knots[1]");
  j = good;
  knots = &j["steps"][step]["surface"]["axes"]["range_m"]["knots"];
  (*knots)[1] = nullptr;
  expect_refused(j, where + "range_m.knots[1]: expected a number");
  j = good;
  j["steps"][step]["surface"]["axes"]["range_m"]["knots"] = {1.0};
  expect_refused(j, where + "range_m.knots: has 1 breakpoints");
  j = good;
  knots = &j["steps"][step]["surface"]["axes"]["amplitude"]["knots"];
  knots->push_back(knots->back().get<double>() + 1.0);
  j["steps"][step]["surface"]["axes"]["amplitude"].erase("intervals");
  j["steps"][step]["surface"]["axes"]["amplitude"].erase("hi");
  expect_refused(j, "surface.shape[1]: must be the axis's knot intervals + 3");
  // A B-spline (any knots) has no fixed-point form: the firmware export refuses
  // it before writing anything.
  const test::CliResult firmware =
      run("fit --confidence none --in " + path("calib.csv") + " --out " + path("fw_model.json") +
          " --surface bspline --firmware " + path("fw"));
  EXPECT_EQ(firmware.status, 1);
  EXPECT_NE(firmware.err.find("--firmware exports the chain only"), std::string::npos)
      << firmware.err;
  EXPECT_FALSE(fs::exists(path("fw_model.json")));
  EXPECT_FALSE(fs::exists(path("fw.json")));
  // The good file corrects.
  const test::CliResult ok = run("correct --model " + path("model.json") + " --in " +
                                 path("test.csv") + " --out " + path("corrected.csv"));
  EXPECT_EQ(ok.status, 0) << ok.err;
}

}  // namespace
}  // namespace tofkit
