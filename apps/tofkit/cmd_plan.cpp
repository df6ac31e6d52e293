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
  experiments::ProtocolOptions po;
  po.count = o.count;
  po.complete = !o.plan.single_distance;
  const experiments::Protocol protocol = experiments::plan_protocol(device, o.plan, po);
  const auto list = [](const std::vector<double>& v) {
    std::string out;
    for (double x : v) out += (out.empty() ? "" : ",") + fmt::format("{:.4f}", x);
    return out;
  };
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
    // The protocol's steps with their durations on a bench (moving plates
    // about 2 min each, a rail position 30 s, a temperature step's soak 30
    // min, a power-on's warm-up as long as the stability record).
    fmt::print("# protocol: {:<16} {:>6} {:>9}  observes\n", "step", "rows", "minutes");
    double total = 0;
    for (const auto& step : protocol.steps) {
      fmt::print("# protocol: {:<16} {:>6.0f} {:>9.0f}  {}\n", step.file, step.grid.rows(),
                 step.bench_minutes, step.observes);
      total += step.bench_minutes;
    }
    fmt::print("# protocol: {:<16} {:>6} {:>9.0f}\n", "total", "", total);
    for (const auto& u : protocol.unobserved)
      fmt::print("# not observed (a type B term from fit --spec stands in): {}\n", u);
    return;
  }
  const std::string tofkit = tofkit_with_device(ctx);
  std::string inputs, extra;
  for (const auto& step : protocol.steps) {
    fmt::print("# {}: {}\n", step.file, step.observes);
    std::string line = fmt::format("{} measure --distance {} --reflectance {}", tofkit,
                                   list(step.grid.distances_m), list(step.grid.reflectances));
    if (step.grid.ambient_c.size() != 1 ||
        step.grid.ambient_c.front() != device::Conditions{}.ambient_c) {
      std::string temperatures;
      for (double t : step.grid.ambient_c)
        temperatures += (temperatures.empty() ? "" : ",") + number(t);
      line += " --temperature " + temperatures;
    }
    line += fmt::format(" --count {}", step.grid.count);
    if (step.seed != 1) line += fmt::format(" --seed {}", step.seed);
    if (step.timing.start_s > 0) line += fmt::format(" --start-s {:.10g}", step.timing.start_s);
    if (step.timing.every_s > 0) line += fmt::format(" --every {:g}", step.timing.every_s);
    fmt::print("{} --out {}\n", line, step.file);
    switch (step.role) {
      case experiments::StepRole::calibration:
        inputs += " --in " + step.file;
        break;
      case experiments::StepRole::stability:
        extra +=
            fmt::format(" --stability {} --stability-every {:g}", step.file, step.timing.every_s);
        break;
      case experiments::StepRole::power_on:
        extra += " --power-on " + step.file;
        break;
    }
  }
  for (const auto& u : protocol.unobserved)
    fmt::print("# not observed (its budget term is type B, from fit --spec): {}\n", u);
  // The fit of every file together with its uncertainty budget, then a field
  // test on the same power-on half an hour after the calibration: targets the
  // fit never saw, their sigma with the drift of that half hour.
  // A laser fired on the TDC's clock leaves the interpolator's nonlinearity
  // periodic in the time of flight: the rail lets a periodic step correct it.
  const bool periodic =
      !o.plan.single_distance && config.tdc.laser_sync && !config.oscillator.enabled;
  // The planner's protocol fits the physical walk model: between and below
  // its weakest plates the walk curves, where a gray-value hinge interpolates
  // linearly (on a held-out device: weak field targets 2.5-10 mm off with the
  // hinge, within 1.4 mm with the walk model). The paper's protocol keeps the
  // paper's chain.
  fmt::print("{} fit{} --chain offset,{},temperature{} --budget{} --out model.json\n", tofkit,
             inputs, o.plan.single_distance ? "grayvalue" : "walk",
             periodic ? " --tdc-periodic" : "", extra);
  const double since_s = 1800;
  fmt::print("{} measure --distance {}:{}:{} --reflectance {},{},{} --start-s {} --out test.csv\n",
             tofkit, number(o.plan.range_min_m), number(o.plan.range_max_m),
             number((o.plan.range_max_m - o.plan.range_min_m) / 10), number(o.plan.reflectance_min),
             number(std::sqrt(o.plan.reflectance_min * o.plan.reflectance_max)),
             number(o.plan.reflectance_max), protocol.calibration_start_s + since_s);
  fmt::print(
      "{} correct --model model.json --in test.csv --since-calibration {:g} --out "
      "test_corrected.csv\n",
      tofkit, since_s);
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
               "the paper's protocol: all plates at one distance (the one centring the plates' "
               "powers on the field's, or --at) and the temperature run; no second distance, "
               "rail, stability record or other power-on (their budget terms are type B)");
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
