// Configuration files, overrides and dumps; raw and corrected CSV tables;
// all-or-nothing output files; command-line value lists.
#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <bit>
#include <cmath>
#include <csignal>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <sstream>
#include <stdexcept>
#include <string>
#include <type_traits>
#include <vector>

#include "tofkit/device/config_limits.hpp"
#include "tofkit/device/device_config.hpp"
#include "tofkit/io/atomic_file.hpp"
#include "tofkit/io/config_file.hpp"
#include "tofkit/io/input_file.hpp"
#include "tofkit/io/raw_csv.hpp"
#include "tofkit/io/value_list.hpp"

using namespace tofkit;
namespace fs = std::filesystem;

namespace {

// A fresh directory per test, removed afterwards.
class TempDir {
 public:
  TempDir() {
    static std::atomic<int> counter{0};
    path_ = fs::temp_directory_path() /
            ("tofkit_io_test_" + std::to_string(::getpid()) + "_" + std::to_string(counter++));
    fs::create_directories(path_);
  }
  ~TempDir() {
    std::error_code ec;
    fs::remove_all(path_, ec);
  }
  TempDir(const TempDir&) = delete;
  TempDir& operator=(const TempDir&) = delete;
  [[nodiscard]] fs::path operator/(const std::string& name) const { return path_ / name; }
  [[nodiscard]] const fs::path& path() const { return path_; }

 private:
  fs::path path_;
};

void write_text(const fs::path& path, const std::string& text) {
  std::ofstream out(path, std::ios::binary);
  out << text;
}

std::string read_text(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

// The message of the ConfigError thrown by loading `text` as dev.toml.
std::string config_error(const TempDir& dir, const std::string& text,
                         const std::vector<std::string>& overrides = {}) {
  const fs::path file = dir / "dev.toml";
  write_text(file, text);
  try {
    (void)io::load_device_config("", file, overrides);
  } catch (const io::ConfigError& e) {
    return e.what();
  }
  ADD_FAILURE() << "no ConfigError for:\n" << text;
  return {};
}

bool same_bits(double a, double b) {
  if (std::isnan(a) || std::isnan(b)) return std::isnan(a) && std::isnan(b);
  return std::bit_cast<std::uint64_t>(a) == std::bit_cast<std::uint64_t>(b);
}

// Every field of two configs holds bit-identical values.
void expect_same_config(const device::DeviceConfig& a, const device::DeviceConfig& b) {
  EXPECT_EQ(a.name, b.name);
  auto ca = a;
  auto cb = b;
  const auto fa = device::config_fields(ca);
  const auto fb = device::config_fields(cb);
  ASSERT_EQ(fa.size(), fb.size());
  for (std::size_t i = 0; i < fa.size(); ++i) {
    EXPECT_TRUE(same_bits(device::field_value(fa[i]), device::field_value(fb[i])))
        << fa[i].key << ": " << device::field_value(fa[i]) << " vs " << device::field_value(fb[i]);
  }
}

}  // namespace

// ---------------------------------------------------------------------------
// The key registry

// Oracle: the bytes of each section struct. Every member must be bound to a
// key, so the bytes no key covers can only be alignment padding (< 8 bytes).
TEST(DeviceConfig, FieldsCoverEveryMemberOfEverySection) {
  device::DeviceConfig config;
  const auto fields = device::config_fields(config);
  struct Section {
    const char* name;
    const void* begin;
    std::size_t size;
  };
  const Section sections[] = {
      {"laser", &config.link.laser, sizeof config.link.laser},
      {"receiver", &config.link.receiver, sizeof config.link.receiver},
      {"environment", &config.link.environment, sizeof config.link.environment},
      {"discriminator", &config.discriminator, sizeof config.discriminator},
      {"tdc", &config.tdc, sizeof config.tdc},
      {"thermal", &config.thermal, sizeof config.thermal},
      {"measurement", &config.measurement, sizeof config.measurement},
  };
  for (const auto& section : sections) {
    std::vector<bool> covered(section.size, false);
    const auto* base = static_cast<const unsigned char*>(section.begin);
    for (const auto& f : fields) {
      std::visit(
          [&](auto* p) {
            const auto* bytes = reinterpret_cast<const unsigned char*>(p);
            if (bytes < base || bytes >= base + section.size) return;
            EXPECT_EQ(f.key.rfind(std::string(section.name) + ".", 0), 0u)
                << f.key << " is bound to a member of " << section.name;
            for (std::size_t i = 0; i < sizeof(*p); ++i) {
              const auto offset = static_cast<std::size_t>(bytes - base) + i;
              EXPECT_FALSE(covered[offset]) << f.key << " overlaps another key";
              covered[offset] = true;
            }
          },
          f.value);
    }
    std::size_t uncovered = 0;
    for (const bool c : covered) uncovered += c ? 0 : 1;
    EXPECT_LT(uncovered, 8u) << "a member of [" << section.name << "] has no key";
  }
}

TEST(DeviceConfig, KeysAreUniqueWithSaneRangesAndDescriptions) {
  device::DeviceConfig config;
  const auto fields = device::config_fields(config);
  std::vector<std::string> keys;
  for (const auto& f : fields) {
    EXPECT_EQ(std::count(keys.begin(), keys.end(), f.key), 0) << f.key;
    keys.push_back(f.key);
    EXPECT_LT(f.min, f.max) << f.key;
    EXPECT_FALSE(f.description.empty()) << f.key;
  }
  // The stable interface of DESIGN.md.
  for (const char* key :
       {"laser.wavelength_nm", "laser.peak_power_w", "laser.pulse_width_ns", "laser.repetition_hz",
        "receiver.aperture_diameter_mm", "receiver.bandwidth_mhz", "receiver.apd_gain",
        "receiver.excess_noise_factor", "receiver.responsivity_a_per_w",
        "discriminator.threshold_v", "tdc.lsb_ps", "thermal.delay_tempco_ps_per_c",
        "receiver.bias_tracking_error_v_per_c", "tdc.laser_sync", "tdc.bin_tempco_ppm_per_c",
        "measurement.shots"}) {
    EXPECT_EQ(std::count(keys.begin(), keys.end(), key), 1) << key;
  }
}

TEST(DeviceConfig, PresetsAreValidAndDistinct) {
  for (const auto& name : device::preset_names()) {
    const auto config = device::preset(name);
    EXPECT_EQ(config.name, name);
    EXPECT_TRUE(device::validate(config).empty()) << name << ": " << device::validate(config)[0];
  }
  const auto paper = device::preset("paper");
  const auto accurange = device::preset("accurange");
  EXPECT_EQ(paper.link.laser.wavelength_nm, device::DeviceConfig{}.link.laser.wavelength_nm);
  EXPECT_EQ(accurange.link.laser.wavelength_nm, 780.0);
  EXPECT_EQ(accurange.link.laser.peak_power_w, 0.02);
  EXPECT_NEAR(accurange.link.receiver.aperture_diameter_mm, 2.5 * 25.4, 1e-9);
  try {
    (void)device::preset("nope");
    FAIL() << "no exception";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("accurange"), std::string::npos) << e.what();
  }
}

