// Hostile input, round 3 (issue 32): one test per class of input that got
// past the guards. Each case must exit 1 with a message naming the key, file,
// row or option at fault and leave its directory as it was; fits must finish
// in seconds. Held-out variants (other keys, commands, layouts) beside each.
#include <fcntl.h>
#include <gtest/gtest.h>
#include <sys/ioctl.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <termios.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <csignal>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <map>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>
#include <thread>
#include <variant>
#include <vector>

#include "cli_runner.hpp"
#include "tofkit/device/device_config.hpp"

namespace fs = std::filesystem;
using tofkit::test::CliResult;

namespace {

class Hostile : public tofkit::test::RefusalFixture {
 protected:
  Hostile() : RefusalFixture("tofkit_hostile3_") {}

  // Seconds a run takes.
  static double seconds_of(const std::function<void()>& f) {
    const auto t0 = std::chrono::steady_clock::now();
    f();
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  }
};

}  // namespace

// Class 1 and 8: a subnormal or absurdly small value of a positive physical
// key passed "> 0" and then crashed the device's setup (1e-300 ns pulse) or
// overflowed (a 1e-310 C sensor step wrote temperature_c = inf). Every key
// refuses a subnormal; every key with a positive lower bound refuses 1e-300.
TEST(HostileConfig, EveryKeyRefusesSubnormalsAndValuesBelowItsPhysicalBound) {
  tofkit::device::DeviceConfig config;
  for (const auto& f : tofkit::device::config_fields(config)) {
    if (!std::holds_alternative<double*>(f.value)) continue;
    for (const double tiny : {5e-324, 1e-310, 1e-300, -1e-310}) {
      const bool below = tiny < f.min || (f.min_nonzero > 0 && std::abs(tiny) < f.min_nonzero) ||
                         std::fpclassify(tiny) == FP_SUBNORMAL;
      if (!below) continue;
      tofkit::device::DeviceConfig c;
      for (const auto& g : tofkit::device::config_fields(c)) {
        if (g.key == f.key) *std::get<double*>(g.value) = tiny;
      }
      const auto messages = tofkit::device::validate(c);
      ASSERT_FALSE(messages.empty()) << f.key << " = " << tiny << " accepted";
      EXPECT_EQ(messages[0].rfind(f.key + " = ", 0), 0u) << messages[0];
    }
    // "Not > 0": a key whose range starts above 0 starts at a physical value.
    EXPECT_TRUE(f.min == 0 || std::abs(f.min) >= 1e-12) << f.key << " min " << f.min;
    EXPECT_TRUE(f.min_nonzero == 0 || f.min_nonzero >= 1e-30) << f.key;
  }
}

// Held out: every key at its smallest valid value (and 1e-300) through the
// CLI: a measurement with finite columns, or exit 1 naming the key; never a
// crash, an inf or a nan.
TEST_F(Hostile, EveryKeyAtItsSmallestValueMeasuresOrIsRefusedByName) {
  tofkit::device::DeviceConfig config;
  for (const auto& f : tofkit::device::config_fields(config)) {
    if (!std::holds_alternative<double*>(f.value)) continue;
    std::vector<double> values = {f.min, 1e-300};
    if (f.min_nonzero > 0) values.push_back(f.min_nonzero);
    for (const double v : values) {
      std::ostringstream set;
      set.precision(17);
      set << f.key << "=" << v;
      const CliResult r =
          run("--set " + set.str() +
              " measure --distance 1,5 --reflectance 0.1,0.9 --shots 4 --out a.csv");
      ASSERT_TRUE(r.status == 0 || r.status == 1) << set.str() << ": status " << r.status;
      if (r.status == 1) {
        EXPECT_NE(r.err.find(f.key), std::string::npos) << set.str() << "\n" << r.err;
        continue;
      }
      const std::string csv = read("a.csv");
      EXPECT_EQ(csv.find("inf"), std::string::npos) << set.str() << "\n" << csv;
      EXPECT_EQ(csv.find("nan"), std::string::npos) << set.str() << "\n" << csv;
    }
  }
  expect_refused(
      "--set laser.pulse_width_ns=1e-300 scan --scene none.toml --pattern spherical --azimuth 0 "
      "--elevation 0 --out o",
      {"laser.pulse_width_ns"});
  expect_refused("--set receiver.saturation_v=1e-310 plan --single-distance --bench",
                 {"receiver.saturation_v"});
}

