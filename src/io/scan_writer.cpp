#include "tofkit/io/scan_writer.hpp"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/task_group.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <optional>
#include <stdexcept>
#include <utility>

#include "tofkit/io/atomic_file.hpp"
#include "tofkit/io/scan_output.hpp"

namespace tofkit::io {
namespace {

constexpr std::size_t kPointsPerChunk = 1 << 14;

constexpr std::size_t kBandBytes = 16 << 20;
constexpr std::uint64_t kBlockColumns = 16;  // (16 floats: a cache line)

struct Plane {
  Plane(const char* name_, const char* quantity_, const char* units_)
      : name(name_), quantity(quantity_), units(units_) {}
  const char* name;
  const char* quantity;
  const char* units;
  std::unique_ptr<ScratchFile> rows;  // the finished rows, float32, row-major (for the PNGs)
  FiniteRange finite;
  std::unique_ptr<ScratchFile> by_beam;  // spherical: the pixels in beam order
  std::optional<StreamingOutput> npy;    // its header, then the rows as they are finished
  std::uint64_t row_bytes = 0;           // of the finished rows

  // Finished rows (float32, row-major) to the .npy and the rows kept for the PNGs.
  void append_rows(std::string_view bytes) {
    if (rows) rows->append(bytes);
    if (npy) npy->append(bytes);
    row_bytes += bytes.size();
  }
};

// What a LAS record holds of a point (x, y, z, time, intensity), packed.
constexpr std::size_t kLasFieldBytes = 4 * sizeof(double) + sizeof(float);
void append_las_fields(std::string& out, const CloudPoint& p) {
  char bytes[kLasFieldBytes];
  std::memcpy(bytes, &p.x, sizeof(double));
  std::memcpy(bytes + 8, &p.y, sizeof(double));
  std::memcpy(bytes + 16, &p.z, sizeof(double));
  std::memcpy(bytes + 24, &p.time_s, sizeof(double));
  std::memcpy(bytes + 32, &p.intensity, sizeof(float));
  out.append(bytes, sizeof bytes);
}
void read_las_fields(const char* bytes, CloudPoint& p) {
  p = CloudPoint{};
  std::memcpy(&p.x, bytes, sizeof(double));
  std::memcpy(&p.y, bytes + 8, sizeof(double));
  std::memcpy(&p.z, bytes + 16, sizeof(double));
  std::memcpy(&p.time_s, bytes + 24, sizeof(double));
  std::memcpy(&p.intensity, bytes + 32, sizeof(float));
}

// A pixel's value from its one beam, as ImageBuilder computes it (a weight-1
// sum divided by its weight: the same float bits).
float single(double value) {
  return static_cast<float>((0.0 + 1.0 * value) / 1.0);
}

}  // namespace

struct ScanWriter::Impl {
  ScanWriterSettings settings;
  scan::BeamPattern description;
  scan::ImageBuilder images;
  bool want_images = false, want_cloud = false;
  // Only a LAS asked for: the working file keeps the fields LAS records
  // hold (36 of a CloudPoint's 56 bytes; at 10^8 beams, 0.65 GB less
  // written and read back).
  bool las_only = false;
  // `spherical` goes down columns, so no image row is finished before the
  // last column: its pixels (one beam each) are kept on disk in beam order
  // and turned into rows at the end, a band of rows at a time.
  bool column_major = false;
  std::optional<StreamingOutput> csv;
  std::vector<Plane> planes;  // range, intensity[, sigma]
  std::unique_ptr<ScratchFile> points;
  LasBounds bounds;
  Summary summary;
  std::string text;

  Impl(const scan::ScanResult& d, std::vector<std::size_t> row_last, ScanWriterSettings s)
      : settings(std::move(s)), description(d.pattern), images(d.pattern, std::move(row_last)) {}

