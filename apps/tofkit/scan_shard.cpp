#include "scan_shard.hpp"

#include <algorithm>
#include <charconv>
#include <fstream>
#include <stdexcept>

#include "tofkit/io/input_file.hpp"

namespace tofkit::app {
namespace {

constexpr int kShardVersion = 1;
constexpr const char* kScanShardKind = "tofkit scan shard";
constexpr std::size_t kMergeBlockBeams = 1 << 15;

nlohmann::json pattern_json(const scan::BeamPattern& p) {
  return {{"name", p.name},
          {"rows", p.rows},
          {"columns", p.columns},
          {"shots_multiplier", p.shots_multiplier},
          {"column_positions_m", p.column_positions_m},
          {"sample_extent_m", p.sample_extent_m}};
}

nlohmann::json header_json(const ScanShardHeader& h) {
  return {{"kind", kScanShardKind},
          {"version", kShardVersion},
          {"shard", h.shard.index},
          {"shards", h.shard.count},
          {"first_beam", h.first_beam},
          {"last_beam", h.last_beam},
          {"beams", h.beams},
          {"record_bytes", sizeof(scan::BeamResult)},
          {"pattern", pattern_json(h.pattern)},
          {"row_last_beam", h.row_last_beam},
          {"has_model", h.has_model},
          {"ambient_c", h.ambient_c},
          {"outputs", h.outputs},
          {"scan", h.scan_record}};
}

// A shard's header; throws naming the file.
struct LoadedShard {
  std::filesystem::path directory;
  nlohmann::json json;
  ScanShardHeader header;
};

LoadedShard load_shard(const std::filesystem::path& directory) {
  const auto file = directory / "shard.json";
  LoadedShard s{directory, {}, {}};
  const std::string text = io::read_text_file(file, "shard file");
  try {
    s.json = nlohmann::json::parse(text);
    if (s.json.at("kind") != kScanShardKind)
      throw std::runtime_error("is not a scan shard (kind '" + s.json.at("kind").dump() + "')");
    if (s.json.at("version") != kShardVersion)
      throw std::runtime_error("shard version " + s.json.at("version").dump() +
                               ", this tofkit reads " + std::to_string(kShardVersion));
    if (s.json.at("record_bytes") != sizeof(scan::BeamResult))
      throw std::runtime_error("written by another build of tofkit (record size differs)");
    auto& h = s.header;
    h.shard = {s.json.at("shard").get<std::uint64_t>(), s.json.at("shards").get<std::uint64_t>()};
    h.first_beam = s.json.at("first_beam");
    h.last_beam = s.json.at("last_beam");
    h.beams = s.json.at("beams");
    const auto& p = s.json.at("pattern");
    h.pattern.name = p.at("name");
    h.pattern.rows = p.at("rows");
    h.pattern.columns = p.at("columns");
    h.pattern.shots_multiplier = p.at("shots_multiplier");
    h.pattern.column_positions_m = p.at("column_positions_m").get<std::vector<double>>();
    h.pattern.sample_extent_m = p.at("sample_extent_m");
    h.row_last_beam = s.json.at("row_last_beam").get<std::vector<std::size_t>>();
    h.has_model = s.json.at("has_model");
    h.ambient_c = s.json.at("ambient_c");
    h.outputs = s.json.at("outputs").get<std::set<std::string>>();
    h.scan_record = s.json.at("scan");
    if (h.shard.count == 0 || h.shard.index >= h.shard.count || h.first_beam > h.last_beam ||
        h.last_beam > h.beams ||
        h.row_last_beam.size() != static_cast<std::size_t>(std::max(0, h.pattern.rows)))
      throw std::runtime_error("inconsistent shard record");
  } catch (const nlohmann::json::exception& e) {
    throw std::runtime_error(file.string() + ": not a shard record: " + e.what());
  } catch (const std::runtime_error& e) {
    throw std::runtime_error(file.string() + ": " + e.what());
  }
  return s;
}

}  // namespace

std::pair<std::uint64_t, std::uint64_t> Shard::range(std::uint64_t total) const {
  // floor(total k / count) without overflow (k <= count < 2^32).
  const auto at = [&](std::uint64_t k) { return total / count * k + total % count * k / count; };
  return {at(index), at(index + 1)};
}

Shard parse_shard(const std::string& text, const std::string& option) {
  const auto slash = text.find('/');
  Shard s;
  auto number = [&](std::string_view part, std::uint64_t& v) {
    const auto r = std::from_chars(part.data(), part.data() + part.size(), v);
    return r.ec == std::errc() && r.ptr == part.data() + part.size() && !part.empty();
  };
  const std::string_view t(text);
  if (slash == std::string::npos || !number(t.substr(0, slash), s.index) ||
      !number(t.substr(slash + 1), s.count) || s.count == 0 || s.count > 1000000 ||
      s.index >= s.count) {
    throw std::invalid_argument(option + ": '" + text +
                                "' is not K/N with N = 1 .. 1000000 and K = 0 .. N - 1 (e.g. 0/4)");
  }
  return s;
}

std::string scan_sidecar(const std::string& file, const char* quantity, const char* units,
                         double scale, double offset, int rows, int columns,
                         const nlohmann::json& scan_record) {
  nlohmann::json j;
  j["file"] = file;
  j["quantity"] = quantity;
  j["units"] = units;
  j["value"] = "offset + scale * pixel";
  j["scale"] = scale;
  j["offset"] = offset;
  j["invalid_value"] = 0;
  j["rows"] = rows;
  j["columns"] = columns;
  j["frame"] = "REP-103: sensor looks along +x, z up; row 0 top, column 0 left";
  j["scan"] = scan_record;
  return j.dump(2) + "\n";
}

io::ScanWriterSettings scan_writer_settings(const std::filesystem::path& directory,
                                            const ScanShardHeader& header) {
  io::ScanWriterSettings s;
  s.directory = directory;
  s.outputs = header.outputs;
  s.ambient_c = header.ambient_c;
  s.has_model = header.has_model;
  const int rows = header.pattern.rows, columns = header.pattern.columns;
  const nlohmann::json record = header.scan_record;
  s.sidecar = [rows, columns, record](const std::string& file, const char* quantity,
                                      const char* units, double scale, double offset) {
    return scan_sidecar(file, quantity, units, scale, offset, rows, columns, record);
  };
  return s;
}

ScanShardWriter::ScanShardWriter(const std::filesystem::path& directory, ScanShardHeader header)
    : directory_(directory), header_(std::move(header)), beams_(directory / "beams.bin") {}

void ScanShardWriter::add(std::span<const scan::BeamResult> beams) {
  beams_.append(std::string_view(reinterpret_cast<const char*>(beams.data()), beams.size_bytes()));
  written_ += beams.size();
}

void ScanShardWriter::finish() {
  if (written_ != header_.last_beam - header_.first_beam)
    throw std::logic_error("ScanShardWriter: the shard's beams are not all written");
  beams_.commit();
  io::write_file_atomically(directory_ / "shard.json", header_json(header_).dump(1) + "\n");
}

bool is_scan_shard(const std::filesystem::path& directory) {
  std::error_code ec;
  return std::filesystem::is_regular_file(directory / "shard.json", ec) &&
         std::filesystem::exists(directory / "beams.bin", ec);
}

io::ScanWriter::Summary merge_scan_shards(const std::filesystem::path& out,
                                          const std::vector<std::filesystem::path>& directories) {
  if (directories.empty()) throw std::runtime_error("merge: no shard directory given");
  std::vector<LoadedShard> shards;
  for (const auto& d : directories) shards.push_back(load_shard(d));
  std::sort(shards.begin(), shards.end(), [](const LoadedShard& a, const LoadedShard& b) {
    return a.header.shard.index < b.header.shard.index;
  });
  // One scan: the same record apart from the range; every shard once.
  auto common = [](nlohmann::json j) {
    for (const char* k : {"shard", "first_beam", "last_beam"}) j.erase(k);
    return j;
  };
  const nlohmann::json reference = common(shards.front().json);
  const std::uint64_t count = shards.front().header.shard.count;
  std::uint64_t expected_first = 0;
  for (std::size_t k = 0; k < shards.size(); ++k) {
    const auto& s = shards[k];
    const std::string name = (s.directory / "shard.json").string();
    if (common(s.json) != reference)
      throw std::runtime_error("merge: " + name + " is a shard of another scan than " +
                               (shards.front().directory / "shard.json").string());
    if (k > 0 && s.header.shard.index == shards[k - 1].header.shard.index)
      throw std::runtime_error("merge: shard " + std::to_string(s.header.shard.index) + "/" +
                               std::to_string(count) + " is given twice (" + name + ")");
    if (s.header.shard.index != k)
      throw std::runtime_error("merge: shard " + std::to_string(k) + "/" + std::to_string(count) +
                               " is missing");
    if (s.header.first_beam != expected_first)
      throw std::runtime_error("merge: " + name + " does not start where the shard before ends");
    expected_first = s.header.last_beam;
    const auto size = std::filesystem::file_size(s.directory / "beams.bin");
    if (size != (s.header.last_beam - s.header.first_beam) * sizeof(scan::BeamResult))
      throw std::runtime_error("merge: " + (s.directory / "beams.bin").string() +
                               " has the wrong size (damaged or cut short)");
  }
  if (shards.size() != count)
    throw std::runtime_error("merge: shard " + std::to_string(shards.size()) + "/" +
                             std::to_string(count) + " is missing");
  const ScanShardHeader& h = shards.front().header;
  scan::ScanResult description;
  description.pattern = h.pattern;
  description.has_model = h.has_model;
  io::ScanWriter writer(description, h.row_last_beam, scan_writer_settings(out, h));
  std::vector<scan::BeamResult> block(kMergeBlockBeams);
  std::uint64_t next = 0;
  for (const auto& s : shards) {
    const auto file = s.directory / "beams.bin";
    io::note_input(file);
    std::ifstream in(file, std::ios::binary);
    for (std::uint64_t left = s.header.last_beam - s.header.first_beam; left > 0;) {
      const std::size_t n = static_cast<std::size_t>(std::min<std::uint64_t>(left, block.size()));
      in.read(reinterpret_cast<char*>(block.data()),
              static_cast<std::streamsize>(n * sizeof(scan::BeamResult)));
      if (!in) throw std::runtime_error("merge: cannot read " + file.string());
      writer.add(next, {block.data(), n});
      next += n;
      left -= n;
    }
  }
  return writer.finish();
}

}  // namespace tofkit::app