TEST(DeviceConfig, ValidateGivesOneMessagePerBadKey) {
  device::DeviceConfig config;
  config.link.laser.peak_power_w = -1;
  config.link.receiver.bandwidth_mhz = 0;
  config.measurement.shots = 0;
  config.link.receiver.optics_efficiency = std::numeric_limits<double>::quiet_NaN();
  const auto messages = device::validate(config);
  ASSERT_EQ(messages.size(), 4u);
  for (const char* key : {"laser.peak_power_w", "receiver.bandwidth_mhz", "measurement.shots",
                          "receiver.optics_efficiency"}) {
    EXPECT_EQ(std::count_if(messages.begin(), messages.end(),
                            [&](const std::string& m) { return m.rfind(key, 0) == 0; }),
              1)
        << key;
  }
}

// ---------------------------------------------------------------------------
// Configuration files

TEST(ConfigFile, UnknownKeyNamesFileLineKeyAndSuggestion) {
  TempDir dir;
  const auto msg = config_error(dir, "# device\n[receiver]\nbandwith_mhz = 100\n");
  EXPECT_NE(msg.find("dev.toml:3"), std::string::npos) << msg;
  EXPECT_NE(msg.find("receiver.bandwith_mhz"), std::string::npos) << msg;
  EXPECT_NE(msg.find("did you mean receiver.bandwidth_mhz"), std::string::npos) << msg;
}

TEST(ConfigFile, UnknownSectionAndTopLevelKey) {
  TempDir dir;
  auto msg = config_error(dir, "[reciever]\nbandwidth_mhz = 100\n");
  EXPECT_NE(msg.find("dev.toml:1"), std::string::npos) << msg;
  EXPECT_NE(msg.find("reciever"), std::string::npos) << msg;
  EXPECT_NE(msg.find("did you mean receiver"), std::string::npos) << msg;
  msg = config_error(dir, "shots = 10\n");
  EXPECT_NE(msg.find("dev.toml:1"), std::string::npos) << msg;
  EXPECT_NE(msg.find("measurement.shots"), std::string::npos) << msg;  // suggestion
}

TEST(ConfigFile, WrongTypeNamesKeyAndFile) {
  TempDir dir;
  auto msg = config_error(dir, "[laser]\nwavelength_nm = 905\npeak_power_w = \"high\"\n");
  EXPECT_NE(msg.find("dev.toml:3"), std::string::npos) << msg;
  EXPECT_NE(msg.find("laser.peak_power_w"), std::string::npos) << msg;
  EXPECT_NE(msg.find("string"), std::string::npos) << msg;
  msg = config_error(dir, "[measurement]\nshots = 2.5\n");
  EXPECT_NE(msg.find("dev.toml:2"), std::string::npos) << msg;
  EXPECT_NE(msg.find("integer"), std::string::npos) << msg;
  msg = config_error(dir, "[receiver]\nbias_temperature_compensated = 1\n");
  EXPECT_NE(msg.find("receiver.bias_temperature_compensated"), std::string::npos) << msg;
}

TEST(ConfigFile, OutOfRangeValuesNameKeyAndFile) {
  TempDir dir;
  auto msg = config_error(dir, "[laser]\npeak_power_w = -1.0\n");
  EXPECT_NE(msg.find("dev.toml:2"), std::string::npos) << msg;
  EXPECT_NE(msg.find("laser.peak_power_w"), std::string::npos) << msg;
  msg = config_error(dir, "[receiver]\n\nbandwidth_mhz = 0\n");
  EXPECT_NE(msg.find("dev.toml:3"), std::string::npos) << msg;
  EXPECT_NE(msg.find("receiver.bandwidth_mhz"), std::string::npos) << msg;
  // Both at once: one line each.
  msg = config_error(dir, "[laser]\npeak_power_w = -1.0\n[receiver]\nbandwidth_mhz = 0\n");
  EXPECT_NE(msg.find("laser.peak_power_w"), std::string::npos) << msg;
  EXPECT_NE(msg.find("receiver.bandwidth_mhz"), std::string::npos) << msg;
}

