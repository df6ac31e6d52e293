#pragma once
/// \file The ranging pipeline: RawMeasurement -> Range. One mechanism: the
/// start distance c_air t / 2 plus an ordered list of steps, each adding a
/// correction C = true - measured (thesis Section 4.6 sign convention), then
/// an optional confidence model for the expected error.
///
///   distance_m = c_air tof / 2 (or distance_raw_m when tof_ns is not finite)
///              + sum over steps of C_step(inputs)
///
/// Step kinds: `offset` (constant: trigger and receive-chain delays, paper
/// Section 4), `grayvalue` (hinge in echo pulse width, Section 5.1),
/// `temperature` (hinge in sensor temperature, Section 5.2), `surface`
/// (a correction surface over the distance before the step, amplitude and
/// temperature; thesis Section 4.6), `walk` (the physical walk of an echo
/// shape through the threshold as a function of echo pulse width,
/// ranging/walk_model.hpp: an alternative to `grayvalue` that extrapolates)
/// and `periodic` (a Fourier series in the
/// time of flight modulo the TDC's coarse clock period: with the laser fired
/// on the clock, the stop's phase in that period selects the interpolator
/// codes, so their residual nonlinearity and a bin-width error leave a range
/// error that repeats every c / 2 f_coarse).

#include <cstddef>
#include <cstdint>
#include <cstring>
#include <limits>
#include <memory>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "tofkit/ranging/confidence_model.hpp"
#include "tofkit/ranging/correction_surface.hpp"
#include "tofkit/ranging/piecewise_linear.hpp"
#include "tofkit/ranging/raw_measurement.hpp"
#include "tofkit/ranging/time_to_distance.hpp"
#include "tofkit/ranging/walk_model.hpp"

namespace tofkit::ranging {

enum class StepKind { kOffset, kGrayvalue, kTemperature, kSurface, kWalk, kPeriodic };

/// "offset", "grayvalue", "temperature", "surface", "walk", "periodic".
[[nodiscard]] std::string_view step_kind_name(StepKind kind);
/// Inverse of step_kind_name; throws std::invalid_argument on an unknown name.
[[nodiscard]] StepKind step_kind_from_name(std::string_view name);

/// Closed interval of an input a step was fitted on.
struct InputDomain {
  double min = -std::numeric_limits<double>::infinity();
  double max = std::numeric_limits<double>::infinity();
  [[nodiscard]] bool contains(double x) const { return x >= min && x <= max; }
};

/// How a step was fitted (kept in the model file; not used for correcting).
struct StepFitInfo {
  std::size_t rows = 0;          ///< rows the step was fitted on
  double residual_rms_m = kNaN;  ///< RMS of true - corrected after the fit
};

/// One correction. Only the fields of its kind are used.
struct Step {
  StepKind kind = StepKind::kOffset;
  double offset_m = 0;  ///< kOffset
  PiecewiseLinear
      function;  ///< kGrayvalue (x = pulse_width_ns) / kTemperature (x = temperature_c), y in m
  InputDomain domain;  ///< kGrayvalue / kTemperature / kWalk: x range fitted on; outside ->
                       ///< kCorrOutOfDomain
  std::shared_ptr<const CorrectionSurface> surface;  ///< kSurface
  /// kWalk: C = -(c_air / 2) (t_rise(pulse_width_ns) - t_rise(reference width)).
  std::shared_ptr<const WalkModel> walk;
  /// kPeriodic: C(t) = sum_h a_h cos(2 pi h t / T) + b_h sin(2 pi h t / T),
  /// T = period_ns; harmonics_m = {a_1, b_1, a_2, b_2, ...} in m. The range
  /// gets C(tof_ns). With both_stops, C is the TDC's error at a stop (its
  /// interpolator's nonlinearity, periodic in the stop's time with the laser
  /// fired on its clock), corrected at both stops of the echo: the time of
  /// flight (the rising edge's stop) by C(tof_ns), the pulse width (the falling
  /// edge's stop less the rising one's) by C(tof_ns + pulse_width_ns) -
  /// C(tof_ns), so that the steps after it read corrected widths. A row
  /// without a finite tof_ns gets no periodic correction, one without a finite
  /// width none of its width.
  /// harmonics_per_c_m (empty, or laid out as harmonics_m, m per C): the
  /// coefficients' change with the temperature reading, so that C uses
  /// harmonics_m + harmonics_per_c_m (temperature_c - reference_temperature_c)
  /// (a row without a finite reading: harmonics_m alone). The interpolator's
  /// bins widen with the timing board's temperature (carry-chain delays), so
  /// the error's shape over the period scales with it.
  double period_ns = 0;
  std::vector<double> harmonics_m;
  std::vector<double> harmonics_per_c_m;
  double reference_temperature_c = 0;
  bool both_stops = false;
  StepFitInfo fit;

