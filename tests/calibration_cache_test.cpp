// The factory calibration's cache (io/calibration_cache.hpp): keyed by the
// config, the seed and the build; an entry gives back exactly the model that
// was stored; a scan from the cache writes the bytes of one that made its
// calibration; a corrupt or unwritable cache never fails a scan.

#include "tofkit/io/calibration_cache.hpp"

#include <gtest/gtest.h>

#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "cli_runner.hpp"
#include "tofkit/device/virtual_rangefinder.hpp"
#include "tofkit/experiments/device_plan.hpp"
#include "tofkit/experiments/measurement_grid.hpp"
#include "tofkit/io/model_json.hpp"
#include "tofkit/ranging/uncertainty_budget.hpp"

namespace fs = std::filesystem;

using tofkit::test::ScopedEnv;

namespace {

fs::path fresh_dir(const std::string& name) {
  return tofkit::test::fresh_dir("tofkit_cache_", name);
}

std::map<std::string, std::string> files_of(const fs::path& dir) {
  std::map<std::string, std::string> files;
  for (const auto& e : fs::recursive_directory_iterator(dir)) {
    if (e.is_regular_file())
      files[fs::relative(e.path(), dir).string()] = tofkit::test::read_file(e.path());
  }
  return files;
}

// The factory calibration of the default device (model and budget), made once
// for the tests here.
const tofkit::io::FactoryCalibration& factory_made() {
  static const tofkit::io::FactoryCalibration made = [] {
    auto fit = tofkit::experiments::factory_calibration(tofkit::device::DeviceConfig{}, 1);
    return tofkit::io::FactoryCalibration{std::move(fit.pipeline), std::move(fit.budget)};
  }();
  return made;
}

}  // namespace

TEST(CalibrationCache, BuildIdIsTheOneReadelfReads) {
  // An independent reader of the same note: binutils' readelf on this test's
  // own executable (the calibration code is linked into it statically).
  // (By pid: /proc/self in the shell's child would be readelf itself.)
  FILE* pipe =
      ::popen(("readelf -n /proc/" + std::to_string(::getpid()) + "/exe 2>/dev/null").c_str(), "r");
  ASSERT_NE(pipe, nullptr);
  std::string text;
  char buffer[4096];
  while (const std::size_t n = std::fread(buffer, 1, sizeof buffer, pipe)) text.append(buffer, n);
  ::pclose(pipe);
  const std::size_t at = text.find("Build ID: ");
  if (at == std::string::npos) GTEST_SKIP() << "readelf not found or no build-id note";
  const std::string readelf_id = text.substr(at + 10, text.find('\n', at) - at - 10);
  EXPECT_EQ(tofkit::io::calibration_code_build_id(), readelf_id);
  EXPECT_GE(readelf_id.size(), 16u);
}

TEST(CalibrationCache, DirectoryFromTheEnvironment) {
  using tofkit::io::calibration_cache_directory;
  {
    ScopedEnv own("TOFKIT_CACHE_DIR", "/x/own"), xdg("XDG_CACHE_HOME", "/x/xdg"),
        home("HOME", "/x/home");
    EXPECT_EQ(calibration_cache_directory(), fs::path("/x/own"));
  }
  {
    ScopedEnv own("TOFKIT_CACHE_DIR", nullptr), xdg("XDG_CACHE_HOME", "/x/xdg"),
        home("HOME", "/x/home");
    EXPECT_EQ(calibration_cache_directory(), fs::path("/x/xdg/tofkit"));
  }
  {
    ScopedEnv own("TOFKIT_CACHE_DIR", ""), xdg("XDG_CACHE_HOME", nullptr), home("HOME", "/x/home");
    EXPECT_EQ(calibration_cache_directory(), fs::path("/x/home/.cache/tofkit"));
  }
  {
    ScopedEnv own("TOFKIT_CACHE_DIR", "off"), xdg("XDG_CACHE_HOME", "/x/xdg"),
        home("HOME", "/x/home");
    EXPECT_EQ(calibration_cache_directory(), std::nullopt);
  }
  {
    ScopedEnv own("TOFKIT_CACHE_DIR", nullptr), xdg("XDG_CACHE_HOME", nullptr),
        home("HOME", nullptr);
    EXPECT_EQ(calibration_cache_directory(), std::nullopt);
  }
}