TEST(ConfigFile, SyntaxErrorNamesFileLineAndColumn) {
  TempDir dir;
  const auto msg = config_error(dir, "[laser]\npeak_power_w = 1.0\nwavelength_nm = = 3\n");
  EXPECT_NE(msg.find("dev.toml:3:"), std::string::npos) << msg;
  EXPECT_NE(msg.find("syntax"), std::string::npos) << msg;
}

TEST(ConfigFile, MissingFileIsAnError) {
  EXPECT_THROW((void)io::load_device_config("", fs::path("/nonexistent/dev.toml"), {}),
               io::ConfigError);
}

TEST(ConfigFile, ValuesApplyAndIntegersAreAcceptedForReals) {
  TempDir dir;
  const fs::path file = dir / "dev.toml";
  write_text(file,
             "[receiver]\nbandwidth_mhz = 120\nbias_temperature_compensated = false\n"
             "[measurement]\nshots = 250\n");
  const auto config = io::load_device_config("", file, {});
  EXPECT_EQ(config.link.receiver.bandwidth_mhz, 120.0);
  EXPECT_FALSE(config.link.receiver.bias_temperature_compensated);
  EXPECT_EQ(config.measurement.shots, 250);
  EXPECT_EQ(config.name, "paper");
  // Everything not named keeps the preset's value.
  EXPECT_EQ(config.link.laser.peak_power_w, device::preset("paper").link.laser.peak_power_w);
}

TEST(ConfigFile, OverridesWinOverTheFileAndAreTraced) {
  TempDir dir;
  const fs::path file = dir / "dev.toml";
  write_text(file, "[receiver]\nbandwidth_mhz = 120\n");
  const std::vector<std::string> overrides = {"receiver.bandwidth_mhz=130", "tdc.lsb_ps = 25",
                                              "receiver.bias_temperature_compensated=false"};
  const auto loaded = io::load_device_config_traced("", file, overrides);
  EXPECT_EQ(loaded.config.link.receiver.bandwidth_mhz, 130.0);
  EXPECT_EQ(loaded.config.tdc.lsb_ps, 25.0);
  EXPECT_FALSE(loaded.config.link.receiver.bias_temperature_compensated);
  ASSERT_EQ(loaded.sources.size(), 4u);
  EXPECT_EQ(loaded.sources[0].key, "receiver.bandwidth_mhz");
  EXPECT_NE(loaded.sources[0].origin.find("dev.toml:2"), std::string::npos);
  EXPECT_EQ(loaded.sources[1].origin, "--set");
}

TEST(ConfigFile, OverrideErrorsNameSetAndKey) {
  auto error = [](const std::string& assignment) {
    try {
      (void)io::load_device_config("paper", std::nullopt, std::vector<std::string>{assignment});
    } catch (const io::ConfigError& e) {
      return std::string(e.what());
    }
    return std::string("no error");
  };
  auto msg = error("receiver.bandwith_mhz=100");
  EXPECT_NE(msg.find("--set"), std::string::npos) << msg;
  EXPECT_NE(msg.find("did you mean receiver.bandwidth_mhz"), std::string::npos) << msg;
  msg = error("laser.peak_power_w=lots");
  EXPECT_NE(msg.find("laser.peak_power_w"), std::string::npos) << msg;
  msg = error("laser.peak_power_w=-2");
  EXPECT_NE(msg.find("--set"), std::string::npos) << msg;
  EXPECT_NE(msg.find("laser.peak_power_w"), std::string::npos) << msg;
  msg = error("laser.peak_power_w");
  EXPECT_NE(msg.find("section.key=value"), std::string::npos) << msg;
}

TEST(ConfigFile, PresetFromFileOrArgument) {
  TempDir dir;
  const fs::path file = dir / "dev.toml";
  write_text(file, "preset = \"accurange\"\n[measurement]\nshots = 64\n");
  auto expected = device::preset("accurange");
  expected.measurement.shots = 64;
  expect_same_config(io::load_device_config("", file, {}), expected);
  expect_same_config(io::load_device_config("accurange", file, {}), expected);
  EXPECT_THROW((void)io::load_device_config("paper", file, {}), io::ConfigError);
  expect_same_config(io::load_device_config("accurange", std::nullopt, {}),
                     device::preset("accurange"));
  EXPECT_THROW((void)io::load_device_config("nope", std::nullopt, {}), io::ConfigError);
  write_text(file, "preset = \"nope\"\n");
  EXPECT_THROW((void)io::load_device_config("", file, {}), io::ConfigError);
}

