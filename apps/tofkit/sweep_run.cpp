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

#include "mpi_world.hpp"
#include "tofkit/device/config_limits.hpp"
#include "tofkit/device/virtual_rangefinder.hpp"
#include "tofkit/experiments/measurement_grid.hpp"
#include "tofkit/io/atomic_file.hpp"
#include "tofkit/io/input_file.hpp"
#include "tofkit/io/plot.hpp"
#include "tofkit/physics/link_budget.hpp"

namespace tofkit::app {
namespace {

namespace fs = std::filesystem;

constexpr const char* kConditions[] = {"distance_m", "reflectance", "angle_deg", "ambient_c",
                                       "seed"};
constexpr std::uint64_t kBatchPoints = 32;
constexpr int kJournalVersion = 1;
constexpr const char* kSweepShardKind = "tofkit sweep shard";
constexpr double kDetectionSnr = 10.0;  // the paper's detection criterion (budget's)

bool is_condition(const std::string& key) {
  return std::find_if(std::begin(kConditions), std::end(kConditions),
                      [&](const char* c) { return key == c; }) != std::end(kConditions);
}

std::uint64_t fnv1a(std::uint64_t h, std::string_view bytes) {
  for (const unsigned char c : bytes) h = (h ^ c) * 1099511628211ull;
  return h;
}

// Checks a condition's value; "" when fine.
std::string condition_problem(const std::string& key, double v) {
  if (!std::isfinite(v)) return "not a finite number";
  if (key == "distance_m" && !(v > 0 && v <= 1e5)) return "must be in (0, 100000] m";
  if (key == "reflectance" && !(v > 0 && v <= 1)) return "must be in (0, 1]";
  if (key == "angle_deg" && !(v >= 0 && v <= 89.9)) return "must be in [0, 89.9] degrees";
  if (key == "ambient_c" && !(v >= -60 && v <= 150)) return "must be in [-60, 150] C";
  if (key == "seed" && !(v >= 0 && v == std::floor(v) && v < 9.007e15))
    return "must be a whole number >= 0";
  return "";
}

std::string format_number(double v) {
  return fmt::format("{}", v);
}

struct PointSetting {
  std::vector<std::string> sets;  // device overrides
  double distance_m, reflectance, angle_deg, ambient_c;
  std::uint64_t seed;
  std::vector<std::string> values;  // the axes' values
};

PointSetting point_setting(const SweepPlan& plan, std::uint64_t index) {
  PointSetting p{{},
                 plan.distance_m,
                 plan.reflectance,
                 plan.angle_deg,
                 plan.ambient_c,
                 plan.seed,
                 std::vector<std::string>(plan.axes.size())};
  // Last axis fastest.
  for (std::size_t k = plan.axes.size(); k-- > 0;) {
    const auto& axis = plan.axes[k];
    const std::size_t i = index % axis.values.size();
    index /= axis.values.size();
    p.values[k] = axis.values[i];
    if (axis.device_key) {
      p.sets.push_back(axis.key + "=" + axis.values[i]);
    } else {
      const double v = axis.numbers[i];
      if (axis.key == "distance_m") p.distance_m = v;
      if (axis.key == "reflectance") p.reflectance = v;
      if (axis.key == "angle_deg") p.angle_deg = v;
      if (axis.key == "ambient_c") p.ambient_c = v;
      if (axis.key == "seed") p.seed = static_cast<std::uint64_t>(v);
    }
  }
  std::reverse(p.sets.begin(), p.sets.end());  // the file's order
  return p;
}

device::DeviceConfig point_config(const AppContext& ctx, const std::vector<std::string>& sets) {
  std::vector<std::string> overrides = ctx.overrides;
  overrides.insert(overrides.end(), sets.begin(), sets.end());
  return io::load_device_config(ctx.preset, ctx.config_file, overrides);
}

std::vector<std::string> split_line(const std::string& line) {
  std::vector<std::string> out;
  std::size_t start = 0;
  for (std::size_t comma; (comma = line.find(',', start)) != std::string::npos; start = comma + 1)
    out.push_back(line.substr(start, comma - start));
  out.push_back(line.substr(start));
  return out;
}

}  // namespace

std::uint64_t SweepPlan::points() const {
  std::uint64_t n = 1;
  for (const auto& a : axes) n *= a.values.size();
  return n;
}

SweepPlan load_sweep_plan(const fs::path& file, const AppContext& ctx) {
  const std::string text = io::read_text_file(file, "plan file");
  toml::table root;
  try {
    root = toml::parse(text, file.string());
  } catch (const toml::parse_error& e) {
    throw std::invalid_argument(fmt::format("{}:{}:{}: {}", file.string(), e.source().begin.line,
                                            e.source().begin.column, e.description()));
  }
  auto where = [&](const toml::node& node) {
    return file.string() + ":" + std::to_string(node.source().begin.line);
  };
  SweepPlan plan;
  plan.ambient_c = device::Conditions{}.ambient_c;
  std::set<std::string> given;  // conditions given as scalars
  bool has_measure = false;
  for (const auto& [key, node] : root) {
    const std::string k(key.str());
    if (k != "axes" && k != "measure" && k != "budget")
      throw std::invalid_argument(where(node) + ": unknown key '" + k +
                                  "' (a plan has [axes], [measure] and [budget])");
    if (!node.is_table())
      throw std::invalid_argument(where(node) + ": '" + k + "' must be a table ([" + k + "])");
  }
  // Axes in the file's order.
  if (const toml::table* axes = root["axes"].as_table()) {
    std::vector<std::pair<std::uint32_t, std::string>> order;
    for (const auto& [key, node] : *axes) order.emplace_back(node.source().begin.line, key.str());
    std::sort(order.begin(), order.end());
    for (const auto& [line, key] : order) {
      const toml::node& node = *axes->get(key);
      const std::string at = where(node) + ": axis '" + key + "'";
      const toml::array* values = node.as_array();
      if (values == nullptr || values->empty())
        throw std::invalid_argument(at + ": expected a non-empty list of values");
      SweepAxis axis{key, !is_condition(key), {}, {}};
      for (const auto& v : *values) {
        if (auto d = v.value<double>(); d && (v.is_number())) {
          axis.values.push_back(format_number(*d));
          axis.numbers.push_back(*d);
        } else if (auto b = v.value<bool>(); b && v.is_boolean()) {
          axis.values.push_back(*b ? "true" : "false");
          axis.numbers.push_back(*b ? 1 : 0);
        } else if (auto s = v.value<std::string>(); s && v.is_string()) {
          if (s->find_first_of(",\n\r\"") != std::string::npos)
            throw std::invalid_argument(at + ": a value may not hold a comma, quote or newline");
          axis.values.push_back(*s);
          axis.numbers.push_back(std::nan(""));
        } else {
          throw std::invalid_argument(at + ": values must be numbers, booleans or strings");
        }
        if (!axis.device_key) {
          if (!v.is_number()) throw std::invalid_argument(at + ": a condition takes numbers");
          const std::string problem = condition_problem(key, axis.numbers.back());
          if (!problem.empty())
            throw std::invalid_argument(at + ": " + axis.values.back() + " " + problem);
        }
      }
      if (axis.device_key) {
        // Through the same path as --set: an unknown key or a bad value is
        // refused here, naming the plan's line.
        for (const auto& value : axis.values) {
          try {
            (void)point_config(ctx, {key + "=" + value});
          } catch (const std::exception& e) {
            throw std::invalid_argument(at + ": " + e.what());
          }
        }
      }
      plan.axes.push_back(std::move(axis));
    }
  }
  if (plan.axes.empty()) throw std::invalid_argument(file.string() + ": [axes] lists no axis");
  if (const toml::table* measure = root["measure"].as_table()) {
    has_measure = true;
    for (const auto& [key, node] : *measure) {
      const std::string k(key.str());
      const std::string at = where(node) + ": [measure] " + k;
      if (k == "shots" || k == "count") {
        const auto v = node.value<std::int64_t>();
        if (!v || !node.is_integer() || *v < 1 || *v > (k == "shots" ? 10'000'000 : 1'000'000))
          throw std::invalid_argument(
              at + ": expected a whole number >= 1" +
              std::string(k == "shots" ? " (at most 1e7)" : " (at most 1e6)"));
        (k == "shots" ? plan.shots : plan.count) = static_cast<int>(*v);
      } else if (k == "mode") {
        const auto v = node.value<std::string>();
        if (!v || (*v != "analytic" && *v != "waveform"))
          throw std::invalid_argument(at + ": expected \"analytic\" or \"waveform\"");
        plan.mode = *v;
      } else if (is_condition(k)) {
        const auto v = node.value<double>();
        if (!v || !node.is_number()) throw std::invalid_argument(at + ": expected a number");
        const std::string problem = condition_problem(k, *v);
        if (!problem.empty()) throw std::invalid_argument(at + ": " + problem);
        if (k == "distance_m") plan.distance_m = *v;
        if (k == "reflectance") plan.reflectance = *v;
        if (k == "angle_deg") plan.angle_deg = *v;
        if (k == "ambient_c") plan.ambient_c = *v;
        if (k == "seed") plan.seed = static_cast<std::uint64_t>(*v);
        given.insert(k);
      } else {
        throw std::invalid_argument(at +
                                    ": unknown key (known: shots, count, mode, distance_m, "
                                    "reflectance, angle_deg, ambient_c, seed)");
      }
    }
  }
  plan.measure = has_measure;
  if (const toml::table* budget = root["budget"].as_table()) {
    plan.budget = true;
    for (const auto& [key, node] : *budget)
      throw std::invalid_argument(where(node) + ": [budget] " + std::string(key.str()) +
                                  ": unknown key ([budget] takes none: it adds received_power_w, "
                                  "snr and range_at_snr10_m)");
  }
  if (!plan.measure && !plan.budget)
    throw std::invalid_argument(file.string() + ": nothing to measure: add [measure] or [budget]");
  for (const char* needed : {"distance_m", "reflectance"}) {
    const bool on_axis = std::any_of(plan.axes.begin(), plan.axes.end(),
                                     [&](const SweepAxis& a) { return a.key == needed; });
    if (!on_axis && given.count(needed) == 0)
      throw std::invalid_argument(file.string() + ": " + needed +
                                  " is neither an axis nor given in [measure]");
  }
  if (static_cast<double>(plan.points()) > static_cast<double>(io::resource_limits().max_rows))
    throw std::invalid_argument(
        fmt::format("{}: {} points, more than the row limit of {} (raise "
                    "it with --max-rows)",
                    file.string(), plan.points(), io::resource_limits().max_rows));
  std::uint64_t h = fnv1a(1469598103934665603ull, text);
  h = fnv1a(h, ctx.preset + "\n");
  if (ctx.config_file) h = fnv1a(h, io::read_text_file(*ctx.config_file, "config file"));
  for (const auto& o : ctx.overrides) h = fnv1a(h, o + "\n");
  plan.fingerprint = h;
  return plan;
}

std::string sweep_header(const SweepPlan& plan) {
  std::string h;
  for (const auto& a : plan.axes) h += (h.empty() ? "" : ",") + a.key;
  if (plan.measure)
    h += ",valid,shots_valid_mean,distance_raw_mean_m,distance_raw_std_m,bias_m,"
         "pulse_width_mean_ns,amplitude_mean";
  if (plan.budget) h += ",received_power_w,snr,range_at_snr10_m";
  return h;
}

std::string sweep_row(const SweepPlan& plan, const AppContext& ctx, std::uint64_t index) {
  const PointSetting p = point_setting(plan, index);
  const device::DeviceConfig config = point_config(ctx, p.sets);
  std::string row;
  for (const auto& v : p.values) row += (row.empty() ? "" : ",") + v;
  auto num = [&](double v) { row += "," + (std::isfinite(v) ? format_number(v) : std::string()); };
  if (plan.measure) {
    const std::string problem = device::check_plate_echo(config, p.distance_m, p.angle_deg);
    if (!problem.empty())
      throw std::invalid_argument("sweep point " + std::to_string(index) + " (" + row +
                                  "): " + problem);
    std::vector<experiments::PlannedMeasurement> measurements(
        static_cast<std::size_t>(plan.count),
        experiments::plate(p.distance_m, p.reflectance, p.ambient_c, p.angle_deg, plan.shots));
    const device::VirtualRangefinder rangefinder(config, simulation_mode(plan.mode));
    const auto records = experiments::run(rangefinder, measurements, p.seed);
    double n = 0, sum = 0, sum2 = 0, width = 0, amplitude = 0, shots = 0;
    for (const auto& r : records) {
      shots += r.raw.shots_valid;
      if (!r.raw.has_echo() || !std::isfinite(r.raw.distance_raw_m)) continue;
      n += 1;
      sum += r.raw.distance_raw_m;
      sum2 += r.raw.distance_raw_m * r.raw.distance_raw_m;
      width += r.raw.pulse_width_ns;
      amplitude += r.raw.amplitude;
    }
    const double nan = std::nan("");
    const double mean = n > 0 ? sum / n : nan;
    row += "," + format_number(n);
    num(shots / static_cast<double>(records.size()));
    num(mean);
    num(n > 1 ? std::sqrt(std::max(0.0, (sum2 - n * mean * mean) / (n - 1))) : nan);
    num(mean - p.distance_m);
    num(n > 0 ? width / n : nan);
    num(n > 0 ? amplitude / n : nan);
  }
  if (plan.budget) {
    const auto& link = config.link;
    const auto b = physics::link_budget_at(link, p.distance_m, p.reflectance, p.angle_deg,
                                           link.receiver.nominal_temperature_c);
    num(b.received_power_w);
    num(b.snr);
    num(physics::range_at_snr(link, kDetectionSnr, p.reflectance, p.angle_deg));
  }
  return row;
}

SweepRunSummary run_sweep(const SweepPlan& plan, const AppContext& ctx, const fs::path& out,
                          std::uint64_t first, std::uint64_t last, bool plots,
                          const std::string& shard_record_json) {
  const MpiWorld world = mpi_world();
  if (world.rank == 0) io::create_output_directories(out);
  const fs::path journal = out / ".sweep.journal";
  const std::string stamp = fmt::format("# tofkit sweep journal {} {:016x} {} {}", kJournalVersion,
                                        plan.fingerprint, first, last);
  const std::string header = sweep_header(plan);
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
  auto make_batch = [&](std::size_t b) {
    const std::size_t begin = b * kBatchPoints;
    const std::size_t n = std::min<std::size_t>(kBatchPoints, missing.size() - begin);
    std::vector<std::string> batch(n);
    tbb::parallel_for(std::size_t{0}, n,
                      [&](std::size_t k) { batch[k] = sweep_row(plan, ctx, missing[begin + k]); });
    std::string joined;
    for (const auto& row : batch) joined += row + "\n";
    return joined;
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
