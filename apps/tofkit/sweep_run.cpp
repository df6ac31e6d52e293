#include "sweep_run.hpp"

#include <fmt/format.h>
#include <tbb/parallel_for.h>
#include <toml++/toml.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstring>
#include <fstream>
#include <map>
#include <nlohmann/json.hpp>
#include <set>
#include <sstream>
#include <stdexcept>

#include "characterize_registry.hpp"
#include "mpi_world.hpp"
#include "tofkit/device/config_limits.hpp"
#include "tofkit/device/virtual_rangefinder.hpp"
#include "tofkit/experiments/measurement_grid.hpp"
#include "tofkit/io/atomic_file.hpp"
#include "tofkit/io/input_file.hpp"
#include "tofkit/io/plot.hpp"
#include "tofkit/io/sweep_plan.hpp"
#include "tofkit/physics/link_budget.hpp"

namespace tofkit::app {
namespace {

namespace fs = std::filesystem;

constexpr std::uint64_t kBatchPoints = 32;
constexpr int kJournalVersion = 1;
constexpr const char* kSweepShardKind = "tofkit sweep shard";

std::vector<std::string> split_line(const std::string& line) {
  std::vector<std::string> out;
  std::size_t start = 0;
  for (std::size_t comma; (comma = line.find(',', start)) != std::string::npos; start = comma + 1)
    out.push_back(line.substr(start, comma - start));
  out.push_back(line.substr(start));
  return out;
}

}  // namespace

io::SweepBase sweep_base(const AppContext& ctx) {
  io::SweepBase base{ctx.preset, ctx.config_file, ctx.overrides, {}, {}};
  for (const auto& [name, runner] : characterize_experiments()) base.experiments.push_back(name);
  // A plan's [characterize]: the experiment on the point's device (analytic
  // mode), its findings as the row's columns.
  base.characterize = [](const std::string& experiment, const device::DeviceConfig& config,
                         std::uint64_t seed) {
    const device::VirtualRangefinder device(config);
    std::vector<std::pair<std::string, double>> findings;
    for (const auto& f : characterize_experiments().at(experiment)(device, seed).findings)
      findings.emplace_back(f.name, f.value);
    return findings;
  };
  return base;
}

SweepRunSummary run_sweep(const io::SweepPlan& plan, const AppContext& ctx, const fs::path& out,
                          std::uint64_t first, std::uint64_t last, bool plots,
                          const std::string& shard_record_json) {
  const MpiWorld world = mpi_world();
  const io::SweepBase base = sweep_base(ctx);
  if (world.rank == 0) io::create_output_directories(out);
  const fs::path journal = out / ".sweep.journal";
  const std::string stamp = fmt::format("# tofkit sweep journal {} {:016x} {} {}", kJournalVersion,
                                        plan.fingerprint, first, last);
  const std::string header = io::sweep_header(plan);
  std::map<std::uint64_t, std::string> rows;
  SweepRunSummary summary;
  summary.points = last - first;
  // Resuming: the finished points of an interrupted run of the same plan.
  // (The journal is the one file a sweep keeps outside the all-or-nothing
  // writer: what makes an interrupted sweep resumable.)
  if (world.rank == 0 && fs::exists(journal)) {
    std::ifstream in(journal);
    std::string line;
    std::getline(in, line);
    if (line != stamp)
      throw std::runtime_error(journal.string() +
                               ": left by another plan, configuration or shard (remove it to "
                               "start over)");
    while (std::getline(in, line)) {
      const auto tab = line.find('\t');
      if (tab == std::string::npos) break;  // a line cut short by the interruption
      std::uint64_t index = 0;
      try {
        index = std::stoull(line.substr(0, tab));
      } catch (const std::exception&) {
        break;
      }
      if (index >= first && index < last) rows[index] = line.substr(tab + 1);
    }
    summary.resumed = rows.size();
  }
  std::vector<std::uint64_t> missing;
  for (std::uint64_t i = first; i < last; ++i)
    if (rows.count(i) == 0) missing.push_back(i);
  if (world.size > 1) {
    // Rank 0's list (it alone reads the journal) on every rank.
    std::string bytes(reinterpret_cast<const char*>(missing.data()),
                      missing.size() * sizeof(std::uint64_t));
    mpi_broadcast(bytes);
    missing.resize(bytes.size() / sizeof(std::uint64_t));
    std::memcpy(missing.data(), bytes.data(), bytes.size());
  }
  const std::size_t batches = (missing.size() + kBatchPoints - 1) / kBatchPoints;
  auto make_batch = [&](std::size_t b, std::string& joined) {
    const std::size_t begin = b * kBatchPoints;
    const std::size_t n = std::min<std::size_t>(kBatchPoints, missing.size() - begin);
    std::vector<std::string> batch(n);
    tbb::parallel_for(std::size_t{0}, n, [&](std::size_t k) {
      batch[k] = io::sweep_row(plan, base, missing[begin + k]);
    });
    for (const auto& row : batch) joined += row + "\n";
  };
  if (world.rank != 0) {
    mpi_ordered_chunks(batches, make_batch, {});
    return summary;
  }
  {
    std::ofstream journal_out(journal, std::ios::app);
    if (!journal_out) throw std::runtime_error("cannot write '" + journal.string() + "'");
    if (summary.resumed == 0 && fs::file_size(journal) == 0) journal_out << stamp << "\n";
    journal_out.flush();
    const bool tty = ::isatty(STDERR_FILENO) != 0;
    auto last_report = std::chrono::steady_clock::now();
    auto report = [&](bool final) {
      const auto now = std::chrono::steady_clock::now();
      if (!final && now - last_report < std::chrono::seconds(tty ? 0 : 5)) return;
      last_report = now;
      fmt::print(stderr, "{}tofkit sweep: {} of {} points ({} resumed){}", tty ? "\r" : "",
                 rows.size(), summary.points, summary.resumed, tty && !final ? "" : "\n");
    };
    mpi_ordered_chunks(batches, make_batch, [&](std::size_t b, std::string_view joined) {
      std::size_t k = b * kBatchPoints;
      for (std::size_t start = 0, eol; (eol = joined.find('\n', start)) != std::string::npos;
           start = eol + 1, ++k) {
        const std::string row(joined.substr(start, eol - start));
        journal_out << missing[k] << '\t' << row << '\n';
        rows[missing[k]] = row;
        ++summary.run;
      }
      journal_out.flush();
      if (!journal_out) throw std::runtime_error("cannot write '" + journal.string() + "'");
      report(false);
    });
    report(true);
  }
  std::string table = header + "\n";
  for (const auto& [index, row] : rows) table += row + "\n";
  io::write_file_atomically(out / "sweep.csv", table);
  if (!shard_record_json.empty()) io::write_file_atomically(out / "shard.json", shard_record_json);
  if (plots) write_sweep_plots(out, table, plan.axes.size());
  std::error_code ec;
  fs::remove(journal, ec);
  return summary;
}

bool is_sweep_shard(const fs::path& directory) {
  std::error_code ec;
  if (!fs::is_regular_file(directory / "shard.json", ec) ||
      !fs::is_regular_file(directory / "sweep.csv", ec))
    return false;
  try {
    return nlohmann::json::parse(io::read_text_file(directory / "shard.json", "shard file"))
               .value("kind", "") == kSweepShardKind;
  } catch (const std::exception&) {
    return false;
  }
}

std::uint64_t merge_sweep_shards(const fs::path& out, const std::vector<fs::path>& shards) {
  struct Loaded {
    fs::path dir;
    nlohmann::json json;
    std::string table;
  };
  std::vector<Loaded> loaded;
  for (const auto& d : shards) {
    const fs::path file = d / "shard.json";
    Loaded l{d, {}, io::read_text_file(d / "sweep.csv", "sweep table")};
    try {
      l.json = nlohmann::json::parse(io::read_text_file(file, "shard file"));
      (void)l.json.at("shard").get<std::uint64_t>();
      (void)l.json.at("shards").get<std::uint64_t>();
      (void)l.json.at("first_point").get<std::uint64_t>();
      (void)l.json.at("last_point").get<std::uint64_t>();
    } catch (const nlohmann::json::exception& e) {
      throw std::runtime_error(file.string() + ": not a sweep shard record: " + e.what());
    }
    loaded.push_back(std::move(l));
  }
  std::sort(loaded.begin(), loaded.end(), [](const Loaded& a, const Loaded& b) {
    return a.json["shard"].get<std::uint64_t>() < b.json["shard"].get<std::uint64_t>();
  });
  auto common = [](nlohmann::json j) {
    for (const char* k : {"shard", "first_point", "last_point"}) j.erase(k);
    return j;
  };
  const auto reference = common(loaded.front().json);
  const std::uint64_t count = loaded.front().json["shards"];
  std::string table;
  std::uint64_t next = 0, rows = 0;
  for (std::size_t k = 0; k < loaded.size(); ++k) {
    const auto& l = loaded[k];
    const std::string name = (l.dir / "shard.json").string();
    if (common(l.json) != reference)
      throw std::runtime_error("merge: " + name + " is a shard of another sweep");
    if (l.json["shard"] != k)
      throw std::runtime_error(
          fmt::format("merge: sweep shard {}/{} is {}", k, count,
                      k > 0 && l.json["shard"] == k - 1 ? "given twice" : "missing"));
    if (l.json["first_point"] != next)
      throw std::runtime_error("merge: " + name + " does not start where the shard before ends");
    next = l.json["last_point"];
    const auto eol = l.table.find('\n');
    if (eol == std::string::npos || l.table.substr(0, eol) != reference.value("header", ""))
      throw std::runtime_error("merge: " + (l.dir / "sweep.csv").string() +
                               ": not the shard's table (header differs)");
    if (k == 0) table = l.table.substr(0, eol + 1);
    const std::string body = l.table.substr(eol + 1);
    const auto lines = static_cast<std::uint64_t>(std::count(body.begin(), body.end(), '\n'));
    if (lines !=
        l.json["last_point"].get<std::uint64_t>() - l.json["first_point"].get<std::uint64_t>())
      throw std::runtime_error("merge: " + (l.dir / "sweep.csv").string() +
                               " has the wrong number of rows (damaged or cut short)");
    table += body;
    rows += lines;
  }
  if (loaded.size() != count)
    throw std::runtime_error(
        fmt::format("merge: sweep shard {}/{} is missing", loaded.size(), count));
  io::write_file_atomically(out / "sweep.csv", table);
  write_sweep_plots(out, table, reference.value("axes", std::size_t{1}));
  return rows;
}

void write_sweep_plots(const fs::path& out, const std::string& table, std::size_t axis_count) {
  std::istringstream in(table);
  std::string line;
  std::getline(in, line);
  const std::vector<std::string> columns = split_line(line);
  std::vector<std::vector<std::string>> rows;
  while (std::getline(in, line)) rows.push_back(split_line(line));
  if (rows.empty() || axis_count == 0 || axis_count >= columns.size()) return;
  // x: the first axis (its position among its values when they are not numbers).
  std::vector<std::string> x_values;
  for (const auto& r : rows)
    if (std::find(x_values.begin(), x_values.end(), r[0]) == x_values.end())
      x_values.push_back(r[0]);
  auto x_of = [&](const std::string& v) {
    double d = 0;
    if (!io::parse_number(v, d)) return d;
    return static_cast<double>(std::find(x_values.begin(), x_values.end(), v) - x_values.begin());
  };
  constexpr std::size_t kMaxSeries = 16;
  // (gnuplot's enhanced text reads '_' as a subscript.)
  auto label = [](std::string text) {
    std::replace(text.begin(), text.end(), '_', ' ');
    return text;
  };
  for (std::size_t f = axis_count; f < columns.size(); ++f) {
    io::PlotSpec spec;
    spec.name = "sweep_" + columns[f];
    spec.x_label = label(columns[0]);
    spec.y_label = label(columns[f]);
    spec.title = label(columns[f] + " over " + columns[0]);
    std::map<std::string, std::size_t> series_of;
    for (const auto& r : rows) {
      std::string key;
      for (std::size_t a = 1; a < axis_count; ++a)
        key += (key.empty() ? "" : ", ") + columns[a] + "=" + r[a];
      auto it = series_of.find(key);
      if (it == series_of.end()) {
        if (spec.series.size() == kMaxSeries) continue;
        it = series_of.emplace(key, spec.series.size()).first;
        spec.series.push_back(
            {label(key.empty() ? columns[f] : key), {}, {}, "linespoints pt 7 ps 0.6"});
      }
      double y = 0;
      if (f < r.size() && !io::parse_number(r[f], y)) {
        spec.series[it->second].x.push_back(x_of(r[0]));
        spec.series[it->second].y.push_back(y);
      }
    }
    if (spec.series.size() == kMaxSeries) spec.title += " (first 16 series)";
    io::write_plot(out, spec, true);
  }
}

}  // namespace tofkit::app