// Class 2: a B-spline model whose domain is wider than its knots was loaded;
// correct clamped inputs to the domain and evaluated the basis past the last
// knot (coefficients read out of bounds: a segfault at 1e100, a 3.3 m range
// "corrected" to 18.9 m at 100). Every axis, either end, with and without the
// temperature axis: refused at load naming the axis.
TEST_F(Hostile, ModelsWhoseDomainExceedsTheirKnotsAreRefusedAtLoad) {
  ASSERT_EQ(run("measure --distance 1:8:1 --reflectance 0.05,0.2,0.5,0.9 --temperature 10,25,40 "
                "--out cal.csv")
                .status,
            0);
  for (const std::string& temperature : {std::string(""), std::string(" --temperature")}) {
    ASSERT_EQ(run("fit --in cal.csv --surface bspline --knots 4x4" +
                  std::string(temperature.empty() ? "" : "x3") + temperature + " --out m.json")
                  .status,
              0)
        << temperature;
    const nlohmann::json model = nlohmann::json::parse(read("m.json"));
    ASSERT_EQ(run("correct --model m.json --in cal.csv --out ok.csv").status, 0);
    fs::remove(dir_ / "ok.csv");
    const auto& domain = model["steps"][0]["surface"]["domain"];
    for (const auto& [axis, interval] : domain.items()) {
      for (int end = 0; end < 2; ++end) {
        for (const double factor : {1.5, 1e100}) {
          nlohmann::json bad = model;
          double& v = bad["steps"][0]["surface"]["domain"][axis][end].get_ref<double&>();
          const double span = interval[1].get<double>() - interval[0].get<double>();
          v += (end == 0 ? -1.0 : 1.0) * span * (factor == 1.5 ? 0.5 : factor);
          if (end == 0 && axis == "amplitude" && !(v > 0)) v = interval[0].get<double>() * 0.5;
          write("bad.json", bad.dump());
          expect_refused("correct --model bad.json --in cal.csv --out out.csv",
                         {"bad.json",
                          "BSplineSurface: " +
                              std::string(axis == "range_m"     ? "range"
                                          : axis == "amplitude" ? "amplitude"
                                                                : "temperature") +
                              " domain",
                          "exceeds the axis knots"});
        }
      }
    }
  }
}

// Classes 10 and 11: stream wrote --out with a bare fopen: over its --model
// (also through a symbolic link), and an existing file was truncated before
// the stream failed. It now writes through the one writer like every command.
TEST_F(Hostile, StreamWritesThroughTheOneWriter) {
  ASSERT_EQ(run("measure --distance 1:8:1 --reflectance 0.1,0.9 --temperature 10,25,40 "
                "--out cal.csv")
                .status,
            0);
  ASSERT_EQ(run("fit --in cal.csv --chain offset,grayvalue --out model.json").status, 0);
  const CliResult bytes =
      tofkit::test::run_tofkit(dir_,
                               "emulate --format native --distance 2 --reflectance 0.5 --count 20 "
                               "--shots 10 --out -",
                               "nat.bin", scratch() / "e.txt");
  ASSERT_EQ(bytes.status, 0) << bytes.err;
  expect_refused("stream --format native --in nat.bin --model model.json --out model.json",
                 {"model.json", "input"});
  fs::create_symlink("model.json", dir_ / "link.json");
  expect_refused("stream --format native --in nat.bin --model model.json --out link.json",
                 {"link.json", "symbolic link"});
  expect_refused("stream --format native --in nat.bin --out nat.bin", {"nat.bin", "input"});
  write("keep.csv", "precious\n");
  expect_refused("stream --format native --in /proc/self/mem --out keep.csv", {"/proc/self/mem"});
  expect_refused("stream --format native --in nat.bin --model nope.json --out keep.csv",
                 {"nope.json"});
  expect_refused("stream --format native --in nat.bin --out ''", {"--out"});
  EXPECT_EQ(read("keep.csv"), "precious\n");
  // Held out: a good stream replaces the file whole; no temporary stays.
  const CliResult good =
      run("stream --format native --in nat.bin --model model.json --out keep.csv");
  ASSERT_EQ(good.status, 0) << good.err;
  EXPECT_EQ(read("keep.csv").rfind("sequence,time_s,", 0), 0u);
  for (const auto& e : fs::directory_iterator(dir_)) {
    EXPECT_EQ(e.path().filename().string().find(".tmp."), std::string::npos) << e.path();
  }
}

