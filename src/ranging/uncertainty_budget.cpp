#include "tofkit/ranging/uncertainty_budget.hpp"

#include <fmt/printf.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <stdexcept>
#include <vector>

namespace tofkit::ranging {
namespace {

/// Whether a component's axis is read from the row's lost shots (and needs
/// the budget's shots per measurement).
bool follows_lost_shots(BudgetComponent::Axis axis) {
  return axis == BudgetComponent::Axis::lost_shot_share ||
         axis == BudgetComponent::Axis::false_stop_rate_per_m;
}

}  // namespace

double BudgetComponent::u_m(double x) const {
  if (variance_m2.size() == 1 || !(x > node.front())) return std::sqrt(variance_m2.front());
  if (x >= node.back()) return std::sqrt(variance_m2.back());
  const auto hi =
      static_cast<std::size_t>(std::upper_bound(node.begin(), node.end(), x) - node.begin());
  const std::size_t lo = hi - 1;
  const double w = (x - node[lo]) / (node[hi] - node[lo]);
  return std::sqrt((1 - w) * variance_m2[lo] + w * variance_m2[hi]);
}

void UncertaintyBudget::validate() const {
  for (std::size_t k = 0; k < components.size(); ++k) {
    const BudgetComponent& c = components[k];
    const std::string who = "uncertainty_budget.components[" + std::to_string(k) + "]";
    if (c.name.empty()) throw std::invalid_argument(who + ".name is empty");
    if (c.variance_m2.empty() || c.variance_m2.size() != c.node.size())
      throw std::invalid_argument(who + ": node and variance_m2 must be non-empty, equal length");
    if (c.axis == BudgetComponent::Axis::none && c.node.size() != 1)
      throw std::invalid_argument(who + ": a component without an axis has one node");
    if (follows_lost_shots(c.axis) && !(shots >= 1))
      throw std::invalid_argument(who + ": a lost-shot component needs the budget's shots");
    for (std::size_t j = 0; j < c.node.size(); ++j) {
      if (!std::isfinite(c.node[j]) || (j > 0 && !(c.node[j] > c.node[j - 1])))
        throw std::invalid_argument(who + ".node must be finite and ascending");
      if (!(c.variance_m2[j] >= 0) || !(c.variance_m2[j] < 1e6))
        throw std::invalid_argument(who + ".variance_m2 must be in [0, 1e6) m^2");
    }
  }
}

double lost_shot_share(double shots_valid, double shots) {
  return shots > 0 ? std::clamp(1.0 - shots_valid / shots, 0.0, 1.0) : kNaN;
}

double false_stop_rate_per_m(double lost_share, double distance_m) {
  if (lost_share == 0) return 0.0;  // at any range
  if (!(lost_share > 0 && lost_share <= 1) || !(distance_m > 0) || !std::isfinite(distance_m))
    return kNaN;
  return -std::log1p(-lost_share) / distance_m;
}

double UncertaintyBudget::component_u_m(std::size_t k, double amplitude, double since_s,
                                        double temperature_c, double lost_share,
                                        double distance_m) const {
  const BudgetComponent& c = components[k];
  const bool same = std::isfinite(since_s);
  if ((c.scope == BudgetScope::same_power_on && !same) ||
      (c.scope == BudgetScope::other_power_on && same))
    return 0.0;
  // An axis value the row does not carry: the component's largest u.
  const auto known_or_largest = [&c](bool known, double x) {
    return known ? c.u_m(x)
                 : std::sqrt(*std::max_element(c.variance_m2.begin(), c.variance_m2.end()));
  };
  switch (c.axis) {
    case BudgetComponent::Axis::log_amplitude:
      return std::isfinite(amplitude) && amplitude > 0 ? c.u_m(std::log(amplitude)) : kNaN;
    case BudgetComponent::Axis::time_since_calibration_s:
      return c.u_m(std::abs(since_s));
    case BudgetComponent::Axis::temperature_c:
      return known_or_largest(std::isfinite(temperature_c), temperature_c);
    case BudgetComponent::Axis::lost_shot_share:
      return known_or_largest(std::isfinite(lost_share), lost_share);
    case BudgetComponent::Axis::false_stop_rate_per_m: {
      const double rate = false_stop_rate_per_m(lost_share, distance_m);
      return known_or_largest(!std::isnan(rate), rate);  // +inf: held beyond the last node
    }
    case BudgetComponent::Axis::none:
      break;
  }
  return c.u_m(0.0);
}

void UncertaintyBudget::combined(std::span<const double> amplitude, std::span<const double> since_s,
                                 std::span<double> u_m, std::span<const double> temperature_c,
                                 std::span<const double> lost_share,
                                 std::span<const double> distance_m) const {
  const auto per_row = [&](std::span<const double> s) {
    return s.empty() || s.size() == amplitude.size();
  };
  if (u_m.size() != amplitude.size() ||
      (since_s.size() != 1 && since_s.size() != amplitude.size()) || !per_row(temperature_c) ||
      !per_row(lost_share) || !per_row(distance_m))
    throw std::invalid_argument(
        "UncertaintyBudget::combined: amplitude, since_s (one or one per row), temperature_c, "
        "lost_share and distance_m (none or one per row) and u_m differ in length");
  for (std::size_t i = 0; i < amplitude.size(); ++i) {
    const double since = since_s.size() == 1 ? since_s[0] : since_s[i];
    const double t = temperature_c.empty() ? kNaN : temperature_c[i];
    const double lost = lost_share.empty() ? kNaN : lost_share[i];
    const double d = distance_m.empty() ? kNaN : distance_m[i];
    double v = 0;
    for (std::size_t k = 0; k < components.size(); ++k) {
      const double u = component_u_m(k, amplitude[i], since, t, lost, d);
      v += u * u;
    }
    u_m[i] = std::sqrt(v);
  }
}

std::string UncertaintyBudget::table(std::span<const double> amplitude,
                                     std::span<const double> since_s,
                                     std::span<const double> temperature_c) const {
  const std::size_t points = std::min(amplitude.size(), since_s.size());
  const auto temperature = [&](std::size_t p) {
    return p < temperature_c.size() ? temperature_c[p] : kNaN;
  };
  std::string out = fmt::sprintf("%-40s %-4s ", "component (u mm, share at each point)", "type");
  for (std::size_t p = 0; p < points; ++p)
    out += fmt::sprintf(" %13s", fmt::sprintf("P%zu", p + 1).c_str());
  out += "  step\n";
  std::vector<double> total(points, 0.0);
  for (std::size_t k = 0; k < components.size(); ++k) {
    for (std::size_t p = 0; p < points; ++p) {
      const double u = component_u_m(k, amplitude[p], since_s[p], temperature(p), 0.0);
      total[p] += u * u;
    }
  }
  for (std::size_t k = 0; k < components.size(); ++k) {
    const BudgetComponent& c = components[k];
    out += fmt::sprintf("%-40s %-4s ", c.name.c_str(),
                        c.type_b ? (c.default_specification ? "B*" : "B") : "A");
    for (std::size_t p = 0; p < points; ++p) {
      const double u = component_u_m(k, amplitude[p], since_s[p], temperature(p), 0.0);
      out +=
          fmt::sprintf(" %6.3f (%3.0f%%)", u * 1e3, total[p] > 0 ? 100.0 * u * u / total[p] : 0.0);
    }
    out += "  " + c.step + "\n";
  }
  out += fmt::sprintf("%-40s %-4s ", "combined standard uncertainty", "");
  for (std::size_t p = 0; p < points; ++p)
    out += fmt::sprintf(" %6.3f       ", std::sqrt(total[p]) * 1e3);
  out += "\n";
  for (std::size_t p = 0; p < points; ++p) {
    out += fmt::sprintf(
        "  P%zu: amplitude %.4g, %s%s\n", p + 1, amplitude[p],
        std::isfinite(since_s[p])
            ? fmt::sprintf("%g min after calibration (same power-on)", since_s[p] / 60.0).c_str()
            : "another power-on",
        std::isfinite(temperature(p))
            ? fmt::sprintf(", temperature reading %.1f C", temperature(p)).c_str()
            : "");
  }
  if (std::any_of(components.begin(), components.end(),
                  [](const BudgetComponent& c) { return follows_lost_shots(c.axis); }))
    out += "  (each point keeps all its shots: a row losing them adds the lost-shot term)\n";
  if (std::any_of(components.begin(), components.end(),
                  [](const BudgetComponent& c) { return c.default_specification; }))
    out += "  B*: type B from a default specification, not one stated for this device\n";
  return out;
}

void apply_budget(const UncertaintyBudget& budget, const Pipeline& pipeline, const RawColumns& in,
                  std::span<const double> since_s, std::span<Range> out) {
  if (in.size != out.size() || (since_s.size() != 1 && since_s.size() != out.size()))
    throw std::invalid_argument("apply_budget: rows, since_s (one or one per row) and out differ");
  const std::size_t n = out.size();
  std::vector<double> amplitude(n), temperature(n), lost(n), intensity(n), distance(n), u(n),
      inside(n);
  const auto& confidence = pipeline.confidence();
  const bool by_width = confidence && confidence->intensity_input() == IntensityInput::pulse_width;
  for (std::size_t i = 0; i < n; ++i) {
    amplitude[i] = in.amplitude[i];
    temperature[i] = in.temperature_c[i];
    lost[i] = lost_shot_share(in.shots_valid[i], budget.shots);
    intensity[i] = by_width ? in.pulse_width_ns[i] : amplitude[i];
    distance[i] = out[i].distance_m;
  }
  budget.combined(amplitude, since_s, u, temperature, lost, distance);
  if (confidence) {
    confidence->sigma(distance, intensity, inside);
  } else {
    std::fill(inside.begin(), inside.end(), pipeline.residual_rms_m());
  }
  // The budget's extrapolation term and the pipeline's out-of-domain growth
  // describe one cause (a correction extrapolated past its data): a row gets
  // the larger of the two, not their sum.
  std::size_t extrapolation = budget.components.size();
  for (std::size_t k = 0; k < budget.components.size(); ++k)
    if (budget.components[k].name == kExtrapolationComponent) extrapolation = k;
  for (std::size_t i = 0; i < n; ++i) {
    if (!std::isfinite(out[i].sigma_m)) continue;
    double extra = 0;
    if ((out[i].correction_flags & kCorrOutOfDomain) != 0 && std::isfinite(inside[i]))
      extra = std::max(0.0, out[i].sigma_m * out[i].sigma_m - inside[i] * inside[i]);
    if (extrapolation < budget.components.size()) {
      const double ue = budget.component_u_m(extrapolation, amplitude[i], kNaN);
      if (std::isfinite(ue)) extra = std::max(0.0, extra - ue * ue);
    }
    out[i].sigma_m = std::isfinite(u[i]) ? std::sqrt(u[i] * u[i] + extra) : out[i].sigma_m;
  }
}

}  // namespace tofkit::ranging
