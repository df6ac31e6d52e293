#pragma once
/// \file A scan's files: range / intensity / sigma images as 16-bit PNG with
/// a JSON sidecar and as float32 NumPy .npy; point clouds as binary PLY,
/// binary PCD and LAS 1.2 (point format 1, written here by hand: no Debian
/// package writes LAS); the per-beam table scan.csv; and range_view.png, a
/// picture for people. Beams without an echo are left out of point clouds and
/// are invalid pixels (NaN in .npy, 0 in PNG): no fake ranges (REP-117).
/// Points are in the world frame (REP-103), metres.

#include <cstdint>
#include <functional>
#include <span>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "tofkit/scan/scanner.hpp"

namespace tofkit::io {

/// 16-bit grayscale PNG of `image`: pixel p > 0 stands for offset + scale * p,
/// 0 is invalid. Scale and offset span the image's finite values.
struct Png16 {
  std::string png;
  double scale = 1, offset = 0;
};
[[nodiscard]] Png16 encode_png16(const scan::Image& image);

/// The span of an image's finite values, grown row by row.
struct FiniteRange {
  bool any = false;
  double lo = 0, hi = 0;
  void add(std::span<const float> values);
};
/// encode_png16's scale and offset for an image whose finite values span `finite`.
struct Png16Scale {
  double scale = 1, offset = 0;
};
[[nodiscard]] Png16Scale png16_scale(const FiniteRange& finite);
/// The PNG encode_png16 makes, made row by row: `row(r, values)` fills row r's
/// values, `write` receives the file's bytes in order (memory: a row).
void encode_png16_rows(int rows, int columns, const Png16Scale& scale,
                       const std::function<void(int, std::span<float>)>& row,
                       const std::function<void(std::string_view)>& write);
/// 8-bit RGB PNG (rows x columns x 3).
[[nodiscard]] std::string encode_png_rgb(int rows, int columns,
                                         const std::vector<unsigned char>& rgb);
/// The PNG encode_png_rgb makes, made row by row: `row(r, rgb)` fills row r's
/// pixels (columns x 3), `write` receives the file's bytes in order.
void encode_png_rgb_rows(int rows, int columns,
                         const std::function<void(int, std::span<unsigned char>)>& row,
                         const std::function<void(std::string_view)>& write);

[[nodiscard]] std::string encode_npy(const scan::Image& image);

/// One point of a cloud (a beam with an echo).
struct CloudPoint {
  double x, y, z;  ///< world frame, m
  float intensity, range, sigma;
  int row, column;
  double time_s;
  std::uint32_t flags;  ///< RawMeasurement flags
};
[[nodiscard]] std::vector<CloudPoint> cloud_points(const scan::ScanResult& result);
/// Beam `b` as a point into `point`; false (point untouched) without an echo.
bool cloud_point(const scan::BeamResult& b, CloudPoint& point);

[[nodiscard]] std::string encode_ply(const std::vector<CloudPoint>& points);
[[nodiscard]] std::string encode_pcd(const std::vector<CloudPoint>& points);
/// LAS 1.2, point format 1: X, Y, Z at 0.1 mm scale with offsets at the cloud's
/// minimum; intensity = amplitude in mV (clipped to 65535); GPS time = time_s.
[[nodiscard]] std::string encode_las(const std::vector<CloudPoint>& points);

// The same files in pieces, for a streaming scan: a header (once the count or
// bounds are known) and records appended in beam order; the encode_* forms
// above are header + records, so both give the same bytes.
[[nodiscard]] std::string npy_header(int rows, int columns);
[[nodiscard]] std::string ply_header(std::uint64_t points);
void append_ply_point(std::string& out, const CloudPoint& p);
[[nodiscard]] std::string pcd_header(std::uint64_t points);
void append_pcd_point(std::string& out, const CloudPoint& p);
/// A LAS file's point count and bounds, grown point by point.
struct LasBounds {
  std::uint64_t points = 0;
  double lo[3] = {0, 0, 0}, hi[3] = {0, 0, 0};
  void add(const CloudPoint& p);
  /// The coordinates' offsets: the floor of the minimum, per axis.
  struct Offset {
    double xyz[3];
  };
  [[nodiscard]] Offset offset() const;
};
[[nodiscard]] std::string las_header(const LasBounds& bounds);
void append_las_point(std::string& out, const CloudPoint& p, const LasBounds::Offset& offset);
/// A LAS point record's size (point data format 1).
inline constexpr std::size_t kLasPointBytes = 28;
/// `p`'s LAS record into out[0 .. kLasPointBytes) (append_las_point's bytes).
void put_las_point(char* out, const CloudPoint& p, const LasBounds::Offset& offset);
[[nodiscard]] std::string scan_csv_header(bool has_model);
void append_scan_csv_rows(std::string& out, std::span<const scan::BeamResult> beams,
                          double ambient_c, bool has_model);

[[nodiscard]] std::string encode_scan_csv(const scan::ScanResult& result, double ambient_c);

/// Colour-mapped range with a scale bar (labelled in metres) beside the
/// intensity image.
[[nodiscard]] std::string encode_range_view(const scan::ScanImages& images);

// The same picture for an image too large to hold (a streaming scan's, read
// back from its files): memory independent of the image's size.
/// A pass over all of an image's values, handed to `visit` in pieces.
using ValuePass = std::function<void(const std::function<void(std::span<const float>)>& visit)>;
/// The colour limits encode_range_view takes from an image (its finite
/// values' 1 % and 99 % order statistics, exactly), from two passes.
[[nodiscard]] std::pair<double, double> streamed_limits(const ValuePass& pass, double q = 0.01);
/// `row(r, range, intensity)` fills image row r of both images (rows asked in order).
using ViewRow = std::function<void(int, std::span<float>, std::span<float>)>;
/// encode_range_view's bytes, made row by row from the images' rows and their
/// streamed_limits; `write` receives the file's bytes in order.
void encode_range_view_rows(int rows, int columns, std::pair<double, double> range_limits,
                            std::pair<double, double> intensity_limits, const ViewRow& row,
                            const std::function<void(std::string_view)>& write);

}  // namespace tofkit::io