// Class 12: SIGTERM during demo --out newdir/sub left the directories it had
// created; the writer's handler removes them (empty) with the temporaries.
TEST_F(Hostile, SignalsRemoveTheDirectoriesACommandCreated) {
  for (const int delay_ms : {150, 400}) {
    for (const int sig : {SIGTERM, SIGINT}) {
      const std::string command = "cd '" + dir_.string() +
                                  "' && exec '" TOFKIT_BINARY
                                  "' demo --no-plots --out newdir/sub >/dev/null 2>&1";
      const pid_t pid = ::fork();
      ASSERT_GE(pid, 0);
      if (pid == 0) {
        ::signal(SIGINT, SIG_DFL);
        ::execl("/bin/sh", "sh", "-c", command.c_str(), static_cast<char*>(nullptr));
        ::_exit(127);
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(delay_ms));
      ::kill(pid, sig);
      int status = 0;
      ::waitpid(pid, &status, 0);
      ASSERT_TRUE(WIFSIGNALED(status)) << "demo finished before the signal at " << delay_ms;
      EXPECT_FALSE(fs::exists(dir_ / "newdir")) << "after signal " << sig << " at " << delay_ms;
      fs::remove_all(dir_ / "newdir");
    }
  }
  // Held out: a directory that existed before stays, only the new part goes.
  fs::create_directories(dir_ / "old");
  const pid_t pid = ::fork();
  ASSERT_GE(pid, 0);
  if (pid == 0) {
    const std::string command = "cd '" + dir_.string() +
                                "' && exec '" TOFKIT_BINARY
                                "' demo --no-plots --out old/a/b >/dev/null 2>&1";
    ::execl("/bin/sh", "sh", "-c", command.c_str(), static_cast<char*>(nullptr));
    ::_exit(127);
  }
  std::this_thread::sleep_for(std::chrono::milliseconds(300));
  ::kill(pid, SIGTERM);
  int status = 0;
  ::waitpid(pid, &status, 0);
  EXPECT_TRUE(fs::is_directory(dir_ / "old"));
  EXPECT_FALSE(fs::exists(dir_ / "old" / "a"));
}

