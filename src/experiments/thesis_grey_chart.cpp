#include "tofkit/experiments/thesis_grey_chart.hpp"

#include <cmath>
#include <stdexcept>
#include <string>

namespace tofkit::experiments {

double grey_reflectance(int grey) {
  if (grey < 0 || grey > 255) {
    throw std::invalid_argument("grey level " + std::to_string(grey) + " is outside 0..255");
  }
  constexpr double kBlack = 0.03, kSpan = 0.90, kGamma = 2.2;
  // The thesis numbers its chart 0 = white ... 255 = black.
  return kBlack + kSpan * std::pow(static_cast<double>(255 - grey) / 255.0, kGamma);
}

}  // namespace tofkit::experiments
