#pragma once
/// \file A correction surface: the error (true minus measured distance) as a
/// smooth function of measured range, intensity (amplitude) and optionally the
/// sensor temperature (the thesis's Section 4.6, extended).

#include <cstddef>
#include <cstdint>
#include <span>
#include <string>

namespace tofkit::ranging {

/// Axis-aligned box of inputs a model was fitted on.
struct SurfaceDomain {
  double range_min_m = 0, range_max_m = 0;
  double amplitude_min = 0, amplitude_max = 0;
  double temperature_min_c = 0, temperature_max_c = 0;  ///< used only with a temperature axis
};

/// Affine map of an input onto [-1, 1] over a fitting domain, for conditioning:
/// scaled = (x - center) / half_width.
struct AxisScaling {
  double center = 0;
  double half_width = 1;
  [[nodiscard]] double apply(double x) const { return (x - center) / half_width; }
  /// The map that takes [lo, hi] onto [-1, 1].
  [[nodiscard]] static AxisScaling over(double lo, double hi) {
    return {0.5 * (lo + hi), 0.5 * (hi - lo)};
  }
};

/// Statistics of the fit a surface came from (kept with the model, written to JSON).
struct SurfaceFitStats {
  std::size_t rows = 0;             ///< training rows
  std::size_t parameters = 0;       ///< coefficients
  std::size_t rank = 0;             ///< effective rank (polynomial: after the rcond cutoff)
  double residual_rms_m = 0;        ///< on the training data
  double condition_number = 0;      ///< of the scaled design (B-spline: of the penalized design)
  double rcond = 0;                 ///< polynomial: relative singular-value cutoff used
  double smoothing = 0;             ///< B-spline: penalty weight relative to the data term
  double effective_parameters = 0;  ///< B-spline: trace of the hat matrix; polynomial: rank
  double cv_rms_m = 0;  ///< B-spline: cross-validated RMS (sqrt of the GCV score); 0: not computed
};

/// Column views of the inputs of a batch (all the same length).
struct SurfaceInputs {
  std::span<const double> range_m;
  std::span<const double> amplitude;
  std::span<const double> temperature_c;  ///< may be empty when the surface has no temperature axis
};

/// What a surface's intensity axis reads: the echo amplitude, or the pulse
/// width (ns), which keeps growing with the echo where the amplitude reading clips.
enum class IntensityInput { amplitude, pulse_width };

class CorrectionSurface {
 public:
  virtual ~CorrectionSurface() = default;
  /// The column the intensity axis (SurfaceInputs::amplitude, the domain's
  /// amplitude_min/max) reads.
  [[nodiscard]] virtual IntensityInput intensity_input() const { return IntensityInput::amplitude; }
  /// "poly" or "bspline".
  [[nodiscard]] virtual std::string kind() const = 0;
  [[nodiscard]] virtual bool uses_temperature() const = 0;
  [[nodiscard]] virtual const SurfaceDomain& domain() const = 0;
  /// correction_m[i] = f(inputs[i]) (to be added to the measured range).
  /// Rows outside the domain get out_of_domain[i] = 1 and the value at the
  /// nearest point of the domain (clamped), never an extrapolation.
  virtual void evaluate(const SurfaceInputs& inputs, std::span<double> correction_m,
                        std::span<std::uint8_t> out_of_domain) const = 0;
};

}  // namespace tofkit::ranging
