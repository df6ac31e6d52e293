// The streaming scan: blocks of beams written as they come give the bytes of
// the whole-frame encoders (the oracle: encode_* on run_scan's ScanResult),
// whatever the block size; the streaming writer's files appear only on
// commit; an interrupted scan leaves nothing.

#include <fmt/format.h>
#include <fmt/ranges.h>
#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <limits>
#include <random>
#include <set>
#include <sstream>
#include <string>

#include "cli_runner.hpp"
#include "tofkit/io/atomic_file.hpp"
#include "tofkit/io/scan_output.hpp"
#include "tofkit/io/scan_writer.hpp"
#include "tofkit/io/scene_file.hpp"
#include "tofkit/scan/scanner.hpp"

namespace fs = std::filesystem;
using namespace tofkit;

using tofkit::test::read_file;

namespace {

const fs::path kScenes = fs::path(TOFKIT_REFERENCE_DIR).parent_path() / "examples" / "scenes";

fs::path fresh_dir(const std::string& name) {
  return tofkit::test::fresh_dir("tofkit_scan_stream_", name);
}

std::size_t entries(const fs::path& dir) {
  std::size_t n = 0;
  for ([[maybe_unused]] const auto& e : fs::directory_iterator(dir)) ++n;
  return n;
}

// Every output of the streaming writer fed in blocks of `block` beams equals
// the whole-frame encoder's bytes.
void expect_stream_matches_frame(const scan::Scene& scene, const scan::BeamPattern& pattern,
                                 std::size_t block, const std::string& name) {
  const device::DeviceConfig config;
  const device::VirtualRangefinder device(config, device::SimulationMode::kAnalytic);
  const scan::RayCaster caster(scene);
  const scan::Footprint footprint(config);
  scan::ScanOptions options;
  options.seed = 3;
  options.shots = 5;
  const scan::ScanResult frame = scan::run_scan(caster, footprint, device, pattern, options);
  const scan::ScanImages images = scan::make_images(frame);
  const auto points = io::cloud_points(frame);

  const fs::path dir = fresh_dir(name + std::to_string(block));
  io::ScanWriterSettings settings;
  settings.directory = dir;
  settings.outputs = {"csv", "png", "npy", "ply", "pcd", "las", "view"};
  settings.ambient_c = 21.5;
  settings.sidecar = [](const std::string& file, const char*, const char*, double scale,
                        double offset) {
    std::ostringstream s;
    s.precision(17);
    s << file << ' ' << scale << ' ' << offset;
    return s.str();
  };
  io::ScanWriter writer(scan::describe_scan(pattern, scene), scan::row_last_beams(pattern),
                        settings);
  std::size_t blocks = 0;
  scan::run_scan_blocks(caster, footprint, device, pattern, options, 0, pattern.size(), block,
                        [&](std::size_t first, std::span<scan::BeamResult> beams) {
                          ++blocks;
                          writer.add(first, beams);
                        });
  const auto summary = writer.finish();
  EXPECT_EQ(blocks, (pattern.size() + block - 1) / block);
  EXPECT_EQ(summary.beams, frame.beams.size());
  EXPECT_EQ(summary.points, points.size());

  EXPECT_EQ(read_file(dir / "scan.csv"), io::encode_scan_csv(frame, 21.5)) << name;
  EXPECT_EQ(read_file(dir / "points.ply"), io::encode_ply(points)) << name;
  EXPECT_EQ(read_file(dir / "points.pcd"), io::encode_pcd(points)) << name;
  EXPECT_EQ(read_file(dir / "points.las"), io::encode_las(points)) << name;
  EXPECT_EQ(read_file(dir / "range_view.png"), io::encode_range_view(images)) << name;
  const std::pair<const char*, const scan::Image*> planes[] = {{"range", &images.range},
                                                               {"intensity", &images.intensity}};
  for (const auto& [plane, image] : planes) {
    const io::Png16 png = io::encode_png16(*image);
    EXPECT_EQ(read_file(dir / (std::string(plane) + ".png")), png.png) << name << ' ' << plane;
    EXPECT_EQ(read_file(dir / (std::string(plane) + ".npy")), io::encode_npy(*image)) << name;
    std::ostringstream side;
    side.precision(17);
    side << plane << ".png " << png.scale << ' ' << png.offset;
    EXPECT_EQ(read_file(dir / (std::string(plane) + ".json")), side.str()) << name;
  }
  EXPECT_FALSE(fs::exists(dir / "sigma.png"));  // no model
  EXPECT_EQ(entries(dir), 11u) << "no working file left: " << name;
  fs::remove_all(dir);
}

}  // namespace