// Oracle: the dump, loaded back, reproduces every value bit for bit, also
// for values with long decimal expansions.
TEST(ConfigFile, DumpLoadsBackToAnIdenticalConfig) {
  TempDir dir;
  for (const auto& name : device::preset_names()) {
    device::DeviceConfig config = device::preset(name);
    for (const auto& f : device::config_fields(config)) {
      if (auto* const* d = std::get_if<double*>(&f.value)) {
        **d += (f.max - **d) * (1e-3 / 3.0);  // stays in range, not a short decimal
      } else if (auto* const* i = std::get_if<int*>(&f.value)) {
        if (**i < f.max) ++**i;
      } else {
        bool* b = *std::get_if<bool*>(&f.value);
        *b = !*b;
      }
    }
    ASSERT_TRUE(device::validate(config).empty()) << device::validate(config)[0];
    const std::string text = io::dump_device_config(config);
    for (const auto& f : device::config_fields(config)) {
      const auto dot = f.key.find('.');
      EXPECT_NE(text.find("\n" + f.key.substr(dot + 1) + " = "), std::string::npos) << f.key;
      EXPECT_NE(text.find(f.description), std::string::npos) << f.key;
    }
    const fs::path file = dir / (name + ".toml");
    write_text(file, text);
    expect_same_config(io::load_device_config("", file, {}), config);
  }
}

// ---------------------------------------------------------------------------
// CSV tables

namespace {

std::vector<ranging::Record> sample_records() {
  std::vector<ranging::Record> records;
  const double nan = ranging::kNaN;
  ranging::Record a;
  a.truth = {1.0 / 3.0, 0.1, 0.0, 20.0};
  a.raw = {6.671281903963041, 1.0000000000000002, 4.5e-7, 0.33, 26.0625, 1000, 0};
  records.push_back(a);
  ranging::Record b;  // no echo: empty distances
  b.truth = {12.5, 0.02, 45.0, -10.25};
  b.raw = {nan, nan, nan, nan, 25.9375, 0, ranging::kRawNoEcho};
  records.push_back(b);
  ranging::Record c;  // extremes
  c.truth = {nan, nan, nan, nan};
  c.raw = {1e300,      -0.0,
           5e-324,     std::numeric_limits<double>::max(),
           -273.15,    std::numeric_limits<std::uint32_t>::max(),
           0xFFFFFFFFu};
  records.push_back(c);
  return records;
}

void expect_same_record(const ranging::Record& a, const ranging::Record& b) {
  EXPECT_TRUE(same_bits(a.truth.distance_m, b.truth.distance_m));
  EXPECT_TRUE(same_bits(a.truth.reflectance, b.truth.reflectance));
  EXPECT_TRUE(same_bits(a.truth.angle_deg, b.truth.angle_deg));
  EXPECT_TRUE(same_bits(a.truth.ambient_c, b.truth.ambient_c));
  EXPECT_TRUE(same_bits(a.raw.tof_ns, b.raw.tof_ns));
  EXPECT_TRUE(same_bits(a.raw.distance_raw_m, b.raw.distance_raw_m));
  EXPECT_TRUE(same_bits(a.raw.pulse_width_ns, b.raw.pulse_width_ns));
  EXPECT_TRUE(same_bits(a.raw.amplitude, b.raw.amplitude));
  EXPECT_TRUE(same_bits(a.raw.temperature_c, b.raw.temperature_c));
  EXPECT_EQ(a.raw.shots_valid, b.raw.shots_valid);
  EXPECT_EQ(a.raw.flags, b.raw.flags);
}

std::string csv_error(const fs::path& path, const std::string& text) {
  write_text(path, text);
  try {
    (void)io::read_raw_csv(path);
  } catch (const std::runtime_error& e) {
    return e.what();
  }
  ADD_FAILURE() << "no error for:\n" << text;
  return {};
}

}  // namespace

TEST(RawCsv, HeaderIsTheDesignColumnList) {
  TempDir dir;
  io::write_raw_csv(dir / "raw.csv", {});
  EXPECT_EQ(read_text(dir / "raw.csv"),
            "distance_true_m,reflectance,angle_deg,ambient_c,tof_ns,distance_raw_m,"
            "pulse_width_ns,amplitude,temperature_c,shots_valid,flags\n");
  EXPECT_TRUE(io::read_raw_csv(dir / "raw.csv").empty());
}

TEST(RawCsv, RoundTripIsBitExactWithNaNsAsEmptyFields) {
  TempDir dir;
  const auto records = sample_records();
  io::write_raw_csv(dir / "raw.csv", records);
  const auto back = io::read_raw_csv(dir / "raw.csv");
  ASSERT_EQ(back.size(), records.size());
  for (std::size_t i = 0; i < records.size(); ++i) expect_same_record(records[i], back[i]);
  // The no-echo row keeps its row, with empty distance fields.
  const std::string text = read_text(dir / "raw.csv");
  EXPECT_NE(text.find("\n12.5,0.02,45,-10.25,,,,,25.9375,0,1\n"), std::string::npos) << text;
  // Byte-reproducible: writing the read-back records gives the same bytes.
  io::write_raw_csv(dir / "again.csv", back);
  EXPECT_EQ(read_text(dir / "again.csv"), text);
}

TEST(RawCsv, ReaderGoesByTheHeader) {
  TempDir dir;
  const fs::path path = dir / "x.csv";
  write_text(path,
             "note,distance_raw_m,flags,tof_ns,shots_valid,reflectance\r\n"
             "a,1.5,0,10.0,7,0.5\r\n"
             "\r\n"
             "b,,1,,0,0.25\r\n");
  const auto records = io::read_raw_csv(path);
  ASSERT_EQ(records.size(), 2u);
  EXPECT_EQ(records[0].raw.distance_raw_m, 1.5);
  EXPECT_EQ(records[0].raw.tof_ns, 10.0);
  EXPECT_EQ(records[0].raw.shots_valid, 7u);
  EXPECT_EQ(records[0].truth.reflectance, 0.5);
  EXPECT_TRUE(std::isnan(records[0].truth.distance_m));
  EXPECT_TRUE(std::isnan(records[0].raw.pulse_width_ns));
  EXPECT_FALSE(records[1].raw.has_echo());

  // Without shots_valid/flags: derived from whether the row has a distance.
  write_text(path, "distance_raw_m\n2.0\n\n");
  const auto minimal = io::read_raw_csv(path);
  ASSERT_EQ(minimal.size(), 1u);
  EXPECT_TRUE(minimal[0].raw.has_echo());
  EXPECT_TRUE(std::isnan(minimal[0].raw.tof_ns));
}

