#pragma once
/// \file A scan's files: range / intensity / sigma images as 16-bit PNG with
/// a JSON sidecar and as float32 NumPy .npy; point clouds as binary PLY,
/// binary PCD and LAS 1.2 (point format 1, written here by hand: no Debian
/// package writes LAS); the per-beam table scan.csv; and range_view.png, a
/// picture for people. Beams without an echo are left out of point clouds and
/// are invalid pixels (NaN in .npy, 0 in PNG): no fake ranges (REP-117).
/// Points are in the world frame (REP-103), metres.

#include <string>
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
/// 8-bit RGB PNG (rows x columns x 3).
[[nodiscard]] std::string encode_png_rgb(int rows, int columns,
                                         const std::vector<unsigned char>& rgb);

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

[[nodiscard]] std::string encode_ply(const std::vector<CloudPoint>& points);
[[nodiscard]] std::string encode_pcd(const std::vector<CloudPoint>& points);
/// LAS 1.2, point format 1: X, Y, Z at 0.1 mm scale with offsets at the cloud's
/// minimum; intensity = amplitude in mV (clipped to 65535); GPS time = time_s.
[[nodiscard]] std::string encode_las(const std::vector<CloudPoint>& points);

[[nodiscard]] std::string encode_scan_csv(const scan::ScanResult& result, double ambient_c);

/// Colour-mapped range with a scale bar (labelled in metres) beside the
/// intensity image.
[[nodiscard]] std::string encode_range_view(const scan::ScanImages& images);

}  // namespace tofkit::io