// Class 15: stream --in - on a terminal set it raw for good (after exit the
// shell had -icanon -echo -isig), and Ctrl-C arrived as byte 0x03. Run on a
// new pseudo-terminal as its controlling terminal: Ctrl-C ends it (exit 0,
// "interrupted") and the terminal's settings are as before; likewise when the
// stream fails (its --out refused) or ends by --count.
TEST_F(Hostile, StreamOnATerminalRestoresItAndStopsOnCtrlC) {
  struct Case {
    std::string args;
    bool ctrl_c;
    int status;
  };
  write("keep.csv", "x\n");
  fs::create_symlink("keep.csv", dir_ / "link.csv");
  for (const Case& c : {Case{"--out o.csv", true, 0}, Case{"--out link.csv", false, 1},
                        Case{"--out - --count 1", true, 0}}) {
    const int master = ::posix_openpt(O_RDWR | O_NOCTTY);
    ASSERT_GE(master, 0);
    ASSERT_EQ(::grantpt(master), 0);
    ASSERT_EQ(::unlockpt(master), 0);
    const std::string slave_path = ::ptsname(master);
    const int slave = ::open(slave_path.c_str(), O_RDWR | O_NOCTTY);
    ASSERT_GE(slave, 0);
    termios before{};
    ASSERT_EQ(::tcgetattr(slave, &before), 0);
    const std::string out = (scratch() / "tty_err.txt").string();
    const pid_t pid = ::fork();
    ASSERT_GE(pid, 0);
    if (pid == 0) {
      ::setsid();
      ::ioctl(slave, TIOCSCTTY, 0);
      ::dup2(slave, 0);
      const int err = ::open(out.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0600);
      ::dup2(err, 2);
      const int null = ::open("/dev/null", O_WRONLY);
      ::dup2(null, 1);
      if (::chdir(dir_.c_str()) != 0) ::_exit(126);
      const std::string command =
          "exec '" TOFKIT_BINARY "' stream --format native --in - " + c.args;
      ::execl("/bin/sh", "sh", "-c", command.c_str(), static_cast<char*>(nullptr));
      ::_exit(127);
    }
    int status = 0;
    pid_t done = 0;
    if (c.ctrl_c) {
      std::this_thread::sleep_for(std::chrono::milliseconds(500));
      EXPECT_EQ(::waitpid(pid, &status, WNOHANG), 0) << c.args << ": ended by itself";
      ASSERT_EQ(::write(master, "\x03", 1), 1);
    }
    for (int i = 0; i < 300 && done == 0; ++i) {
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
      done = ::waitpid(pid, &status, WNOHANG);
    }
    if (done == 0) {
      ::kill(pid, SIGKILL);
      ::waitpid(pid, &status, 0);
      ADD_FAILURE() << c.args << ": Ctrl-C did not end the stream";
    } else {
      EXPECT_TRUE(WIFEXITED(status) && WEXITSTATUS(status) == c.status)
          << c.args << ": status " << status << "\n"
          << tofkit::test::read_file(out);
    }
    termios after{};
    ASSERT_EQ(::tcgetattr(slave, &after), 0);
    EXPECT_EQ(after.c_lflag, before.c_lflag) << c.args << ": local modes not restored";
    EXPECT_EQ(after.c_iflag, before.c_iflag) << c.args;
    EXPECT_EQ(after.c_oflag, before.c_oflag) << c.args;
    ::close(slave);
    ::close(master);
  }
  EXPECT_EQ(read("keep.csv"), "x\n");
}

// Class 13: --firmware '/' or 'out/' wrote the hidden files /.json and /.h
// (exit 0); '' silently wrote none. A stem that names no file is refused.
// Also: emulate --out '' fell back to a pseudo-terminal.
TEST_F(Hostile, OutputStemsAndPathsThatNameNoFileAreRefused) {
  ASSERT_EQ(run("measure --distance 1:8:1 --reflectance 0.1,0.9 --out cal.csv").status, 0);
  fs::create_directories(dir_ / "out");
  for (const std::string stem : {"out/", "''", ".", "out/..", "out/.", "/"}) {
    expect_refused("fit --in cal.csv --chain offset,grayvalue --firmware " + stem + " --out m.json",
                   {"--firmware", "not a file stem"});
  }
  expect_refused("emulate --format native --distance 1 --reflectance 0.5 --out ''", {"--out"});
  // Held out: a real stem writes both files.
  ASSERT_EQ(run("fit --in cal.csv --chain offset,grayvalue --firmware out/c --out m.json").status,
            0);
  EXPECT_TRUE(fs::exists(dir_ / "out" / "c.json"));
  EXPECT_TRUE(fs::exists(dir_ / "out" / "c.h"));
}

