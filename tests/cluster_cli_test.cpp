// Shards, merge and sweep end to end: a scan split into shards and merged is
// the one-process scan byte for byte (every output format); a sweep's row
// holds the statistics of `tofkit measure` at the same settings and the
// figures of `tofkit budget`; sweep shards merge into the one-process table;
// an interrupted sweep resumes from its finished points; bad plans name the
// line and write nothing.

#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "cli_runner.hpp"
#include "tofkit/experiments/device_plan.hpp"
#include "tofkit/io/model_json.hpp"

namespace fs = std::filesystem;

namespace {

const fs::path kScenes = fs::path(TOFKIT_REFERENCE_DIR).parent_path() / "examples" / "scenes";

class Cluster : public tofkit::test::CliFixture {
 protected:
  Cluster() : CliFixture("tofkit_cluster_cli_") {}

  // Every file of `a` equals `b`'s, and `b` has no other file.
  void expect_same_files(const std::string& a, const std::string& b, std::size_t files) {
    std::size_t n = 0;
    for (const auto& e : fs::directory_iterator(dir_ / a)) {
      ++n;
      EXPECT_EQ(read(a + "/" + e.path().filename().string()),
                read(b + "/" + e.path().filename().string()))
          << e.path().filename();
    }
    std::size_t m = 0;
    for ([[maybe_unused]] const auto& e : fs::directory_iterator(dir_ / b)) ++m;
    EXPECT_EQ(n, files);
    EXPECT_EQ(m, files);
  }
};

std::vector<std::vector<std::string>> csv_rows(const std::string& text) {
  std::vector<std::vector<std::string>> rows;
  std::istringstream in(text);
  for (std::string line; std::getline(in, line);) {
    std::vector<std::string> cells;
    std::istringstream l(line);
    for (std::string cell; std::getline(l, cell, ',');) cells.push_back(cell);
    if (!line.empty() && line.back() == ',') cells.emplace_back();
    rows.push_back(cells);
  }
  return rows;
}

const char* kIssuePlan = R"([axes]
"laser.pulse_width_ns" = [1.0, 2.0, 4.0]
"receiver.bandwidth_mhz" = [80.0, 150.0]
distance_m = [1.0, 4.0]
reflectance = [0.1, 0.9]
[measure]
shots = 1000
count = 3
[budget]
)";

}  // namespace

TEST_F(Cluster, ScanShardsMergeIntoTheOneProcessBytesForEveryOutput) {
  // A line scan (pixels averaged from several samples, across shard edges)
  // with a model (sigma plane), and a two-revolution spinning scan of raw ranges.
  ASSERT_EQ(run("measure --distance 0.5:8:0.5 --reflectance 0.05,0.2,0.5,0.9 --out raw.csv").status,
            0);
  ASSERT_EQ(run("fit --in raw.csv --out model.json --chain offset,grayvalue").status, 0);
  const std::string scans[] = {
      "scan --scene " + (kScenes / "grey_stripes.toml").string() +
          " --pattern line --y=-0.3:0.3:0.01 --z=-0.05:0.05:0.02 --speed 2 --shots 50 --model "
          "model.json",
      "--set scan.rays_per_beam=5 scan --scene " + (kScenes / "blocks.toml").string() +
          " --pattern spinning --elevation=-15:15:3 --azimuth-step 2 --revolutions 2 --shots 3 "
          "--raw"};
  for (const auto& scan : scans) {
    fs::remove_all(dir_ / "one");
    fs::remove_all(dir_ / "merged");
    fs::create_directories(dir_ / "one");
    ASSERT_EQ(run("--threads 2 " + scan + " --out one").status, 0) << read("stderr.txt");
    std::string shards;
    for (int k = 0; k < 3; ++k) {
      const std::string d = "s" + std::to_string(k);
      fs::remove_all(dir_ / d);
      fs::create_directories(dir_ / d);
      ASSERT_EQ(
          run("--threads 1 " + scan + " --shard " + std::to_string(k) + "/3 --out " + d).status, 0)
          << read("stderr.txt");
      EXPECT_TRUE(fs::exists(dir_ / d / "shard.json"));
      shards = " " + d + shards;  // in reverse: the merge orders them
    }
    ASSERT_EQ(run("merge --out merged" + shards).status, 0) << read("stderr.txt");
    const bool model = scan.find("--raw") == std::string::npos;  // else the factory calibration
    // csv, range/intensity(/sigma) x (png, json, npy), ply, pcd, las, view
    expect_same_files("one", "merged", model ? 14u : 11u);
  }
}

