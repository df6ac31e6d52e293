#include "tofkit/scan/scanner.hpp"

#include <tbb/parallel_for.h>
#include <tbb/task_group.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <map>
#include <stdexcept>
#include <string>

#if defined(__linux__)
#include <sys/mman.h>
#endif

namespace tofkit::scan {
namespace {

constexpr std::size_t kProgressBlock = 1 << 16;

/// Reserves room for n elements and has the kernel map its pages in one call
/// (MADV_POPULATE_WRITE, Linux 5.14+): a megabeam scan's results are ~250 MB,
/// and faulting them in page by page on first touch took about as long as the
/// device's measurements. Elsewhere (or on error) the pages fault in as usual.
template <typename T>
void reserve_populated(std::vector<T>& v, std::size_t n) {
  v.reserve(n);
#if defined(__linux__) && defined(MADV_POPULATE_WRITE)
  constexpr std::uintptr_t kPage = 4096;
  const auto begin = reinterpret_cast<std::uintptr_t>(v.data());
  const std::uintptr_t first = (begin + kPage - 1) & ~(kPage - 1);
  const std::uintptr_t last = (begin + n * sizeof(T)) & ~(kPage - 1);
  if (last > first) {
#if defined(MADV_HUGEPAGE)
    // Transparent huge pages where the system allows them (THP "madvise"):
    // 512 times fewer pages to map and to miss in the TLB.
    (void)::madvise(reinterpret_cast<void*>(first), last - first, MADV_HUGEPAGE);
#endif
    (void)::madvise(reinterpret_cast<void*>(first), last - first, MADV_POPULATE_WRITE);
  }
#endif
}

/// A block's footprints, targets, conditions and measurements, kept per
/// thread (the surface lists keep their storage from block to block).
struct BlockScratch {
  std::vector<Footprint::Result> footprints;
  std::vector<device::Target> targets;
  std::vector<device::Conditions> conditions;
  std::vector<ranging::RawMeasurement> raw;
  void resize(std::size_t n) {
    if (targets.size() < n) {
      footprints.resize(n);
      targets.resize(n);
      conditions.resize(n);
      raw.resize(n);
    }
  }
};

BlockScratch& block_scratch() {
  thread_local BlockScratch scratch;
  return scratch;
}

struct Accumulator {
  std::vector<double> weight, range, intensity, sigma, truth, truth_weight;
  explicit Accumulator(std::size_t n)
      : weight(n), range(n), intensity(n), sigma(n), truth(n), truth_weight(n) {}
};

}  // namespace

void beam_to_world(const Beam& beam, const RigidTransform& to_world, Beam& out) {
  out.row = beam.row;
  out.column = beam.column;
  out.time_s = beam.time_s;
  out.position_m = beam.position_m;
  out.origin_m = to_world.transform(beam.origin_m);
  out.direction = to_world.rotate(beam.direction);
}

void record_footprint(const Footprint::Result& footprint, BeamResult& b) {
  double largest = 0, reflectance = ranging::kNaN, cos_incidence = ranging::kNaN;
  for (const auto& surface : footprint.target.surfaces) {
    if (surface.fraction > largest) {
      largest = surface.fraction;
      reflectance = surface.reflectance;
      cos_incidence = surface.cos_incidence;
    }
  }
  b.true_range_m = footprint.true_range_m;
  b.surfaces = static_cast<int>(footprint.target.surfaces.size());
  b.reflectance = reflectance;
  b.cos_incidence = cos_incidence;
}

namespace {

/// Beams [begin, end) of `pattern` measured into out[0 .. end - begin).
void measure_beams(const RayCaster& caster, const Footprint& footprint,
                   const device::VirtualRangefinder& device, const BeamPattern& /*pattern*/,
                   const ScanOptions& options, const RigidTransform& pose, int shots,
                   std::size_t begin, std::size_t end, const Beam* from_beams, BeamResult* out) {
  tbb::parallel_for(
      tbb::blocked_range<std::size_t>(begin, end, 256),
      [&](const tbb::blocked_range<std::size_t>& block) {
        // The block in stages, each over all its beams: the beams
        // in the world frame and their conditions, the footprints,
        // the targets, then their measurements in one call (single
        // shots run in lanes). A stage reads what the one before
        // wrote long after the stores: a load that follows a store
        // to the same bytes closely, but is wider than it, waits
        // for the store to reach the cache (~15 cycles a time).
        BlockScratch& s = block_scratch();
        const std::size_t count = block.size();
        s.resize(count);
        BeamResult* const beams = out + (block.begin() - begin);
        for (std::size_t k = 0; k < count; ++k) {
          const Beam& from = from_beams[block.begin() - begin + k];
          beam_to_world(from, pose, beams[k].beam);
          const device::Conditions& at_start = options.conditions;
          device::Conditions& conditions = s.conditions[k];
          conditions = at_start;
          if (options.clocks_follow_beams) {
            conditions.minutes_since_power_on =
                at_start.minutes_since_power_on + from.time_s / 60.0;
            conditions.ms_since_laser_on = at_start.ms_since_laser_on + from.time_s * 1e3;
          }
        }
        for (std::size_t k = 0; k < count; ++k)
          footprint.trace(caster, beams[k].beam.origin_m, beams[k].beam.direction, s.footprints[k]);
        for (std::size_t k = 0; k < count; ++k) {
          Footprint::Result& fp = s.footprints[k];
          record_footprint(fp, beams[k]);
          beams[k].range = {};
          // (Swapped, not copied: both buffers are reused.)
          std::swap(s.targets[k].surfaces, fp.target.surfaces);
        }
        device.measure({s.targets.data(), count}, {s.conditions.data(), count}, options.seed,
                       block.begin(), shots, {s.raw.data(), count});
        for (std::size_t k = 0; k < count; ++k) beams[k].raw = s.raw[k];
      });
}

// The pattern's description without its beams: each beam is kept once, in its
// BeamResult (world frame).
void describe_pattern(const BeamPattern& pattern, BeamPattern& description) {
  description.name = pattern.name;
  description.rows = pattern.rows;
  description.columns = pattern.columns;
  description.shots_multiplier = pattern.shots_multiplier;
  description.column_positions_m = pattern.column_positions_m;
  description.sample_extent_m = pattern.sample_extent_m;
}

}  // namespace

int shots_per_beam(const device::DeviceConfig& config, int shots, const BeamPattern& pattern) {
  const std::int64_t base = shots > 0 ? shots : config.measurement.shots;
  const std::int64_t total = base * pattern.shots_multiplier;
  if (total > device::kMaxShots) {
    throw std::invalid_argument(std::to_string(pattern.shots_multiplier) + " samples x " +
                                std::to_string(base) + " shots = " + std::to_string(total) +
                                " shots per point is over the limit of " +
                                std::to_string(device::kMaxShots));
  }
  return static_cast<int>(total);
}

double reported_distance_m(const BeamResult& b) {
  return std::isnan(b.range.distance_m) ? b.raw.distance_raw_m : b.range.distance_m;
}

ScanResult run_scan(const RayCaster& caster, const Footprint& footprint,
                    const device::VirtualRangefinder& device, const BeamPattern& pattern,
                    const ScanOptions& options) {
  ScanResult result;
  run_scan(caster, footprint, device, pattern, options, result);
  return result;
}

void run_scan(const RayCaster& caster, const Footprint& footprint,
              const device::VirtualRangefinder& device, const BeamPattern& pattern,
              const ScanOptions& options, ScanResult& result) {
  result.has_model = false;
  describe_pattern(pattern, result.pattern);
  result.pattern.beams.clear();
  result.sensor = caster.scene().sensor;
  const RigidTransform pose = result.sensor.to_world();
  const std::size_t n = pattern.size();
  if (result.beams.capacity() < n) {
    result.beams = {};
    reserve_populated(result.beams, n);
  }
  result.beams.resize(n);
  const int shots = shots_per_beam(device.config(), options.shots, pattern);
  std::vector<Beam> made;  // an on-demand pattern's block
  for (std::size_t begin = 0; begin < n; begin += kProgressBlock) {
    const std::size_t end = std::min(n, begin + kProgressBlock);
    const Beam* from = pattern.beams.data() + begin;
    if (pattern.make_beams) {
      made.resize(end - begin);
      pattern.get(begin, made);
      from = made.data();
    }
    measure_beams(caster, footprint, device, pattern, options, pose, shots, begin, end, from,
                  &result.beams[begin]);
    if (options.progress) options.progress(end, n);
  }
}

void run_scan_blocks(const RayCaster& caster, const Footprint& footprint,
                     const device::VirtualRangefinder& device, const BeamPattern& pattern,
                     const ScanOptions& options, std::size_t first, std::size_t last,
                     std::size_t block_beams, const BeamBlockSink& sink) {
  last = std::min(last, pattern.size());
  if (first >= last) return;
  block_beams = std::max<std::size_t>(1, block_beams);
  const RigidTransform pose = caster.scene().sensor.to_world();
  const int shots = shots_per_beam(device.config(), options.shots, pattern);
  // Two buffers: the sink writes one block (on this thread) while the next
  // is measured (on the others).
  std::vector<BeamResult> buffers[2];
  std::vector<Beam> made[2];  // the blocks' beams (sensor frame)
  for (auto& b : buffers) b.resize(std::min(block_beams, last - first));
  for (auto& b : made) b.resize(std::min(block_beams, last - first));
  auto measure = [&](std::size_t begin, int k) {
    const std::size_t end = std::min(last, begin + block_beams);
    pattern.get(begin, std::span<Beam>(made[k]).first(end - begin));
    measure_beams(caster, footprint, device, pattern, options, pose, shots, begin, end,
                  made[k].data(), buffers[k].data());
  };
  measure(first, 0);
  tbb::task_group next;
  for (std::size_t begin = first, k = 0; begin < last; begin += block_beams, k ^= 1) {
    const std::size_t end = std::min(last, begin + block_beams);
    const bool more = end < last;
    if (more) next.run([&, end, k] { measure(end, static_cast<int>(k ^ 1)); });
    try {
      sink(begin, {buffers[k].data(), end - begin});
    } catch (...) {
      next.wait();
      throw;
    }
    next.wait();
    if (options.progress) options.progress(end - first, last - first);
  }
}

ScanResult describe_scan(const BeamPattern& pattern, const Scene& scene) {
  ScanResult result;
  describe_pattern(pattern, result.pattern);
  result.sensor = scene.sensor;
  return result;
}

ScanResult run_scan(const Scene& scene, const device::DeviceConfig& config,
                    device::SimulationMode mode, const BeamPattern& pattern,
                    const ScanOptions& options) {
  const device::VirtualRangefinder rangefinder(config, mode);
  const RayCaster caster(scene);
  return run_scan(caster, Footprint(config), rangefinder, pattern, options);
}

void apply_pipeline(const ranging::Pipeline& pipeline, std::span<BeamResult> beams,
                    const ranging::UncertaintyBudget* budget) {
  // The raw measurements read in place from the beams (one batch, no copy).
  std::vector<ranging::Range> ranges(beams.size());
  if (!ranges.empty()) {
    const auto raw = ranging::RawColumns::of(&beams[0].raw, beams.size(), sizeof(BeamResult));
    pipeline.apply(raw, ranges);
    if (budget && !budget->empty()) {
      const double unknown[1] = {ranging::kNaN};
      ranging::apply_budget(*budget, pipeline, raw, unknown, ranges);
    }
  }
  for (std::size_t i = 0; i < ranges.size(); ++i) beams[i].range = ranges[i];
}

void apply_pipeline(const ranging::Pipeline& pipeline, ScanResult& result) {
  apply_pipeline(pipeline, std::span<BeamResult>(result.beams));
  result.has_model = true;
}

std::vector<std::size_t> row_last_beams(const BeamPattern& pattern) {
  std::vector<std::size_t> last(static_cast<std::size_t>(std::max(0, pattern.rows)), 0);
  std::vector<Beam> block(std::min<std::size_t>(pattern.size(), 1 << 14));
  for (std::size_t first = 0; first < pattern.size(); first += block.size()) {
    const std::size_t count = std::min(block.size(), pattern.size() - first);
    pattern.get(first, std::span<Beam>(block).first(count));
    for (std::size_t k = 0; k < count; ++k) {
      const int r = block[k].row;
      if (r >= 0 && r < pattern.rows) last[static_cast<std::size_t>(r)] = first + k;
    }
  }
  return last;
}

struct ImageBuilder::Impl {
  BeamPattern description;  // without beams
  std::vector<std::size_t> row_last;
  int next_row = 0;
  std::map<int, Accumulator> open;                    // rows begun and not handed out
  std::vector<float> range, intensity, sigma, truth;  // the row being handed out