TEST(CalibrationCache, KeyHoldsConfigSeedAndBuildButNotTheScanSection) {
  using namespace tofkit;
  std::string note;
  const device::DeviceConfig base;
  const auto entry = [&](const device::DeviceConfig& c, std::uint64_t seed) {
    const auto key = io::factory_calibration_key("/c", c, seed, note);
    EXPECT_TRUE(key) << note;
    EXPECT_EQ(key->build_id, io::calibration_code_build_id());
    return key->entry();
  };
  EXPECT_EQ(entry(base, 1).parent_path(), fs::path("/c"));
  EXPECT_EQ(entry(base, 1), entry(base, 1));
  EXPECT_NE(entry(base, 1), entry(base, 2));
  device::DeviceConfig brighter = base;
  brighter.link.laser.peak_power_w *= 2;
  EXPECT_NE(entry(base, 1), entry(brighter, 1));
  // What the calibration never reads shares the entry.
  device::DeviceConfig rays = base;
  rays.scan.rays_per_beam = 19;
  rays.scan.crease_angle_deg = 10;
  EXPECT_EQ(entry(base, 1), entry(rays, 1));
  EXPECT_EQ(io::calibration_config(rays).scan.rays_per_beam, device::ScanConfig{}.rays_per_beam);
}

TEST(CalibrationCache, AnEntryGivesBackExactlyTheStoredModel) {
  using namespace tofkit;
  const fs::path dir = fresh_dir("exact") / "made" / "here";  // made by the store
  std::string note;
  const auto key = io::factory_calibration_key(dir, device::DeviceConfig{}, 1, note);
  ASSERT_TRUE(key) << note;
  EXPECT_FALSE(io::load_factory_calibration(*key, note));
  EXPECT_EQ(note, "");  // absent: no note
  ASSERT_TRUE(io::store_factory_calibration(*key, factory_made(), note)) << note;
  const auto loaded = io::load_factory_calibration(*key, note);
  ASSERT_TRUE(loaded) << note;
  EXPECT_EQ(note, "");
  // No temporary left beside the entry.
  EXPECT_EQ(files_of(dir).size(), 1u);
  // The model JSON, and the ranges of measurements over the field (ranges,
  // reflectances, temperatures; out of domain too), to the bit.
  EXPECT_EQ(io::pipeline_to_json(loaded->pipeline).dump(),
            io::pipeline_to_json(factory_made().pipeline).dump());
  ASSERT_FALSE(factory_made().budget.empty());
  EXPECT_EQ(io::budget_to_json(loaded->budget).dump(),
            io::budget_to_json(factory_made().budget).dump());
  std::vector<experiments::PlannedMeasurement> plan;
  for (double d = 0.3; d < 12; d += 0.37)
    for (const double rho : {0.02, 0.1, 0.5, 0.9})
      for (const double t : {-10.0, 20.0, 45.0}) plan.push_back(experiments::plate(d, rho, t));
  const device::VirtualRangefinder device{device::DeviceConfig{}};
  const auto records = experiments::run(device, plan, 7);
  std::vector<ranging::RawMeasurement> raw;
  for (const auto& r : records) raw.push_back(r.raw);
  // Corrected, then sigma_m from the budget (another power-on), as a scan does.
  std::vector<ranging::Range> a(raw.size()), b(raw.size());
  const auto columns = ranging::RawColumns::of(raw);
  const double unknown = std::numeric_limits<double>::quiet_NaN();
  factory_made().pipeline.apply(raw, a);
  ranging::apply_budget(factory_made().budget, factory_made().pipeline, columns, {&unknown, 1}, a);
  loaded->pipeline.apply(raw, b);
  ranging::apply_budget(loaded->budget, loaded->pipeline, columns, {&unknown, 1}, b);
  std::size_t finite = 0;
  for (std::size_t i = 0; i < raw.size(); ++i) {
    EXPECT_EQ(std::memcmp(&a[i].distance_m, &b[i].distance_m, sizeof(double)), 0) << i;
    EXPECT_EQ(std::memcmp(&a[i].sigma_m, &b[i].sigma_m, sizeof(double)), 0) << i;
    EXPECT_EQ(a[i].correction_flags, b[i].correction_flags) << i;
    finite += std::isfinite(a[i].distance_m) ? 1 : 0;
  }
  EXPECT_GT(finite, raw.size() / 2);
  fs::remove_all(dir.parent_path().parent_path());
}