TEST_F(Cluster, ScanCorrectsBlocksMeasuredWhileItsFactoryCalibrationRunsAsItsModel) {
  // The factory calibration runs beside the scan: 191 k beams (6 blocks) are
  // measured in the time it takes, so blocks are held raw (up to 4), then the
  // scan waits for it; every beam must come out as with the same model given.
  // (Made, not read from the calibration cache.)
  const tofkit::test::ScopedEnv no_cache("TOFKIT_CACHE_DIR", "off");
  const tofkit::device::DeviceConfig config;
  const auto factory = tofkit::experiments::factory_calibration(config);
  tofkit::io::save_pipeline(dir_ / "factory.json", factory.pipeline, nullptr, &factory.budget);
  const std::string scan = "--threads 2 --max-rows 1000000 scan --scene " +
                           (kScenes / "blocks.toml").string() +
                           " --pattern spherical --azimuth=-40:40:0.18 --elevation=-30:30:0.14 "
                           "--shots 1 --write las,npy,csv";
  fs::create_directories(dir_ / "beside");
  fs::create_directories(dir_ / "given");
  ASSERT_EQ(run(scan + " --out beside").status, 0) << read("stderr.txt");
  ASSERT_EQ(run(scan + " --model factory.json --out given").status, 0) << read("stderr.txt");
  EXPECT_GT(read("given/scan.csv").size(), 190000u * 50);
  // (Compared as a whole: a diff of the MB-long files would flood the log.)
  for (const char* f : {"scan.csv", "points.las", "range.npy", "intensity.npy", "sigma.npy"}) {
    EXPECT_TRUE(read(std::string("beside/") + f) == read(std::string("given/") + f)) << f;
  }
}

TEST_F(Cluster, MergeRefusesMissingDoubledOrForeignShardsWritingNothing) {
  const std::string scan = "scan --scene " + (kScenes / "blocks.toml").string() +
                           " --pattern spherical --azimuth=-10:10:1 --elevation=-5:5:1 --shots 1";
  for (const char* d : {"a0", "a1", "b1"}) fs::create_directories(dir_ / d);
  ASSERT_EQ(run(scan + " --shard 0/2 --out a0").status, 0);
  ASSERT_EQ(run(scan + " --shard 1/2 --out a1").status, 0);
  ASSERT_EQ(run(scan + " --seed 9 --shard 1/2 --out b1").status, 0);
  const std::pair<std::string, std::string> cases[] = {
      {"a0", "shard 1/2 is missing"},
      {"a0 a1 a1", "given twice"},
      {"a0 b1", "another scan"},
  };
  for (const auto& [dirs, message] : cases) {
    const auto r = run("merge --out m " + dirs);
    EXPECT_EQ(r.status, 1) << dirs;
    EXPECT_NE(r.err.find(message), std::string::npos) << r.err;
    EXPECT_FALSE(fs::exists(dir_ / "m")) << dirs;
  }
  EXPECT_EQ(run(scan + " --shard 2/2 --out a0").status, 1);
  EXPECT_NE(read("stderr.txt").find("--shard: '2/2' is not K/N"), std::string::npos);
  // A damaged shard (cut short) is refused by name.
  fs::resize_file(dir_ / "a1" / "beams.bin", fs::file_size(dir_ / "a1" / "beams.bin") - 8);
  const auto r = run("merge --out m a0 a1");
  EXPECT_EQ(r.status, 1);
  EXPECT_NE(r.err.find("beams.bin has the wrong size"), std::string::npos) << r.err;
}