// Class 14: evaluate on rows without a distance_m printed a table of nan with
// exit 0 (a missing distance_true_m was already refused).
TEST_F(Hostile, EvaluateWithoutCorrectedDistancesIsRefused) {
  ASSERT_EQ(run("measure --distance 1:8:1 --reflectance 0.1,0.9 --out cal.csv").status, 0);
  expect_refused("evaluate --in cal.csv", {"cal.csv", "distance_m"});
  ASSERT_EQ(run("fit --in cal.csv --chain offset --out m.json").status, 0);
  ASSERT_EQ(run("correct --model m.json --in cal.csv --out cor.csv").status, 0);
  // Held out: the distance_m column there but empty on every row; --json too.
  std::istringstream in(read("cor.csv"));
  std::string line, text;
  std::getline(in, line);
  text = line + "\n";
  while (std::getline(in, line)) {
    std::vector<std::string> cells;
    std::stringstream cs(line);
    for (std::string c; std::getline(cs, c, ',');) cells.push_back(c);
    cells[11] = "";
    for (std::size_t k = 0; k < cells.size(); ++k) text += (k ? "," : "") + cells[k];
    text += "\n";
  }
  write("empty.csv", text);
  expect_refused("evaluate --in empty.csv --json", {"empty.csv", "no row has a distance_m"});
  EXPECT_EQ(run("evaluate --in cor.csv").status, 0);
}

// Class 4: fit --surface bspline --temperature (automatic knots) on the
// README's 180-row calibration ran over 600 s, --knots 50x50 on 288 rows
// likewise: the knot search tries only grids sized to the data and the
// solve's cost, and a given grid beyond the limit is refused naming --knots.
TEST_F(Hostile, BSplineFitsAreBoundedInTime) {
  ASSERT_EQ(run("measure --distance 1:8:0.5 --reflectance 0.02,0.1,0.5,0.9 --temperature "
                "10,25,40 --out calib.csv")
                .status,
            0);
  CliResult r;
  const double seconds = seconds_of(
      [&] { r = run("fit --in calib.csv --surface bspline --temperature --out m.json"); });
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_LT(seconds, 60.0) << "a bounded fit took " << seconds << " s";
  const nlohmann::json model = nlohmann::json::parse(read("m.json"));
  const auto& surface = model["steps"][0]["surface"];
  // Sane: a few millimetres on its own data, within the coefficient limit.
  EXPECT_LT(model["steps"][0]["fit"]["residual_rms_m"].get<double>(), 0.01) << model.dump();
  EXPECT_LE(surface["coefficients"].size(), 400u);
  fs::remove(dir_ / "m.json");
  expect_refused("fit --in calib.csv --surface bspline --knots 50x50 --out m.json",
                 {"--knots 50x50", "coefficients"});
  expect_refused(
      "fit --in calib.csv --surface bspline --temperature --knots 20x20x5 --smoothing 0.01 --out "
      "m.json",
      {"--knots 20x20x5", "coefficients"});
}

// Class 9: --smoothing VALUE with automatic knots was replaced by the
// cross-validated choice (0, 1, 1e100 and auto gave the same model). The
// value is kept (the knots chosen for it); one past the limit is refused.
TEST_F(Hostile, BSplineSmoothingIsHonouredWithAutomaticKnots) {
  ASSERT_EQ(run("measure --distance 1:8:0.5 --reflectance 0.02,0.1,0.5,0.9 --out calib.csv").status,
            0);
  std::map<std::string, std::string> models;
  for (const std::string s : {"0", "1", "auto"}) {
    const CliResult r = run("fit --in calib.csv --surface bspline --confidence none --smoothing " +
                            s + " --out s.json");
    ASSERT_EQ(r.status, 0) << r.err;
    const nlohmann::json j = nlohmann::json::parse(read("s.json"));
    const double used = j["steps"][0]["surface"]["fit"]["smoothing"].get<double>();
    if (s != "auto") EXPECT_EQ(used, std::stod(s)) << s;
    models[s] = read("s.json");
    fs::remove(dir_ / "s.json");
  }
  EXPECT_NE(models["0"], models["1"]);
  EXPECT_NE(models["1"], models["auto"]);
  expect_refused("fit --in calib.csv --surface bspline --smoothing 1e100 --out s.json",
                 {"--smoothing 1e100"});
  expect_refused("fit --in calib.csv --surface bspline --knots 4x4 --smoothing 1e300 --out s.json",
                 {"--smoothing 1e300"});
}

