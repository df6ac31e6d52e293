#pragma once
/// \file The thesis's targets and units: inches, and the matte grey chart of
/// six levels (0, 51, ..., 255) mapped to Lambertian reflectance
/// (reference/characterization_thesis.md, Sections 4.4 and 4.6).

#include <array>

namespace tofkit::experiments {

inline constexpr double kMetersPerInch = 0.0254;  ///< the thesis works in inches

[[nodiscard]] constexpr double inches_to_m(double inches) {
  return inches * kMetersPerInch;
}
[[nodiscard]] constexpr double m_to_inches(double meters) {
  return meters / kMetersPerInch;
}

/// The thesis's six grey levels (0, 51, ..., 255), numbered as the thesis does:
/// 0 = white ... 255 = black ("a grayscale color of 255 produces the largest
/// amount of error").
inline constexpr std::array<int, 6> kThesisGreyLevels{0, 51, 102, 153, 204, 255};

/// Lambertian reflectance of the thesis's grey level g in 0..255 (0 = white):
///   rho = 0.03 + 0.90 ((255 - g) / 255)^2.2
/// Assumption: the chart was printed from sRGB-like grey values (gamma 2.2, the
/// thesis's g being the ink's share) on matte paper; black toner still reflects
/// about 3 %, white paper about 93 %. Levels: 0 -> 0.930, 51 -> 0.582,
/// 102 -> 0.323, 153 -> 0.150, 204 -> 0.056, 255 -> 0.030. Throws
/// std::invalid_argument outside 0..255.
[[nodiscard]] double grey_reflectance(int grey);

}  // namespace tofkit::experiments