TEST_F(Cluster, SweepRowsHoldMeasureStatisticsAndBudgetFigures) {
  write("sweep.toml", kIssuePlan);
  ASSERT_EQ(run("sweep --plan sweep.toml --out sw").status, 0) << read("stderr.txt");
  const auto rows = csv_rows(read("sw/sweep.csv"));
  ASSERT_EQ(rows.size(), 1u + 24u);
  const auto& h = rows[0];
  ASSERT_EQ(h[0], "laser.pulse_width_ns");
  ASSERT_EQ(h[3], "reflectance");
  auto col = [&](const std::string& name) {
    return static_cast<std::size_t>(std::find(h.begin(), h.end(), name) - h.begin());
  };
  EXPECT_TRUE(fs::exists(dir_ / "sw" / "sweep_bias_m.gp"));
  // Two points checked against the other commands at the same settings.
  for (const std::size_t point : {std::size_t{6}, std::size_t{21}}) {
    const auto& row = rows[1 + point];
    const std::string sets =
        "--set laser.pulse_width_ns=" + row[0] + " --set receiver.bandwidth_mhz=" + row[1];
    ASSERT_EQ(run(sets + " measure --distance " + row[2] + " --reflectance " + row[3] +
                  " --shots 1000 --count 3 --out m.csv")
                  .status,
              0);
    const auto m = csv_rows(read("m.csv"));
    ASSERT_EQ(m.size(), 4u);
    const auto mc = static_cast<std::size_t>(std::find(m[0].begin(), m[0].end(), "distance_raw_m") -
                                             m[0].begin());
    double sum = 0, sum2 = 0;
    for (int k = 1; k <= 3; ++k) sum += std::stod(m[k][mc]);
    const double mean = sum / 3;
    for (int k = 1; k <= 3; ++k) sum2 += std::pow(std::stod(m[k][mc]) - mean, 2);
    EXPECT_NEAR(std::stod(row[col("distance_raw_mean_m")]), mean, 1e-12);
    EXPECT_NEAR(std::stod(row[col("distance_raw_std_m")]), std::sqrt(sum2 / 2), 1e-9);
    EXPECT_NEAR(std::stod(row[col("bias_m")]), mean - std::stod(row[2]), 1e-12);
    ASSERT_EQ(run(sets + " budget --json --reflectance " + row[3], "b.json").status, 0);
    const auto b = nlohmann::json::parse(read("b.json"));
    EXPECT_NEAR(std::stod(row[col("range_at_snr10_m")]), b["range_at_snr10_m"].get<double>(), 1e-9);
    for (const auto& r : b["rows"]) {
      if (r["distance_m"].get<double>() == std::stod(row[2])) {
        EXPECT_NEAR(std::stod(row[col("snr")]) / r["snr"].get<double>(), 1.0, 1e-12);
        EXPECT_NEAR(std::stod(row[col("received_power_w")]) / r["received_power_w"].get<double>(),
                    1.0, 1e-12);
      }
    }
  }
}