  Accumulator& row(int r) {
    auto it = open.find(r);
    if (it == open.end())
      it = open.emplace(r, Accumulator(static_cast<std::size_t>(description.columns))).first;
    return it->second;
  }
};

ImageBuilder::ImageBuilder(const BeamPattern& description, std::vector<std::size_t> row_last_beam)
    : impl_(std::make_unique<Impl>()) {
  auto& d = impl_->description;
  d.name = description.name;
  d.rows = description.rows;
  d.columns = description.columns;
  d.shots_multiplier = description.shots_multiplier;
  d.column_positions_m = description.column_positions_m;
  d.sample_extent_m = description.sample_extent_m;
  if (row_last_beam.size() != static_cast<std::size_t>(std::max(0, d.rows)))
    throw std::invalid_argument("ImageBuilder: one last beam per row is needed");
  impl_->row_last = std::move(row_last_beam);
}

ImageBuilder::~ImageBuilder() = default;

void ImageBuilder::add(std::size_t first_beam, std::span<const BeamResult> beams) {
  if (first_beam != next_beam_)
    throw std::logic_error("ImageBuilder: blocks must come in beam order without gaps");
  next_beam_ += beams.size();
  const auto& p = impl_->description;
  auto add_to = [&](Accumulator& acc, std::size_t c, double w, const BeamResult& b) {
    if (!std::isnan(b.true_range_m)) {
      acc.truth[c] += w * b.true_range_m;
      acc.truth_weight[c] += w;
    }
    const double d = reported_distance_m(b);
    if (!b.raw.has_echo() || std::isnan(d)) return;
    acc.weight[c] += w;
    acc.range[c] += w * d;
    acc.intensity[c] += w * b.raw.amplitude;
    acc.sigma[c] += w * b.range.sigma_m;
  };
  if (p.name == "line") {
    // Column c covers [y_c - pitch/2, y_c + pitch/2]; a sample covers
    // [y - e/2, y + e/2]; its weight in the column is the overlap length.
    const auto& ys = p.column_positions_m;
    const double pitch = (ys.front() - ys.back()) / static_cast<double>(ys.size() - 1);
    const double half_e = 0.5 * p.sample_extent_m;
    for (const auto& b : beams) {
      const double y = b.beam.position_m;
      const double lo = y - half_e, hi = y + half_e;
      // Columns run from ys.front() (largest y) downwards.
      const int c_first =
          std::max(0, static_cast<int>(std::floor((ys.front() - hi) / pitch + 0.5)));
      const int c_last =
          std::min(p.columns - 1, static_cast<int>(std::floor((ys.front() - lo) / pitch + 0.5)));
      Accumulator* acc = nullptr;
      for (int c = c_first; c <= c_last; ++c) {
        const double col_hi = ys[static_cast<std::size_t>(c)] + 0.5 * pitch;
        const double col_lo = ys[static_cast<std::size_t>(c)] - 0.5 * pitch;
        const double overlap = std::min(hi, col_hi) - std::max(lo, col_lo);
        if (overlap > 0) {
          if (acc == nullptr) acc = &impl_->row(b.beam.row);
          add_to(*acc, static_cast<std::size_t>(c), overlap, b);
        }
      }
    }
  } else {
    int last_row = -1;
    Accumulator* acc = nullptr;
    for (const auto& b : beams) {
      if (b.beam.row != last_row) acc = &impl_->row(last_row = b.beam.row);
      add_to(*acc, static_cast<std::size_t>(b.beam.column), 1.0, b);
    }
  }
}

void ImageBuilder::take_finished_rows(const std::function<void(const Row&)>& take) {
  auto& m = *impl_;
  const auto columns = static_cast<std::size_t>(m.description.columns);
  const auto finish = [&](std::vector<float>& out, const std::vector<double>& sum,
                          const std::vector<double>& w) {
    out.resize(columns);
    for (std::size_t i = 0; i < columns; ++i) {
      out[i] =
          w[i] > 0 ? static_cast<float>(sum[i] / w[i]) : std::numeric_limits<float>::quiet_NaN();
    }
  };
  while (m.next_row < m.description.rows &&
         m.row_last[static_cast<std::size_t>(m.next_row)] < next_beam_) {
    const int r = m.next_row++;
    auto it = m.open.find(r);
    if (it == m.open.end()) {
      for (auto* v : {&m.range, &m.intensity, &m.sigma, &m.truth})
        v->assign(columns, std::numeric_limits<float>::quiet_NaN());
    } else {
      const Accumulator& acc = it->second;
      finish(m.range, acc.range, acc.weight);
      finish(m.intensity, acc.intensity, acc.weight);
      finish(m.sigma, acc.sigma, acc.weight);
      finish(m.truth, acc.truth, acc.truth_weight);
      m.open.erase(it);
    }
    take(Row{r, m.range, m.intensity, m.sigma, m.truth});
  }
}

ScanImages make_images(const ScanResult& result) {
  const auto& p = result.pattern;
  // Every row finishes after the last beam.
  std::vector<std::size_t> last(static_cast<std::size_t>(std::max(0, p.rows)), 0);
  ImageBuilder builder(p, std::move(last));
  builder.add(0, result.beams);
  ScanImages images;
  for (Image* image : {&images.range, &images.intensity, &images.sigma, &images.truth}) {
    *image = Image{p.rows, p.columns, {}};
    image->values.reserve(static_cast<std::size_t>(p.rows) * p.columns);
  }
  auto append = [](Image& image, std::span<const float> row) {
    image.values.insert(image.values.end(), row.begin(), row.end());
  };
  if (result.beams.empty()) {
    for (Image* image : {&images.range, &images.intensity, &images.sigma, &images.truth})
      image->values.assign(static_cast<std::size_t>(p.rows) * p.columns,
                           std::numeric_limits<float>::quiet_NaN());
    return images;
  }
  builder.take_finished_rows([&](const ImageBuilder::Row& row) {
    append(images.range, row.range);
    append(images.intensity, row.intensity);
    append(images.sigma, row.sigma);
    append(images.truth, row.truth);
  });
  return images;
}

}  // namespace tofkit::scan