TEST(CalibrationCache, UnusableEntriesAndUnwritableCachesAreNotesNeverErrors) {
  using namespace tofkit;
  const fs::path dir = fresh_dir("bad");
  std::string note;
  const auto key = io::factory_calibration_key(dir, device::DeviceConfig{}, 1, note);
  ASSERT_TRUE(key) << note;
  ASSERT_TRUE(io::store_factory_calibration(*key, factory_made(), note)) << note;
  const std::string good = tofkit::test::read_file(key->entry());
  const auto refused = [&](const std::string& content, const std::string& why) {
    std::ofstream(key->entry(), std::ios::binary | std::ios::trunc) << content;
    note.clear();
    EXPECT_FALSE(io::load_factory_calibration(*key, note)) << why;
    EXPECT_NE(note.find(key->entry().string()), std::string::npos) << why << ": " << note;
    EXPECT_NE(note.find("made again"), std::string::npos) << why << ": " << note;
  };
  refused(good.substr(0, good.size() / 2), "truncated");
  refused("", "empty");
  refused("\x89PNG\r\n", "not JSON");
  refused("[1, 2]", "not an entry");
  // Another key in the file (a hash collision, a hand-copied entry).
  auto other = *key;
  other.seed = 2;
  ASSERT_TRUE(io::store_factory_calibration(other, factory_made(), note)) << note;
  refused(tofkit::test::read_file(other.entry()), "another key");
  // A model that does not read.
  std::string broken = good;
  broken.replace(broken.find("\"steps\""), 7, "\"stepz\"");
  refused(broken, "bad model");
  // A cache that cannot be written: its directory under a regular file (not
  // a permission, which root would ignore).
  std::ofstream(dir / "file") << "x";
  auto unwritable = *key;
  unwritable.directory = dir / "file" / "cache";
  note.clear();
  EXPECT_FALSE(io::store_factory_calibration(unwritable, factory_made(), note));
  EXPECT_NE(note.find("not cached"), std::string::npos) << note;
  EXPECT_FALSE(io::load_factory_calibration(unwritable, note));
  fs::remove_all(dir);
}

class CalibrationCacheCli : public tofkit::test::CliFixture {
 protected:
  CalibrationCacheCli() : CliFixture("tofkit_cache_cli_") {}

  // A small scan of the example blocks, every output, corrected by the factory
  // calibration: its outputs and its stderr.
  std::pair<std::map<std::string, std::string>, std::string> scan(const std::string& cache,
                                                                  const std::string& out) {
    ScopedEnv env("TOFKIT_CACHE_DIR", cache.c_str());
    const auto r = run("--set scan.rays_per_beam=4 scan --scene '" + kScene +
                       "' --pattern spherical --azimuth=-15:15:1.5 --elevation=-10:10:1.5 "
                       "--shots 3 --out " +
                       out);
    EXPECT_EQ(r.status, 0) << r.err;
    return {files_of(dir_ / out), read("stderr.txt")};
  }
  const std::string kScene =
      (fs::path(TOFKIT_REFERENCE_DIR).parent_path() / "examples" / "scenes" / "blocks.toml")
          .string();
};

TEST_F(CalibrationCacheCli, AScanFromTheCacheWritesTheBytesOfOneThatCalibrated) {
  const std::string cache = path("cache");
  const auto [made, made_err] = scan(cache, "made");
  EXPECT_NE(made_err.find("seed 1; made now and cached)"), std::string::npos) << made_err;
  ASSERT_EQ(files_of(cache).size(), 1u);
  const fs::path entry = fs::directory_iterator(cache)->path();
  const auto [hit, hit_err] = scan(cache, "hit");
  EXPECT_NE(hit_err.find("seed 1; from the cache)"), std::string::npos) << hit_err;
  const auto [off, off_err] = scan("off", "off");
  EXPECT_NE(off_err.find("seed 1; made now; cache off)"), std::string::npos) << off_err;
  EXPECT_GE(made.size(), 14u);
  EXPECT_TRUE(made == hit) << "a scan from the cache differs from one that made its calibration";
  EXPECT_TRUE(made == off) << "a scan with the cache off differs";

  // A corrupt entry: a note, the calibration made again (same bytes), the
  // entry written again whole.
  const std::string good = tofkit::test::read_file(entry);
  std::ofstream(entry, std::ios::binary | std::ios::trunc) << good.substr(0, 100);
  const auto [again, again_err] = scan(cache, "again");
  EXPECT_NE(again_err.find("unusable"), std::string::npos) << again_err;
  EXPECT_NE(again_err.find("made now and cached"), std::string::npos) << again_err;
  EXPECT_TRUE(made == again);
  EXPECT_EQ(tofkit::test::read_file(entry), good);

  // A cache that cannot be written: the scan succeeds, says so, same bytes.
  write("not_a_dir", "x");
  const auto [ro, ro_err] = scan(path("not_a_dir") + "/cache", "ro");
  EXPECT_NE(ro_err.find("not cached"), std::string::npos) << ro_err;
  EXPECT_TRUE(made == ro);
}
