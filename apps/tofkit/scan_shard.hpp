#pragma once
/// \file Shards of a scan (`tofkit scan --shard K/N`) and their merge
/// (`tofkit merge`). A shard is a fixed contiguous range of the pattern's
/// beams: beams [K n / N, (K + 1) n / N) of n, K = 0 .. N - 1. Each beam has
/// its own random stream, so a shard's beams are those of the whole run. A
/// shard's directory holds shard.json (what the merge needs: the pattern's
/// description, each image row's last beam, the outputs asked for, the
/// sidecars' scan record) and beams.bin (its beams' results, raw records in
/// beam order). The merge feeds the shards' beams, in order, through the
/// writer the one-process scan uses: the same bytes.

#include <cstdint>
#include <filesystem>
#include <memory>
#include <nlohmann/json.hpp>
#include <set>
#include <span>
#include <string>
#include <utility>
#include <vector>

#include "tofkit/io/atomic_file.hpp"
#include "tofkit/io/scan_writer.hpp"
#include "tofkit/scan/scanner.hpp"

namespace tofkit::app {

/// K of N (K = 0 .. N - 1).
struct Shard {
  std::uint64_t index = 0, count = 1;
  [[nodiscard]] bool whole() const { return count == 1; }
  /// Items [first, last) of `total` this shard takes.
  [[nodiscard]] std::pair<std::uint64_t, std::uint64_t> range(std::uint64_t total) const;
};

/// Parses "K/N"; throws std::invalid_argument naming `option`.
[[nodiscard]] Shard parse_shard(const std::string& text, const std::string& option);

/// A PNG plane's JSON sidecar (`tofkit scan`'s): `scan_record` is its "scan" object.
[[nodiscard]] std::string scan_sidecar(const std::string& file, const char* quantity,
                                       const char* units, double scale, double offset, int rows,
                                       int columns, const nlohmann::json& scan_record);

/// What a scan shard records beside its beams.
struct ScanShardHeader {
  Shard shard;
  std::uint64_t first_beam = 0, last_beam = 0, beams = 0;  ///< its range; the scan's total
  scan::BeamPattern pattern;                               ///< description only
  std::vector<std::size_t> row_last_beam;
  bool has_model = false;
  double ambient_c = 0;
  std::set<std::string> outputs;
  nlohmann::json scan_record;
};

/// Writes a shard's directory (shard.json, beams.bin) through the one writer.
class ScanShardWriter {
 public:
  ScanShardWriter(const std::filesystem::path& directory, ScanShardHeader header);
  void add(std::span<const scan::BeamResult> beams);
  void finish();

 private:
  std::filesystem::path directory_;
  ScanShardHeader header_;
  io::StreamingOutput beams_;
  std::uint64_t written_ = 0;
};

/// The scan's ScanWriter settings for `outputs` into `directory` (the sidecars from scan_record).
[[nodiscard]] io::ScanWriterSettings scan_writer_settings(const std::filesystem::path& directory,
                                                          const ScanShardHeader& header);

/// Is `directory` a scan shard's (has shard.json of a scan)?
[[nodiscard]] bool is_scan_shard(const std::filesystem::path& directory);

/// Merges scan shards' directories into `out` (the one-process scan's
/// files); throws std::runtime_error naming the shard that is missing,
/// doubled, of another scan or damaged. Returns the writer's summary.
io::ScanWriter::Summary merge_scan_shards(const std::filesystem::path& out,
                                          const std::vector<std::filesystem::path>& shards);

}  // namespace tofkit::app