TEST(ScanStream, BlocksGiveTheWholeFrameBytesForEveryOutput) {
  const scan::Scene blocks = io::load_scene(kScenes / "blocks.toml");
  scan::PatternSettings s;
  s.rate_hz = 1;
  auto lists = [](scan::PatternListName l) -> std::vector<double> {
    using enum scan::PatternListName;
    if (l == azimuth) return {-20, -12, -5, -1, 0, 3, 9, 15};
    if (l == elevation) return {-10, -4, 0, 2, 6, 11, 30};
    if (l == y) return {0.3, 0.2, 0.1, 0, -0.1, -0.2, -0.3};
    return {0.0, 0.05};
  };
  // Spherical goes down columns (rows finish at the end), on demand.
  const auto spherical = scan::make_pattern("spherical", s, lists, 5e-6, 1'000'000, true);
  ASSERT_TRUE(static_cast<bool>(spherical.make_beams));
  for (const std::size_t block : {std::size_t{1}, std::size_t{13}, std::size_t{100000}})
    expect_stream_matches_frame(blocks, spherical, block, "spherical");
  // Line scans average several samples into a pixel (rows finish one by one).
  const scan::Scene stripes = io::load_scene(kScenes / "grey_stripes.toml");
  s.speed_m_per_s = 0.5;
  const auto line = scan::make_pattern("line", s, lists, 5e-3, 1'000'000);
  for (const std::size_t block : {std::size_t{1}, std::size_t{7}, std::size_t{100000}})
    expect_stream_matches_frame(stripes, line, block, "line");
}

TEST(ScanStream, FewerOutputsGiveTheWholeFrameBytes) {
  // A LAS alone keeps only its fields in the working file; the .npy files
  // take their rows as they come whether or not the PNGs keep them.
  const scan::Scene blocks = io::load_scene(kScenes / "blocks.toml");
  scan::PatternSettings s;
  s.rate_hz = 1;
  auto lists = [](scan::PatternListName l) -> std::vector<double> {
    using enum scan::PatternListName;
    if (l == azimuth) return {-20, -12, -5, -1, 0, 3, 9, 15, 17, 19, 21, 23, 25, 27, 29, 31, 33};
    if (l == elevation) return {-10, -4, 0, 2, 6, 11, 30};
    return {0.0, 0.05};
  };
  const auto pattern = scan::make_pattern("spherical", s, lists, 5e-6, 1'000'000, true);
  const device::DeviceConfig config;
  const device::VirtualRangefinder device(config, device::SimulationMode::kAnalytic);
  const scan::RayCaster caster(blocks);
  const scan::Footprint footprint(config);
  scan::ScanOptions options;
  options.seed = 5;
  const scan::ScanResult frame = scan::run_scan(caster, footprint, device, pattern, options);
  const scan::ScanImages images = scan::make_images(frame);
  const auto points = io::cloud_points(frame);
  ASSERT_GT(points.size(), 20u);
  for (const std::set<std::string>& outputs :
       std::vector<std::set<std::string>>{{"las"}, {"las", "npy"}, {"npy"}, {"ply", "las"}}) {
    const fs::path dir = fresh_dir("few");
    io::ScanWriterSettings settings;
    settings.directory = dir;
    settings.outputs = outputs;
    io::ScanWriter writer(scan::describe_scan(pattern, blocks), scan::row_last_beams(pattern),
                          settings);
    scan::run_scan_blocks(
        caster, footprint, device, pattern, options, 0, pattern.size(), 7,
        [&](std::size_t first, std::span<scan::BeamResult> beams) { writer.add(first, beams); });
    writer.finish();
    std::size_t files = 0;
    const std::string label = fmt::format("{}", fmt::join(outputs, ","));
    if (outputs.count("las")) {
      ++files;
      EXPECT_EQ(read_file(dir / "points.las"), io::encode_las(points)) << label;
    }
    if (outputs.count("ply")) {
      ++files;
      EXPECT_EQ(read_file(dir / "points.ply"), io::encode_ply(points)) << label;
    }
    if (outputs.count("npy")) {
      files += 2;
      EXPECT_EQ(read_file(dir / "range.npy"), io::encode_npy(images.range)) << label;
      EXPECT_EQ(read_file(dir / "intensity.npy"), io::encode_npy(images.intensity)) << label;
    }
    EXPECT_EQ(entries(dir), files) << "no working file left: " << label;
    fs::remove_all(dir);
  }
}

