// tofkit evaluate: accuracy of a corrected CSV against its truth (thesis
// Eqs. 4.1-4.3, 4.10-4.11): per group of a column and overall, bias, variance,
// RMS of true - distance_m and of true - distance_raw_m, improvement, max
// |error|, and the share within 1 and 2 sigma overall and per amplitude tercile.

#include <fmt/format.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <memory>
#include <nlohmann/json.hpp>
#include <stdexcept>
#include <string>
#include <vector>

#include "app.hpp"
#include "tofkit/calib/statistics.hpp"
#include "tofkit/io/raw_csv.hpp"

namespace tofkit::app {
namespace {

struct EvaluateOptions {
  std::vector<std::string> inputs;  // --in, repeated: e.g. one file per time since calibration
  std::string in;                   // the inputs joined by ", " (messages)
  std::string by;
  bool json = false;
};

/// The value of a CSV column of a corrected row, by column name.
double column_value(const io::CorrectedRow& row, const std::string& name) {
  const auto& t = row.record.truth;
  const auto& m = row.record.raw;
  if (name == "distance_true_m") return t.distance_m;
  if (name == "reflectance") return t.reflectance;
  if (name == "angle_deg") return t.angle_deg;
  if (name == "ambient_c") return t.ambient_c;
  if (name == "tof_ns") return m.tof_ns;
  if (name == "distance_raw_m") return m.distance_raw_m;
  if (name == "pulse_width_ns") return m.pulse_width_ns;
  if (name == "amplitude") return m.amplitude;
  if (name == "temperature_c") return m.temperature_c;
  if (name == "shots_valid") return m.shots_valid;
  if (name == "flags") return m.flags;
  if (name == "distance_m") return row.range.distance_m;
  if (name == "sigma_m") return row.range.sigma_m;
  if (name == "correction_flags") return row.range.correction_flags;
  std::string known;
  for (auto columns : {io::raw_csv_columns(), io::corrected_csv_columns()}) {
    for (std::string_view c : columns) known += (known.empty() ? "" : ", ") + std::string(c);
  }
  throw std::invalid_argument("--by " + name + ": no such column (columns: " + known + ")");
}

nlohmann::json number(double v) {
  return std::isfinite(v) ? nlohmann::json(v) : nlohmann::json();
}

nlohmann::json stats_json(const calib::ErrorStats& s) {
  return {{"rows", s.rows},
          {"bias_m", number(s.bias_m)},
          {"abs_bias_m", number(s.abs_bias_m)},
          {"variance_m2", number(s.variance_m2)},
          {"rms_m", number(s.rms_m)},
          {"max_abs_m", number(s.max_abs_m)}};
}

nlohmann::json coverage_json(const calib::Coverage& c) {
  nlohmann::json terciles = nlohmann::json::array();
  for (std::size_t t = 0; t < 3; ++t) {
    terciles.push_back({{"rows", c.tercile_rows[t]}, {"share", number(c.tercile_share[t])}});
  }
  return {{"k_sigma", c.k_sigma},
          {"rows", c.rows},
          {"share", number(c.share)},
          {"amplitude_terciles", terciles}};
}

nlohmann::json group_json(const calib::GroupEvaluation& g) {
  return {{"key", number(g.key)},
          {"rows", g.rows},
          {"rows_without_range", g.rows_without_range},
          {"corrected", stats_json(g.corrected)},
          {"raw", stats_json(g.raw)},
          {"rms_improvement_pct", number(g.rms_improvement_pct)},
          {"bias_improvement_pct", number(g.bias_improvement_pct)},
          {"within_1_sigma", coverage_json(g.within_1_sigma)},
          {"within_2_sigma", coverage_json(g.within_2_sigma)}};
}

void run_evaluate(const EvaluateOptions& o) {
  if (!o.by.empty()) (void)column_value(io::CorrectedRow{}, o.by);  // unknown column: fail early
  std::vector<io::CorrectedRow> rows;
  std::vector<std::size_t> input_of;  // each row's --in
  for (std::size_t f = 0; f < o.inputs.size(); ++f) {
    const std::vector<io::CorrectedRow> part = io::read_corrected_csv(o.inputs[f]);
    rows.insert(rows.end(), part.begin(), part.end());
    input_of.insert(input_of.end(), part.size(), f);
  }
  std::vector<double> truth, distance, raw, sigma, amplitude, key;
  for (std::size_t i = 0; i < rows.size(); ++i) {
    const io::CorrectedRow& r = rows[i];
    // Squared errors of a corrupt cell would overflow every statistic to inf.
    try {
      calib::require_magnitude(r.record.truth.distance_m, "distance_true_m", i);
      calib::require_magnitude(r.range.distance_m, "distance_m", i);
      calib::require_magnitude(r.record.raw.distance_raw_m, "distance_raw_m", i);
      calib::require_magnitude(r.range.sigma_m, "sigma_m", i);
      if (r.range.sigma_m < 0) {  // (its coverage had read 0 % without a word)
        throw std::invalid_argument(
            fmt::format("sigma_m = {} in data row {} is negative: an expected error is >= 0",
                        r.range.sigma_m, i + 1));
      }
    } catch (const std::invalid_argument& e) {
      throw std::runtime_error(o.in + ": " + e.what());
    }
    truth.push_back(r.record.truth.distance_m);
    distance.push_back(r.range.distance_m);
    raw.push_back(r.record.raw.distance_raw_m);
    sigma.push_back(r.range.sigma_m);
    amplitude.push_back(r.record.raw.amplitude);
    if (!o.by.empty()) key.push_back(column_value(r, o.by));
  }
  std::size_t with_truth = 0;
  for (double t : truth) with_truth += std::isfinite(t) ? 1 : 0;
  if (with_truth == 0) {
    throw std::runtime_error(o.in + ": no row has a distance_true_m; evaluate needs the truth");
  }
  std::size_t with_distance = 0;
  for (double d : distance) with_distance += std::isfinite(d) ? 1 : 0;
  if (with_distance == 0) {
    throw std::runtime_error(o.in +
                             ": no row has a distance_m; evaluate needs corrected rows (tofkit "
                             "correct writes them)");
  }
  const calib::Evaluation ev = calib::evaluate({truth, distance, raw, sigma, amplitude, key});
  // Coverage per distance band: thirds of the truths' span (an error that
  // follows the range shows as one band's coverage falling).
  double near = INFINITY, far = -INFINITY;
  for (double t : truth)
    if (std::isfinite(t)) near = std::min(near, t), far = std::max(far, t);
  std::array<double, 3> band_rows{}, band_1{}, band_2{};
  for (std::size_t i = 0; i < truth.size(); ++i) {
    const double e = truth[i] - distance[i];
    if (!std::isfinite(e) || !std::isfinite(sigma[i])) continue;
    const auto b = static_cast<std::size_t>(
        std::clamp(far > near ? 3.0 * (truth[i] - near) / (far - near) : 0.0, 0.0, 2.0));
    band_rows[b] += 1;
    band_1[b] += std::abs(e) <= sigma[i] ? 1 : 0;
    band_2[b] += std::abs(e) <= 2 * sigma[i] ? 1 : 0;
  }
  const auto share = [](double in, double n) { return n > 0 ? in / n : NAN; };
  // Coverage per input file (several --in: e.g. one per time since calibration).
  std::vector<double> file_rows(o.inputs.size()), file_1(o.inputs.size()), file_2(o.inputs.size());
  for (std::size_t i = 0; i < truth.size(); ++i) {
    const double e = truth[i] - distance[i];
    if (!std::isfinite(e) || !std::isfinite(sigma[i])) continue;
    file_rows[input_of[i]] += 1;
    file_1[input_of[i]] += std::abs(e) <= sigma[i] ? 1 : 0;
    file_2[input_of[i]] += std::abs(e) <= 2 * sigma[i] ? 1 : 0;
  }
  if (o.json) {
    nlohmann::json j = {
        {"input", o.in},
        {"by", o.by.empty() ? nlohmann::json() : nlohmann::json(o.by)},
        {"rows", rows.size()},
        {"amplitude_terciles",
         {{"lower", number(ev.terciles.lower)}, {"upper", number(ev.terciles.upper)}}},
        {"overall", group_json(ev.overall)}};
    nlohmann::json groups = nlohmann::json::array();
    for (const auto& g : ev.groups) groups.push_back(group_json(g));
    j["groups"] = groups;
    nlohmann::json bands = nlohmann::json::array();
    for (std::size_t b = 0; b < 3; ++b) {
      bands.push_back({{"from_m", number(near + (far - near) * static_cast<double>(b) / 3)},
                       {"to_m", number(near + (far - near) * static_cast<double>(b + 1) / 3)},
                       {"rows", band_rows[b]},
                       {"within_1_sigma", number(share(band_1[b], band_rows[b]))},
                       {"within_2_sigma", number(share(band_2[b], band_rows[b]))}});
    }
    j["distance_bands"] = bands;
    if (o.inputs.size() > 1) {
      nlohmann::json files = nlohmann::json::array();
      for (std::size_t f = 0; f < o.inputs.size(); ++f) {
        files.push_back({{"input", o.inputs[f]},
                         {"rows", file_rows[f]},
                         {"within_1_sigma", number(share(file_1[f], file_rows[f]))},
                         {"within_2_sigma", number(share(file_2[f], file_rows[f]))}});
      }
      j["inputs"] = files;
    }
    fmt::print("{}\n", j.dump(2));
    return;
  }
  fmt::print("{}: {} rows{}; error = true - distance (mm); raw = true - distance_raw_m\n", o.in,
             rows.size(), o.by.empty() ? "" : ", grouped by " + o.by);
  fmt::print("{}", ev.summary());
  const auto& c1 = ev.overall.within_1_sigma;
  const auto& c2 = ev.overall.within_2_sigma;
  fmt::print(
      "amplitude terciles (edges {:.4g}, {:.4g}): within 1 sigma {:.1f} / {:.1f} / {:.1f} %, "
      "within 2 sigma {:.1f} / {:.1f} / {:.1f} %\n",
      ev.terciles.lower, ev.terciles.upper, 100 * c1.tercile_share[0], 100 * c1.tercile_share[1],
      100 * c1.tercile_share[2], 100 * c2.tercile_share[0], 100 * c2.tercile_share[1],
      100 * c2.tercile_share[2]);
  fmt::print(
      "distance thirds ({:.3g}-{:.3g}-{:.3g}-{:.3g} m): within 1 sigma {:.1f} / {:.1f} / {:.1f} %, "
      "within 2 sigma {:.1f} / {:.1f} / {:.1f} %\n",
      near, near + (far - near) / 3, near + 2 * (far - near) / 3, far,
      100 * share(band_1[0], band_rows[0]), 100 * share(band_1[1], band_rows[1]),
      100 * share(band_1[2], band_rows[2]), 100 * share(band_2[0], band_rows[0]),
      100 * share(band_2[1], band_rows[1]), 100 * share(band_2[2], band_rows[2]));
  if (o.inputs.size() > 1) {
    fmt::print("per input: within 1 / 2 sigma");
    for (std::size_t f = 0; f < o.inputs.size(); ++f) {
      fmt::print("{} {} {:.1f} / {:.1f} %", f == 0 ? "" : ";", o.inputs[f],
                 100 * share(file_1[f], file_rows[f]), 100 * share(file_2[f], file_rows[f]));
    }
    fmt::print("\n");
  }
}

const bool registered = register_command("evaluate", [](CLI::App& sub, AppContext& ctx) {
  sub.description("accuracy of a corrected CSV against its truth, per group and overall");
  auto o = std::make_shared<EvaluateOptions>();
  sub.add_option("--in", o->inputs,
                 "corrected CSV (from tofkit correct); repeat --in to evaluate several files "
                 "together, with the coverage of each (e.g. one per time since calibration)")
      ->required()
      ->expected(1)
      ->multi_option_policy(CLI::MultiOptionPolicy::TakeAll);
  sub.add_option("--by", o->by, "group rows by this column (e.g. reflectance, distance_true_m)");
  sub.add_flag("--json", o->json, "print JSON instead of a table");
  sub.callback([o, &ctx] {
    // The model / table carry everything the command uses; --config, --set
    // and --preset are still checked, so a bad key is an error, not ignored.
    (void)ctx.load_config();
    o->in.clear();
    for (const std::string& path : o->inputs) o->in += (o->in.empty() ? "" : ", ") + path;
    run_evaluate(*o);
  });
});

}  // namespace
}  // namespace tofkit::app
