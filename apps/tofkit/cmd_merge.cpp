// tofkit merge: shards' outputs (scan --shard K/N, sweep --shard K/N) joined
// into the files the one-process run writes, byte for byte.

#include <fmt/format.h>

#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include "app.hpp"
#include "scan_shard.hpp"
#include "sweep_run.hpp"
#include "tofkit/io/atomic_file.hpp"

namespace tofkit::app {
namespace {

struct MergeOptions {
  std::string out;
  std::vector<std::string> shards;
};

void run_merge(const MergeOptions& o) {
  std::vector<std::filesystem::path> dirs(o.shards.begin(), o.shards.end());
  for (const auto& d : dirs) {
    std::error_code ec;
    if (!std::filesystem::is_directory(d, ec))
      throw std::runtime_error("merge: '" + d.string() + "' is not a directory");
  }
  const bool scans = is_scan_shard(dirs.front());
  for (const auto& d : dirs) {
    if ((scans ? is_scan_shard(d) : is_sweep_shard(d)) != true)
      throw std::runtime_error("merge: '" + d.string() + "' is not a " +
                               (scans ? "scan" : "sweep") +
                               " shard's directory (shard.json with beams.bin, or sweep.csv)");
  }
  io::create_output_directories(o.out);
  if (scans) {
    const auto summary = merge_scan_shards(o.out, dirs);
    fmt::print(stderr, "tofkit merge: {} scan shards, {} beams, {} points -> {}/\n", dirs.size(),
               summary.beams, summary.points, o.out);
  } else {
    const auto rows = merge_sweep_shards(o.out, dirs);
    fmt::print(stderr, "tofkit merge: {} sweep shards, {} points -> {}/\n", dirs.size(), rows,
               o.out);
  }
}

const bool registered = register_command("merge", [](CLI::App& sub, AppContext&) {
  sub.description("join shards' outputs (scan/sweep --shard K/N) into the one-process files");
  auto o = std::make_shared<MergeOptions>();
  sub.add_option("--out", o->out, "output directory (made if missing)")->required();
  sub.add_option("shards", o->shards, "the shards' directories (every K of N once)")
      ->required()
      ->check(CLI::ExistingDirectory);
  sub.callback([o] { run_merge(*o); });
});

}  // namespace
}  // namespace tofkit::app
