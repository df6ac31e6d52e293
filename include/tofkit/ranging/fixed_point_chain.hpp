#pragma once
/// \file The offset + gray-value + temperature chain in integer arithmetic, as
/// an FPGA runs it (paper Section 5: "3.8 mm/C scaled by 4 -> 15" is a
/// coefficient with 2 fraction bits; here every coefficient has
/// `fraction_bits`).
///
/// Inputs are integer codes: the time of flight in TDC LSBs, the echo pulse
/// width in pulse-width LSBs and the temperature in sensor LSBs (e.g. 1/16 C).
/// Coefficients are integers scaled by powers of two; intermediates are int64;
/// the output distance is in integer micrometres:
///
///   acc  = constant_q + tof_code * tof_scale_q                       [um 2^-F]
///   x_q  = code << K                                     [input LSB 2^-K]
///   acc += (slope0_q x_q + sum_k slopes_q[k] max(0, x_q - knots_q[k])) >> K
///          for the pulse width and the temperature hinge
///   distance_um = (acc + 2^(F-1)) >> F                   (round half up)
///
/// with F = fraction_bits and K = knot_fraction_bits. The hinge constants
/// (intercept - slope0 x0) and the offset are folded into constant_q.
/// Range of validity (no int64 overflow): |pulse-width and temperature codes|
/// < 2^16, 0 <= tof_code < 2^24, at most kMaxKnots knots per hinge, every
/// coefficient in int32 (checked when built).

#include <cstdint>
#include <limits>
#include <span>
#include <vector>

#include "tofkit/ranging/pipeline.hpp"

namespace tofkit::ranging {

/// Scales of the integer codes and of the coefficients.
struct FixedPointFormat {
  double tdc_lsb_ps = 60.0;           ///< time-of-flight code LSB (device tdc.lsb_ps)
  double pulse_width_lsb_ps = 60.0;   ///< pulse-width code LSB (same TDC measures both edges)
  double temperature_lsb_c = 0.0625;  ///< temperature sensor LSB (12-bit digital sensor: 1/16 C)
  int fraction_bits = 16;             ///< F: coefficients in um (per input LSB) times 2^F
  int knot_fraction_bits = 12;        ///< K: knot positions in input LSBs times 2^K

  /// Throws std::invalid_argument naming the bad field.
  void validate() const;
};

/// One hinge in integer form (see the file comment). Knots and domain bounds
/// are in input LSB * 2^K; slopes in um per input LSB * 2^F.
struct FixedPointHinge {
  bool enabled = false;
  std::int32_t slope0_q = 0;
  std::vector<std::int32_t> knots_q;
  std::vector<std::int32_t> slopes_q;  ///< slope change at each knot
  std::int32_t domain_min_q = std::numeric_limits<std::int32_t>::min();
  std::int32_t domain_max_q = std::numeric_limits<std::int32_t>::max();
};

/// Every integer the firmware needs.
struct FixedPointCoefficients {
  FixedPointFormat format;
  std::int64_t constant_q = 0;   ///< um * 2^F: offset plus the hinges' constant terms
  std::int32_t tof_scale_q = 0;  ///< um per TDC LSB * 2^F: c_air / 2 * tdc_lsb
  FixedPointHinge grayvalue;     ///< x = pulse-width code
  FixedPointHinge temperature;   ///< x = temperature code
};

/// One measurement as integer codes.
struct FixedPointInput {
  std::int32_t tof_code = 0;          ///< round-trip time in TDC LSBs
  std::int32_t pulse_width_code = 0;  ///< echo pulse width in pulse-width LSBs
  std::int32_t temperature_code = 0;  ///< sensor reading in temperature LSBs (signed)
  std::uint32_t flags = 0;            ///< RawFlag bits (kRawNoEcho honoured)
};

/// Output: distance in micrometres, or kFixedNoDistance with kCorrNoEcho.
struct FixedPointOutput {
  std::int32_t distance_um = 0;
  std::uint32_t correction_flags = 0;  ///< CorrectionFlag bits (kCorrNoEcho, kCorrOutOfDomain)
};

inline constexpr std::int32_t kFixedNoDistance = std::numeric_limits<std::int32_t>::min();

class FixedPointChain {
 public:
  static constexpr std::size_t kMaxKnots = 4;

  /// Validates the coefficients (throws std::invalid_argument naming the field).
  explicit FixedPointChain(FixedPointCoefficients coefficients);

  /// Quantizes a float pipeline made of offset, grayvalue and temperature steps
  /// (each at most once); its time-to-distance conversion gives tof_scale_q.
  /// Throws std::invalid_argument for a surface step or a coefficient that
  /// does not fit int32 with the format's fraction bits (naming it).
  [[nodiscard]] static FixedPointChain from_pipeline(const Pipeline& pipeline,
                                                     const FixedPointFormat& format);

  [[nodiscard]] const FixedPointCoefficients& coefficients() const { return c_; }

  [[nodiscard]] FixedPointOutput apply(const FixedPointInput& in) const;
  /// Batch form (in.size() == out.size()).
  void apply(std::span<const FixedPointInput> in, std::span<FixedPointOutput> out) const;

  /// Codes -> the float RawMeasurement they stand for (tof_ns = code * lsb,
  /// ...), for comparing against the float pipeline.
  [[nodiscard]] RawMeasurement to_raw(const FixedPointInput& in) const;
  /// Float measurement -> nearest codes.
  [[nodiscard]] FixedPointInput to_codes(const RawMeasurement& in) const;

 private:
  FixedPointCoefficients c_;
};

}  // namespace tofkit::ranging