TEST_F(Cluster, SweepShardsMergeAndAnInterruptedSweepResumes) {
  write("sweep.toml", kIssuePlan);
  ASSERT_EQ(run("sweep --plan sweep.toml --out full").status, 0);
  ASSERT_EQ(run("sweep --plan sweep.toml --shard 1/3 --out s1").status, 0);
  ASSERT_EQ(run("sweep --plan sweep.toml --shard 0/3 --out s0").status, 0);
  ASSERT_EQ(run("sweep --plan sweep.toml --shard 2/3 --out s2").status, 0);
  ASSERT_EQ(run("merge --out merged s2 s0 s1").status, 0) << read("stderr.txt");
  EXPECT_EQ(read("merged/sweep.csv"), read("full/sweep.csv"));
  EXPECT_TRUE(fs::exists(dir_ / "merged" / "sweep_snr.gp"));

  // 300 points; interrupted (SIGINT) once the journal holds some, then rerun.
  write("long.toml", R"([axes]
"laser.pulse_width_ns" = [1.0, 1.5, 2.0, 2.5, 3.0, 3.5, 4.0, 4.5, 5.0, 5.5]
"receiver.bandwidth_mhz" = [60.0, 80.0, 100.0, 120.0, 140.0]
"discriminator.threshold_v" = [0.02, 0.03, 0.04, 0.05, 0.06, 0.07]
[measure]
shots = 200
distance_m = 2.0
reflectance = 0.5
)");
  ASSERT_EQ(run("--threads 1 sweep --plan long.toml --out once").status, 0);
  const pid_t child = ::fork();
  if (child == 0) {
    ::chdir(dir_.c_str());
    ::execl(TOFKIT_BINARY, TOFKIT_BINARY, "--threads", "1", "sweep", "--plan", "long.toml", "--out",
            "resumed", static_cast<char*>(nullptr));
    ::_exit(127);
  }
  const auto journal = dir_ / "resumed" / ".sweep.journal";
  for (int i = 0; i < 3000; ++i) {  // until two batches are in
    const std::string text = fs::exists(journal) ? read("resumed/.sweep.journal") : "";
    if (std::count(text.begin(), text.end(), '\n') > 40) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  ::kill(child, SIGINT);
  int status = 0;
  ::waitpid(child, &status, 0);
  ASSERT_TRUE(WIFSIGNALED(status)) << "the sweep finished before it was interrupted";
  EXPECT_FALSE(fs::exists(dir_ / "resumed" / "sweep.csv"));
  const auto r = run("--threads 1 sweep --plan long.toml --out resumed");
  ASSERT_EQ(r.status, 0);
  const auto at = r.err.find(" resumed)");
  ASSERT_NE(at, std::string::npos) << r.err;
  const auto open = r.err.rfind('(', at);  // "... of 300 points (N resumed)"
  const int resumed = std::stoi(r.err.substr(open + 1, at - open - 1));
  EXPECT_GT(resumed, 0) << r.err;
  EXPECT_LT(resumed, 300) << r.err;
  EXPECT_EQ(read("resumed/sweep.csv"), read("once/sweep.csv"));
  EXPECT_FALSE(fs::exists(journal));
  // A journal of another plan is refused, not mixed in.
  write("other.toml", kIssuePlan);
  fs::create_directories(dir_ / "mixed");
  write("mixed/.sweep.journal", "# tofkit sweep journal 1 0000000000000000 0 24\n0\tx\n");
  const auto mixed = run("sweep --plan other.toml --out mixed");
  EXPECT_EQ(mixed.status, 1);
  EXPECT_NE(mixed.err.find("left by another plan"), std::string::npos) << mixed.err;
}

// A plan's [characterize] runs a `tofkit characterize` experiment at every
// point: its findings' columns hold what the characterize command itself
// reports (its JSON) for the point's device and seed.
TEST_F(Cluster, SweepRowsHoldACharacterizeExperimentsFindings) {
  write("plan.toml",
        "[axes]\n\"laser.peak_power_w\" = [5.0, 20.0]\n\"receiver.bandwidth_mhz\" = [80.0, "
        "150.0]\n[characterize]\nexperiment = \"sampling\"\n");
  ASSERT_EQ(run("--preset paper sweep --plan plan.toml --out sw").status, 0) << read("stderr.txt");
  const auto rows = csv_rows(read("sw/sweep.csv"));
  ASSERT_EQ(rows.size(), 1u + 4u);
  const auto& h = rows[0];
  ASSERT_GT(h.size(), 3u);
  for (const std::size_t point : {std::size_t{1}, std::size_t{2}}) {
    const auto& row = rows[1 + point];
    ASSERT_EQ(run("--preset paper --set laser.peak_power_w=" + row[0] +
                  " --set receiver.bandwidth_mhz=" + row[1] + " characterize sampling --out c")
                  .status,
              0);
    const auto findings = nlohmann::json::parse(read("c/sampling.json"))["findings"];
    ASSERT_EQ(findings.size(), h.size() - 2);
    for (std::size_t k = 2; k < h.size(); ++k) {
      ASSERT_EQ(h[k].rfind("sampling.", 0), 0u) << h[k];
      const std::string name = h[k].substr(9);
      ASSERT_TRUE(findings.contains(name)) << name;
      EXPECT_EQ(std::stod(row[k]), findings[name].get<double>()) << name << ", point " << point;
    }
  }
  // Over the peak power, the sampled spread falls (a stronger echo, less jitter).
  const auto col = static_cast<std::size_t>(
      std::find(h.begin(), h.end(), "sampling.sd_mm_at_8_shots") - h.begin());
  ASSERT_LT(col, h.size());
  EXPECT_LT(std::stod(rows[3][col]), std::stod(rows[1][col]));
  EXPECT_TRUE(fs::exists(dir_ / "sw" / "sweep_sampling.sd_mm_at_8_shots.gp"));
}

TEST_F(Cluster, BadSweepPlansNameTheLineAndWriteNothing) {
  const std::pair<std::string, std::string> cases[] = {
      {"[axes]\n\"laser.pulse_widht_ns\" = [1.0]\ndistance_m=[1]\nreflectance=[0.5]\n[measure]\n",
       "plan.toml:2: axis 'laser.pulse_widht_ns'"},
      {"[axes]\ndistance_m = [1.0, -2]\nreflectance=[0.5]\n[measure]\n",
       "plan.toml:2: axis 'distance_m': -2 must be"},
      {"[axes]\ndistance_m = [1.0]\nreflectance=[0.5]\n[measure]\nshots = 0\n",
       "plan.toml:5: [measure] shots"},
      {"[axes]\ndistance_m = [1.0]\n[mesure]\n", "plan.toml:3: unknown key 'mesure'"},
      {"[axes]\ndistance_m = [1.0]\n[measure]\n", "reflectance is neither an axis"},
      {"[axes]\ndistance_m = [1.0\n", "plan.toml:2:"},
      {"[axes]\ndistance_m = [1.0]\n[characterize]\nexperiment = \"samplng\"\n",
       "plan.toml:4: [characterize] experiment: unknown experiment 'samplng' (known: "},
      {"[axes]\ndistance_m = [1.0]\n[characterize]\nexperimnt = \"sampling\"\n",
       "plan.toml:4: [characterize] experimnt: unknown key"},
  };
  for (const auto& [plan, message] : cases) {
    write("plan.toml", plan);
    const auto r = run("sweep --plan plan.toml --out out");
    EXPECT_EQ(r.status, 1) << plan;
    EXPECT_NE(r.err.find(message), std::string::npos) << r.err;
    EXPECT_FALSE(fs::exists(dir_ / "out")) << plan;
  }
}

TEST_F(Cluster, MpirunGivesTheOneProcessBytesAndAFailedRankLeavesNothing) {
#if !defined(TOFKIT_TEST_MPI)
  GTEST_SKIP() << "tofkit was built without MPI (scripts/setup installs libopenmpi-dev)";
#else
  if (std::system("command -v mpirun >/dev/null 2>&1") != 0)
    GTEST_SKIP() << "mpirun is missing (scripts/setup installs openmpi-bin)";
  // Under ASan, LeakSanitizer reports Open MPI's own allocations at exit
  // (libmpi frees them only at unload) and fails the ranks: leak checks off there.
  const std::string mpirun =
      std::string("mpirun --allow-run-as-root --oversubscribe -np 2 ") +
      (std::getenv("TOFKIT_SANITIZED") != nullptr ? "-x ASAN_OPTIONS=detect_leaks=0 " : "");
  // A scan of 3 chunks (80 k beams) with a model, and the issue's sweep.
  ASSERT_EQ(run("measure --distance 0.5:8:0.5 --reflectance 0.05,0.2,0.5,0.9 --out raw.csv").status,
            0);
  ASSERT_EQ(run("fit --in raw.csv --out model.json --chain offset,grayvalue").status, 0);
  const std::string scan = "scan --scene " + (kScenes / "blocks.toml").string() +
                           " --pattern spherical --azimuth=-40:40:0.2 --elevation=-15:25:0.2 "
                           "--shots 2 --model model.json";
  fs::create_directories(dir_ / "one");
  fs::create_directories(dir_ / "two");
  ASSERT_EQ(run("--threads 2 " + scan + " --out one").status, 0) << read("stderr.txt");
  const std::string command = "cd '" + dir_.string() + "' && " + mpirun + TOFKIT_BINARY +
                              " --threads 1 " + scan + " --out two >/dev/null 2>mpi.txt";
  ASSERT_EQ(std::system(command.c_str()), 0) << read("mpi.txt");
  expect_same_files("one", "two", 14u);
  {
    // The factory calibration (no --model), made (not cached): one process
    // corrects with it as it comes from the fit, beside its scan; under
    // mpirun rank 0 makes it first and sends it as JSON, and each rank
    // corrects the beams it measures (5 chunks): the same bytes, sigma too.
    const tofkit::test::ScopedEnv no_cache("TOFKIT_CACHE_DIR", "off");
    const std::string factory = "scan --scene " + (kScenes / "blocks.toml").string() +
                                " --pattern spherical --azimuth=-40:40:0.3 --elevation=-15:25:0.3 "
                                "--shots 1 --write csv,npy,las";
    fs::create_directories(dir_ / "fone");
    fs::create_directories(dir_ / "ftwo");
    ASSERT_EQ(run("--threads 2 " + factory + " --out fone").status, 0) << read("stderr.txt");
    const std::string f2 = "cd '" + dir_.string() + "' && " + mpirun + TOFKIT_BINARY +
                           " --threads 1 " + factory + " --out ftwo >/dev/null 2>mpi.txt";
    ASSERT_EQ(std::system(f2.c_str()), 0) << read("mpi.txt");
    EXPECT_NE(read("fone/scan.csv").find("sigma_m"), std::string::npos);
    // (Compared as a whole: a diff of the long files would flood the log.)
    for (const char* f : {"scan.csv", "points.las", "range.npy", "intensity.npy", "sigma.npy"})
      EXPECT_TRUE(read(std::string("fone/") + f) == read(std::string("ftwo/") + f)) << f;
  }
  write("sweep.toml", kIssuePlan);
  ASSERT_EQ(run("sweep --plan sweep.toml --out sw1").status, 0);
  const std::string sweep = "cd '" + dir_.string() + "' && " + mpirun + TOFKIT_BINARY +
                            " --threads 1 sweep --plan sweep.toml --out sw2 >/dev/null 2>mpi.txt";
  ASSERT_EQ(std::system(sweep.c_str()), 0) << read("mpi.txt");
  EXPECT_EQ(read("sw2/sweep.csv"), read("sw1/sweep.csv"));
  // Rank 1 fails (its scene is missing): the job ends with an error, no file.
  write("rank.sh", "#!/bin/sh\nscene=" + (kScenes / "blocks.toml").string() +
                       "\n[ \"$OMPI_COMM_WORLD_RANK\" = 1 ] && scene=/nonexistent.toml\nexec " +
                       TOFKIT_BINARY + " --threads 1 " +
                       "scan --scene $scene --pattern spherical --azimuth=-40:40:0.1 "
                       "--elevation=-15:25:0.1 --shots 2 --out failed\n");
  fs::create_directories(dir_ / "failed");
  const std::string failing = "cd '" + dir_.string() + "' && chmod +x rank.sh && " + mpirun +
                              "./rank.sh >/dev/null 2>mpi.txt";
  EXPECT_NE(std::system(failing.c_str()), 0);
  EXPECT_TRUE(fs::is_empty(dir_ / "failed")) << "a failed rank left files";
#endif
}