TEST(RawCsv, MalformedFilesNameFileLineAndColumn) {
  TempDir dir;
  const fs::path path = dir / "bad.csv";
  const std::string header =
      "distance_true_m,reflectance,angle_deg,ambient_c,tof_ns,distance_raw_m,"
      "pulse_width_ns,amplitude,temperature_c,shots_valid,flags\n";
  const std::string good = "1,0.1,0,20,6.6,1,5,0.3,26,100,0\n";

  auto msg = csv_error(path, header + good + "1,0.1,0,20,6.x,1,5,0.3,26,100,0\n");
  EXPECT_NE(msg.find("bad.csv:3"), std::string::npos) << msg;
  EXPECT_NE(msg.find("tof_ns"), std::string::npos) << msg;
  EXPECT_NE(msg.find("6.x"), std::string::npos) << msg;

  msg = csv_error(path, header + "1,0.1,0,20,6.6,1,5,0.3,26,100\n");
  EXPECT_NE(msg.find("bad.csv:2"), std::string::npos) << msg;
  EXPECT_NE(msg.find("11"), std::string::npos) << msg;

  msg = csv_error(path, header + good + good + "1,0.1,0,20,6.6,1,5,0.3,26,-3,0\n");
  EXPECT_NE(msg.find("bad.csv:4"), std::string::npos) << msg;
  EXPECT_NE(msg.find("shots_valid"), std::string::npos) << msg;

  msg = csv_error(path, "distance_true_m,reflectance\n1,0.1\n");
  EXPECT_NE(msg.find("bad.csv:1"), std::string::npos) << msg;
  EXPECT_NE(msg.find("tof_ns"), std::string::npos) << msg;

  msg = csv_error(path, "tof_ns,tof_ns\n1,2\n");
  EXPECT_NE(msg.find("twice"), std::string::npos) << msg;

  // A spreadsheet's export in semicolons or tabs: the message says so.
  for (const char* separator : {";", "\t"}) {
    std::string other = header + good;
    for (char& c : other)
      if (c == ',') c = separator[0];
    msg = csv_error(path, other);
    EXPECT_NE(msg.find("bad.csv:1: header has neither 'tof_ns' nor 'distance_raw_m' (its fields "
                       "are not separated by commas"),
              std::string::npos)
        << msg;
  }
  msg = csv_error(path, "distance_true_m,reflectance\n1,0.1\n");
  EXPECT_EQ(msg.find("separated"), std::string::npos) << msg;

  msg = csv_error(path, "");
  EXPECT_NE(msg.find("bad.csv"), std::string::npos) << msg;

  EXPECT_THROW((void)io::read_raw_csv(dir / "missing.csv"), std::runtime_error);
}

TEST(CorrectedCsv, RoundTripAddsTheThreeColumns) {
  TempDir dir;
  const auto records = sample_records();
  const std::vector<ranging::Range> ranges = {
      {1.0 / 3.0, 0.0046, 0}, {ranging::kNaN, ranging::kNaN, ranging::kCorrNoEcho}, {2.0, 1e-3, 2}};
  io::write_corrected_csv(dir / "c.csv", records, ranges);
  const std::string text = read_text(dir / "c.csv");
  EXPECT_EQ(text.substr(0, text.find('\n')),
            "distance_true_m,reflectance,angle_deg,ambient_c,tof_ns,distance_raw_m,"
            "pulse_width_ns,amplitude,temperature_c,shots_valid,flags,distance_m,sigma_m,"
            "correction_flags");
  const auto rows = io::read_corrected_csv(dir / "c.csv");
  ASSERT_EQ(rows.size(), 3u);
  for (std::size_t i = 0; i < rows.size(); ++i) {
    expect_same_record(rows[i].record, records[i]);
    EXPECT_TRUE(same_bits(rows[i].range.distance_m, ranges[i].distance_m));
    EXPECT_TRUE(same_bits(rows[i].range.sigma_m, ranges[i].sigma_m));
    EXPECT_EQ(rows[i].range.correction_flags, ranges[i].correction_flags);
  }
  // A raw table is not a corrected one; the raw reader accepts a corrected one.
  io::write_raw_csv(dir / "raw.csv", records);
  EXPECT_THROW((void)io::read_corrected_csv(dir / "raw.csv"), std::runtime_error);
  EXPECT_EQ(io::read_raw_csv(dir / "c.csv").size(), 3u);
  EXPECT_THROW(io::write_corrected_csv(dir / "d.csv", records, std::span(ranges).first(2)),
               std::invalid_argument);
  EXPECT_FALSE(fs::exists(dir / "d.csv"));
}

// ---------------------------------------------------------------------------
// All-or-nothing output

