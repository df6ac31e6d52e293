// The `tofkit` CLI attacked with bad inputs (issue 7's reproducers): every
// case must exit with status 1, print a message naming the file, line, key or
// option at fault, and leave its working directory exactly as it was (no
// file created, changed or left behind, temporaries included).
#include <gtest/gtest.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <csignal>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <map>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "cli_runner.hpp"

namespace fs = std::filesystem;

namespace {

class Robustness : public tofkit::test::RefusalFixture {
 protected:
  Robustness() : RefusalFixture("tofkit_robustness_") {}

  // plate.toml: one 1 x 1 m plate 2 m ahead.
  void write_plate_scene() const {
    write("plate.toml",
          "[[surface]]\nkind = \"plane\"\ncenter_m = [2, 0, 0]\nnormal = [-1, 0, 0]\n"
          "size_m = [1, 1]\nreflectance = 0.5\n");
  }

  // A small calibration table and a model fitted on it.
  void make_calibration() const {
    ASSERT_EQ(run("measure --distance 1:8:1 --reflectance 0.1,0.5,0.9 --temperature 10,25,40 "
                  "--out cal.csv")
                  .status,
              0);
    ASSERT_EQ(run("fit --in cal.csv --chain offset --out model.json").status, 0);
  }

  // `source` (cal.csv) with one cell replaced (row 1-based after the header, column by index).
  void write_with_cell(const std::string& name, std::size_t row, std::size_t column,
                       const std::string& value, const std::string& source = "cal.csv") const {
    std::ifstream in(dir_ / source);
    std::ostringstream out;
    std::string line;
    for (std::size_t i = 0; std::getline(in, line); ++i) {
      if (i == row) {
        std::vector<std::string> cells;
        std::stringstream s(line);
        for (std::string c; std::getline(s, c, ',');) cells.push_back(c);
        cells[column] = value;
        line.clear();
        for (std::size_t k = 0; k < cells.size(); ++k) line += (k ? "," : "") + cells[k];
      }
      out << line << "\n";
    }
    write(name, out.str());
  }
};

// Item 1: an overflowing squared error must not crash the hinge fit.
TEST_F(Robustness, HugeCellsInAChainFitAreAnErrorNotACrash) {
  make_calibration();
  write_with_cell("huge_truth.csv", 3, 0, "1e155");
  write_with_cell("huge_tof.csv", 3, 4, "1e155");
  for (const char* chain : {"offset,grayvalue", "offset,temperature"}) {
    for (const char* file : {"huge_truth.csv", "huge_tof.csv"}) {
      const auto before = snapshot();
      const tofkit::test::CliResult r =
          run(std::string("fit --in ") + file + " --chain " + chain + " --out out.json");
      EXPECT_EQ(r.status, 1) << file << " " << chain << "\n" << r.err;
      EXPECT_EQ(snapshot(), before);
    }
  }
}

// The same for the columns a surface or a confidence model reads: a corrupt
// amplitude, pulse width or truth is refused naming the column and data row,
// not taken into a fit (a 1e300 amplitude stretched the log-amplitude axis of
// a confidence model to 690 nepers and the fit exited 0). Columns a model
// does not read are not judged: a grayvalue chain without a confidence fits.
TEST_F(Robustness, HugeCellsInASurfaceOrConfidenceFitAreNamed) {
  make_calibration();
  // Columns: distance_true_m 0, pulse_width_ns 6, amplitude 7.
  write_with_cell("huge_truth.csv", 5, 0, "1e300");
  write_with_cell("huge_width.csv", 5, 6, "1e300");
  write_with_cell("huge_amplitude.csv", 5, 7, "1e300");
  for (const char* model : {"--surface bspline", "--surface poly:2"}) {
    for (const auto& [file, needle] :
         {std::pair{"huge_truth.csv", "distance_true_m = 1e+300 in data row 5"},
          std::pair{"huge_amplitude.csv", "amplitude = 1e+300 in data row 5"}}) {
      expect_refused(std::string("fit --in ") + file + " " + model + " --out out.json",
                     {file, needle, "is too large"});
    }
  }
  expect_refused("fit --in huge_width.csv --surface bspline --out out.json",
                 {"pulse_width_ns = 1e+300 in data row 5"});
  expect_refused("fit --in huge_amplitude.csv --chain offset,grayvalue --out out.json",
                 {"amplitude = 1e+300 in data row 5"});
  EXPECT_EQ(run("fit --in huge_amplitude.csv --chain offset,grayvalue --confidence none --out "
                "out.json")
                .status,
            0);
  // The noise-systematic confidence reads the correction's axis: pulse width
  // behind a grayvalue step (the amplitude is not judged), amplitude without one.
  ASSERT_EQ(run("measure --distance 1:8:1 --reflectance 0.1,0.5,0.9 --temperature 10,25,40 "
                "--count 2 --out repeats.csv")
                .status,
            0);
  write_with_cell("repeats_amplitude.csv", 5, 7, "1e300", "repeats.csv");
  const tofkit::test::CliResult width_axis =
      run("fit --in repeats_amplitude.csv --chain offset,grayvalue --confidence noise-systematic "
          "--out out.json");
  EXPECT_EQ(width_axis.status, 0) << width_axis.err;
  expect_refused(
      "fit --in repeats_amplitude.csv --chain offset,temperature --confidence "
      "noise-systematic --out out.json",
      {"amplitude = 1e+300 in data row 5"});
}

// evaluate squares the errors: a corrupt 1e308 cell had turned the bias, RMS
// and improvement into -inf, inf and nan with exit 0.
TEST_F(Robustness, HugeCellsInAnEvaluationAreNamed) {
  make_calibration();
  ASSERT_EQ(run("correct --model model.json --in cal.csv --out cor.csv").status, 0);
  // Columns: distance_true_m 0, distance_raw_m 5, then distance_m 11, sigma_m 12.
  write_with_cell("cor_distance.csv", 4, 11, "1e308", "cor.csv");
  write_with_cell("cor_truth.csv", 4, 0, "-1e308", "cor.csv");
  expect_refused("evaluate --in cor_distance.csv",
                 {"cor_distance.csv", "distance_m = 1e+308 in data row 4", "is too large"});
  expect_refused("evaluate --in cor_truth.csv", {"distance_true_m = -1e+308 in data row 4"});
  // A negative sigma is no expected error (its coverage had read 0 %, exit 0).
  write_with_cell("cor_sigma.csv", 4, 12, "-0.001", "cor.csv");
  expect_refused("evaluate --in cor_sigma.csv", {"sigma_m = -0.001 in data row 4 is negative"});
  EXPECT_EQ(run("evaluate --in cor.csv").status, 0);
}

// Item 2: deeply nested configs are refused before the TOML parser sees them.
TEST_F(Robustness, DeeplyNestedConfigsAreRefused) {
  std::string header = "[a";
  for (int i = 1; i < 50'000; ++i) header += ".a";
  write("deep.toml", header + "]\n");
  expect_refused("--config deep.toml config", {"deep.toml:1:"});
  std::string key = "a";
  for (int i = 1; i < 200'000; ++i) key += ".a";
  write("dotted.toml", key + " = 1\n");
  expect_refused("--config dotted.toml config", {"dotted.toml:1:"});
  write("arrays.toml", "x = " + std::string(50'000, '[') + std::string(50'000, ']') + "\n");
  expect_refused("--config arrays.toml config", {"arrays.toml:1:", "nesting"});
}

// Item 3: settings whose derived quantities would hang or exhaust memory.
TEST_F(Robustness, SettingsThatWouldHangAreRefusedNamingTheKey) {
  expect_refused(
      "--set receiver.bandwidth_mhz=1 measure --distance 1 --reflectance 0.5 --out a.csv",
      {"receiver.bandwidth_mhz", "--set"});
  expect_refused(
      "--set receiver.bandwidth_mhz=0.004 measure --distance 1 --reflectance 0.5 --out a.csv",
      {"receiver.bandwidth_mhz"});
  expect_refused(
      "--set measurement.sample_period_ps=0.01 measure --distance 1 --reflectance 0.5 "
      "--mode waveform --out a.csv",
      {"measurement.sample_period_ps"});
  // A TDC table of 1e15 bins had ended in a bare "out of memory".
  for (const char* tdc : {"tdc.lsb_ps=1e-9", "tdc.coarse_clock_mhz=1e-9"}) {
    expect_refused(
        std::string("--set ") + tdc + " measure --distance 1 --reflectance 0.5 --out a.csv",
        {"tdc.lsb_ps", "tdc.coarse_clock_mhz", "interpolator bins"});
  }
  expect_refused("measure --distance 1 --reflectance 0.5 --count 1e8 --out a.csv",
                 {"--count", "--max-rows"});
  expect_refused("measure --distance 0:10000000:1 --reflectance 0.5 --out a.csv",
                 {"--distance", "--max-rows"});
  expect_refused(
      "measure --distance 1e5 --reflectance 0.5 --angle 89.9 --mode waveform --out a.csv",
      {"--distance/--angle"});
  // A scan's beams are rows of scan.csv: a 0.01 x 0.1 degree sphere (65 M
  // beams, some 20 GB) had run until memory ran out.
  write_plate_scene();
  expect_refused(
      "scan --scene plate.toml --pattern spherical --azimuth -180:180:0.01 --elevation -90:90:0.1 "
      "--out .",
      {"spherical: the pattern has 6.484e+07 beams", "--max-rows"});
  EXPECT_EQ(run("--max-rows 5 scan --scene plate.toml --pattern spherical --azimuth 0:2:1 "
                "--elevation 0,1 --write csv --out .")
                .status,
            1);
  EXPECT_EQ(run("--max-rows 6 scan --scene plate.toml --pattern spherical --azimuth 0:2:1 "
                "--elevation 0,1 --shots 100 --write csv --out .")
                .status,
            0);
  // The limit is a limit, not a ban: raised, a bigger grid runs.
  EXPECT_EQ(run("--max-rows 5 measure --distance 1:6:1 --reflectance 0.5 --out a.csv").status, 1);
  EXPECT_EQ(run("--max-rows 6 measure --distance 1:6:1 --reflectance 0.5 --out a.csv").status, 0);
}

// Item 4: values that used to be read as something else.
TEST_F(Robustness, NumbersThatDoNotFitADoubleAreErrorsWithTheirPlace) {
  make_calibration();
  write_with_cell("overflow.csv", 3, 4, "1e999");
  expect_refused("correct --model model.json --in overflow.csv --out c.csv",
                 {"overflow.csv:4:", "tof_ns", "1e999"});
  // (The field had 1e8 digits; 1e7 takes the same path at a tenth of the cost.)
  write_with_cell("long.csv", 2, 4, "1" + std::string(10'000'000, '0'));
  expect_refused("correct --model model.json --in long.csv --out c.csv",
                 {"long.csv:3:", "tof_ns", "characters"});
  fs::remove(dir_ / "long.csv");
  expect_refused("budget --reflectance nan", {"--reflectance"});
  // A NUL in a field is shown as \x00, and the reason follows (what() is a
  // C string: the message had ended at the NUL).
  write_with_cell("nul.csv", 2, 4, std::string("15.2\0", 5));
  expect_refused("correct --model model.json --in nul.csv --out c.csv",
                 {"nul.csv:3:", "tof_ns", "'15.2\\x00' is not a number"});
  expect_refused("measure --distance 1 --reflectance 0.5 --seed -1 --out a.csv", {"--seed -1"});
  expect_refused("measure --distance 1 --reflectance 0.5 --seed 18446744073709551616 --out a.csv",
                 {"--seed 18446744073709551616"});
  // scan and emulate read their seed as measure does (scan took -1 as 2^64 - 1).
  write_plate_scene();
  for (const std::string seed : {"-1", "18446744073709551616", "1.5"}) {
    expect_refused(
        "scan --scene plate.toml --pattern spherical --azimuth 0:2:1 --elevation 0 "
        "--seed " +
            seed + " --out .",
        {"--seed " + seed});
    expect_refused("emulate --distance 1 --reflectance 0.5 --seed " + seed + " --out -",
                   {"--seed " + seed});
  }
}

TEST_F(Robustness, OldMacLineEndingsReadLikeUnixOnes) {
  make_calibration();
  std::ifstream in(dir_ / "cal.csv");
  std::ostringstream s;
  s << in.rdbuf();
  std::string text = s.str();
  for (auto& c : text) c = c == '\n' ? '\r' : c;
  write("cr.csv", text);
  ASSERT_EQ(run("correct --model model.json --in cal.csv --out lf_out.csv").status, 0);
  ASSERT_EQ(run("correct --model model.json --in cr.csv --out cr_out.csv").status, 0);
  std::ifstream a(dir_ / "lf_out.csv"), b(dir_ / "cr_out.csv");
  std::ostringstream sa, sb;
  sa << a.rdbuf();
  sb << b.rdbuf();
  EXPECT_EQ(sa.str(), sb.str());
  const std::string lf = sa.str();
  EXPECT_GT(std::count(lf.begin(), lf.end(), '\n'), 50);
}

TEST_F(Robustness, InputLargerThanTheLimitIsRefusedNotTruncated) {
  make_calibration();
  expect_refused("--max-input-mb 0.003 correct --model model.json --in cal.csv --out c.csv",
                 {"cal.csv", "--max-input-mb"});
}

// Item 5: outputs are all-or-nothing and never destroy something else.
TEST_F(Robustness, AFailingCommandLeavesNoOutputBehind) {
  make_calibration();
  // --firmware's file cannot be written (a directory has its name): no model either.
  fs::create_directories(dir_ / "fw.json");
  expect_refused("fit --in cal.csv --chain offset --out m2.json --firmware fw", {"fw.json"});
  // characterize: its JSON cannot be written, so its CSV must not appear.
  fs::create_directories(dir_ / "out" / "warmup.json");
  expect_refused("characterize warmup --out out", {"warmup.json"});
  // demo: the last file fails; none of the others may stay (nor new directories).
  fs::create_directories(dir_ / "demo" / "summary.json");
  expect_refused("demo --out demo --no-plots", {"summary.json"});
}

TEST_F(Robustness, OutputsNeverReplaceInputsLinksOrDevices) {
  make_calibration();
  expect_refused("correct --model model.json --in cal.csv --out cal.csv", {"cal.csv", "input"});
  fs::create_hard_link(dir_ / "cal.csv", dir_ / "same.csv");
  expect_refused("correct --model model.json --in cal.csv --out same.csv", {"same.csv", "input"});
  fs::create_symlink("elsewhere.csv", dir_ / "link.csv");
  expect_refused("correct --model model.json --in cal.csv --out link.csv", {"link.csv", "link"});
  ASSERT_EQ(::mkfifo((dir_ / "fifo").c_str(), 0600), 0);
  expect_refused("correct --model model.json --in cal.csv --out fifo", {"fifo", "regular"});
}

TEST_F(Robustness, SigtermRemovesTemporaries) {
  ASSERT_EQ(run("measure --distance 1:8:0.001 --reflectance 0.1,0.9 --count 10 --shots 1 "
                "--out big.csv")
                .status,
            0);
  ASSERT_EQ(run("fit --in big.csv --chain offset --out model.json").status, 0);
  // Signal a correct at several moments: whenever it arrives, no temporary
  // may be left (either nothing new, or the finished output).
  for (int delay_ms : {50, 150, 300, 600}) {
    const std::string command = "cd '" + dir_.string() +
                                "' && exec '" TOFKIT_BINARY
                                "' correct --model model.json --in big.csv --out c.csv "
                                ">/dev/null 2>&1";
    const pid_t pid = ::fork();
    ASSERT_GE(pid, 0);
    if (pid == 0) {
      ::execl("/bin/sh", "sh", "-c", command.c_str(), static_cast<char*>(nullptr));
      ::_exit(127);
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(delay_ms));
    ::kill(pid, SIGTERM);
    int status = 0;
    ::waitpid(pid, &status, 0);
    for (const auto& e : fs::directory_iterator(dir_)) {
      EXPECT_EQ(e.path().filename().string().find(".tmp."), std::string::npos)
          << "left behind after SIGTERM at " << delay_ms << " ms: " << e.path();
    }
    fs::remove(dir_ / "c.csv");
  }
}

// Item 6: messages name the file, line or key.
TEST_F(Robustness, MessagesNameTheFileLineOrKey) {
  make_calibration();
  write("overflow.json", "{\n  \"version\": 1e999\n}\n");
  expect_refused("correct --model overflow.json --in cal.csv --out c.csv", {"overflow.json:2:"});
  fs::create_directories(dir_ / "modeldir");
  expect_refused("correct --model modeldir --in cal.csv --out c.csv", {"modeldir", "directory"});
  expect_refused(
      "--set measurement.reference_temperature_c=90 fit --in cal.csv --chain offset --out m.json",
      {"measurement.reference_temperature_c"});
  expect_refused("--set laser.repetition_hz=1e9 budget", {"--set laser.repetition_hz=1e9"});
  expect_refused("--set bogus.key=1 correct --model model.json --in cal.csv --out c.csv",
                 {"bogus.key"});
  ASSERT_EQ(run("correct --model model.json --in cal.csv --out c.csv").status, 0);
  expect_refused("--set bogus.key=1 evaluate --in c.csv", {"bogus.key"});
  write("bad.toml", "[receiver]\nbandwidth_mhz = \"wide\"\n");
  expect_refused("--config bad.toml evaluate --in c.csv", {"bad.toml:2"});
}

TEST_F(Robustness, OutOfMemoryIsAMessageNotACrash) {
  // The sanitizers' allocator aborts on an 800 GB request instead of throwing.
  if (std::getenv("TOFKIT_SANITIZED") != nullptr) GTEST_SKIP() << "allocator under ASan aborts";
  expect_refused(
      "--max-rows 1000000000000 measure --distance 0:1e11:1 --reflectance 0.5 --out x.csv",
      {"out of memory", "--max-rows"});
}

TEST_F(Robustness, DemoVerdictIsNoWhenNoEchoIsMeasured) {
  const std::string out_command = "cd '" + dir_.string() +
                                  "' && '" TOFKIT_BINARY
                                  "' --set discriminator.threshold_v=100 demo --out d2 "
                                  "--no-plots 2>/dev/null > demo.txt";
  ASSERT_EQ(std::system(out_command.c_str()), 0);
  std::ifstream v(dir_ / "demo.txt");
  std::string line, verdict, not_fitted;
  while (std::getline(v, line)) {
    if (line.find("within +-11 mm") != std::string::npos) verdict = line;
    if (line.rfind("chain step not fitted", 0) == 0) not_fitted = line;
  }
  EXPECT_EQ(verdict.find("within +-11 mm: yes"), std::string::npos) << verdict;
  EXPECT_NE(verdict.find("without a measurement"), std::string::npos) << verdict;
  // The few reliable rows (near plates) share one ambient: the fit refuses
  // the temperature step, and the demo reports it rather than failing.
  EXPECT_NE(not_fitted.find("temperature: no spread in temperature_c between conditions"),
            std::string::npos)
      << not_fitted;
  EXPECT_NE(verdict.find("1 chain step(s) not fitted"), std::string::npos) << verdict;
}

}  // namespace

// Values the option checks had let through: NaN (CLI11's ranges compare and
// every comparison with NaN is false), an empty --write item after a comma,
// a distance a TFmini frame cannot carry (clamped to 655.31 m before).
TEST_F(Robustness, NanOptionsEmptyItemsAndUnfitFramesAreRefused) {
  write_plate_scene();
  expect_refused(
      "emulate --format native --rate nan --distance 2 --reflectance 0.5 --count 1 "
      "--out -",
      {"--rate", "not a number"});
  expect_refused("--max-input-mb nan measure --distance 1 --reflectance 0.5 --out a.csv",
                 {"--max-input-mb", "not a number"});
  expect_refused("plan --at nan", {"--at", "not a number"});
  expect_refused(
      "scan --scene plate.toml --pattern spherical --azimuth 0 --elevation 0 "
      "--ambient nan --out .",
      {"--ambient", "not a number"});
  expect_refused(
      "scan --scene plate.toml --pattern spherical --azimuth 0 --elevation 0 "
      "--write csv, --out .",
      {"--write", "unknown output ''"});
  expect_refused(
      "--set laser.repetition_hz=100000 --set laser.peak_power_w=10000 emulate "
      "--format tfmini --rate 10000 --distance 1000 --reflectance 1 --shots 10 --out -",
      {"TFmini frame: distance_raw_m", "does not fit its field"});
}

// A mirror or a spinning head sets when each beam is measured; beams closer
// in time than one measurement (its shots at the repetition rate) are samples
// the device cannot give. 1 degree steps at 10 revolutions a second are
// 0.278 ms apart: 1000 shots at 1 MHz (1 ms) had been scanned anyway. Without
// --shots the scan averages what fits (277 shots); asked for more, it refuses
// naming the options to change.
TEST_F(Robustness, BeamsFasterThanTheDeviceMeasuresAreRefused) {
  write_plate_scene();
  expect_refused(
      "scan --scene plate.toml --pattern mirror --elevation -10:10:1 --shots 1000 --out .",
      {"mirror: beams 0.2778 ms apart, less than one measurement (1 ms of shots)", "--shots",
       "--rate"});
  const auto fitted =
      run("scan --scene plate.toml --pattern mirror --elevation -10:10:1 --raw "
          "--write csv --out .");
  EXPECT_EQ(fitted.status, 0) << fitted.err;
  EXPECT_NE(fitted.err.find("277 shots"), std::string::npos) << fitted.err;
  expect_refused(
      "scan --scene plate.toml --pattern spinning --elevation -2,2 --azimuth-step 0.1 "
      "--rate 10 --shots 100 --out .",
      {"spinning: beams 0.02778 ms apart", "(0.1 ms of shots)"});
  EXPECT_EQ(run("scan --scene plate.toml --pattern mirror --elevation -10:10:1 --shots 250 "
                "--write csv --out .")
                .status,
            0);
}
