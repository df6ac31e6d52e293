// `tofkit emulate` and `tofkit stream` end to end. Oracles: `tofkit measure`
// + `tofkit correct` with the same seed (the offline path), the native frame's
// encoder applied to measure's rows (the exact quantization on the wire), and
// the sequence numbers (no frame lost).
//
// The pty run lasts TOFKIT_LINK_E2E_SECONDS (default 1.5 s) at 10 kHz; the
// acceptance run is TOFKIT_LINK_E2E_SECONDS=10.

#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "cli_runner.hpp"
#include "tofkit/io/model_json.hpp"
#include "tofkit/io/raw_csv.hpp"
#include "tofkit/link/decoder.hpp"
#include "tofkit/link/native_frame.hpp"
#include "tofkit/link/tfmini.hpp"
#include "tofkit/ranging/pipeline.hpp"

namespace fs = std::filesystem;

const fs::path kScenes = fs::path(TOFKIT_REFERENCE_DIR).parent_path() / "examples" / "scenes";

namespace tofkit {
namespace {

class StreamCli : public test::CliFixture {
 protected:
  StreamCli() : CliFixture("tofkit_stream_test_") {}

  // A model fitted on the device's own calibration run.
  void make_model() const {
    ASSERT_EQ(run("measure --distance 1:10:1 --reflectance 0.05,0.2,0.5,0.9 --temperature 10,20,30 "
                  "--count 3 --shots 100 --seed 5 --out cal.csv")
                  .status,
              0);
    ASSERT_EQ(run("fit --in cal.csv --out model.json --chain offset,grayvalue,temperature").status,
              0);
  }
};

// One CSV table by header name.
struct Table {
  std::vector<std::string> header;
  std::vector<std::vector<std::string>> rows;
  [[nodiscard]] std::size_t column(const std::string& name) const {
    for (std::size_t i = 0; i < header.size(); ++i) {
      if (header[i] == name) return i;
    }
    ADD_FAILURE() << "no column " << name;
    return 0;
  }
  [[nodiscard]] double number(std::size_t row, const std::string& name) const {
    const std::string& s = rows[row][column(name)];
    return s.empty() ? ranging::kNaN : std::stod(s);
  }
};

std::vector<std::string> split(const std::string& line) {
  std::vector<std::string> fields;
  std::stringstream s(line);
  std::string f;
  while (std::getline(s, f, ',')) fields.push_back(f);
  if (!line.empty() && line.back() == ',') fields.emplace_back();
  return fields;
}

Table read_table(const std::string& file) {
  std::ifstream in(file);
  Table t;
  std::string line;
  std::getline(in, line);
  t.header = split(line);
  while (std::getline(in, line)) t.rows.push_back(split(line));
  return t;
}

bool same(double a, double b) {
  return (std::isnan(a) && std::isnan(b)) || a == b;
}

TEST_F(StreamCli, EmulatorThroughAPtyEqualsMeasureAndCorrect) {
  make_model();
  const char* env = std::getenv("TOFKIT_LINK_E2E_SECONDS");
  const double seconds = env != nullptr ? std::atof(env) : 1.5;
  const int rate = 10'000;
  const int frames = static_cast<int>(seconds * rate);
  // Eight grid points (inside and outside the calibration) of frames / 8 repeats each.
  const std::string grid = "--distance 0.7,3,8.5,40 --reflectance 0.1,0.9 --count " +
                           std::to_string(frames / 8) + " --shots 100 --seed 42";

  // emulate in the background on a new pty; its first stdout line is the path.
  const std::string emulate = "cd '" + dir_.string() +
                              "' && '" TOFKIT_BINARY "' emulate --format native --rate " +
                              std::to_string(rate) + " " + grid + " >pty.txt 2>emulate.txt &";
  ASSERT_EQ(std::system(emulate.c_str()), 0);
  std::string pty;
  for (int i = 0; i < 500 && pty.empty(); ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
    const std::string text = read("pty.txt");
    if (text.find('\n') != std::string::npos) pty = text.substr(0, text.find('\n'));
  }
  ASSERT_FALSE(pty.empty()) << read("emulate.txt");
  const auto streamed =
      run("stream --format native --in " + pty + " --model model.json --out live.csv --stats");
  ASSERT_EQ(streamed.status, 0) << streamed.err;
  std::cout << read("emulate.txt") << streamed.err;

  ASSERT_EQ(run("measure " + grid + " --out raw.csv").status, 0);
  ASSERT_EQ(run("correct --model model.json --in raw.csv --out corrected.csv").status, 0);

  const Table live = read_table(path("live.csv"));
  const auto offline = io::read_corrected_csv(path("corrected.csv"));
  const auto raw = io::read_raw_csv(path("raw.csv"));
  ASSERT_EQ(live.rows.size(), offline.size());
  ASSERT_EQ(live.rows.size(), static_cast<std::size_t>(frames / 8 * 8));
  EXPECT_NE(streamed.err.find("checksum_failures 0"), std::string::npos);
  EXPECT_NE(streamed.err.find("sequence_gaps 0"), std::string::npos);

  // The offline path through the wire's quantization: measure's rows encoded
  // as native frames, decoded, corrected with the same model -> bit-identical.
  const ranging::Pipeline pipeline = io::load_pipeline(path("model.json"));
  auto decoder = link::make_decoder(link::Format::kNative);
  std::vector<link::Frame> decoded;
  for (std::size_t i = 0; i < raw.size(); ++i) {
    decoder->feed(link::encode_native({static_cast<std::uint32_t>(i), 0, raw[i].raw}), decoded);
  }
  ASSERT_EQ(decoded.size(), raw.size());
  // The wire's half resolution steps through each step's steepest slope.
  double tolerance_m = 0.5e-6 * 0.15;  // 0.5 fs of time of flight
  for (const auto& step : pipeline.steps()) {
    double steepest = 0;
    for (const double slope : step.function.segment_slopes()) {
      steepest = std::max(steepest, std::abs(slope));
    }
    if (step.kind == ranging::StepKind::kGrayvalue) tolerance_m += steepest * 0.5e-3;
    if (step.kind == ranging::StepKind::kTemperature) tolerance_m += steepest * 0.5 / 128;
  }
  std::size_t with_echo = 0;
  for (std::size_t i = 0; i < live.rows.size(); ++i) {
    SCOPED_TRACE(i);
    ASSERT_EQ(std::stoull(live.rows[i][live.column("sequence")]), i);  // no frame lost, in order
    const ranging::Range r = pipeline.apply(decoded[i].raw);
    ASSERT_TRUE(same(live.number(i, "distance_m"), r.distance_m));
    ASSERT_TRUE(same(live.number(i, "sigma_m"), r.sigma_m));
    ASSERT_EQ(live.number(i, "correction_flags"), r.correction_flags);
    // And against `correct` itself: equal up to the wire's resolution.
    const double d = offline[i].range.distance_m;
    ASSERT_EQ(std::isnan(live.number(i, "distance_m")), std::isnan(d));
    if (!std::isnan(d)) {
      ++with_echo;
      ASSERT_NEAR(live.number(i, "distance_m"), d, tolerance_m);
    }
  }
  EXPECT_GT(with_echo, live.rows.size() / 2);
}

// The same seed gives the same values with and without --corrupt, for the
// plate grid and for a scan of a scene.
TEST_F(StreamCli, CorruptionChangesBytesNeverValues) {
  const struct {
    std::string emulate;
    std::size_t frames;
  } cases[] = {
      {"--format native --rate 1000000 --distance 2,6 --reflectance 0.3 "
       "--count 2000 --shots 50 --seed 9 --out -",
       4000},
      {"--format native --rate 1000000 --scene " + (kScenes / "blocks.toml").string() +
           " --pattern spinning --elevation=-10:10:2 --azimuth-step 2 --revolutions 2 "
           "--shots 30 --seed 11 --out -",
       11 * 180 * 2},  // elevations x azimuths x revolutions
  };
  for (const auto& c : cases) {
    SCOPED_TRACE(c.emulate);
    ASSERT_EQ(run("emulate " + c.emulate, "clean.bin").status, 0);
    ASSERT_EQ(run("emulate " + c.emulate + " --corrupt 0.01", "dirty.bin").status, 0);
    const std::string clean = read("clean.bin"), dirty = read("dirty.bin");
    ASSERT_EQ(clean.size(), dirty.size());
    ASSERT_EQ(clean.size(), c.frames * link::kNativeFrameBytes);
    std::size_t differing = 0;
    for (std::size_t i = 0; i < clean.size(); ++i) differing += clean[i] != dirty[i] ? 1 : 0;
    EXPECT_NEAR(static_cast<double>(differing) / static_cast<double>(clean.size()), 0.01, 0.002);

    ASSERT_EQ(run("stream --format native --in clean.bin --out clean.csv").status, 0);
    const auto s = run("stream --format native --in dirty.bin --out dirty.csv --stats");
    ASSERT_EQ(s.status, 0);
    const Table a = read_table(path("clean.csv")), b = read_table(path("dirty.csv"));
    ASSERT_EQ(a.rows.size(), c.frames);
    EXPECT_LT(b.rows.size(), a.rows.size());
    // 0.99^30 = 74 % of 30-byte frames are untouched.
    EXPECT_GT(b.rows.size(), c.frames * 7 / 10);
    // Every frame that got through carries exactly the clean run's values.
    for (std::size_t i = 0; i < b.rows.size(); ++i) {
      const auto seq = std::stoull(b.rows[i][0]);
      std::vector<std::string> row_b = b.rows[i], row_a = a.rows[seq];
      row_b.back() = row_a.back() = "";  // link_status: a sequence gap before it
      ASSERT_EQ(row_b, row_a) << seq;
    }
  }
}

// `emulate --scene` against `tofkit scan` with the same scene, pattern options
// and seed: one frame per beam of scan.csv, in its (time) order, carrying
// scan.csv's values. Exact oracle: scan.csv's rows through the format's own
// encoder and decoder; independent one: scan.csv itself within the wire's
// half resolution step.
TEST_F(StreamCli, EmulatedSceneCarriesTheScansBeamsInTimeOrder) {
  const std::string scene = (kScenes / "blocks.toml").string();
  // Two patterns: a spherical scan, and a mirror whose revolution rate is
  // scan's --rate and emulate's --scan-rate (emulate's --rate is frames/s).
  struct Case {
    std::string pattern, scan_rate;
  } cases[] = {{"--pattern spherical --azimuth=-20:20:2 --elevation=-12:40:2.6", ""},
               {"--pattern mirror --elevation=-30:30:1.5 --revolutions 6 --speed 0.2", "25"}};
  for (const auto& c : cases) {
    const std::string common = "--scene " + scene + " " + c.pattern + " --shots 20 --seed 5";
    SCOPED_TRACE(common);
    fs::create_directories(dir_ / "scan");
    ASSERT_EQ(run("scan " + common + (c.scan_rate.empty() ? "" : " --rate " + c.scan_rate) +
                  " --write csv --out scan")
                  .status,
              0);
    const Table beams = read_table(path("scan/scan.csv"));
    ASSERT_GT(beams.rows.size(), 200u);
    std::vector<ranging::RawMeasurement> expected(beams.rows.size());
    std::size_t with_echo = 0;
    for (std::size_t i = 0; i < beams.rows.size(); ++i) {
      if (i > 0) ASSERT_GE(beams.number(i, "time_s"), beams.number(i - 1, "time_s"));
      auto& r = expected[i];
      r.tof_ns = beams.number(i, "tof_ns");
      r.distance_raw_m = beams.number(i, "distance_raw_m");
      r.pulse_width_ns = beams.number(i, "pulse_width_ns");
      r.amplitude = beams.number(i, "amplitude");
      r.temperature_c = beams.number(i, "temperature_c");
      r.shots_valid = static_cast<std::uint32_t>(beams.number(i, "shots_valid"));
      r.flags = static_cast<std::uint32_t>(beams.number(i, "flags"));
      with_echo += r.has_echo() ? 1 : 0;
    }
    EXPECT_GT(with_echo, beams.rows.size() / 2);
    EXPECT_LT(with_echo, beams.rows.size());  // misses, too (NaN must stay empty)

    for (const auto format : {link::Format::kNative, link::Format::kTfmini}) {
      const std::string name = format == link::Format::kNative ? "native" : "tfmini";
      SCOPED_TRACE(name);
      const std::string emulate = "emulate --format " + name + " --rate 1000000 " + common +
                                  (c.scan_rate.empty() ? "" : " --scan-rate " + c.scan_rate) +
                                  " --out -";
      const auto e = run("--threads 2 " + emulate, "scene.bin");
      ASSERT_EQ(e.status, 0) << e.err;
      // The same bytes on one thread.
      ASSERT_EQ(run("--threads 1 " + emulate, "scene_1.bin").status, 0);
      ASSERT_EQ(read("scene.bin"), read("scene_1.bin"));
      ASSERT_EQ(run("stream --format " + name + " --in scene.bin --out live.csv").status, 0);
      const Table live = read_table(path("live.csv"));
      ASSERT_EQ(live.rows.size(), beams.rows.size());

      auto decoder = link::make_decoder(format);
      std::vector<link::Frame> decoded;
      for (std::size_t i = 0; i < expected.size(); ++i) {
        if (format == link::Format::kNative) {
          decoder->feed(link::encode_native({static_cast<std::uint32_t>(i), 0, expected[i]}),
                        decoded);
        } else {
          decoder->feed(link::encode_tfmini(link::tfmini_reading_from(expected[i])), decoded);
        }
      }
      ASSERT_EQ(decoded.size(), expected.size());
      for (std::size_t i = 0; i < live.rows.size(); ++i) {
        SCOPED_TRACE(i);
        ASSERT_EQ(std::stoull(live.rows[i][live.column("sequence")]), i);
        const auto& d = decoded[i].raw;
        ASSERT_TRUE(same(live.number(i, "tof_ns"), d.tof_ns));
        ASSERT_TRUE(same(live.number(i, "distance_raw_m"), d.distance_raw_m));
        ASSERT_TRUE(same(live.number(i, "pulse_width_ns"), d.pulse_width_ns));
        ASSERT_TRUE(same(live.number(i, "amplitude"), d.amplitude));
        ASSERT_TRUE(same(live.number(i, "temperature_c"), d.temperature_c));
        ASSERT_EQ(live.number(i, "shots_valid"), d.shots_valid);
        ASSERT_EQ(live.number(i, "flags"), d.flags);
        const auto& x = expected[i];
        if (format == link::Format::kNative) {
          // The native frame's resolution: 1 fs, 1 ps, 1 uV, 1/128 C.
          ASSERT_EQ(std::isnan(live.number(i, "tof_ns")), std::isnan(x.tof_ns));
          if (!std::isnan(x.tof_ns)) {
            ASSERT_NEAR(live.number(i, "tof_ns"), x.tof_ns, 0.5e-6 + 1e-12);
            ASSERT_NEAR(live.number(i, "pulse_width_ns"), x.pulse_width_ns, 0.5e-3 + 1e-12);
            ASSERT_NEAR(live.number(i, "amplitude"), x.amplitude, 0.5e-6 + 1e-12);
          }
          ASSERT_NEAR(live.number(i, "temperature_c"), x.temperature_c, 0.5 / 128 + 1e-12);
          ASSERT_EQ(live.number(i, "shots_valid"), x.shots_valid);
          ASSERT_EQ(live.number(i, "flags"), x.flags);
        } else if (x.has_echo()) {
          // TFmini: whole centimetres.
          ASSERT_NEAR(live.number(i, "distance_raw_m"), x.distance_raw_m, 0.005 + 1e-12);
        } else {
          ASSERT_TRUE(std::isnan(live.number(i, "distance_raw_m")));
        }
      }
    }
    fs::remove_all(dir_ / "scan");
  }
}

// A bad scene stops emulate before anything is written: no frame on stdout,
// no pty path printed; the message names the file, line and key. So do
// options that mix the scene with the plate grid, and a beam a frame cannot
// carry (shots x raster samples above the native frame's 16-bit field).
TEST_F(StreamCli, EmulatedBadSceneFailsWithAMessageAndNoOutput) {
  write("bad.toml",
        "[sensor]\npose_m = [0, 0, 0]\n[[surface]]\nkind = \"plane\"\ncenter_m = [0.5, 0, 0]\n"
        "normal = [-1, 0, 0]\nsize_m = [0.3, 0.2]\nreflectanse = 0.5\n");
  const std::string bad = "--scene bad.toml --pattern spherical --azimuth 0 --elevation 0";
  const std::string blocks = "--scene " + (kScenes / "blocks.toml").string();
  const struct {
    std::string args;
    std::vector<std::string> needles;
  } cases[] = {
      {bad + " --out -", {"bad.toml:8", "reflectanse"}},
      {bad, {"bad.toml:8", "reflectanse"}},  // a pty: its path is not printed either
      {bad + " --distance 1 --out -", {"--distance"}},
      {"--distance 1 --reflectance 0.5 --elevation 0 --out -", {"--elevation needs --scene"}},
      {blocks + " --out -", {"--scene needs --pattern"}},
      {blocks + " --pattern raster --y 0,0.1 --z 0 --samples 5000 --shots 20 --out -",
       {"beam 0", "shots_valid"}},
  };
  for (const auto& c : cases) {
    const auto r = run("emulate --format native --rate 1000 " + c.args);
    EXPECT_EQ(r.status, 1) << c.args;
    for (const auto& needle : c.needles) EXPECT_NE(r.err.find(needle), std::string::npos) << r.err;
    EXPECT_EQ(r.out, "") << c.args;
  }
}

TEST_F(StreamCli, TfminiCaptureFromStdinInAnyOrderOfArrival) {
  // A TFmini capture: three frames, one with a stray false header before it
  // and one reporting -1 (no echo: an empty distance, never a fake range).
  std::string bytes = "\x59\x59\x07";
  for (const link::TfminiReading r :
       {link::TfminiReading{123, 900, 2256}, link::TfminiReading{link::kTfminiLowSignal, 20, 2256},
        link::TfminiReading{4567, 150, 2264}}) {
    const auto f = link::encode_tfmini(r);
    bytes.append(f.begin(), f.end());
  }
  std::ofstream(dir_ / "tf.bin", std::ios::binary) << bytes;
  const std::string command = "cd '" + dir_.string() +
                              "' && '" TOFKIT_BINARY
                              "' stream --format tfmini --in - --out tf.csv <tf.bin 2>stderr.txt";
  ASSERT_EQ(std::system(command.c_str()), 0) << read("stderr.txt");
  const Table t = read_table(path("tf.csv"));
  ASSERT_EQ(t.rows.size(), 3u);
  EXPECT_DOUBLE_EQ(t.number(0, "distance_raw_m"), 1.23);
  EXPECT_DOUBLE_EQ(t.number(0, "amplitude"), 900);
  EXPECT_DOUBLE_EQ(t.number(0, "temperature_c"), 26);
  EXPECT_TRUE(std::isnan(t.number(1, "distance_raw_m")));
  EXPECT_EQ(t.number(1, "flags"), ranging::kRawNoEcho);
  EXPECT_EQ(t.number(1, "link_status"), link::kLinkLowSignal);
  EXPECT_DOUBLE_EQ(t.number(2, "distance_raw_m"), 45.67);
  // The rows read back as a raw CSV (truth columns empty).
  const auto records = io::read_raw_csv(path("tf.csv"));
  ASSERT_EQ(records.size(), 3u);
  EXPECT_TRUE(std::isnan(records[0].truth.distance_m));
}

TEST_F(StreamCli, BadInputFailsWithAMessageAndNoOutput) {
  auto r = run("stream --format native --in missing.bin --out out.csv");
  EXPECT_EQ(r.status, 1);
  EXPECT_NE(r.err.find("missing.bin"), std::string::npos);
  EXPECT_FALSE(fs::exists(dir_ / "out.csv"));

  std::ofstream(dir_ / "capture.bin") << "x";
  r = run("stream --format native --in capture.bin --baud 115200 --out out.csv");
  EXPECT_EQ(r.status, 1);
  EXPECT_NE(r.err.find("not a serial port"), std::string::npos);
  EXPECT_FALSE(fs::exists(dir_ / "out.csv"));

  r = run("stream --format native --in capture.bin --out capture.bin");
  EXPECT_EQ(r.status, 1);
  EXPECT_EQ(read("capture.bin"), "x");

  r = run("stream --format native --in capture.bin --model nope.json --out out.csv");
  EXPECT_EQ(r.status, 1);
  EXPECT_NE(r.err.find("nope.json"), std::string::npos);
  EXPECT_FALSE(fs::exists(dir_ / "out.csv"));

  r = run("emulate --format native --distance 1 --reflectance 0.5 --shots 70000 --out -");
  EXPECT_NE(r.status, 0);
}

}  // namespace
}  // namespace tofkit
