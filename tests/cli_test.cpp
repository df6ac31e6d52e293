// The `tofkit` executable end to end: the link budget as JSON, configuration
// errors that stop a command before it writes anything, reproducible
// measurements whatever the thread count, and the config dump loading back.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>
#include <vector>

#include "cli_runner.hpp"
#include "tofkit/device/virtual_rangefinder.hpp"
#include "tofkit/io/raw_csv.hpp"

namespace fs = std::filesystem;

namespace {

class CliTest : public tofkit::test::CliFixture {
 protected:
  CliTest() : CliFixture("tofkit_cli_test_") {}
};

}  // namespace

// Oracles: the paper's Figure 3 (SNR = 10 near 10 m for rho = 0.1) and the
// extended-target law Pr ~ 1/R^2 (paper Eq. 6).
TEST_F(CliTest, BudgetJsonCoversTheDistancesWithAllFields) {
  const auto r = run("budget --json");
  ASSERT_EQ(r.status, 0) << r.err;
  const auto j = nlohmann::json::parse(r.out);
  EXPECT_EQ(j.at("reflectance").get<double>(), 0.1);
  const double range = j.at("range_at_snr10_m").get<double>();
  EXPECT_GT(range, 9.0);
  EXPECT_LT(range, 11.0);

  const auto& rows = j.at("rows");
  ASSERT_EQ(rows.size(), 30u);
  const double pr_r2_first = rows[0].at("received_power_w").get<double>() * 0.25;
  double previous_snr = 1e300;
  for (std::size_t i = 0; i < rows.size(); ++i) {
    const auto& row = rows[i];
    for (const char* key : {"distance_m", "received_power_w", "background_power_w",
                            "signal_current_a", "signal_shot_a", "background_shot_a", "dark_shot_a",
                            "thermal_a", "total_noise_a", "snr"}) {
      ASSERT_TRUE(row.contains(key) && row.at(key).is_number()) << key;
    }
    const double d = row.at("distance_m").get<double>();
    EXPECT_NEAR(d, 0.5 * static_cast<double>(i + 1), 1e-12);
    EXPECT_NEAR(row.at("received_power_w").get<double>() * d * d, pr_r2_first, 1e-9 * pr_r2_first);
    const double snr = row.at("snr").get<double>();
    EXPECT_LT(snr, previous_snr);
    previous_snr = snr;
    // Noise terms add in quadrature (paper Eq. 8).
    const double total = row.at("total_noise_a").get<double>();
    double sum_sq = 0;
    for (const char* key : {"signal_shot_a", "background_shot_a", "dark_shot_a", "thermal_a"}) {
      sum_sq += std::pow(row.at(key).get<double>(), 2);
    }
    EXPECT_NEAR(total, std::sqrt(sum_sq), 1e-9 * total);
    EXPECT_NEAR(snr, row.at("signal_current_a").get<double>() / total, 1e-9 * snr);
  }
  // The SNR = 10 range lies between the rows that bracket SNR = 10.
  const auto bracket = static_cast<std::size_t>(range / 0.5) - 1;
  EXPECT_GE(rows[bracket].at("snr").get<double>(), 10.0);
  EXPECT_LE(rows[bracket + 1].at("snr").get<double>(), 10.0);

  // The text form carries the same range.
  const auto text = run("budget");
  ASSERT_EQ(text.status, 0) << text.err;
  EXPECT_NE(text.out.find("SNR = 10"), std::string::npos) << text.out;
}