TEST(AtomicFile, AFailingWriterLeavesNothingBehind) {
  TempDir dir;
  const fs::path path = dir / "out.csv";
  EXPECT_THROW(io::write_file_atomically(path,
                                         [](std::ostream& out) {
                                           out << "half a file";
                                           throw std::runtime_error("simulated failure");
                                         }),
               std::runtime_error);
  EXPECT_TRUE(fs::is_empty(dir.path()));

  // An existing file survives a failed rewrite untouched.
  io::write_file_atomically(path, "old\n");
  EXPECT_THROW(io::write_file_atomically(path,
                                         [](std::ostream& out) {
                                           out << "new";
                                           throw std::runtime_error("simulated failure");
                                         }),
               std::runtime_error);
  EXPECT_EQ(read_text(path), "old\n");
  EXPECT_EQ(std::distance(fs::directory_iterator(dir.path()), fs::directory_iterator()), 1);

  io::write_file_atomically(path, "new\n");
  EXPECT_EQ(read_text(path), "new\n");
}

// A file that outlives its command (a calibration cache entry) is replaced at
// once, transaction or not, and a signal while it is written leaves the old
// file whole and no temporary (the handler removes it, as for outputs).
TEST(AtomicFile, AFileReplacedNowLeavesNoTemporaryWhenSignalled) {
  TempDir dir;
  const fs::path path = dir / "entry.json";
  io::replace_file_now(path, "one\n");
  EXPECT_EQ(read_text(path), "one\n");
  {
    io::OutputTransaction transaction;  // never committed
    io::replace_file_now(path, "two\n");
    EXPECT_EQ(read_text(path), "two\n");
  }
  EXPECT_EQ(read_text(path), "two\n");
  EXPECT_THROW(io::replace_file_now(dir / "nodir" / "x.json", "x"), std::runtime_error);

  constexpr std::size_t kBig = std::size_t{64} << 20;
  for (const int delay_us : {0, 1000, 5000, 20000}) {
    int ready[2];
    ASSERT_EQ(::pipe(ready), 0);
    const pid_t pid = ::fork();
    ASSERT_GE(pid, 0);
    if (pid == 0) {
      const std::string big(kBig, 'x');
      const char go = 1;
      if (::write(ready[1], &go, 1) != 1) ::_exit(2);
      io::replace_file_now(path, big);
      ::_exit(0);
    }
    char go = 0;
    ASSERT_EQ(::read(ready[0], &go, 1), 1);
    ::close(ready[0]);
    ::close(ready[1]);
    ::usleep(static_cast<useconds_t>(delay_us));
    ::kill(pid, SIGTERM);
    int status = 0;
    ::waitpid(pid, &status, 0);
    for (const auto& e : fs::directory_iterator(dir.path()))
      EXPECT_EQ(e.path().filename().string().find(".tmp."), std::string::npos)
          << "left after SIGTERM at " << delay_us << " us: " << e.path();
    const auto size = fs::file_size(path);
    EXPECT_TRUE(size == 4 || size == kBig) << size;  // the old file or the whole new one
    if (size == kBig) io::replace_file_now(path, "two\n");
  }
}

TEST(AtomicFile, MissingDirectoryIsAnErrorNamingIt) {
  TempDir dir;
  try {
    io::write_file_atomically(dir / "nodir" / "x.csv", "x");
    FAIL() << "no exception";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("nodir"), std::string::npos) << e.what();
  }
}

// ---------------------------------------------------------------------------
// Value lists

TEST(ValueList, CommaSeparated) {
  EXPECT_EQ(io::parse_value_list("1, 2.5 ,3e-1", "--x"), (std::vector<double>{1.0, 2.5, 0.3}));
  EXPECT_EQ(io::parse_value_list("-4", "--x"), (std::vector<double>{-4.0}));
}

TEST(ValueList, RangesIncludeTheirStop) {
  const auto d = io::parse_value_list("0.5:15:0.5", "--distance");
  ASSERT_EQ(d.size(), 30u);
  for (std::size_t i = 0; i < d.size(); ++i) EXPECT_DOUBLE_EQ(d[i], 0.5 * (i + 1));
  EXPECT_EQ(d.back(), 15.0);

  const auto r = io::parse_value_list("0.1:0.3:0.1", "--reflectance");  // 0.1 * 3 != 0.3
  ASSERT_EQ(r.size(), 3u);
  EXPECT_EQ(r.back(), 0.3);

  EXPECT_EQ(io::parse_value_list("3:1:-1", "--x"), (std::vector<double>{3, 2, 1}));
  EXPECT_EQ(io::parse_value_list("1:1.9:0.5", "--x"), (std::vector<double>{1, 1.5}));
  EXPECT_EQ(io::parse_value_list("2:2:1", "--x"), (std::vector<double>{2}));
}

TEST(ValueList, ErrorsNameTheOption) {
  for (const char* bad : {"", "a", "1,,2", "1,x", "1:2", "1:2:0", "2:1:1", "1:2:3:4", "1:2,3",
                          "nan", "inf", "0:1e9:1e-3"}) {
    try {
      (void)io::parse_value_list(bad, "--distance");
      ADD_FAILURE() << "no error for '" << bad << "'";
    } catch (const std::invalid_argument& e) {
      EXPECT_EQ(std::string(e.what()).rfind("--distance: ", 0), 0u) << e.what();
    }
  }
}

// ---- hardening (issue 7): one number parser, one input reader, one writer ----