// The picture of an image too large to hold: its colour limits selected in
// passes over pieces of the values and its rows drawn one at a time give the
// whole-frame picture's bytes (whose limits come from sorting the values), on
// images with NaN, infinities, negatives, ties, a constant image and an empty
// one, whatever the pieces' size.
TEST(ScanStream, RangeViewByRowsGivesTheWholeFrameBytes) {
  std::mt19937 random(33);
  std::uniform_real_distribution<float> spread(-3.0f, 40.0f);
  auto image_of = [&](int rows, int columns, int kind) {
    scan::Image image{rows, columns, std::vector<float>(static_cast<std::size_t>(rows) * columns)};
    for (std::size_t i = 0; i < image.values.size(); ++i) {
      float v = spread(random);
      if (kind == 1) v = std::round(v);                            // many ties
      if (kind == 2) v = 7.25f;                                    // constant
      if (kind == 3) v = std::numeric_limits<float>::quiet_NaN();  // no finite value
      if (kind == 0 && i % 7 == 3) v = std::numeric_limits<float>::quiet_NaN();
      if (kind == 0 && i % 97 == 5) v = std::numeric_limits<float>::infinity();
      if (kind == 0 && i % 89 == 7) v = -0.5f * v * v;
      image.values[i] = v;
    }
    return image;
  };
  for (const auto& [rows, columns] : {std::pair{37, 53}, std::pair{1, 700}, std::pair{400, 3}}) {
    for (int kind = 0; kind < 4; ++kind) {
      scan::ScanImages images;
      images.range = image_of(rows, columns, kind);
      images.intensity = image_of(rows, columns, (kind + 1) % 4);
      for (const std::size_t piece : {std::size_t{1}, std::size_t{64}, std::size_t{1} << 20}) {
        auto pass = [&](const scan::Image& image) -> io::ValuePass {
          return [&image, piece](const std::function<void(std::span<const float>)>& visit) {
            for (std::size_t first = 0; first < image.values.size(); first += piece)
              visit(std::span<const float>(image.values)
                        .subspan(first, std::min(piece, image.values.size() - first)));
          };
        };
        std::string png;
        int asked = -1;
        io::encode_range_view_rows(
            rows, columns, io::streamed_limits(pass(images.range)),
            io::streamed_limits(pass(images.intensity)),
            [&](int r, std::span<float> range, std::span<float> intensity) {
              EXPECT_GT(r, asked);  // in order, each row once
              asked = r;
              const auto at = static_cast<std::ptrdiff_t>(r) * columns;
              std::copy_n(images.range.values.begin() + at, columns, range.begin());
              std::copy_n(images.intensity.values.begin() + at, columns, intensity.begin());
            },
            [&](std::string_view bytes) { png += bytes; });
        EXPECT_EQ(png, io::encode_range_view(images))
            << rows << " x " << columns << ", kind " << kind << ", pieces of " << piece;
      }
    }
  }
}