  /// Throws std::invalid_argument naming the problem.
  void validate() const;
};

[[nodiscard]] Step make_offset_step(double offset_m);
[[nodiscard]] Step make_grayvalue_step(PiecewiseLinear function, InputDomain pulse_width_domain_ns);
[[nodiscard]] Step make_temperature_step(PiecewiseLinear function,
                                         InputDomain temperature_domain_c);
[[nodiscard]] Step make_surface_step(std::shared_ptr<const CorrectionSurface> surface);
/// The walk of `walk`'s shape; `pulse_width_domain_ns`: widths it was fitted on
/// (outside: still corrected by the shape, flagged kCorrOutOfDomain).
[[nodiscard]] Step make_walk_step(std::shared_ptr<const WalkModel> walk,
                                  InputDomain pulse_width_domain_ns);
[[nodiscard]] Step make_periodic_step(double period_ns, std::vector<double> harmonics_m,
                                      bool both_stops = false);
/// A periodic step's correction at time of flight tof_ns (0 when not finite)
/// and temperature reading temperature_c (step.harmonics_per_c_m's share 0
/// when not finite). Reads period_ns and the harmonics of `step` only.
[[nodiscard]] double periodic_correction(const Step& step, double tof_ns, double temperature_c);

/// One input field read in place: element i is the T at `data` + i * `stride`
/// bytes (a member of an array of structs, a column of a structured NumPy
/// array, or a plain array when stride == sizeof(T)). Need not be aligned.
template <typename T>
struct StridedColumn {
  const std::byte* data = nullptr;
  std::ptrdiff_t stride = sizeof(T);  ///< bytes from one element to the next

  [[nodiscard]] T operator[](std::size_t i) const {
    T value;
    std::memcpy(&value, data + static_cast<std::ptrdiff_t>(i) * stride, sizeof(T));
    return value;
  }
};

/// RawMeasurement's fields as separate columns (nanoflann's pattern: the
/// caller's memory in the caller's layout, read in place). All seven are
/// required; `size` rows each.
struct RawColumns {
  std::size_t size = 0;
  StridedColumn<double> tof_ns, distance_raw_m, pulse_width_ns, amplitude, temperature_c;
  StridedColumn<std::uint32_t> shots_valid, flags;

  /// The fields of an array of RawMeasurements (stride sizeof(RawMeasurement)).
  [[nodiscard]] static RawColumns of(std::span<const RawMeasurement> rows);
  /// The device's fields of measurement records (their `raw`), in place.
  [[nodiscard]] static RawColumns of(std::span<const Record> records);
  /// The RawMeasurement inside each of `size` records `stride` bytes apart
  /// (e.g. ranging::Record's `raw`); `first` is the first row's RawMeasurement.
  [[nodiscard]] static RawColumns of(const RawMeasurement* first, std::size_t size,
                                     std::ptrdiff_t stride);
  /// Throws std::invalid_argument naming the first missing column.
  void validate() const;
};

class Pipeline {
 public:
  Pipeline() = default;
  explicit Pipeline(TimeToDistance time_to_distance);

  [[nodiscard]] const TimeToDistance& time_to_distance() const { return time_to_distance_; }
  [[nodiscard]] const std::vector<Step>& steps() const { return steps_; }
  [[nodiscard]] const std::shared_ptr<const ConfidenceModel>& confidence() const {
    return confidence_;
  }
  /// The fit's residual RMS: sigma_m of every range when there is no confidence model.
  [[nodiscard]] double residual_rms_m() const { return residual_rms_m_; }

  /// Appends a step (validated; throws std::invalid_argument).
  void add_step(Step step);
  void set_confidence(std::shared_ptr<const ConfidenceModel> confidence);
  void set_residual_rms_m(double residual_rms_m);

  /// sigma_m of a row outside a step's domain is the in-domain sigma times
  /// (1 + kOutOfDomainSigmaGrowth d), d its largest distance outside a step's
  /// domain in widths of that domain (log scale for a surface's positive
  /// amplitude axis): a linear continuation's error grows with the lever arm,
  /// so at a quarter of the domain's width outside, sigma has doubled. A
  /// walk step with its shape's bootstrap replicates instead adds the variance of its
  /// own prediction there (WalkModel::relative_rise_variance_ns2, beyond that
  /// at the domain's edge): physics that extrapolates, with a known error.
  static constexpr double kOutOfDomainSigmaGrowth = 4.0;

  /// The batch hot path (in.size() == out.size(), else std::invalid_argument).
  /// No echo: NaN distance and sigma, kCorrNoEcho. An input outside a step's
  /// domain: the correction is still applied (hinges continue linearly,
  /// surfaces clamp), kCorrOutOfDomain is set and sigma_m grows (above). A NaN
  /// input a step needs: NaN distance and kCorrNonFinite.
  void apply(std::span<const RawMeasurement> in, std::span<Range> out) const;
  /// The same over columns read in place (in.size == out.size(), all columns
  /// present, else std::invalid_argument): the one implementation, which the
  /// span form calls.
  void apply(const RawColumns& in, std::span<Range> out) const;
  /// One measurement (convenience; the batch form is the fast one).
  [[nodiscard]] Range apply(const RawMeasurement& in) const;

  /// The uncorrected start distance of a measurement: c_air tof / 2, or
  /// distance_raw_m when tof_ns is not finite.
  [[nodiscard]] double start_distance_m(const RawMeasurement& in) const;

  /// One line per step.
  [[nodiscard]] std::string summary() const;

 private:
  TimeToDistance time_to_distance_;
  double metres_per_ns_ = metres_per_ns(TimeToDistance{});
  std::vector<Step> steps_;
  std::shared_ptr<const ConfidenceModel> confidence_;
  double residual_rms_m_ = kNaN;
};

}  // namespace tofkit::ranging