TEST(NumberField, RejectsOverflowGarbageAndOverlongFields) {
  double v = -1;
  EXPECT_FALSE(io::parse_number("1.5e3", v).has_value());
  EXPECT_EQ(v, 1500.0);
  EXPECT_FALSE(io::parse_number("+2", v).has_value());
  EXPECT_EQ(v, 2.0);
  // Underflow rounds (as strtod does); only overflow is an error.
  EXPECT_FALSE(io::parse_number("1e-400", v).has_value());
  EXPECT_EQ(v, 0.0);
  EXPECT_FALSE(io::parse_number("4.9e-324", v).has_value());
  EXPECT_EQ(v, std::numeric_limits<double>::denorm_min());
  for (const char* bad : {"1e999", "-1e999", "1.8e308"}) {
    const auto why = io::parse_number(bad, v);
    ASSERT_TRUE(why.has_value()) << bad;
    EXPECT_NE(why->find("too large"), std::string::npos) << *why;
  }
  EXPECT_FALSE(io::parse_number("1.7e308", v).has_value());  // the largest finite still reads
  for (const char* bad : {"", "x", "1x", "+-1", "++1", "nan", "inf", "-inf", "0x10", "1,5"}) {
    EXPECT_TRUE(io::parse_number(bad, v).has_value()) << bad;
  }
  EXPECT_TRUE(io::parse_number(std::string(io::kMaxNumberLength + 1, '1'), v).has_value());
  EXPECT_FALSE(io::parse_number(std::string(io::kMaxNumberLength, '0'), v).has_value());
}

TEST(NumberField, CsvOverflowNamesFileLineAndColumn) {
  TempDir dir;
  write_text(dir / "raw.csv", "tof_ns,amplitude\n13.3,0.5\n13.3, 1e999\n");
  try {
    (void)io::read_raw_csv(dir / "raw.csv");
    FAIL() << "1e999 read as a number";
  } catch (const std::runtime_error& e) {
    // Line 3, character 7 (after the blank), field 2.
    EXPECT_NE(std::string(e.what()).find("raw.csv:3:7: column 2 (amplitude): '1e999' is too large"),
              std::string::npos)
        << e.what();
  }
}

TEST(NumberField, LineEndingsLfCrLfAndCrReadAlike) {
  TempDir dir;
  const std::string lf = "tof_ns,amplitude,flags\n13.3,0.5,0\n,,1\n26.6,0.25,0\n";
  std::string crlf, cr;
  for (char c : lf) {
    crlf += c == '\n' ? std::string("\r\n") : std::string(1, c);
    cr += c == '\n' ? '\r' : c;
  }
  write_text(dir / "lf.csv", lf);
  write_text(dir / "crlf.csv", crlf);
  write_text(dir / "cr.csv", cr);
  const auto a = io::read_raw_csv(dir / "lf.csv");
  ASSERT_EQ(a.size(), 3u);
  for (const char* name : {"crlf.csv", "cr.csv"}) {
    const auto b = io::read_raw_csv(dir / name);
    ASSERT_EQ(b.size(), a.size()) << name;
    for (std::size_t i = 0; i < a.size(); ++i) {
      EXPECT_TRUE(std::isnan(a[i].raw.tof_ns) ? std::isnan(b[i].raw.tof_ns)
                                              : a[i].raw.tof_ns == b[i].raw.tof_ns);
      EXPECT_EQ(a[i].raw.flags, b[i].raw.flags);
    }
  }
  // Line numbers count CR-only lines too.
  write_text(dir / "bad.csv", "tof_ns\r13.3\rx\r");
  try {
    (void)io::read_raw_csv(dir / "bad.csv");
    FAIL();
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("bad.csv:3:1:"), std::string::npos) << e.what();
  }
}

TEST(InputFile, RefusesDirectoriesOversizeAndRowFloods) {
  TempDir dir;
  fs::create_directories(dir / "model.json");
  try {
    (void)io::read_text_file(dir / "model.json", "model file");
    FAIL();
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("is a directory"), std::string::npos) << e.what();
  }
  auto& limits = io::resource_limits();
  const io::ResourceLimits saved = limits;
  write_text(dir / "raw.csv", "tof_ns\n1\n2\n3\n4\n");
  limits.max_input_bytes = 10;
  EXPECT_THROW((void)io::read_raw_csv(dir / "raw.csv"), std::runtime_error);
  limits = saved;
  limits.max_rows = 3;
  try {
    (void)io::read_raw_csv(dir / "raw.csv");
    ADD_FAILURE() << "4 rows read under a limit of 3";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("--max-rows"), std::string::npos) << e.what();
  }
  EXPECT_THROW((void)io::parse_value_list("1,2,3,4", "--x"), std::invalid_argument);
  EXPECT_THROW((void)io::parse_value_list("1:4:1", "--x"), std::invalid_argument);
  EXPECT_EQ(io::parse_value_list("1:3:1", "--x").size(), 3u);
  limits = saved;
  EXPECT_EQ(io::read_raw_csv(dir / "raw.csv").size(), 4u);
}