namespace {

// `source` with column `column` of data row `row` (1-based; 0: every row) set to `value`.
std::string with_cells(const std::string& source, std::size_t row, std::size_t column,
                       const std::string& value) {
  std::istringstream in(source);
  std::string line, out;
  for (std::size_t i = 0; std::getline(in, line); ++i) {
    if (i > 0 && (row == 0 || i == row)) {
      std::vector<std::string> cells;
      std::stringstream s(line);
      for (std::string c; std::getline(s, c, ',');) cells.push_back(c);
      cells[column] = value;
      line.clear();
      for (std::size_t k = 0; k < cells.size(); ++k) line += (k ? "," : "") + cells[k];
    }
    out += line + "\n";
  }
  return out;
}

}  // namespace

// Class 5: one distance_true_m = -1 made a walk chain's fit take 143 s (exit
// 0, 160 mm RMS), a constant amplitude column over 120 s, and one 4.3e9 ns
// pulse width gave NaN BICs and 68 mm RMS with exit 0. Impossible cells are
// refused before fitting, naming the row; a constant amplitude column pins no
// walk shape, so the walk fit leaves it out (as a fit without amplitude) and
// finishes in seconds.
TEST_F(Hostile, ImpossibleOrDegenerateTruthIsRefusedBeforeFitting) {
  ASSERT_EQ(run("measure --distance 1:8:1 --reflectance 0.02,0.1,0.5,0.9 --temperature 10,25,40 "
                "--out cal.csv")
                .status,
            0);
  const std::string cal = read("cal.csv");
  // Columns: distance_true_m 0, pulse_width_ns 6, amplitude 7, temperature_c 8.
  write("neg_truth.csv", with_cells(cal, 4, 0, "-1"));
  write("wide.csv", with_cells(cal, 4, 6, "4.3e9"));
  write("neg_width.csv", with_cells(cal, 4, 6, "-2"));
  write("neg_amplitude.csv", with_cells(cal, 4, 7, "-0.5"));
  write("cold.csv", with_cells(cal, 4, 8, "-300"));
  write("flat_amplitude.csv", with_cells(cal, 0, 7, "1"));
  struct Case {
    std::string file, model;
    std::vector<std::string> needles;
  };
  const std::vector<Case> cases = {
      {"neg_truth.csv", "--chain offset,walk,temperature", {"distance_true_m = -1 in data row 4"}},
      {"neg_truth.csv", "--chain offset,grayvalue", {"distance_true_m = -1 in data row 4"}},
      {"neg_truth.csv", "--surface bspline", {"distance_true_m = -1 in data row 4"}},
      {"wide.csv", "--chain offset,grayvalue", {"pulse_width_ns = 4.3e+09 in data row 4"}},
      {"wide.csv", "--chain offset,walk", {"pulse_width_ns = 4.3e+09 in data row 4"}},
      {"neg_width.csv", "--surface bspline --intensity pulse-width", {"pulse_width_ns = -2"}},
      {"neg_amplitude.csv", "--chain offset,walk", {"amplitude = -0.5 in data row 4"}},
      {"cold.csv", "--chain offset,temperature", {"temperature_c = -300 in data row 4"}},
  };
  // A guard against the 120-143 s fits above, not a speed figure: the fits
  // take 3-6 s, and 11 s was seen on a loaded 2-core machine.
  constexpr double kBounded_s = 60.0;
  for (const Case& c : cases) {
    const double seconds = seconds_of(
        [&] { expect_refused("fit --in " + c.file + " " + c.model + " --out m.json", c.needles); });
    EXPECT_LT(seconds, kBounded_s) << c.file << " " << c.model;
  }
  const double flat_seconds = seconds_of([&] {
    EXPECT_EQ(
        run("fit --in flat_amplitude.csv --chain offset,walk,temperature --out flat.json").status,
        0);
  });
  EXPECT_LT(flat_seconds, kBounded_s);
  // evaluate reads the truth too.
  ASSERT_EQ(run("fit --in cal.csv --chain offset --out m.json").status, 0);
  ASSERT_EQ(run("correct --model m.json --in cal.csv --out cor.csv").status, 0);
  write("cor_neg.csv", with_cells(read("cor.csv"), 3, 0, "-2"));
  expect_refused("evaluate --in cor_neg.csv", {"distance_true_m = -2 in data row 3"});
}

