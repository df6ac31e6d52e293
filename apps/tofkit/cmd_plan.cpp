// tofkit plan --range-max M --reflectance-min R [--bench]: which calibration
// plates span the echo powers the field will produce (link budget, paper
// Eq. 6), printed as `tofkit measure` lines for the virtual device or as a
// table to follow on a bench.

#include <fmt/format.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <memory>
#include <stdexcept>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "app.hpp"
#include "tofkit/calib/calibration_plan.hpp"
#include "tofkit/device/virtual_rangefinder.hpp"
#include "tofkit/experiments/device_plan.hpp"

namespace tofkit::app {
namespace {

/// The planner names its fields ("plan: calibration_distance_m must ..."):
/// the option that sets each is added, "calibration_distance_m (--at)".
std::string with_option(std::string message) {
  static constexpr std::pair<const char*, const char*> kOptions[] = {
      {"range_min_m", "--range-min"},
      {"range_max_m", "--range-max"},
      {"reflectance_min", "--reflectance-min"},
      {"reflectance_max", "--reflectance-max"},
      {"calibration_distance_m", "--at"},
      {"plates", "--plates"},
      {"temperature_min_c", "--temperature-min"},
      {"temperature_max_c", "--temperature-max"},
      {"temperature_step_c", "--temperature-step"},
  };
  for (const auto& [field, option] : kOptions) {
    const std::string head = std::string("plan: ") + field;
    if (message.rfind(head, 0) == 0 && message.size() > head.size() &&
        (message[head.size()] == ' ' || message[head.size()] == ':')) {
      return message.insert(head.size(), std::string(" (") + option + ")");
    }
  }
  return message;
}

struct PlanOptions {
  calib::CalibrationPlanOptions plan;
  bool bench = false;
  int count = 5;
};

std::string number(double v) {
  return fmt::format("{:.3g}", v);
}

/// A word as a shell reads it back: quoted when it holds anything but
/// letters, digits and -_.,:/=+@%.
std::string shell_word(const std::string& word) {
  const bool plain = !word.empty() && std::all_of(word.begin(), word.end(), [](char c) {
    return std::isalnum(static_cast<unsigned char>(c)) != 0 ||
           std::string_view("-_.,:/=+@%").find(c) != std::string_view::npos;
  });
  if (plain) return word;
  std::string quoted = "'";
  for (const char c : word) quoted += c == '\'' ? std::string("'\\''") : std::string(1, c);
  return quoted + "'";
}

/// "tofkit" and the global options that chose the device (--preset,
/// --config, every --set in order), so a printed line measures this device.
std::string tofkit_with_device(const AppContext& ctx) {
  std::string line = "tofkit";
  if (!ctx.preset.empty()) line += " --preset " + shell_word(ctx.preset);
  if (ctx.config_file) line += " --config " + shell_word(ctx.config_file->string());
  for (const std::string& set : ctx.overrides) line += " --set " + shell_word(set);
  return line;
}

void run_plan(const PlanOptions& o, const AppContext& ctx) {
  const device::DeviceConfig config = ctx.load_config();
  const device::VirtualRangefinder device(config);
  const calib::CalibrationPlan plan = experiments::plan_for_device(device, o.plan);
  fmt::print(
      "# field {}-{} m x reflectance {}-{}: received peak power {:.3g} .. {:.3g} W (x{:.0f})\n",
      number(o.plan.range_min_m), number(o.plan.range_max_m), number(o.plan.reflectance_min),
      number(o.plan.reflectance_max), plan.field_power_min_w, plan.field_power_max_w,
      plan.field_power_max_w / plan.field_power_min_w);
  fmt::print("# {} plates at log-even powers; calibration distance {} m{}\n", plan.plates.size(),
             number(plan.calibration_distance_m),
             o.plan.single_distance ? " (every plate)" : " where a plate allows");
  // Clipping: the walk model learns the onset and the recovery from clipped plates.
  const double clip_w = plan.clip_power_w;
  if (plan.field_power_max_w > clip_w) {
    fmt::print(
        "# the field's strongest echo ({} m, reflectance {}) overdrives the amplifier "
        "(receiver.saturation_v = {} V) by {:.2f} neper(s); the brightest plate by {:.2f}\n",
        number(o.plan.range_min_m), number(o.plan.reflectance_max),
        number(config.link.receiver.saturation_v), std::log(plan.field_power_max_w / clip_w),
        std::log(plan.plates.back().received_power_w / clip_w));
  }
  // The powers are optical; whether an echo crosses the comparator's
  // threshold is the device's (gain, transimpedance, threshold): the
  // field's weakest target and each plate, noise-free, at 20 C.
  const auto detected = [&](double distance_m, double reflectance) {
    return device.echo(device::Target::plate(distance_m, reflectance), {}).detected;
  };
  if (!detected(o.plan.range_max_m, o.plan.reflectance_min)) {
    fmt::print(
        "# the field's weakest target ({} m, reflectance {}) stays below the threshold "
        "(discriminator.threshold_v = {} V): no echo, or only noise crossings\n",
        number(o.plan.range_max_m), number(o.plan.reflectance_min),
        number(config.discriminator.threshold_v));
  }
  std::string silent;
  for (const auto& p : plan.plates) {
    if (!detected(p.distance_m, p.reflectance))
      silent += fmt::format("{}{:.4f} at {:.4f} m", silent.empty() ? "" : ", ", p.reflectance,
                            p.distance_m);
  }
  if (!silent.empty())
    fmt::print("# plates below the threshold (no echo, or only noise crossings): {}\n", silent);
  if (o.bench) {
    // clip_Np: how far the plate's echo overdrives the amplifier (ln of its
    // power over the clip power; "-" below the clip).
    fmt::print("{:>4} {:>10} {:>12} {:>14} {:>10} {:>8}\n", "#", "distance_m", "reflectance",
               "power_W", "SNR", "clip_Np");
    int k = 0;
    for (const auto& p : plan.plates) {
      const double clip_np = std::log(p.received_power_w / clip_w);
      fmt::print("{:>4} {:>10.3f} {:>12.3f} {:>14.4g} {:>10.1f} {:>8}\n", ++k, p.distance_m,
                 p.reflectance, p.received_power_w, p.snr,
                 clip_np > 0 ? fmt::format("{:.2f}", clip_np) : "-");
    }
    fmt::print("# temperature run: plate {:.3f} at {:.3f} m, temperatures",
               plan.temperature_plate.reflectance, plan.temperature_plate.distance_m);
    for (double t : plan.temperatures_c) fmt::print(" {}", number(t));
    fmt::print(" C\n");
    return;
  }
  // One measure line per distance (plates sharing a distance together).
  std::vector<std::pair<double, std::string>> lines;
  for (const auto& p : plan.plates) {
    auto it = std::find_if(lines.begin(), lines.end(),
                           [&](const auto& l) { return l.first == p.distance_m; });
    if (it == lines.end()) {
      lines.emplace_back(p.distance_m, "");
      it = lines.end() - 1;
    }
    it->second += (it->second.empty() ? "" : ",") + fmt::format("{:.4f}", p.reflectance);
  }
  const std::string tofkit = tofkit_with_device(ctx);
  std::string inputs;
  int part = 0;
  for (const auto& [distance, reflectances] : lines) {
    fmt::print("{} measure --distance {:.4f} --reflectance {} --count {} --out plates{}.csv\n",
               tofkit, distance, reflectances, o.count, ++part);
    inputs += fmt::format(" --in plates{}.csv", part);
  }
  std::string temperatures;
  for (double t : plan.temperatures_c)
    temperatures += (temperatures.empty() ? "" : ",") + number(t);
  fmt::print(
      "{} measure --distance {:.4f} --reflectance {:.4f} --temperature {} --count {} --out "
      "temperature.csv\n",
      tofkit, plan.temperature_plate.distance_m, plan.temperature_plate.reflectance, temperatures,
      o.count);
  // The fit of every file together, then a test on another seed (another
  // power-on) over the field: targets the fit never saw.
  fmt::print(
      "{} fit{} --in temperature.csv --chain offset,grayvalue,temperature --out model.json\n",
      tofkit, inputs);
  fmt::print("{} measure --distance {}:{}:{} --reflectance {},{},{} --seed 2 --out test.csv\n",
             tofkit, number(o.plan.range_min_m), number(o.plan.range_max_m),
             number((o.plan.range_max_m - o.plan.range_min_m) / 10), number(o.plan.reflectance_min),
             number(std::sqrt(o.plan.reflectance_min * o.plan.reflectance_max)),
             number(o.plan.reflectance_max));
  fmt::print("{} correct --model model.json --in test.csv --out test_corrected.csv\n", tofkit);
  fmt::print("tofkit evaluate --in test_corrected.csv --by reflectance\n");
}

const bool registered = register_command("plan", [](CLI::App& sub, AppContext& ctx) {
  sub.description(
      "plan a calibration from the link budget: plates whose echoes span the field's powers "
      "(measure lines, or --bench for a table)");
  auto o = std::make_shared<PlanOptions>();
  auto& p = o->plan;
  sub.add_option("--range-min", p.range_min_m, "nearest field range, m")->capture_default_str();
  sub.add_option("--range-max", p.range_max_m, "farthest field range, m")->capture_default_str();
  sub.add_option("--reflectance-min", p.reflectance_min, "darkest field target")
      ->capture_default_str();
  sub.add_option("--reflectance-max", p.reflectance_max, "brightest field target")
      ->capture_default_str();
  sub.add_option("--at", p.calibration_distance_m,
                 "calibration distance, m (default: geometric mean of the field's ranges)")
      ->check(kNotNan);
  sub.add_option("--plates", p.plates, "number of plates (target powers)")->capture_default_str();
  sub.add_option("--temperature-min", p.temperature_min_c, "temperature run start, C")
      ->capture_default_str();
  sub.add_option("--temperature-max", p.temperature_max_c, "temperature run end, C")
      ->capture_default_str();
  sub.add_option("--temperature-step", p.temperature_step_c, "temperature run step, C")
      ->capture_default_str();
  sub.add_option("--count", o->count, "repeats per plate in the measure lines")
      ->check(InRange(1, 100000))
      ->capture_default_str();
  sub.add_flag("--single-distance", p.single_distance,
               "all plates at one distance: the one centring the plates' powers on the field's "
               "(or --at)");
  sub.add_flag("--bench", o->bench, "print a table to follow on a bench instead");
  sub.callback([o, &ctx] {
    try {
      run_plan(*o, ctx);
    } catch (const std::invalid_argument& e) {
      throw std::runtime_error(with_option(e.what()));
    }
  });
});

}  // namespace
}  // namespace tofkit::app