TEST(ScanStream, OnDemandPatternsMakeTheStoredBeams) {
  scan::PatternSettings s;
  s.rate_hz = 2;
  s.revolutions = 3;
  s.azimuth_step_deg = 7.5;
  auto lists = [](scan::PatternListName l) -> std::vector<double> {
    return l == scan::PatternListName::azimuth ? std::vector<double>{-3, 1, 4}
                                               : std::vector<double>{-2, 0, 5, 9};
  };
  for (const char* name : {"mirror", "spherical", "spinning"}) {
    const auto stored = scan::make_pattern(name, s, lists, 1e-6);
    const auto lazy = scan::make_pattern(name, s, lists, 1e-6, scan::kMaxPatternBeams, true);
    ASSERT_EQ(lazy.size(), stored.beams.size()) << name;
    EXPECT_TRUE(lazy.beams.empty());
    std::vector<scan::Beam> made(lazy.size() - 2);
    lazy.get(2, made);  // from an offset, as a shard asks
    for (std::size_t i = 0; i < made.size(); ++i) {
      const auto &a = made[i], &b = stored.beams[i + 2];
      EXPECT_TRUE(a.row == b.row && a.column == b.column && a.time_s == b.time_s &&
                  a.origin_m == b.origin_m && a.direction == b.direction)
          << name << " beam " << i + 2;
    }
    EXPECT_EQ(scan::row_last_beams(lazy), scan::row_last_beams(stored)) << name;
  }
  // The spherical beams' directions are direction_from_angles' of their
  // pixel's azimuth (column 0: the largest) and elevation (row 0: the largest),
  // to the bit, though made from tabulated sines and cosines.
  const auto lazy = scan::make_pattern("spherical", s, lists, 1e-6, scan::kMaxPatternBeams, true);
  const std::vector<double> azimuths = {4, 1, -3}, elevations = {9, 5, 0, -2};
  std::vector<scan::Beam> all(lazy.size());
  lazy.get(0, all);
  for (const auto& b : all) {
    const auto expected = scan::direction_from_angles(azimuths[static_cast<std::size_t>(b.column)],
                                                      elevations[static_cast<std::size_t>(b.row)]);
    EXPECT_EQ(b.direction, expected) << b.row << ", " << b.column;
  }
}

TEST(ScanStream, StreamingOutputAppearsOnlyWhenCommitted) {
  const fs::path dir = fresh_dir("output");
  {
    io::StreamingOutput out(dir / "a.bin");
    out.append("hello world");
    out.write_at(6, "there");
    EXPECT_EQ(out.size(), 11u);
    EXPECT_FALSE(fs::exists(dir / "a.bin"));
    out.commit();
  }
  EXPECT_EQ(read_file(dir / "a.bin"), "hello there");
  {
    io::StreamingOutput dropped(dir / "b.bin");
    dropped.append("never");
  }
  EXPECT_FALSE(fs::exists(dir / "b.bin"));
  {
    io::OutputTransaction transaction;  // rolled back: nothing stays
    io::StreamingOutput out(dir / "c.bin");
    out.append(std::string(3 << 20, 'x'));  // past the buffer
    out.commit();
    EXPECT_FALSE(fs::exists(dir / "c.bin"));
    EXPECT_EQ(transaction.staged(), 1u);
  }
  EXPECT_FALSE(fs::exists(dir / "c.bin"));
  {
    io::OutputTransaction transaction;
    io::StreamingOutput out(dir / "d.bin");
    io::ScratchFile scratch(dir / "d.bin");
    scratch.append("0123456789");
    out.append("<");
    out.append_from(scratch.fd(), 2, 5);
    out.append(">");
    out.commit();
    transaction.commit();
  }
  EXPECT_EQ(read_file(dir / "d.bin"), "<23456>");
  EXPECT_EQ(entries(dir), 2u);  // a.bin, d.bin: no temporary or working file left
  EXPECT_THROW(io::StreamingOutput(dir / "missing" / "x"), std::runtime_error);
  fs::remove_all(dir);
}

TEST(ScanStream, AnInterruptedScanLeavesNothing) {
  const fs::path dir = fresh_dir("interrupted");
  // A scan of some seconds, interrupted after one (SIGINT, then SIGTERM).
  for (const char* signal : {"INT", "TERM"}) {
    const std::string command =
        std::string("timeout -s ") + signal +
        " 1 " TOFKIT_BINARY " --threads 1 --max-rows 50000000 scan --scene " +
        (kScenes / "blocks.toml").string() +
        " --pattern spherical --azimuth=-40:60:0.02 --elevation=-25:60:0.02 --shots 1 --out " +
        dir.string() + " 2>/dev/null";
    const int status = std::system(command.c_str());
    ASSERT_TRUE(WIFEXITED(status));
    EXPECT_EQ(WEXITSTATUS(status), 124) << "the scan should still have been running";
    EXPECT_EQ(entries(dir), 0u) << signal;
  }
  fs::remove_all(dir);
}