TEST_F(CliTest, BadConfigStopsBeforeWritingAnything) {
  struct Case {
    const char* toml;
    const char* key;
  };
  const Case cases[] = {
      {"[receiver]\nbandwith_mhz = 100\n", "receiver.bandwith_mhz"},
      {"[laser]\npeak_power_w = \"1 W\"\n", "laser.peak_power_w"},
      {"[laser]\npeak_power_w = -1.0\n", "laser.peak_power_w"},
      {"[receiver]\nbandwidth_mhz = 0\n", "receiver.bandwidth_mhz"},
  };
  for (const auto& c : cases) {
    write("bad.toml", c.toml);
    const auto r =
        run("--config bad.toml measure --distance 1,2 --reflectance 0.5 --shots 10 --out out.csv");
    EXPECT_NE(r.status, 0) << c.toml;
    EXPECT_NE(r.err.find(c.key), std::string::npos) << r.err;
    EXPECT_NE(r.err.find("bad.toml:2"), std::string::npos) << r.err;
    EXPECT_NE(r.err.find("tofkit measure: error:"), std::string::npos) << r.err;
    EXPECT_FALSE(fs::exists(dir_ / "out.csv")) << c.toml;
  }
  // The same through --set.
  const auto r =
      run("measure --set receiver.bandwidth_mhz=0 --distance 1 --reflectance 0.5 "
          "--out out.csv");
  EXPECT_NE(r.status, 0);
  EXPECT_NE(r.err.find("--set"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("receiver.bandwidth_mhz"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(dir_ / "out.csv"));
  // A bad value list too.
  const auto l = run("measure --distance 1,x --reflectance 0.5 --out out.csv");
  EXPECT_EQ(l.status, 1);
  EXPECT_NE(l.err.find("--distance"), std::string::npos) << l.err;
  EXPECT_FALSE(fs::exists(dir_ / "out.csv"));
}

TEST_F(CliTest, UsageErrorsExitWithTwo) {
  EXPECT_EQ(run("measure --distance 1 --reflectance 0.5").status, 2);  // no --out
  EXPECT_EQ(run("no-such-command").status, 2);
  // A value outside its option's set or range is bad input (1), not a usage error.
  EXPECT_EQ(run("measure --distance 1 --reflectance 0.5 --mode bogus --out x.csv").status, 1);
  EXPECT_EQ(run("measure --distance 1 --reflectance 0.5 --shots 0 --out x.csv").status, 1);
  EXPECT_EQ(run("--help").status, 0);
}

// Oracle: counter-based randomness, stream per request - the thread count
// must not change a single byte; the seed must.
TEST_F(CliTest, MeasureIsByteIdenticalAcrossThreadCounts) {
  for (const std::string mode : {"analytic", "waveform"}) {
    const std::string grid =
        "measure --distance 1:3:1 --reflectance 0.1,0.8 --shots 200 --count 2 --mode " + mode;
    ASSERT_EQ(run("--threads 1 " + grid + " --seed 7 --out t1.csv").status, 0) << mode;
    const auto r2 = run("--threads 2 " + grid + " --seed 7 --out t2.csv");
    ASSERT_EQ(r2.status, 0) << r2.err;
    EXPECT_NE(r2.err.find("12 rows"), std::string::npos) << r2.err;
    EXPECT_NE(r2.err.find("on 2 thread(s)"), std::string::npos) << r2.err;
    ASSERT_EQ(run(grid + " --threads 2 --seed 8 --out s8.csv").status, 0) << mode;
    const std::string t1 = read("t1.csv");
    EXPECT_FALSE(t1.empty());
    EXPECT_EQ(t1, read("t2.csv")) << mode;
    EXPECT_NE(t1, read("s8.csv")) << mode;

    // Cartesian product order: distance outermost, repeats innermost.
    const auto records = tofkit::io::read_raw_csv(dir_ / "t1.csv");
    ASSERT_EQ(records.size(), 12u);
    for (std::size_t i = 0; i < records.size(); ++i) {
      EXPECT_EQ(records[i].truth.distance_m, 1.0 + static_cast<double>(i / 4)) << i;
      EXPECT_EQ(records[i].truth.reflectance, (i / 2) % 2 == 0 ? 0.1 : 0.8) << i;
      EXPECT_EQ(records[i].truth.angle_deg, 0.0);
      EXPECT_TRUE(records[i].raw.has_echo()) << i;
      // Raw distance near the truth: uncorrected fixed delay (2.5 ns = 0.37 m) and walk.
      EXPECT_NEAR(records[i].raw.distance_raw_m, records[i].truth.distance_m, 1.0) << i;
    }
    // Repeats are independent draws, not copies.
    EXPECT_NE(records[0].raw.tof_ns, records[1].raw.tof_ns);
  }
}

// The self-oscillating loop has no sampled-waveform evaluation: --mode waveform
// on it is refused (exit 1, naming the option and where oscillator.enabled came
// from), not run as a copy of the analytic mode; nothing is written.
TEST_F(CliTest, WaveformModeIsRefusedForTheLoop) {
  for (const std::string& args :
       {std::string("--preset accurange measure --distance 0.5 --reflectance 0.5 --mode waveform "
                    "--out a.csv"),
        std::string("--preset paper --set oscillator.enabled=true measure --distance 0.5 "
                    "--reflectance 0.5 --mode waveform --out a.csv")}) {
    const auto r = run(args);
    EXPECT_EQ(r.status, 1) << args;
    EXPECT_NE(r.err.find("--mode waveform"), std::string::npos) << r.err;
    EXPECT_NE(r.err.find("oscillator.enabled"), std::string::npos) << r.err;
    EXPECT_FALSE(std::filesystem::exists(dir_ / "a.csv")) << args;
  }
  EXPECT_NE(run("--preset accurange measure --distance 0.5 --reflectance 0.5 --mode waveform "
                "--out a.csv")
                .err.find("preset 'accurange'"),
            std::string::npos);
  EXPECT_NE(run("--preset paper --set oscillator.enabled=true measure --distance 0.5 "
                "--reflectance 0.5 --mode waveform --out a.csv")
                .err.find("--set oscillator.enabled=true"),
            std::string::npos);
  // The analytic mode runs on the loop, and waveform on the pulsed paper device.
  EXPECT_EQ(run("--preset accurange measure --distance 0.5 --reflectance 0.5 --out a.csv").status,
            0);
  EXPECT_EQ(run("--preset paper measure --distance 1 --reflectance 0.5 --mode waveform --count 2 "
                "--out b.csv")
                .status,
            0);
}

TEST_F(CliTest, ConfigDumpLoadsBackToTheSameDump) {
  const auto first = run("--preset accurange --set measurement.shots=77 config --dump");
  ASSERT_EQ(first.status, 0) << first.err;
  EXPECT_NE(first.out.find("shots = 77"), std::string::npos);
  write("dump.toml", first.out);
  const auto second = run("--config dump.toml config --dump");
  ASSERT_EQ(second.status, 0) << second.err;
  EXPECT_EQ(first.out, second.out);

  const auto summary = run("--config dump.toml --set tdc.lsb_ps=30 config");
  ASSERT_EQ(summary.status, 0) << summary.err;
  EXPECT_NE(summary.out.find("accurange"), std::string::npos) << summary.out;
  EXPECT_NE(summary.out.find("tdc.lsb_ps = 30"), std::string::npos) << summary.out;
  EXPECT_NE(summary.out.find("--set"), std::string::npos) << summary.out;
}

// `plan --single-distance`: every plate line stands at one distance, the one
// that centres the plates' log-power span (reflectance 0.02-0.95) on the
// field's. Oracle (paper Eq. 6 at normal incidence, Pr ~ rho / R^2, the
// receiver's field covering the footprint): d^4 = rho_p,min rho_p,max R_min^2
// R_max^2 / (rho_min rho_max).
// --single-distance centres the plates' log-power span (reflectance
// 0.02-0.95) on the field's (paper Eq. 6: Pr ~ rho / R^2, a closed form for the
// distance) when the field's echoes do not clip, as with the APD gain 20 x
// lower. With the paper's device the field's strongest echo (0.7 m, rho 0.85)
// overdrives the amplifier, so the plates move nearer until the brightest
// (0.95) is overdriven by one neper: its noise-free linear peak at the planned
// distance, asked of the device, is e x receiver.saturation_v.
TEST_F(CliTest, PlanSingleDistanceCentresThePlatesPowerSpanOnTheField) {
  const std::string field =
      "plan --range-min 0.7 --range-max 7.4 --reflectance-min 0.06 --reflectance-max 0.85 "
      "--single-distance";
  const auto distances_of = [](const std::string& out) {
    std::vector<double> distances;
    std::size_t pos = 0;
    while ((pos = out.find("--distance ", pos)) != std::string::npos) {
      pos += 11;
      // The plates' lines (--count); the closing test line spans the field.
      const std::size_t end = out.find('\n', pos);
      if (out.substr(pos, end - pos).find("--count") == std::string::npos) continue;
      distances.push_back(std::stod(out.substr(pos, out.find(' ', pos) - pos)));
    }
    return distances;
  };
  const auto low_gain = run("--set receiver.apd_gain=5 " + field);
  ASSERT_EQ(low_gain.status, 0) << low_gain.err;
  const std::vector<double> centred = distances_of(low_gain.out);
  ASSERT_GE(centred.size(), 2u) << low_gain.out;  // the plates and the temperature run
  for (double d : centred) EXPECT_EQ(d, centred.front()) << low_gain.out;
  const double expected = std::pow(0.02 * 0.95 * 0.7 * 0.7 * 7.4 * 7.4 / (0.06 * 0.85), 0.25);
  EXPECT_NEAR(centred.front(), expected, 0.01 * expected) << low_gain.out;

  const auto r = run(field);
  ASSERT_EQ(r.status, 0) << r.err;
  const std::vector<double> distances = distances_of(r.out);
  ASSERT_GE(distances.size(), 2u) << r.out;
  for (double d : distances) EXPECT_EQ(d, distances.front()) << r.out;
  const tofkit::device::DeviceConfig config = tofkit::device::preset("paper");
  const tofkit::device::VirtualRangefinder paper(config);
  const double saturation_v = config.link.receiver.saturation_v;
  EXPECT_GT(paper.echo(tofkit::device::Target::plate(0.7, 0.85), {}).peak_v,
            std::exp(1.0) * saturation_v);
  EXPECT_LT(distances.front(), expected);
  EXPECT_NEAR(
      paper.echo(tofkit::device::Target::plate(distances.front(), 0.95), {}).peak_v / saturation_v,
      std::exp(1.0), 0.01 * std::exp(1.0))
      << r.out;
  // An empty field (range_min > range_max) is refused, naming the range.
  const auto bad = run("plan --range-min 5 --range-max 2 --reflectance-min 0.06 --single-distance");
  EXPECT_EQ(bad.status, 1);
  EXPECT_NE(read("stderr.txt").find("range_max_m (--range-max) must be > range_min_m"),
            std::string::npos)
      << read("stderr.txt");
  // A calibration distance beyond the plan's reach (1 mm .. 10 km) is refused
  // naming --at: 1 nm had been printed as "calibration distance 1e-09 m".
  for (const char* at : {"1e-9", "2e4"}) {
    EXPECT_EQ(run(std::string("plan --range-max 8 --reflectance-min 0.05 --at ") + at).status, 1);
    EXPECT_NE(read("stderr.txt").find("calibration_distance_m (--at) must be in [0.001, 10000] m"),
              std::string::npos)
        << read("stderr.txt");
  }
}

// The bench table marks the plates whose echo overdrives the amplifier
// (clip_Np: ln of the plate's power over the clip power): the device's own
// noise-free echo of each plate agrees (saturated exactly where marked), and
// with the field clipping the brightest plate is overdriven by one neper.
TEST_F(CliTest, PlanBenchTableMarksThePlatesThatClip) {
  const auto r =
      run("plan --range-min 0.7 --range-max 7.4 --reflectance-min 0.06 --reflectance-max 0.85 "
          "--single-distance --bench");
  ASSERT_EQ(r.status, 0) << r.err;
  const tofkit::device::VirtualRangefinder paper(tofkit::device::preset("paper"));
  std::istringstream lines(r.out);
  std::string line;
  int plates = 0, clipped = 0;
  std::string last_clip;
  while (std::getline(lines, line)) {
    if (line.empty() || line[0] == '#' || line.find("distance_m") != std::string::npos) continue;
    std::istringstream row(line);
    int k = 0;
    double distance = 0, reflectance = 0, power = 0, snr = 0;
    std::string clip;
    ASSERT_TRUE(row >> k >> distance >> reflectance >> power >> snr >> clip) << line;
    ++plates;
    const bool saturated =
        paper.echo(tofkit::device::Target::plate(distance, reflectance), {}).saturated;
    EXPECT_EQ(saturated, clip != "-") << line;
    clipped += clip != "-";
    last_clip = clip;
  }
  EXPECT_EQ(plates, 10);
  EXPECT_EQ(clipped, 3);
  EXPECT_EQ(last_clip, "1.00");
}

// The plan's powers are optical; whether a plate's echo crosses the
// comparator is the device's. The paper's device misses the field's weakest
// target (8 m, rho 0.05: 0 of 1000 shots echo) and nearly misses the faintest
// plate (0.02 at 5.06 m: 1 of 1000), and the plan says so; with the APD gain
// 20 x lower, the four faintest plates (about 20 x the power of the first).
// A field it sees whole gets no such lines.
TEST_F(CliTest, PlanNamesThePlatesBelowTheThreshold) {
  const auto paper = run("plan --range-max 8 --reflectance-min 0.05");
  ASSERT_EQ(paper.status, 0) << paper.err;
  EXPECT_NE(paper.out.find("the field's weakest target (8 m, reflectance 0.05) stays below"),
            std::string::npos)
      << paper.out;
  EXPECT_NE(paper.out.find("only noise crossings): 0.0200 at 5.0596 m\n"), std::string::npos)
      << paper.out;
  const auto low_gain = run("--set receiver.apd_gain=5 plan --range-max 8 --reflectance-min 0.05");
  ASSERT_EQ(low_gain.status, 0) << low_gain.err;
  const auto line = low_gain.out.substr(low_gain.out.find("# plates below the threshold"));
  std::size_t plates = 0;
  for (std::size_t at = line.find(" m"); at < line.find('\n'); at = line.find(" m", at + 1))
    ++plates;
  EXPECT_EQ(plates, 4u) << line;
  const auto near = run("plan --range-min 0.5 --range-max 3 --reflectance-min 0.3");
  ASSERT_EQ(near.status, 0) << near.err;
  EXPECT_EQ(near.out.find("below the threshold"), std::string::npos) << near.out;
}
