#include "tofkit/io/sweep_plan.hpp"

#include <fmt/format.h>
#include <fmt/ranges.h>
#include <toml++/toml.h>

#include <algorithm>
#include <cmath>
#include <set>
#include <stdexcept>

#include "tofkit/device/config_limits.hpp"
#include "tofkit/device/virtual_rangefinder.hpp"
#include "tofkit/experiments/measurement_grid.hpp"
#include "tofkit/io/config_file.hpp"
#include "tofkit/io/input_file.hpp"
#include "tofkit/physics/link_budget.hpp"

namespace tofkit::io {
namespace {

namespace fs = std::filesystem;

constexpr const char* kConditions[] = {"distance_m", "reflectance", "angle_deg", "ambient_c",
                                       "seed"};
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

device::DeviceConfig point_config(const SweepBase& ctx, const std::vector<std::string>& sets) {
  std::vector<std::string> overrides = ctx.overrides;
  overrides.insert(overrides.end(), sets.begin(), sets.end());
  return load_device_config(ctx.preset, ctx.config_file, overrides);
}

}  // namespace

std::uint64_t SweepPlan::points() const {
  std::uint64_t n = 1;
  for (const auto& a : axes) n *= a.values.size();
  return n;
}

SweepPlan load_sweep_plan(const fs::path& file, const SweepBase& ctx) {
  const std::string text = read_text_file(file, "plan file");
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
    if (k != "axes" && k != "measure" && k != "budget" && k != "characterize")
      throw std::invalid_argument(where(node) + ": unknown key '" + k +
                                  "' (a plan has [axes], [measure], [budget] and [characterize])");
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
  if (const toml::table* characterize = root["characterize"].as_table()) {
    for (const auto& [key, node] : *characterize) {
      const std::string at = where(node) + ": [characterize] " + std::string(key.str());
      if (key.str() != "experiment")
        throw std::invalid_argument(at + ": unknown key ([characterize] takes experiment)");
      const auto name = node.value<std::string>();
      if (!name || !node.is_string()) throw std::invalid_argument(at + ": expected a name");
      if (!ctx.characterize)
        throw std::invalid_argument(at +
                                    ": characterize experiments run from the tofkit "
                                    "command line only");
      if (std::find(ctx.experiments.begin(), ctx.experiments.end(), *name) == ctx.experiments.end())
        throw std::invalid_argument(fmt::format("{}: unknown experiment '{}' (known: {})", at,
                                                *name, fmt::join(ctx.experiments, ", ")));
      plan.characterize = *name;
    }
    if (plan.characterize.empty())
      throw std::invalid_argument(file.string() + ": [characterize] names no experiment");
  }
  if (!plan.measure && !plan.budget && plan.characterize.empty())
    throw std::invalid_argument(file.string() +
                                ": nothing to measure: add [measure], [budget] or [characterize]");
  for (const char* needed : {"distance_m", "reflectance"}) {
    if (!plan.measure && !plan.budget) break;  // (a characterize experiment sets its own)
    const bool on_axis = std::any_of(plan.axes.begin(), plan.axes.end(),
                                     [&](const SweepAxis& a) { return a.key == needed; });
    if (!on_axis && given.count(needed) == 0)
      throw std::invalid_argument(file.string() + ": " + needed +
                                  " is neither an axis nor given in [measure]");
  }
  if (static_cast<double>(plan.points()) > static_cast<double>(resource_limits().max_rows))
    throw std::invalid_argument(
        fmt::format("{}: {} points, more than the row limit of {} (raise "
                    "it with --max-rows)",
                    file.string(), plan.points(), resource_limits().max_rows));
  if (!plan.characterize.empty()) {
    // The experiment's findings name its columns: those of the first point
    // (an experiment reports the same findings at every setting).
    const PointSetting first = point_setting(plan, 0);
    for (const auto& [name, value] :
         ctx.characterize(plan.characterize, point_config(ctx, first.sets), first.seed))
      plan.characterize_findings.push_back(name);
  }
  std::uint64_t h = fnv1a(1469598103934665603ull, text);
  h = fnv1a(h, ctx.preset + "\n");
  if (ctx.config_file) h = fnv1a(h, read_text_file(*ctx.config_file, "config file"));
  for (const auto& o : ctx.overrides) h = fnv1a(h, o + "\n");
  plan.fingerprint = h;
  return plan;
}

std::string sweep_header(const SweepPlan& plan) {
  std::string h;
  for (const auto& a : plan.axes) {
    if (!h.empty()) h.push_back(',');
    h.append(a.key);
  }
  if (plan.measure)
    h += ",valid,shots_valid_mean,distance_raw_mean_m,distance_raw_std_m,bias_m,"
         "pulse_width_mean_ns,amplitude_mean";
  if (plan.budget) h += ",received_power_w,snr,range_at_snr10_m";
  for (const auto& name : plan.characterize_findings) h += "," + plan.characterize + "." + name;
  return h;
}

std::string sweep_row(const SweepPlan& plan, const SweepBase& ctx, std::uint64_t index) {
  const PointSetting p = point_setting(plan, index);
  const device::DeviceConfig config = point_config(ctx, p.sets);
  std::string row;
  for (const auto& v : p.values) {
    if (!row.empty()) row.push_back(',');
    row.append(v);
  }
  auto num = [&](double v) {
    row.push_back(',');
    if (std::isfinite(v)) row.append(format_number(v));
  };
  if (plan.measure) {
    const std::string problem = device::check_plate_echo(config, p.distance_m, p.angle_deg);
    if (!problem.empty())
      throw std::invalid_argument("sweep point " + std::to_string(index) + " (" + row +
                                  "): " + problem);
    std::vector<experiments::PlannedMeasurement> measurements(
        static_cast<std::size_t>(plan.count),
        experiments::plate(p.distance_m, p.reflectance, p.ambient_c, p.angle_deg, plan.shots));
    const device::VirtualRangefinder rangefinder(config, plan.mode == "waveform"
                                                             ? device::SimulationMode::kWaveform
                                                             : device::SimulationMode::kAnalytic);
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
    num(n);
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
  if (!plan.characterize.empty()) {
    if (!ctx.characterize)
      throw std::invalid_argument("sweep: [characterize] runs from the tofkit command line only");
    const auto findings = ctx.characterize(plan.characterize, config, p.seed);
    for (const auto& name : plan.characterize_findings) {
      const auto it = std::find_if(findings.begin(), findings.end(),
                                   [&](const auto& f) { return f.first == name; });
      num(it == findings.end() ? std::nan("") : it->second);
    }
  }
  return row;
}

}  // namespace tofkit::io
