#include "tofkit/io/scan_output.hpp"

#include <fmt/format.h>
#include <spng.h>

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <cstring>
#include <iterator>
#include <limits>
#include <stdexcept>

namespace tofkit::io {
namespace {

template <typename T>
void put(std::string& out, T value) {
  char bytes[sizeof(T)];
  std::memcpy(bytes, &value, sizeof(T));  // little-endian host (x86-64, aarch64)
  out.append(bytes, sizeof(T));
}

std::string encode_png(int rows, int columns, int bit_depth, int color_type, const void* data,
                       std::size_t size) {
  spng_ctx* ctx = spng_ctx_new(SPNG_CTX_ENCODER);
  if (ctx == nullptr) throw std::runtime_error("PNG: cannot create an encoder");
  spng_set_option(ctx, SPNG_ENCODE_TO_BUFFER, 1);
  spng_ihdr ihdr{};
  ihdr.width = static_cast<std::uint32_t>(columns);
  ihdr.height = static_cast<std::uint32_t>(rows);
  ihdr.bit_depth = static_cast<std::uint8_t>(bit_depth);
  ihdr.color_type = static_cast<std::uint8_t>(color_type);
  spng_set_ihdr(ctx, &ihdr);
  int err = spng_encode_image(ctx, data, size, SPNG_FMT_PNG, SPNG_ENCODE_FINALIZE);
  std::string out;
  if (err == 0) {
    std::size_t length = 0;
    void* buffer = spng_get_png_buffer(ctx, &length, &err);
    if (buffer != nullptr) {
      out.assign(static_cast<const char*>(buffer), length);
      std::free(buffer);
    }
  }
  spng_ctx_free(ctx);
  if (err != 0) throw std::runtime_error(std::string("PNG encoding failed: ") + spng_strerror(err));
  return out;
}

// Finite values' [q, 1 - q] quantiles (for colour limits).
std::pair<double, double> limits(const scan::Image& image, double q) {
  std::vector<float> v;
  for (const float x : image.values) {
    if (std::isfinite(x)) v.push_back(x);
  }
  if (v.empty()) return {0, 1};
  std::sort(v.begin(), v.end());
  const auto at = [&](double f) {
    return v[static_cast<std::size_t>(f * static_cast<double>(v.size() - 1))];
  };
  double lo = at(q), hi = at(1 - q);
  if (!(hi > lo)) hi = lo + 1e-3;
  return {lo, hi};
}

// A float's bits as an unsigned key in the floats' order (negatives reversed).
std::uint32_t order_key(float x) {
  const auto u = std::bit_cast<std::uint32_t>(x);
  return (u & 0x80000000u) != 0 ? ~u : (u | 0x80000000u);
}
float from_order_key(std::uint32_t k) {
  return std::bit_cast<float>((k & 0x80000000u) != 0 ? (k & 0x7FFFFFFFu) : ~k);
}

// Google's Turbo colour map (polynomial approximation), t in [0, 1].
std::array<unsigned char, 3> turbo(double t) {
  t = std::clamp(t, 0.0, 1.0);
  const double r =
      0.13572138 +
      t * (4.61539260 +
           t * (-42.66032258 + t * (132.13108234 + t * (-152.94239396 + t * 59.28637943))));
  const double g =
      0.09140261 +
      t * (2.19418839 + t * (4.84296658 + t * (-14.18503333 + t * (4.27729857 + t * 2.82956604))));
  const double b =
      0.10667330 +
      t * (12.64194608 +
           t * (-60.58204836 + t * (110.36276771 + t * (-89.90310912 + t * 27.34824973))));
  auto c = [](double x) {
    return static_cast<unsigned char>(std::lround(255 * std::clamp(x, 0.0, 1.0)));
  };
  return {c(r), c(g), c(b)};
}

// 3 x 5 pixel glyphs for scale-bar labels.
const char* glyph(char ch) {
  switch (ch) {
    case '0':
      return "111101101101111";
    case '1':
      return "010110010010111";
    case '2':
      return "111001111100111";
    case '3':
      return "111001111001111";
    case '4':
      return "101101111001001";
    case '5':
      return "111100111001111";
    case '6':
      return "111100111101111";
    case '7':
      return "111001001001001";
    case '8':
      return "111101111101111";
    case '9':
      return "111101111001111";
    case '.':
      return "000000000000010";
    case '-':
      return "000000111000000";
    case 'm':
      return "000000111111101";
    case 'V':
      return "101101101101010";
    default:
      return "000000000000000";
  }
}

struct Canvas {
  int rows, columns;
  std::vector<unsigned char> rgb;
  Canvas(int r, int c, unsigned char grey)
      : rows(r), columns(c), rgb(static_cast<std::size_t>(r) * c * 3, grey) {}
  void set(int r, int c, std::array<unsigned char, 3> colour) {
    if (r < 0 || c < 0 || r >= rows || c >= columns) return;
    std::memcpy(&rgb[(static_cast<std::size_t>(r) * columns + c) * 3], colour.data(), 3);
  }
  void text(int r, int c, const std::string& s, int scale) {
    for (const char ch : s) {
      const char* g = glyph(ch);
      for (int y = 0; y < 5; ++y) {
        for (int x = 0; x < 3; ++x) {
          if (g[y * 3 + x] != '1') continue;
          for (int dy = 0; dy < scale; ++dy) {
            for (int dx = 0; dx < scale; ++dx)
              set(r + y * scale + dy, c + x * scale + dx, {255, 255, 255});
          }
        }
      }
      c += 4 * scale;
    }
  }
};

}  // namespace

Png16Scale png16_scale(const FiniteRange& finite) {
  double lo = 0, hi = 1;
  if (finite.any) {
    lo = finite.lo, hi = finite.hi;
    if (!(hi > lo)) hi = lo + 1e-3;
  }
  // Stored 1 .. 65535 spans [lo, hi]; 0 is invalid.
  Png16Scale out;
  out.scale = (hi - lo) / 65534.0;
  out.offset = lo - out.scale;
  return out;
}

void FiniteRange::add(std::span<const float> values) {
  for (const float v : values) {
    if (!std::isfinite(v)) continue;
    if (!any) lo = hi = v, any = true;
    lo = std::min<double>(lo, v), hi = std::max<double>(hi, v);
  }
}

namespace {

void png16_row(std::span<const float> values, const Png16Scale& s, std::uint16_t* pixels) {
  for (std::size_t i = 0; i < values.size(); ++i) {
    const float v = values[i];
    pixels[i] = 0;
    if (!std::isfinite(v)) continue;
    const double p = std::round((v - s.offset) / s.scale);
    pixels[i] = static_cast<std::uint16_t>(std::clamp(p, 1.0, 65535.0));
  }
}

int write_to_sink(spng_ctx*, void* user, void* data, std::size_t length) {
  auto& sink = *static_cast<const std::function<void(std::string_view)>*>(user);
  try {
    sink(std::string_view(static_cast<const char*>(data), length));
  } catch (...) {
    return SPNG_IO_ERROR;
  }
  return 0;
}

// One progressive encoder for every image written by rows: `row(r)` returns
// row r's bytes (bit_depth and colour type as the header says).
void encode_png_byte_rows(int rows, int columns, int bit_depth, int color_type,
                          const std::function<std::span<const unsigned char>(int)>& row,
                          const std::function<void(std::string_view)>& write) {
  spng_ctx* ctx = spng_ctx_new(SPNG_CTX_ENCODER);
  if (ctx == nullptr) throw std::runtime_error("PNG: cannot create an encoder");
  std::function<void(std::string_view)> sink = write;
  spng_set_png_stream(ctx, write_to_sink, &sink);
  spng_ihdr ihdr{};
  ihdr.width = static_cast<std::uint32_t>(columns);
  ihdr.height = static_cast<std::uint32_t>(rows);
  ihdr.bit_depth = static_cast<std::uint8_t>(bit_depth);
  ihdr.color_type = static_cast<std::uint8_t>(color_type);
  spng_set_ihdr(ctx, &ihdr);
  int err = spng_encode_image(ctx, nullptr, 0, SPNG_FMT_PNG,
                              SPNG_ENCODE_PROGRESSIVE | SPNG_ENCODE_FINALIZE);
  for (int r = 0; r < rows && err == 0; ++r) {
    const std::span<const unsigned char> bytes = row(r);
    err = spng_encode_row(ctx, const_cast<unsigned char*>(bytes.data()), bytes.size());
    if (err == SPNG_EOI) err = 0;
  }
  spng_ctx_free(ctx);
  if (err != 0) throw std::runtime_error(std::string("PNG encoding failed: ") + spng_strerror(err));
}

}  // namespace

void encode_png16_rows(int rows, int columns, const Png16Scale& scale,
                       const std::function<void(int, std::span<float>)>& row,
                       const std::function<void(std::string_view)>& write) {
  std::vector<float> values(static_cast<std::size_t>(columns));
  std::vector<std::uint16_t> pixels(static_cast<std::size_t>(columns));
  encode_png_byte_rows(
      rows, columns, 16, SPNG_COLOR_TYPE_GRAYSCALE,
      [&](int r) {
        row(r, values);
        png16_row(values, scale, pixels.data());
        return std::span<const unsigned char>(reinterpret_cast<const unsigned char*>(pixels.data()),
                                              pixels.size() * sizeof(std::uint16_t));
      },
      write);
}

Png16 encode_png16(const scan::Image& image) {
  Png16 out;
  FiniteRange finite;
  finite.add(image.values);
  const Png16Scale s = png16_scale(finite);
  out.scale = s.scale;
  out.offset = s.offset;
  std::vector<std::uint16_t> pixels(image.values.size(), 0);
  png16_row(image.values, s, pixels.data());
  out.png = encode_png(image.rows, image.columns, 16, SPNG_COLOR_TYPE_GRAYSCALE, pixels.data(),
                       pixels.size() * sizeof(std::uint16_t));
  return out;
}

void encode_png_rgb_rows(int rows, int columns,
                         const std::function<void(int, std::span<unsigned char>)>& row,
                         const std::function<void(std::string_view)>& write) {
  std::vector<unsigned char> rgb(static_cast<std::size_t>(columns) * 3);
  encode_png_byte_rows(
      rows, columns, 8, SPNG_COLOR_TYPE_TRUECOLOR,
      [&](int r) {
        row(r, rgb);
        return std::span<const unsigned char>(rgb);
      },
      write);
}

std::string encode_png_rgb(int rows, int columns, const std::vector<unsigned char>& rgb) {
  return encode_png(rows, columns, 8, SPNG_COLOR_TYPE_TRUECOLOR, rgb.data(), rgb.size());
}

std::string npy_header(int rows, int columns) {
  std::string header =
      fmt::format("{{'descr': '<f4', 'fortran_order': False, 'shape': ({}, {}), }}", rows, columns);
  // Magic (6) + version (2) + length (2) + header + '\n', padded to 64 bytes.
  const std::size_t total = (10 + header.size() + 1 + 63) / 64 * 64;
  header.append(total - 10 - header.size() - 1, ' ');
  header.push_back('\n');
  std::string out("\x93NUMPY\x01\x00", 8);
  put(out, static_cast<std::uint16_t>(header.size()));
  out += header;
  return out;
}

std::string encode_npy(const scan::Image& image) {
  std::string out = npy_header(image.rows, image.columns);
  for (const float v : image.values) put(out, v);
  return out;
}

bool cloud_point(const scan::BeamResult& b, CloudPoint& point) {
  const double d = scan::reported_distance_m(b);
  if (!b.raw.has_echo() || !std::isfinite(d)) return false;  // REP-117
  const auto& o = b.beam.origin_m;
  const auto& u = b.beam.direction;
  point = {o[0] + d * u[0],
           o[1] + d * u[1],
           o[2] + d * u[2],
           static_cast<float>(b.raw.amplitude),
           static_cast<float>(d),
           static_cast<float>(b.range.sigma_m),
           b.beam.row,
           b.beam.column,
           b.beam.time_s,
           b.raw.flags};
  return true;
}

std::vector<CloudPoint> cloud_points(const scan::ScanResult& result) {
  std::vector<CloudPoint> points;
  CloudPoint point{};
  for (const auto& b : result.beams) {
    if (cloud_point(b, point)) points.push_back(point);
  }
  return points;
}

std::string ply_header(std::uint64_t points) {
  return fmt::format(
      "ply\nformat binary_little_endian 1.0\ncomment tofkit scan: world frame (REP-103), metres\n"
      "element vertex {}\nproperty double x\nproperty double y\nproperty double z\n"
      "property float intensity\nproperty float range\nproperty float sigma\nproperty int row\n"
      "property int column\nproperty double time\nproperty int flags\nend_header\n",
      points);
}

void append_ply_point(std::string& out, const CloudPoint& p) {
  put(out, p.x), put(out, p.y), put(out, p.z);
  put(out, p.intensity), put(out, p.range), put(out, p.sigma);
  put(out, static_cast<std::int32_t>(p.row)), put(out, static_cast<std::int32_t>(p.column));
  put(out, p.time_s), put(out, static_cast<std::int32_t>(p.flags));
}

std::string encode_ply(const std::vector<CloudPoint>& points) {
  std::string out = ply_header(points.size());
  for (const auto& p : points) append_ply_point(out, p);
  return out;
}

std::string pcd_header(std::uint64_t points) {
  return fmt::format(
      "# .PCD v0.7 - tofkit scan, world frame (REP-103), metres\nVERSION 0.7\n"
      "FIELDS x y z intensity range sigma row column time flags\n"
      "SIZE 4 4 4 4 4 4 4 4 8 4\nTYPE F F F F F F I I F U\nCOUNT 1 1 1 1 1 1 1 1 1 1\n"
      "WIDTH {}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {}\nDATA binary\n",
      points, points);
}

void append_pcd_point(std::string& out, const CloudPoint& p) {
  put(out, static_cast<float>(p.x)), put(out, static_cast<float>(p.y)),
      put(out, static_cast<float>(p.z));
  put(out, p.intensity), put(out, p.range), put(out, p.sigma);
  put(out, static_cast<std::int32_t>(p.row)), put(out, static_cast<std::int32_t>(p.column));
  put(out, p.time_s), put(out, p.flags);
}

std::string encode_pcd(const std::vector<CloudPoint>& points) {
  std::string out = pcd_header(points.size());
  for (const auto& p : points) append_pcd_point(out, p);
  return out;
}

void LasBounds::add(const CloudPoint& p) {
  const double c[3] = {p.x, p.y, p.z};
  if (points == 0) {
    for (int k = 0; k < 3; ++k) lo[k] = hi[k] = c[k];
  }
  for (int k = 0; k < 3; ++k) lo[k] = std::min(lo[k], c[k]), hi[k] = std::max(hi[k], c[k]);
  ++points;
}

LasBounds::Offset LasBounds::offset() const {
  Offset o;
  for (int k = 0; k < 3; ++k) o.xyz[k] = std::floor(lo[k]);
  return o;
}

namespace {
constexpr double kLasScale = 1e-4;
}  // namespace

std::string las_header(const LasBounds& bounds) {
  // ASPRS LAS 1.2, public header block (227 bytes) + point data format 1 (28 bytes).
  constexpr double kScale = kLasScale;
  const std::uint64_t points = bounds.points;
  const double* lo = bounds.lo;
  const double* hi = bounds.hi;
  const LasBounds::Offset kept = bounds.offset();
  const double* offset = kept.xyz;
  std::string out;
  out += "LASF";
  put(out, std::uint16_t{0});          // file source ID
  put(out, std::uint16_t{0});          // global encoding (GPS week time)
  out.append(16, '\0');                // project ID (GUID)
  out.push_back(1), out.push_back(2);  // version 1.2
  std::string id(32, '\0'), software(32, '\0');
  std::memcpy(id.data(), "tofkit scan (virtual)", 21);
  std::memcpy(software.data(), "tofkit", 6);
  out += id;
  out += software;
  put(out, std::uint16_t{1}), put(out, std::uint16_t{2026});  // creation day, year
  put(out, std::uint16_t{227});                               // header size
  put(out, std::uint32_t{227});                               // offset to point data
  put(out, std::uint32_t{0});                                 // variable length records
  out.push_back(1);                                           // point data format 1
  put(out, std::uint16_t{28});                                // point record length
  put(out, static_cast<std::uint32_t>(points));
  put(out, static_cast<std::uint32_t>(points));  // points by return: all first returns
  for (int k = 0; k < 4; ++k) put(out, std::uint32_t{0});
  for (int k = 0; k < 3; ++k) put(out, kScale);
  for (int k = 0; k < 3; ++k) put(out, offset[k]);
  for (int k = 0; k < 3; ++k) put(out, hi[k]), put(out, lo[k]);  // max x, min x, max y, ...
  return out;
}

void put_las_point(char* out, const CloudPoint& p, const LasBounds::Offset& offset) {
  constexpr double kScale = kLasScale;
  const auto put_at = [&out](auto value) {
    std::memcpy(out, &value, sizeof value);  // little-endian host (x86-64, aarch64)
    out += sizeof value;
  };
  const double c[3] = {p.x, p.y, p.z};
  for (int k = 0; k < 3; ++k)
    put_at(static_cast<std::int32_t>(std::lround((c[k] - offset.xyz[k]) / kScale)));
  const double mv =
      std::isfinite(p.intensity) ? std::clamp(1e3 * p.intensity, 0.0f * 1.0, 65535.0) : 0.0;
  put_at(static_cast<std::uint16_t>(std::lround(mv)));
  put_at(static_cast<std::uint8_t>(1 | (1 << 3)));  // return 1 of 1
  put_at(std::uint8_t{0});                          // classification: never classified
  put_at(std::uint8_t{0});                          // scan angle rank
  put_at(std::uint8_t{0});                          // user data
  put_at(std::uint16_t{0});                         // point source ID
  put_at(p.time_s);                                 // GPS time
}

void append_las_point(std::string& out, const CloudPoint& p, const LasBounds::Offset& offset) {
  char record[kLasPointBytes];
  put_las_point(record, p, offset);
  out.append(record, sizeof record);
}

std::string encode_las(const std::vector<CloudPoint>& points) {
  LasBounds bounds;
  for (const auto& p : points) bounds.add(p);
  std::string out = las_header(bounds);
  const LasBounds::Offset offset = bounds.offset();
  for (const auto& p : points) append_las_point(out, p, offset);
  return out;
}

std::string scan_csv_header(bool has_model) {
  return fmt::format(
      "row,column,time_s,origin_x_m,origin_y_m,origin_z_m,dir_x,dir_y,dir_z,"
      "distance_true_m,reflectance,angle_deg,ambient_c,tof_ns,distance_raw_m,"
      "pulse_width_ns,amplitude,temperature_c,shots_valid,flags{}\n",
      has_model ? ",distance_m,sigma_m,correction_flags" : "");
}

void append_scan_csv_rows(std::string& text, std::span<const scan::BeamResult> beams,
                          double ambient_c, bool has_model) {
  fmt::memory_buffer out;
  auto num = [&](double v) {
    out.push_back(',');
    if (!std::isnan(v)) fmt::format_to(std::back_inserter(out), "{}", v);
  };
  for (const auto& b : beams) {
    fmt::format_to(std::back_inserter(out), "{},{}", b.beam.row, b.beam.column);
    num(b.beam.time_s);
    for (const double v : b.beam.origin_m) num(v);
    for (const double v : b.beam.direction) num(v);
    num(b.true_range_m);
    num(b.reflectance);
    num(device::incidence_angle_deg(b.cos_incidence));
    num(ambient_c);
    const auto& m = b.raw;
    for (const double v :
         {m.tof_ns, m.distance_raw_m, m.pulse_width_ns, m.amplitude, m.temperature_c})
      num(v);
    fmt::format_to(std::back_inserter(out), ",{},{}", m.shots_valid, m.flags);
    if (has_model) {
      num(b.range.distance_m);
      num(b.range.sigma_m);
      fmt::format_to(std::back_inserter(out), ",{}", b.range.correction_flags);
    }
    out.push_back('\n');
  }
  text.append(out.data(), out.size());
}

std::string encode_scan_csv(const scan::ScanResult& result, double ambient_c) {
  std::string out = scan_csv_header(result.has_model);
  append_scan_csv_rows(out, result.beams, ambient_c, result.has_model);
  return out;
}

namespace {

// The range view's layout (encode_range_view): two panels of the image, zoomed
// to about 384 pixels, with a scale bar and its labels under each.
struct ViewLayout {
  int zoom, h, w, gap = 16, bar = 14, label = 5 * 2 + 6;
  ViewLayout(int rows, int columns)
      : zoom(std::max(1, 384 / std::max(rows, columns))), h(rows * zoom), w(columns * zoom) {}
  [[nodiscard]] int canvas_rows() const { return h + 2 * gap + bar + label; }
  [[nodiscard]] int canvas_columns() const { return 2 * w + 3 * gap; }
};

std::array<unsigned char, 3> range_colour(float d, std::pair<double, double> limits) {
  return std::isfinite(d) ? turbo((d - limits.first) / (limits.second - limits.first))
                          : std::array<unsigned char, 3>{0, 0, 0};
}
std::array<unsigned char, 3> intensity_grey(float a, std::pair<double, double> limits) {
  const auto g = static_cast<unsigned char>(
      std::lround(255 * std::clamp((a - limits.first) / (limits.second - limits.first), 0.0, 1.0)));
  return std::isfinite(a) ? std::array<unsigned char, 3>{g, g, g}
                          : std::array<unsigned char, 3>{0, 0, 0};
}

// The scale bars under each panel, labelled at both ends, into `canvas`,
// whose row 0 is the picture's row `first_row`.
void draw_view_scales(Canvas& canvas, int first_row, const ViewLayout& v,
                      std::pair<double, double> range, std::pair<double, double> intensity) {
  const int bar_top = v.gap + v.h + v.gap / 2 - first_row;
  for (int c = 0; c < v.w; ++c) {
    const double t = static_cast<double>(c) / std::max(1, v.w - 1);
    const auto g = static_cast<unsigned char>(std::lround(255 * t));
    for (int r = 0; r < v.bar; ++r) {
      canvas.set(bar_top + r, v.gap + c, turbo(t));
      canvas.set(bar_top + r, 2 * v.gap + v.w + c, {g, g, g});
    }
  }
  const int text_top = bar_top + v.bar + 4;
  const auto lo_text = fmt::format("{:.3f}m", range.first);
  const auto hi_text = fmt::format("{:.3f}m", range.second);
  canvas.text(text_top, v.gap, lo_text, 2);
  canvas.text(text_top, v.gap + v.w - 8 * static_cast<int>(hi_text.size()), hi_text, 2);
  const auto ilo = fmt::format("{:.3f}V", intensity.first);
  const auto ihi = fmt::format("{:.3f}V", intensity.second);
  canvas.text(text_top, 2 * v.gap + v.w, ilo, 2);
  canvas.text(text_top, 2 * v.gap + 2 * v.w - 8 * static_cast<int>(ihi.size()), ihi, 2);
}

}  // namespace

std::string encode_range_view(const scan::ScanImages& images) {
  const auto& range = images.range;
  const auto& intensity = images.intensity;
  const ViewLayout v(range.rows, range.columns);
  Canvas canvas(v.canvas_rows(), v.canvas_columns(), 32);
  const auto r_limits = limits(range, 0.01);
  const auto i_limits = limits(intensity, 0.01);
  for (int r = 0; r < v.h; ++r) {
    for (int c = 0; c < v.w; ++c) {
      const float d = range.at(r / v.zoom, c / v.zoom), a = intensity.at(r / v.zoom, c / v.zoom);
      canvas.set(v.gap + r, v.gap + c, range_colour(d, r_limits));
      canvas.set(v.gap + r, 2 * v.gap + v.w + c, intensity_grey(a, i_limits));
    }
  }
  draw_view_scales(canvas, 0, v, r_limits, i_limits);
  return encode_png_rgb(canvas.rows, canvas.columns, canvas.rgb);
}

std::pair<double, double> streamed_limits(const ValuePass& pass, double q) {
  // Radix selection of the two order statistics `limits` reads off the sorted
  // finite values: a pass counting the values by their keys' high 16 bits
  // finds each one's bucket, a second counting that bucket's values by their
  // low 16 bits finds its key, hence the value itself.
  std::vector<std::uint64_t> high(std::size_t{1} << 16, 0);
  std::uint64_t n = 0;
  pass([&](std::span<const float> values) {
    for (const float x : values) {
      if (!std::isfinite(x)) continue;
      ++high[order_key(x) >> 16];
      ++n;
    }
  });
  if (n == 0) return {0, 1};
  const double fractions[2] = {q, 1 - q};
  std::uint64_t rank[2];
  std::uint32_t bucket[2] = {0, 0};
  for (int j = 0; j < 2; ++j) {
    rank[j] = static_cast<std::uint64_t>(fractions[j] * static_cast<double>(n - 1));
    std::uint64_t below = 0;
    while (below + high[bucket[j]] <= rank[j]) below += high[bucket[j]++];
    rank[j] -= below;  // the rank within its bucket
  }
  std::vector<std::uint64_t> low[2] = {std::vector<std::uint64_t>(std::size_t{1} << 16, 0),
                                       std::vector<std::uint64_t>(std::size_t{1} << 16, 0)};
  pass([&](std::span<const float> values) {
    for (const float x : values) {
      if (!std::isfinite(x)) continue;
      const std::uint32_t key = order_key(x);
      for (int j = 0; j < 2; ++j) {
        if (key >> 16 == bucket[j]) ++low[j][key & 0xFFFFu];
      }
    }
  });
  double value[2];
  for (int j = 0; j < 2; ++j) {
    std::uint32_t k = 0;
    for (std::uint64_t below = 0; below + low[j][k] <= rank[j];) below += low[j][k++];
    value[j] = from_order_key((bucket[j] << 16) | k);
  }
  double lo = value[0], hi = value[1];
  if (!(hi > lo)) hi = lo + 1e-3;
  return {lo, hi};
}

void encode_range_view_rows(int rows, int columns, std::pair<double, double> range_limits,
                            std::pair<double, double> intensity_limits, const ViewRow& row,
                            const std::function<void(std::string_view)>& write) {
  const ViewLayout v(rows, columns);
  // The rows below the panels (scale bars and labels), drawn once.
  const int bottom_first = v.gap + v.h;
  Canvas bottom(v.canvas_rows() - bottom_first, v.canvas_columns(), 32);
  draw_view_scales(bottom, bottom_first, v, range_limits, intensity_limits);
  std::vector<float> range(static_cast<std::size_t>(columns)), intensity(range.size());
  int image_row = -1;
  encode_png_rgb_rows(
      v.canvas_rows(), v.canvas_columns(),
      [&](int r, std::span<unsigned char> rgb) {
        if (r >= bottom_first) {
          const auto* from = &bottom.rgb[static_cast<std::size_t>(r - bottom_first) * rgb.size()];
          std::copy(from, from + rgb.size(), rgb.begin());
          return;
        }
        std::fill(rgb.begin(), rgb.end(), static_cast<unsigned char>(32));
        if (r < v.gap) return;
        const int ir = (r - v.gap) / v.zoom;
        if (ir != image_row) row(image_row = ir, range, intensity);
        for (int c = 0; c < v.w; ++c) {
          const auto d = range_colour(range[static_cast<std::size_t>(c / v.zoom)], range_limits);
          const auto a =
              intensity_grey(intensity[static_cast<std::size_t>(c / v.zoom)], intensity_limits);
          std::memcpy(&rgb[static_cast<std::size_t>(v.gap + c) * 3], d.data(), 3);
          std::memcpy(&rgb[static_cast<std::size_t>(2 * v.gap + v.w + c) * 3], a.data(), 3);
        }
      },
      write);
}

}  // namespace tofkit::io