namespace {

// Peak resident memory (bytes) of `tofkit <args>` run in `dir`, and its status.
std::pair<double, int> peak_memory_of(const fs::path& dir, const std::string& args) {
  const pid_t pid = ::fork();
  if (pid == 0) {
    const std::string command =
        "cd '" + dir.string() + "' && exec '" TOFKIT_BINARY "' " + args + " >/dev/null 2>/dev/null";
    ::execl("/bin/sh", "sh", "-c", command.c_str(), static_cast<char*>(nullptr));
    ::_exit(127);
  }
  int status = 0;
  struct rusage usage {};
  ::wait4(pid, &status, 0, &usage);
  return {static_cast<double>(usage.ru_maxrss) * 1024.0,
          WIFEXITED(status) ? WEXITSTATUS(status) : -1};
}

// A binary PLY of `n` vertices with the given per-vertex properties (each a
// uchar, value 2) and one face (0, 1, 2) with the given index type and values.
std::string ply(std::size_t n, const std::vector<std::string>& properties,
                const std::string& index_type = "int") {
  std::string text =
      "ply\nformat binary_little_endian 1.0\nelement vertex " + std::to_string(n) + "\n";
  for (const auto& p : properties) text += "property uchar " + p + "\n";
  text += "element face 1\nproperty list uchar " + index_type + " vertex_indices\nend_header\n";
  text.append(n * properties.size(), '\x02');
  text.push_back('\x03');
  for (const float i : {0.0f, 1.5f, 2.0f}) {
    if (index_type == "float") {
      text.append(reinterpret_cast<const char*>(&i), 4);
    } else {
      const auto k = static_cast<std::int32_t>(i);
      text.append(reinterpret_cast<const char*>(&k), 4);
    }
  }
  return text;
}

}  // namespace

// Class 6: a 100 MB binary PLY of 1e8 one-byte vertices took 3.25 GB before
// being refused. A vertex must have x, y and z, and the mesh may take at most
// a small multiple of the file; a float face index 1.5 had been truncated.
TEST_F(Hostile, MeshReadersUseMemoryBoundedByTheirInput) {
  const auto scene = [&](const std::string& mesh) {
    write("scene.toml",
          "[[surface]]\nkind = \"mesh\"\nfile = \"" + mesh + "\"\nreflectance = 0.5\n");
  };
  const std::string scan =
      "scan --scene scene.toml --pattern spherical --azimuth 0 --elevation 0 "
      "--write csv --out o";
  // Under ASan the peak counts its shadow memory and quarantine, not the
  // reader's: the bounds hold for the Release build; the refusals for both.
  const double slack = std::getenv("TOFKIT_SANITIZED") != nullptr ? 1e12 : 0.0;
  write("x_only.ply", ply(20'000'000, {"x"}));
  scene("x_only.ply");
  const auto [x_only_bytes, x_only_status] = peak_memory_of(dir_, scan);
  EXPECT_EQ(x_only_status, 1);
  EXPECT_LT(x_only_bytes, 3.0 * 20e6 + 64e6 + slack) << "peak " << x_only_bytes / 1e6 << " MB";
  expect_refused(scan, {"x_only.ply", "no property 'y'"});
  // Held out: three one-byte coordinates (the smallest vertex): 8x the file at
  // most, plus the file itself and the program.
  const std::size_t n = 3'000'000;
  write("xyz.ply", ply(n, {"x", "y", "z"}));
  scene("xyz.ply");
  const auto [xyz_bytes, xyz_status] = peak_memory_of(dir_, scan);
  EXPECT_EQ(xyz_status, 1);  // (all its vertices are one point)
  EXPECT_LT(xyz_bytes, 9.0 * 3.0 * static_cast<double>(n) + 64e6 + slack)
      << "peak " << xyz_bytes / 1e6 << " MB for a " << 3 * n / 1e6 << " MB file";
  write("index.ply", ply(3, {"x", "y", "z"}, "float"));
  scene("index.ply");
  expect_refused(scan, {"index.ply", "bad face index 1.5"});
}