TEST(OutputTransaction, CommitsAllOrNothing) {
  TempDir dir;
  write_text(dir / "b.txt", "old b\n");
  {
    io::OutputTransaction outputs;
    io::write_file_atomically(dir / "a.txt", "new a\n");
    io::write_file_atomically(dir / "b.txt", "new b\n");
    io::create_output_directories(dir / "sub" / "deeper");
    io::write_file_atomically(dir / "sub" / "deeper" / "c.txt", "new c\n");
    EXPECT_EQ(outputs.staged(), 3u);
    // Staged: nothing visible yet, the old content intact.
    EXPECT_FALSE(fs::exists(dir / "a.txt"));
    EXPECT_EQ(read_text(dir / "b.txt"), "old b\n");
    // no commit: rolled back
  }
  EXPECT_FALSE(fs::exists(dir / "a.txt"));
  EXPECT_FALSE(fs::exists(dir / "sub"));
  EXPECT_EQ(read_text(dir / "b.txt"), "old b\n");
  EXPECT_EQ(std::distance(fs::directory_iterator(dir.path()), fs::directory_iterator()), 1);
  {
    io::OutputTransaction outputs;
    io::write_file_atomically(dir / "a.txt", "new a\n");
    io::write_file_atomically(dir / "b.txt", "new b\n");
    EXPECT_THROW(io::write_file_atomically(dir / "a.txt", "again\n"), std::runtime_error);
    outputs.commit();
  }
  EXPECT_EQ(read_text(dir / "a.txt"), "new a\n");
  EXPECT_EQ(read_text(dir / "b.txt"), "new b\n");
  EXPECT_EQ(std::distance(fs::directory_iterator(dir.path()), fs::directory_iterator()), 2);
}

TEST(OutputTransaction, NeverReplacesInputsLinksOrDevices) {
  TempDir dir;
  write_text(dir / "in.csv", "tof_ns\n1\n");
  fs::create_hard_link(dir / "in.csv", dir / "alias.csv");
  fs::create_symlink(dir / "in.csv", dir / "link.csv");
  {
    io::OutputTransaction outputs;
    (void)io::read_raw_csv(dir / "in.csv");
    EXPECT_THROW(io::write_file_atomically(dir / "in.csv", "x"), std::runtime_error);
    EXPECT_THROW(io::write_file_atomically(dir / "alias.csv", "x"), std::runtime_error);
    EXPECT_THROW(io::write_file_atomically(dir / "link.csv", "x"), std::runtime_error);
    EXPECT_THROW(io::write_file_atomically("/dev/null", "x"), std::runtime_error);
    outputs.commit();
  }
  EXPECT_EQ(read_text(dir / "in.csv"), "tof_ns\n1\n");
  EXPECT_TRUE(fs::is_symlink(dir / "link.csv"));
  EXPECT_TRUE(fs::is_character_file("/dev/null"));
  // Outside a command's transaction the input registry is empty again.
  io::write_file_atomically(dir / "alias.csv", "tof_ns\n2\n");
}

TEST(ConfigShape, DeepNestingAndLongDottedKeysAreRefusedBeforeParsing) {
  TempDir dir;
  std::string header = "[a";
  for (int i = 0; i < 50'000; ++i) header += ".a";
  EXPECT_NE(config_error(dir, header + "]\n").find("dev.toml:1:"), std::string::npos);
  EXPECT_NE(config_error(dir, "x = " + std::string(10'000, '[') + "\n").find("nesting"),
            std::string::npos);
  EXPECT_NE(config_error(dir, "x = " + std::string(10'000, '{') + "\n").find("nesting"),
            std::string::npos);
  // Dots and brackets inside strings and comments do not count.
  EXPECT_NO_THROW(io::check_toml_shape("# " + std::string(1000, '.') + std::string(100, '[') +
                                           "\nname = \"" + std::string(1000, '.') + "\"\n",
                                       "x.toml"));
  EXPECT_NO_THROW(io::check_toml_shape(io::dump_device_config(device::preset("paper")), "d"));
}

TEST(ConfigLimits, DerivedQuantitiesNameTheKeysThatSetThem) {
  TempDir dir;
  // The pulse template grows as 1 / bandwidth: refused below ~8 MHz, named by key and origin.
  const std::string slow = config_error(dir, "[receiver]\nbandwidth_mhz = 1\n");
  EXPECT_NE(slow.find("dev.toml:2 (receiver.bandwidth_mhz)"), std::string::npos) << slow;
  EXPECT_NE(slow.find("pulse template"), std::string::npos) << slow;
  device::DeviceConfig c = device::preset("paper");
  c.link.receiver.bandwidth_mhz = 9;
  EXPECT_TRUE(device::check_config_limits(c).empty());
  c.link.receiver.bandwidth_mhz = 7;
  EXPECT_FALSE(device::check_config_limits(c).empty());
  // A rule that names two keys blames the one the user set.
  const std::string rate = config_error(dir, "[laser]\nrepetition_hz = 1e9\n");
  EXPECT_NE(rate.find("dev.toml:2 (laser.repetition_hz): "), std::string::npos) << rate;
  // The waveform record counts the echo spread, not only window_ns.
  c = device::preset("paper");
  EXPECT_TRUE(device::check_waveform_limits(c, 0).empty());
  c.measurement.sample_period_ps = 1;  // 30 ns window: 3e4 samples, fine alone
  EXPECT_TRUE(device::check_waveform_limits(c, 0).empty());
  EXPECT_FALSE(device::check_waveform_limits(c, 1000).empty());  // 1 us of echo spread
  // A plate's spread: footprint x tan(angle), there and back.
  const double spread = device::plate_echo_spread_ns(c, 100.0, 45.0);
  const double footprint =
      c.link.laser.exit_beam_diameter_mm * 1e-3 + 100.0 * c.link.laser.beam_divergence_mrad * 1e-3;
  EXPECT_NEAR(spread, 2.0 * footprint / 0.299792458, 1e-9);
  EXPECT_TRUE(device::check_plate_echo(c, 100.0, 80.0).empty());
  EXPECT_FALSE(device::check_plate_echo(c, 1e5, 89.9).empty());
}