  [[nodiscard]] bool wants(const char* output) const { return settings.outputs.count(output) != 0; }
  [[nodiscard]] std::filesystem::path at(const std::string& name) const {
    return settings.directory / name;
  }
};

ScanWriter::ScanWriter(const scan::ScanResult& description, std::vector<std::size_t> row_last_beam,
                       ScanWriterSettings settings)
    : impl_(std::make_unique<Impl>(description, std::move(row_last_beam), std::move(settings))) {
  auto& m = *impl_;
  m.settings.has_model = m.settings.has_model || description.has_model;
  m.want_images = m.wants("png") || m.wants("npy") || m.wants("view");
  m.want_cloud = m.wants("ply") || m.wants("pcd") || m.wants("las");
  if (m.wants("csv")) {
    m.csv.emplace(m.at("scan.csv"));
    m.csv->append(scan_csv_header(m.settings.has_model));
  }
  if (m.want_images) {
    m.planes.emplace_back("range", "range", "m");
    m.planes.emplace_back("intensity", "echo amplitude", "V");
    if (m.settings.has_model) m.planes.emplace_back("sigma", "expected range error (1 sigma)", "m");
    m.column_major = m.description.name == "spherical";
    for (auto& p : m.planes) {
      // The rows are read back only for the PNGs; the .npy (its header known
      // now) takes them as they come, not copied from a working file at the end.
      if (m.wants("png") || m.wants("view")) p.rows = std::make_unique<ScratchFile>(m.at(p.name));
      if (m.wants("npy")) {
        p.npy.emplace(m.at(std::string(p.name) + ".npy"));
        p.npy->append(npy_header(m.description.rows, m.description.columns));
      }
      if (m.column_major) p.by_beam = std::make_unique<ScratchFile>(m.at(p.name));
    }
  }
  if (m.want_cloud) m.points = std::make_unique<ScratchFile>(m.at("points"));
  m.las_only = m.wants("las") && !m.wants("ply") && !m.wants("pcd");
}

ScanWriter::~ScanWriter() = default;

void ScanWriter::add(std::size_t first_beam, std::span<const scan::BeamResult> beams) {
  auto& m = *impl_;
  m.summary.beams += beams.size();
  for (const auto& b : beams) m.summary.mixed += b.surfaces > 1 ? 1 : 0;
  if (m.csv) {
    m.text.clear();
    append_scan_csv_rows(m.text, beams, m.settings.ambient_c, m.settings.has_model);
    m.csv->append(m.text);
  }
  CloudPoint point{};
  if (m.want_cloud) m.text.clear();
  for (const auto& b : beams) {
    if (!cloud_point(b, point)) continue;
    ++m.summary.points;
    if (!m.want_cloud) continue;
    m.bounds.add(point);
    if (m.las_only)
      append_las_fields(m.text, point);
    else
      m.text.append(reinterpret_cast<const char*>(&point), sizeof point);
  }
  if (m.want_cloud) m.points->append(m.text);
  if (m.want_images && m.column_major) {
    const float nan = std::numeric_limits<float>::quiet_NaN();
    for (std::size_t k = 0; k < m.planes.size(); ++k) {
      m.text.clear();
      for (const auto& b : beams) {
        const double d = scan::reported_distance_m(b);
        const bool echo = b.raw.has_echo() && !std::isnan(d);
        const float v = !echo    ? nan
                        : k == 0 ? single(d)
                        : k == 1 ? single(b.raw.amplitude)
                                 : single(b.range.sigma_m);
        m.text.append(reinterpret_cast<const char*>(&v), sizeof v);
      }
      m.planes[k].by_beam->append(m.text);
    }
  } else if (m.want_images) {
    m.images.add(first_beam, beams);
    m.images.take_finished_rows([&](const scan::ImageBuilder::Row& row) {
      const std::span<const float> values[] = {row.range, row.intensity, row.sigma};
      for (std::size_t k = 0; k < m.planes.size(); ++k) {
        m.planes[k].finite.add(values[k]);
        m.planes[k].append_rows(std::string_view(reinterpret_cast<const char*>(values[k].data()),
                                                 values[k].size_bytes()));
      }
    });
  }
}

ScanWriter::Summary ScanWriter::finish() {
  auto& m = *impl_;
  if (m.csv) m.csv->commit();
  const int rows = m.description.rows, columns = m.description.columns;
  const std::size_t row_bytes = static_cast<std::size_t>(columns) * sizeof(float);
  // The images and the point clouds are independent files, finished side by
  // side (the writer's end runs after the last beam, alone: at 10^8 beams,
  // seconds).
  const auto finish_images = [&] {
    if (m.want_images && m.column_major) {
      // Pixel (i, j) is beam (columns - 1 - j) rows + (rows - 1 - i): for a band
      // of rows, each column's values are one contiguous run (rows reversed).
      const auto e = static_cast<std::uint64_t>(rows), a = static_cast<std::uint64_t>(columns);
      const std::uint64_t band =
          std::max<std::uint64_t>(1, kBandBytes / std::max<std::uint64_t>(1, a * sizeof(float)));
      std::vector<float> values, run;
      for (auto& p : m.planes) {
        if (p.by_beam->size() != e * a * sizeof(float))
          throw std::logic_error("ScanWriter: a spherical scan ended before its last beam");
        for (std::uint64_t r0 = 0; r0 < e; r0 += band) {
          const std::uint64_t n = std::min(band, e - r0);
          values.resize(n * a);
          run.resize(n * kBlockColumns);
          // kBlockColumns columns' runs at a time, stored a cache line of a
          // row at a time (one column at a time, every value went to a line
          // of its own: 1.3 x the time at 10^8 beams).
          for (std::uint64_t j0 = 0; j0 < a; j0 += kBlockColumns) {
            const std::uint64_t w = std::min<std::uint64_t>(kBlockColumns, a - j0);
            for (std::uint64_t dj = 0; dj < w; ++dj) {
              const std::uint64_t first = (a - 1 - (j0 + dj)) * e + (e - r0 - n);
              p.by_beam->read(first * sizeof(float), n * sizeof(float), run.data() + dj * n);
            }
            for (std::uint64_t t = 0; t < n; ++t)
              for (std::uint64_t dj = 0; dj < w; ++dj)
                values[t * a + j0 + dj] = run[dj * n + n - 1 - t];
          }
          p.finite.add(values);
          p.append_rows(
              {reinterpret_cast<const char*>(values.data()), values.size() * sizeof(float)});
        }
        p.by_beam.reset();
      }
    }
    if (m.want_images) {
      if (!m.column_major && m.images.next_beam() == 0) {
        // No beam: every pixel invalid (make_images' empty frame).
        const std::vector<float> nan(static_cast<std::size_t>(columns),
                                     std::numeric_limits<float>::quiet_NaN());
        for (int r = 0; r < rows; ++r)
          for (auto& p : m.planes)
            p.append_rows({reinterpret_cast<const char*>(nan.data()), row_bytes});
      }
      for (auto& p : m.planes) {
        if (p.row_bytes != static_cast<std::uint64_t>(rows) * row_bytes)
          throw std::logic_error("ScanWriter: the scan ended before every image row was finished");
        if (m.wants("png")) {
          const std::string name = std::string(p.name) + ".png";
          StreamingOutput png(m.at(name));
          const Png16Scale s = png16_scale(p.finite);
          encode_png16_rows(
              rows, columns, s,
              [&](int r, std::span<float> values) {
                p.rows->read(static_cast<std::uint64_t>(r) * row_bytes, row_bytes, values.data());
              },
              [&](std::string_view bytes) { png.append(bytes); });
          png.commit();
          StreamingOutput json(m.at(std::string(p.name) + ".json"));
          json.append(m.settings.sidecar(name, p.quantity, p.units, s.scale, s.offset));
          json.commit();
        }
        if (p.npy) p.npy->commit();
      }
    }
  };
  const auto finish_clouds = [&] {
    if (m.want_cloud) {
      const std::uint64_t n = m.summary.points;
      const LasBounds::Offset offset = m.bounds.offset();
      const struct {
        const char* output;
        const char* file;
      } clouds[] = {{"ply", "points.ply"}, {"pcd", "points.pcd"}, {"las", "points.las"}};
      std::vector<CloudPoint> chunk(kPointsPerChunk);
      std::string fields;  // (las_only: the working file's records)
      for (const auto& c : clouds) {
        if (!m.wants(c.output)) continue;
        StreamingOutput out(m.at(c.file));
        const std::string_view kind = c.output;
        out.append(kind == "ply"   ? ply_header(n)
                   : kind == "pcd" ? pcd_header(n)
                                   : las_header(m.bounds));
        for (std::uint64_t i = 0; i < n; i += kPointsPerChunk) {
          const std::size_t count =
              static_cast<std::size_t>(std::min<std::uint64_t>(kPointsPerChunk, n - i));
          if (m.las_only) {
            fields.resize(count * kLasFieldBytes);
            m.points->read(i * kLasFieldBytes, fields.size(), fields.data());
            for (std::size_t k = 0; k < count; ++k)
              read_las_fields(fields.data() + k * kLasFieldBytes, chunk[k]);
          } else {
            m.points->read(i * sizeof(CloudPoint), count * sizeof(CloudPoint), chunk.data());
          }
          m.text.clear();
          if (kind == "las") {
            // Fixed-size records, encoded on every thread: the scan's last
            // serial step (a 1.44 M-beam scan's 0.5 M points: some 10 ms alone).
            m.text.resize(count * kLasPointBytes);
            tbb::parallel_for(tbb::blocked_range<std::size_t>(0, count, 2048),
                              [&](const tbb::blocked_range<std::size_t>& r) {
                                for (std::size_t k = r.begin(); k < r.end(); ++k)
                                  put_las_point(m.text.data() + k * kLasPointBytes, chunk[k],
                                                offset);
                              });
            out.append(m.text);
            continue;
          }
          for (std::size_t k = 0; k < count; ++k) {
            if (kind == "ply")
              append_ply_point(m.text, chunk[k]);
            else if (kind == "pcd")
              append_pcd_point(m.text, chunk[k]);
            else
              append_las_point(m.text, chunk[k], offset);
          }
          out.append(m.text);
        }
        out.commit();
      }
    }
  };
  tbb::task_group images;
  images.run(finish_images);
  try {
    finish_clouds();
  } catch (...) {
    try {
      images.wait();
    } catch (...) {  // (the first failure is the one reported)
    }
    throw;
  }
  images.wait();
  if (m.wants("view")) {
    // The picture's colour limits are order statistics of the whole image,
    // selected in two passes over the finished images read back; its rows
    // are then drawn and encoded one at a time (memory: a row, not the image).
    auto pass = [&](std::size_t k) -> ValuePass {
      return [&, k](const std::function<void(std::span<const float>)>& visit) {
        constexpr std::uint64_t kChunkValues = 1 << 16;
        std::vector<float> chunk(kChunkValues);
        const std::uint64_t total = static_cast<std::uint64_t>(rows) * columns;
        for (std::uint64_t first = 0; first < total; first += kChunkValues) {
          const std::uint64_t count = std::min(kChunkValues, total - first);
          m.planes[k].rows->read(first * sizeof(float), count * sizeof(float), chunk.data());
          visit({chunk.data(), static_cast<std::size_t>(count)});
        }
      };
    };
    const auto range_limits = streamed_limits(pass(0));
    const auto intensity_limits = streamed_limits(pass(1));
    StreamingOutput out(m.at("range_view.png"));
    encode_range_view_rows(
        rows, columns, range_limits, intensity_limits,
        [&](int r, std::span<float> range, std::span<float> intensity) {
          m.planes[0].rows->read(static_cast<std::uint64_t>(r) * row_bytes, row_bytes,
                                 range.data());
          m.planes[1].rows->read(static_cast<std::uint64_t>(r) * row_bytes, row_bytes,
                                 intensity.data());
        },
        [&](std::string_view bytes) { out.append(bytes); });
    out.commit();
  }
  return m.summary;
}

}  // namespace tofkit::io
