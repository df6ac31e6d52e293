#include "tofkit/scan/pattern.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <functional>
#include <numbers>
#include <stdexcept>

namespace tofkit::scan {
namespace {

double rad(double deg) {
  return deg * std::numbers::pi / 180.0;
}

/// Largest |angle| of a pattern (a turn of the mirror or the table) and
/// largest |position| of a stage (the scene's extent): beyond, a typo.
constexpr double kMaxAngleDeg = 360.0;
constexpr double kMaxPositionM = kSceneExtentM;

// Descending copy (image row/column 0 = top/left = largest value), each value
// finite and within +-limit (unit: its unit's name, for the message).
std::vector<double> descending(std::vector<double> v, const char* what, double limit,
                               const char* unit) {
  if (v.empty()) throw std::invalid_argument(std::string(what) + ": the list is empty");
  for (const double x : v) {
    if (!std::isfinite(x)) throw std::invalid_argument(std::string(what) + ": not finite");
    if (std::abs(x) > limit) {
      char text[160];
      std::snprintf(text, sizeof text, "%s: %g is beyond +-%g %s", what, x, limit, unit);
      throw std::invalid_argument(text);
    }
  }
  std::sort(v.begin(), v.end(), std::greater<>());
  return v;
}

/// Throws std::length_error when `beams` (counted before any is made) exceed max_beams.
void require_beams(double beams, std::size_t max_beams, const char* pattern) {
  if (beams > static_cast<double>(max_beams)) {
    char text[160];
    std::snprintf(text, sizeof text, "%s: the pattern has %.4g beams, more than the limit of %zu",
                  pattern, beams, max_beams);
    throw std::length_error(text);
  }
}

void require_positive(double v, const char* what) {
  if (!(v > 0 && std::isfinite(v)))
    throw std::invalid_argument(std::string(what) + " must be positive");
}

}  // namespace

Vec3 direction_from_angles(double azimuth_deg, double elevation_deg) {
  const double a = rad(azimuth_deg), e = rad(elevation_deg);
  return {std::cos(e) * std::cos(a), std::cos(e) * std::sin(a), std::sin(e)};
}

BeamPattern raster_pattern(const RasterOptions& o, double period_s, std::size_t max_beams) {
  const auto ys = descending(o.y_m, "raster y", kMaxPositionM, "m"),
             zs = descending(o.z_m, "raster z", kMaxPositionM, "m");
  require_positive(o.stage_speed_m_per_s, "raster stage speed");
  if (o.samples < 1) throw std::invalid_argument("raster samples must be at least 1");
  require_beams(static_cast<double>(ys.size()) * static_cast<double>(zs.size()), max_beams,
                "raster");
  BeamPattern p{
      "raster", static_cast<int>(zs.size()), static_cast<int>(ys.size()), o.samples, {}, {}, 0, {},
      0};
  double t = 0;
  Vec3 last{0, ys[0], zs[0]};
  for (std::size_t r = 0; r < zs.size(); ++r) {
    for (std::size_t k = 0; k < ys.size(); ++k) {
      const std::size_t c = r % 2 == 0 ? k : ys.size() - 1 - k;  // serpentine
      const Vec3 at{0, ys[c], zs[r]};
      const Vec3 step = at - last;
      t += std::sqrt(dot(step, step)) / o.stage_speed_m_per_s;
      p.beams.push_back({static_cast<int>(r), static_cast<int>(c), t, 0, at, {1, 0, 0}});
      t += o.samples * period_s;
      last = at;
    }
  }
  return p;
}

BeamPattern line_pattern(const LineOptions& o, double period_s, std::size_t max_beams) {
  const auto ys = descending(o.y_m, "line y", kMaxPositionM, "m"),
             zs = descending(o.z_m, "line z", kMaxPositionM, "m");
  require_positive(o.stage_speed_m_per_s, "line stage speed");
  if (ys.size() < 2) throw std::invalid_argument("line y needs at least two columns");
  // The stage sweeps at one speed: its columns are evenly spaced (the images
  // place column c at ys.front() - c pitch), and apart (else no sample fits).
  const double pitch = (ys.front() - ys.back()) / static_cast<double>(ys.size() - 1);
  for (std::size_t c = 1; c < ys.size(); ++c) {
    if (!(pitch > 0) || !(std::abs(ys[c - 1] - ys[c] - pitch) <= 1e-6 * pitch)) {
      throw std::invalid_argument(
          "line y must be evenly spaced distinct positions (the stage's columns), as a:b:step "
          "gives them");
    }
  }
  if (!(o.turnaround_s >= 0)) throw std::invalid_argument("line turnaround must be >= 0");
  BeamPattern p{"line", static_cast<int>(zs.size()), static_cast<int>(ys.size()), 1, {}, ys, 0, {},
                0};
  // The stage sweeps from half a column before the first centre to half a
  // column past the last, so every column is covered.
  const double start = ys.front() + 0.5 * pitch, stop = ys.back() - 0.5 * pitch;
  const double length = start - stop;
  const double v = o.stage_speed_m_per_s;
  p.sample_extent_m = v * period_s;
  if (length / v < period_s) {  // (columns 1e-9 m apart had made 0 beams, exit 0)
    char text[200];
    std::snprintf(text, sizeof text,
                  "line: a sweep lasts %.4g s, less than one measurement (%.4g s of shots): no "
                  "sample fits; slow the stage or spread the columns",
                  length / v, period_s);
    throw std::invalid_argument(text);
  }
  // At most one sample per output period of a line's sweep, and one more.
  require_beams(static_cast<double>(zs.size()) * (length / v / period_s + 1.0), max_beams, "line");
  double t_line = 0;
  for (std::size_t r = 0; r < zs.size(); ++r) {
    // The device samples at its own clock: the first sample of a line comes at
    // the next tick after the stage starts, so lines get different counts.
    const double first = std::ceil(t_line / period_s) * period_s;
    const double duration = length / v;
    int k = 0;
    for (double t = first; t + period_s <= t_line + duration + 1e-12; t += period_s, ++k) {
      // Position at the middle of the measurement's integration.
      const double travelled = v * (t + 0.5 * period_s - t_line);
      const double y = r % 2 == 0 ? start - travelled : stop + travelled;
      p.beams.push_back({static_cast<int>(r), k, t, y, {0, y, zs[r]}, {1, 0, 0}});
    }
    t_line += duration + o.turnaround_s;
  }
  return p;
}

namespace {

/// Makes the stored form of an on-demand pattern.
BeamPattern stored(BeamPattern p) {
  if (!p.make_beams) return p;
  p.beams.resize(p.beam_count);
  p.get(0, p.beams);
  p.make_beams = nullptr;
  return p;
}

BeamPattern mirror_on_demand(const MirrorOptions& o, std::size_t max_beams) {
  const auto es = descending(o.elevation_deg, "mirror elevation", kMaxAngleDeg, "degrees");
  require_positive(o.revolutions_per_s, "mirror revolutions per second");
  if (o.revolutions < 1) throw std::invalid_argument("mirror revolutions must be at least 1");
  require_beams(static_cast<double>(o.revolutions) * static_cast<double>(es.size()), max_beams,
                "mirror");
  // Rows: revolutions (profiles); columns: elevation, top first. The mirror
  // turns upwards (increasing elevation) in time.
  BeamPattern p{"mirror", o.revolutions, static_cast<int>(es.size()), 1, {}, {}, 0, {}, 0};
  const double period = 1.0 / o.revolutions_per_s;
  const double speed = o.stage_speed_m_per_s;
  p.beam_count = static_cast<std::size_t>(o.revolutions) * es.size();
  p.make_beams = [es, period, speed](std::size_t first, std::span<Beam> out) {
    for (std::size_t n = 0; n < out.size(); ++n) {
      const std::size_t index = first + n;
      const int r = static_cast<int>(index / es.size());
      const std::size_t k = es.size() - 1 - index % es.size();
      const double t = r * period + (es[k] - es.back()) / 360.0 * period;
      const Vec3 origin{0, -speed * t, 0};
      out[n] = {r, static_cast<int>(k), t, 0, origin, direction_from_angles(0, es[k])};
    }
  };
  return p;
}

BeamPattern spherical_on_demand(const SphericalOptions& o, std::size_t max_beams) {
  const auto as = descending(o.azimuth_deg, "spherical azimuth", kMaxAngleDeg, "degrees");
  const auto es = descending(o.elevation_deg, "spherical elevation", kMaxAngleDeg, "degrees");
  require_positive(o.revolutions_per_s, "spherical revolutions per second");
  require_beams(static_cast<double>(as.size()) * static_cast<double>(es.size()), max_beams,
                "spherical");
  BeamPattern p{
      "spherical", static_cast<int>(es.size()), static_cast<int>(as.size()), 1, {}, {}, 0, {}, 0};
  const double period = 1.0 / o.revolutions_per_s;
  p.beam_count = as.size() * es.size();
  // The table turns from the right (smallest azimuth) to the left; one mirror
  // revolution (an elevation profile, bottom to top) per azimuth.
  // The angles' sines and cosines once per listed value (direction_from_angles'
  // products of them: the same bits).
  struct Trig {
    std::vector<double> cos, sin;
  };
  auto trig = [](const std::vector<double>& degrees) {
    Trig t;
    for (const double d : degrees) {
      t.cos.push_back(std::cos(rad(d)));
      t.sin.push_back(std::sin(rad(d)));
    }
    return t;
  };
  p.make_beams = [as, es, period, ta = trig(as), te = trig(es)](std::size_t first,
                                                                std::span<Beam> out) {
    for (std::size_t n = 0; n < out.size(); ++n) {
      const std::size_t index = first + n;
      const std::size_t j = as.size() - 1 - index / es.size();
      const std::size_t i = es.size() - 1 - index % es.size();
      const double t0 = static_cast<double>(as.size() - 1 - j) * period;
      const double t = t0 + (es[i] - es.back()) / 360.0 * period;
      out[n] = {static_cast<int>(i),
                static_cast<int>(j),
                t,
                0,
                {0, 0, 0},
                {te.cos[i] * ta.cos[j], te.cos[i] * ta.sin[j], te.sin[i]}};
    }
  };
  return p;
}

BeamPattern spinning_on_demand(const SpinningOptions& o, std::size_t max_beams) {
  const auto es = descending(o.elevation_deg, "spinning elevation", kMaxAngleDeg, "degrees");
  require_positive(o.azimuth_step_deg, "spinning azimuth step");
  require_positive(o.rotation_hz, "spinning rotation rate");
  if (o.revolutions < 1) throw std::invalid_argument("spinning revolutions must be at least 1");
  const double firings = std::round(360.0 / o.azimuth_step_deg);  // per revolution
  if (!(firings >= 1 && firings <= 10'000'000))
    throw std::invalid_argument("spinning azimuth step out of range");
  const int per_rev = static_cast<int>(firings);
  require_beams(static_cast<double>(o.revolutions) * per_rev * static_cast<double>(es.size()),
                max_beams, "spinning");
  BeamPattern p{"spinning", static_cast<int>(es.size()) * o.revolutions, per_rev, 1, {}, {}, 0, {},
                0};
  const double firing_period = 1.0 / (o.rotation_hz * per_rev);
  p.beam_count = static_cast<std::size_t>(o.revolutions) * per_rev * es.size();
  // The head turns clockwise seen from above (azimuth decreasing), starting
  // at +180 deg: column 0 is the left edge of the image, as for the others.
  p.make_beams = [es, per_rev, firing_period](std::size_t first, std::span<Beam> out) {
    for (std::size_t n = 0; n < out.size(); ++n) {
      const std::size_t index = first + n;
      const std::size_t i = index % es.size();
      const std::size_t firing = index / es.size();
      const int rev = static_cast<int>(firing / static_cast<std::size_t>(per_rev));
      const int c = static_cast<int>(firing % static_cast<std::size_t>(per_rev));
      const double az = 180.0 - (c + 0.5) * 360.0 / per_rev;
      const double t = (rev * per_rev + c) * firing_period;
      out[n] = {rev * static_cast<int>(es.size()) + static_cast<int>(i),
                c,
                t,
                0,
                {0, 0, 0},
                direction_from_angles(az, es[i])};
    }
  };
  return p;
}

}  // namespace

void BeamPattern::get(std::size_t first, std::span<Beam> out) const {
  if (make_beams) {
    make_beams(first, out);
  } else {
    std::copy_n(beams.begin() + static_cast<std::ptrdiff_t>(first), out.size(), out.begin());
  }
}

BeamPattern mirror_pattern(const MirrorOptions& o, std::size_t max_beams) {
  return stored(mirror_on_demand(o, max_beams));
}

BeamPattern spherical_pattern(const SphericalOptions& o, std::size_t max_beams) {
  return stored(spherical_on_demand(o, max_beams));
}

BeamPattern spinning_pattern(const SpinningOptions& o, std::size_t max_beams) {
  return stored(spinning_on_demand(o, max_beams));
}

const char* pattern_list_name(PatternListName list) {
  static constexpr const char* kNames[] = {"y", "z", "azimuth", "elevation"};
  return kNames[static_cast<std::size_t>(list)];
}

BeamPattern make_pattern(const std::string& name, const PatternSettings& s, const PatternList& list,
                         double measurement_period_s, std::size_t max_beams, bool on_demand) {
  using enum PatternListName;
  if (name == "raster")
    return raster_pattern({list(y), list(z), s.samples, s.speed_m_per_s}, measurement_period_s,
                          max_beams);
  if (name == "line")
    return line_pattern({list(y), list(z), s.speed_m_per_s, s.turnaround_s}, measurement_period_s,
                        max_beams);
  BeamPattern p;
  if (name == "mirror")
    p = mirror_on_demand({list(elevation), s.revolutions, s.rate_hz, s.speed_m_per_s}, max_beams);
  else if (name == "spherical")
    p = spherical_on_demand({list(azimuth), list(elevation), s.rate_hz}, max_beams);
  else if (name == "spinning")
    p = spinning_on_demand({list(elevation), s.azimuth_step_deg, s.rate_hz, s.revolutions},
                           max_beams);
  else
    throw std::invalid_argument("pattern: '" + name +
                                "' is not raster, line, mirror, spherical or spinning");
  // A mirror or a spinning head sets the beams' times; a measurement averages
  // its shots over one output period, so beams closer in time than that are
  // samples the device cannot give (a spinning head's lasers, one per
  // elevation, fire together: only successive firings count).
  // (In blocks: an on-demand pattern's beams are made and dropped.)
  std::vector<Beam> block(std::min<std::size_t>(p.size(), 1 << 14));
  double previous_time = 0;
  for (std::size_t i = 0; i < p.size(); ++i) {
    const std::size_t k = i % block.size();
    if (k == 0) p.get(i, std::span<Beam>(block).first(std::min(block.size(), p.size() - i)));
    const double gap = block[k].time_s - previous_time;
    previous_time = block[k].time_s;
    if (i > 0 && gap > 0 && gap < measurement_period_s * (1 - 1e-9)) {
      char text[240];
      std::snprintf(text, sizeof text,
                    "%s: beams %.4g ms apart, less than one measurement (%.4g ms of shots): use "
                    "fewer shots (--shots), a lower rate (--rate) or a coarser angle step",
                    name.c_str(), gap * 1e3, measurement_period_s * 1e3);
      throw std::invalid_argument(text);
    }
  }
  return on_demand ? p : stored(std::move(p));
}

}  // namespace tofkit::scan
