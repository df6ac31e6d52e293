#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "tofkit/calib/confidence_model.hpp"
#include "tofkit/calib/surface_fit.hpp"
#include "tofkit/io/firmware_export.hpp"
#include "tofkit/io/model_json.hpp"
#include "tofkit/physics/constants.hpp"
#include "tofkit/ranging/fixed_point_chain.hpp"
#include "tofkit/ranging/piecewise_linear.hpp"
#include "tofkit/ranging/pipeline.hpp"
#include "tofkit/ranging/time_to_distance.hpp"

namespace tofkit::ranging {
namespace {

namespace fs = std::filesystem;

/// A fresh directory per test under the system temp dir.
fs::path scratch_dir(const std::string& name) {
  const fs::path dir = fs::temp_directory_path() /
                       ("tofkit_ranging_test_" + name + "_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir;
}

/// The paper's chain: 50 mm offset, gray value -36 / +70 mm/ns around 6.5 ns,
/// temperature -3.8 mm/C above 16 C.
Pipeline paper_pipeline() {
  Pipeline p;
  p.add_step(make_offset_step(0.050));
  PiecewiseLinear g;
  g.x0 = 6.5;
  g.intercept = 0.0;
  g.slope0 = -0.036;
  g.knots = {6.5};
  g.slopes = {0.106};
  p.add_step(make_grayvalue_step(g, {3.0, 12.0}));
  PiecewiseLinear h;
  h.x0 = 20.0;
  h.slope0 = 0.0;
  h.knots = {16.0};
  h.slopes = {-0.0038};
  h.intercept = 0.0038 * 4.0;  // so h(20) = 0
  p.add_step(make_temperature_step(h, {0.0, 40.0}));
  p.set_residual_rms_m(0.003);
  return p;
}

/// The paper's corrections written out independently of PiecewiseLinear.
double paper_correction_m(double pulse_width_ns, double temperature_c) {
  const double g =
      pulse_width_ns < 6.5 ? -0.036 * (pulse_width_ns - 6.5) : 0.070 * (pulse_width_ns - 6.5);
  const double h = temperature_c < 16.0 ? 0.0038 * 4.0 : -0.0038 * (temperature_c - 20.0);
  return 0.050 + g + h;
}

RawMeasurement measurement(double tof_ns, double pulse_width_ns, double temperature_c,
                           double amplitude = 0.5) {
  RawMeasurement m;
  m.tof_ns = tof_ns;
  m.pulse_width_ns = pulse_width_ns;
  m.temperature_c = temperature_c;
  m.amplitude = amplitude;
  m.shots_valid = 10;
  return m;
}

TEST(TimeToDistance, GroupSpeedOfLightInAir) {
  const TimeToDistance conversion;
  // Group index of air at 905 nm, 20 C, 1013 hPa is about 1.00027 (IAG 1999).
  const double n_g = physics::kSpeedOfLightVacuum_m_per_s / 2 * 1e-9 / metres_per_ns(conversion);
  EXPECT_GT(n_g, 1.00024);
  EXPECT_LT(n_g, 1.00030);
  EXPECT_NEAR(tof_to_distance_m(66.7, conversion), 66.7 * metres_per_ns(conversion), 1e-15);
  // Warmer air is thinner: the pulse is faster.
  TimeToDistance hot = conversion;
  hot.air.temperature_c = 40.0;
  EXPECT_GT(metres_per_ns(hot), metres_per_ns(conversion));
  TimeToDistance bad;
  bad.wavelength_nm = 0;
  EXPECT_THROW(bad.validate(), std::invalid_argument);
}

TEST(PiecewiseLinear, EvaluatesTheHingeFormula) {
  PiecewiseLinear f;
  f.x0 = 1.0;
  f.intercept = 2.0;
  f.slope0 = 0.5;
  f.knots = {2.0, 4.0};
  f.slopes = {1.0, -2.0};
  EXPECT_DOUBLE_EQ(f(0.0), 1.5);
  EXPECT_DOUBLE_EQ(f(3.0), 2.0 + 0.5 * 2 + 1.0);
  EXPECT_DOUBLE_EQ(f(5.0), 2.0 + 0.5 * 4 + 3.0 - 2.0);
  EXPECT_EQ(f.segment_slopes(), (std::vector<double>{0.5, 1.5, -0.5}));
  EXPECT_DOUBLE_EQ(f.slope_at(4.5), -0.5);
  // Continuity at the knots.
  for (double k : f.knots) EXPECT_NEAR(f(k - 1e-9), f(k + 1e-9), 1e-8);
  PiecewiseLinear bad = f;
  bad.knots = {4.0, 2.0};
  EXPECT_THROW(bad.validate(), std::invalid_argument);
  bad.knots = {2.0};
  EXPECT_THROW(bad.validate(), std::invalid_argument);
}

TEST(Pipeline, AppliesTheChainAsWrittenOut) {
  const Pipeline p = paper_pipeline();
  const double k = metres_per_ns(p.time_to_distance());
  std::mt19937_64 rng(1);
  std::uniform_real_distribution<double> tof(5, 60), pw(3, 12), t(0, 40);
  std::vector<RawMeasurement> in;
  for (int i = 0; i < 1000; ++i) in.push_back(measurement(tof(rng), pw(rng), t(rng)));
  std::vector<Range> out(in.size());
  p.apply(in, out);
  for (std::size_t i = 0; i < in.size(); ++i) {
    const double expected =
        in[i].tof_ns * k + paper_correction_m(in[i].pulse_width_ns, in[i].temperature_c);
    EXPECT_NEAR(out[i].distance_m, expected, 1e-12);
    EXPECT_EQ(out[i].correction_flags, 0u);
    EXPECT_EQ(out[i].sigma_m, 0.003);
    const Range single = p.apply(in[i]);
    EXPECT_EQ(single.distance_m, out[i].distance_m);
  }
}

TEST(Pipeline, FlagsNoEchoOutOfDomainAndNaN) {
  const Pipeline p = paper_pipeline();
  const double k = metres_per_ns(p.time_to_distance());
  std::vector<RawMeasurement> in{measurement(20, 5, 20),
                                 measurement(20, 5, 20),
                                 measurement(20, 14, 20),
                                 measurement(20, 5, 45),
                                 measurement(20, std::nan(""), 20),
                                 measurement(std::nan(""), 5, 20)};
  in[1].shots_valid = 0;
  in[1].flags = kRawNoEcho;
  in[5].distance_raw_m = 3.0;  // no time of flight: the reported distance is the start
  std::vector<Range> out(in.size());
  p.apply(in, out);
  EXPECT_EQ(out[0].correction_flags, 0u);
  EXPECT_TRUE(std::isnan(out[1].distance_m));
  EXPECT_TRUE(std::isnan(out[1].sigma_m));
  EXPECT_EQ(out[1].correction_flags, kCorrNoEcho);
  // Outside the domain: flagged, and the hinge continues linearly.
  EXPECT_EQ(out[2].correction_flags, kCorrOutOfDomain);
  EXPECT_NEAR(out[2].distance_m, 20 * k + paper_correction_m(14, 20), 1e-12);
  EXPECT_EQ(out[3].correction_flags, kCorrOutOfDomain);
  EXPECT_NEAR(out[3].distance_m, 20 * k + paper_correction_m(5, 45), 1e-12);
  EXPECT_TRUE(std::isnan(out[4].distance_m));
  EXPECT_EQ(out[4].correction_flags, kCorrNonFinite);
  EXPECT_NEAR(out[5].distance_m, 3.0 + paper_correction_m(5, 20), 1e-12);
  std::vector<Range> short_out(2);
  EXPECT_THROW(p.apply(in, short_out), std::invalid_argument);
}

// Finite steps whose sum overflows (an offset of 1.7e308 twice) give no
// number: NaN and the non-finite flag, not inf (correct had written "inf",
// which evaluate then refused).
TEST(Pipeline, ACorrectionThatOverflowsIsNaNAndFlagged) {
  Pipeline p;
  p.add_step(make_offset_step(1.7e308));
  p.add_step(make_offset_step(1.7e308));
  std::vector<RawMeasurement> in{measurement(20, 5, 20)};
  std::vector<Range> out(1);
  p.apply(in, out);
  EXPECT_TRUE(std::isnan(out[0].distance_m));
  EXPECT_EQ(out[0].correction_flags, kCorrNonFinite);
}

// A number beyond kMaxMagnitude is a corrupt cell, not a measurement: read as
// missing, so a 1e300 ns time of flight does not pass through as a 1.5e299 m
// range, and a corrupt input a step reads flags its row as non-finite.
TEST(Pipeline, CorruptMagnitudesReadAsMissing) {
  const Pipeline p = paper_pipeline();
  const double k = metres_per_ns(p.time_to_distance());
  std::vector<RawMeasurement> in{measurement(1e300, 5, 20), measurement(1e300, 5, 20),
                                 measurement(20, -1e200, 20), measurement(20, 5, 1e101),
                                 measurement(kMaxMagnitude, 5, 20)};
  in[0].distance_raw_m = 1.5e299;
  in[1].distance_raw_m = 3.0;  // the time of flight corrupt, the distance not: the start
  std::vector<Range> out(in.size());
  p.apply(in, out);
  for (std::size_t i : {0, 2, 3}) {
    EXPECT_TRUE(std::isnan(out[i].distance_m)) << i;
    EXPECT_EQ(out[i].correction_flags, kCorrNonFinite) << i;
    EXPECT_TRUE(std::isnan(p.apply(in[i]).distance_m)) << i;
  }
  EXPECT_NEAR(out[1].distance_m, 3.0 + paper_correction_m(5, 20), 1e-12);
  EXPECT_EQ(out[1].correction_flags, 0u);
  EXPECT_TRUE(std::isnan(p.start_distance_m(in[0])));
  EXPECT_EQ(p.start_distance_m(in[1]), 3.0);
  // The limit itself is a measurement.
  EXPECT_TRUE(std::isfinite(out[4].distance_m));
  EXPECT_EQ(p.start_distance_m(in[4]), kMaxMagnitude * k);
}

/// Bitwise equality of two ranges (NaN equal to NaN).
bool same_range(const Range& a, const Range& b) {
  return std::memcmp(&a.distance_m, &b.distance_m, sizeof(double)) == 0 &&
         std::memcmp(&a.sigma_m, &b.sigma_m, sizeof(double)) == 0 &&
         a.correction_flags == b.correction_flags;
}

TEST(Pipeline, ReadsStridedColumnsInPlace) {
  const Pipeline p = paper_pipeline();
  // Rows across several blocks, with no echo, NaN and out-of-domain rows.
  std::mt19937_64 rng(2);
  std::uniform_real_distribution<double> tof(5, 60), pw(2, 13), t(-5, 45);
  std::vector<RawMeasurement> in;
  for (int i = 0; i < 1000; ++i) in.push_back(measurement(tof(rng), pw(rng), t(rng)));
  in[3].shots_valid = 0;
  in[300].flags = kRawNoEcho;
  in[511].pulse_width_ns = std::nan("");
  in[700].tof_ns = std::nan("");
  in[700].distance_raw_m = 4.0;
  std::vector<Range> expected(in.size());
  p.apply(in, expected);

  // RawMeasurements inside larger records (a structured array's rows).
  std::vector<Record> records(in.size());
  for (std::size_t i = 0; i < in.size(); ++i) records[i].raw = in[i];
  std::vector<Range> out(in.size());
  p.apply(RawColumns::of(records), out);
  for (std::size_t i = 0; i < in.size(); ++i) EXPECT_TRUE(same_range(out[i], expected[i])) << i;

  // One array per field, stored last row first (a negative stride, as NumPy's a[::-1]).
  const std::size_t n = in.size();
  std::vector<double> tof_v(n), raw_v(n), pw_v(n), amp_v(n), temp_v(n);
  std::vector<std::uint32_t> shots_v(n), flags_v(n);
  for (std::size_t i = 0; i < n; ++i) {
    const std::size_t j = n - 1 - i;
    tof_v[j] = in[i].tof_ns, raw_v[j] = in[i].distance_raw_m, pw_v[j] = in[i].pulse_width_ns;
    amp_v[j] = in[i].amplitude, temp_v[j] = in[i].temperature_c;
    shots_v[j] = in[i].shots_valid, flags_v[j] = in[i].flags;
  }
  const auto reversed = []<typename T>(const std::vector<T>& v) {
    return StridedColumn<T>{reinterpret_cast<const std::byte*>(&v.back()),
                            -static_cast<std::ptrdiff_t>(sizeof(T))};
  };
  RawColumns columns{n,
                     reversed(tof_v),
                     reversed(raw_v),
                     reversed(pw_v),
                     reversed(amp_v),
                     reversed(temp_v),
                     reversed(shots_v),
                     reversed(flags_v)};
  std::fill(out.begin(), out.end(), Range{});
  p.apply(columns, out);
  for (std::size_t i = 0; i < n; ++i) EXPECT_TRUE(same_range(out[i], expected[i])) << i;

  columns.flags = {};
  EXPECT_THROW(p.apply(columns, out), std::invalid_argument);
  std::vector<Range> short_out(2);
  EXPECT_THROW(p.apply(RawColumns::of(in), short_out), std::invalid_argument);
  // Nothing in, nothing out (an empty vector's null data pointer is not offset).
  EXPECT_NO_THROW(p.apply(std::span<const RawMeasurement>(), std::span<Range>()));
  EXPECT_NO_THROW(p.apply(RawColumns::of(std::span<const Record>()), std::span<Range>()));
}

/// range + amplitude surface for testing the surface step: C = 1e-3 r + 1e-2 a, clamped.
class LinearSurface final : public calib::CorrectionSurface {
 public:
  LinearSurface() { domain_ = {1.0, 5.0, 0.1, 1.0, 0, 0}; }
  std::string kind() const override { return "poly"; }
  bool uses_temperature() const override { return false; }
  const calib::SurfaceDomain& domain() const override { return domain_; }
  void evaluate(const calib::SurfaceInputs& in, std::span<double> c,
                std::span<std::uint8_t> ood) const override {
    for (std::size_t i = 0; i < c.size(); ++i) {
      const double r = std::clamp(in.range_m[i], domain_.range_min_m, domain_.range_max_m);
      const double a = std::clamp(in.amplitude[i], domain_.amplitude_min, domain_.amplitude_max);
      c[i] = 1e-3 * r + 1e-2 * a;
      ood[i] = (r != in.range_m[i] || a != in.amplitude[i]) ? 1 : 0;
    }
  }

 private:
  calib::SurfaceDomain domain_;
};

class ConstantConfidence final : public calib::ConfidenceModel {
 public:
  std::string kind() const override { return "thesis"; }
  void sigma(std::span<const double> range, std::span<const double> amplitude,
             std::span<double> sigma) const override {
    for (std::size_t i = 0; i < sigma.size(); ++i) sigma[i] = 0.001 * range[i] + amplitude[i] * 0;
  }
};

TEST(Pipeline, SigmaGrowsWithTheDistanceOutsideTheDomain) {
  Pipeline p;
  PiecewiseLinear g;
  g.x0 = 6.0;
  g.slope0 = 0.01;
  p.add_step(make_grayvalue_step(g, {3.0, 11.0}));  // domain width 8 ns
  p.set_residual_rms_m(0.002);
  const auto sigma_at = [&](double pulse_width_ns) {
    RawMeasurement m;
    m.tof_ns = 20.0;
    m.pulse_width_ns = pulse_width_ns;
    m.shots_valid = 10;
    return p.apply(m);
  };
  EXPECT_DOUBLE_EQ(sigma_at(11.0).sigma_m, 0.002);
  EXPECT_EQ(sigma_at(11.0).correction_flags, 0u);
  const double growth = Pipeline::kOutOfDomainSigmaGrowth;
  // 2 ns beyond the top = a quarter of the domain's width; 4 ns below the bottom = a half.
  EXPECT_NEAR(sigma_at(13.0).sigma_m, 0.002 * (1 + growth * 0.25), 1e-15);
  EXPECT_NEAR(sigma_at(-1.0).sigma_m, 0.002 * (1 + growth * 0.5), 1e-15);
  EXPECT_EQ(sigma_at(13.0).correction_flags, kCorrOutOfDomain);
  // Just outside: flagged, sigma still (almost) the in-domain one.
  const Range edge = sigma_at(std::nextafter(11.0, 12.0));
  EXPECT_EQ(edge.correction_flags, kCorrOutOfDomain);
  EXPECT_NEAR(edge.sigma_m, 0.002, 1e-12);
}

TEST(Pipeline, SurfaceStepSeesTheDistanceBeforeIt) {
  Pipeline p;
  p.add_step(make_offset_step(0.5));
  p.add_step(make_surface_step(std::make_shared<LinearSurface>()));
  p.set_confidence(std::make_shared<ConstantConfidence>());
  const double k = metres_per_ns(p.time_to_distance());
  std::vector<RawMeasurement> in{measurement(2.0 / k, 5, 20, 0.5),
                                 measurement(10.0 / k, 5, 20, 0.5),
                                 measurement(2.0 / k, 5, 20, std::nan(""))};
  std::vector<Range> out(in.size());
  p.apply(in, out);
  EXPECT_NEAR(out[0].distance_m, 2.5 + 1e-3 * 2.5 + 1e-2 * 0.5, 1e-12);
  EXPECT_EQ(out[0].correction_flags, 0u);
  EXPECT_NEAR(out[0].sigma_m, 0.001 * out[0].distance_m, 1e-15);
  EXPECT_NEAR(out[1].distance_m, 10.5 + 1e-3 * 5.0 + 1e-2 * 0.5, 1e-12);  // clamped, flagged
  EXPECT_EQ(out[1].correction_flags, kCorrOutOfDomain);
  EXPECT_TRUE(std::isnan(out[2].distance_m));
  EXPECT_EQ(out[2].correction_flags, kCorrNonFinite);
}

TEST(Pipeline, ValidatesSteps) {
  Pipeline p;
  EXPECT_THROW(p.add_step(make_offset_step(std::nan(""))), std::invalid_argument);
  EXPECT_THROW(p.add_step(make_surface_step(nullptr)), std::invalid_argument);
  EXPECT_THROW(p.add_step(make_grayvalue_step(PiecewiseLinear{}, {2.0, 1.0})),
               std::invalid_argument);
  EXPECT_EQ(step_kind_from_name("temperature"), StepKind::kTemperature);
  EXPECT_THROW((void)step_kind_from_name("tilt"), std::invalid_argument);
}

// ---- fixed point ----

struct CodeSample {
  std::vector<FixedPointInput> codes;
};

std::vector<FixedPointInput> random_codes(const FixedPointFormat& f, std::size_t n, unsigned seed,
                                          double pw_lo = 3.0, double pw_hi = 12.0,
                                          double t_lo = 0.0, double t_hi = 40.0) {
  std::mt19937_64 rng(seed);
  const auto code_range = [](double lo, double hi, double lsb) {
    return std::uniform_int_distribution<int>(static_cast<int>(std::ceil(lo / lsb)),
                                              static_cast<int>(std::floor(hi / lsb)));
  };
  auto tof = code_range(3.0, 70.0, f.tdc_lsb_ps * 1e-3);  // 0.45 - 10.5 m
  auto pw = code_range(pw_lo, pw_hi, f.pulse_width_lsb_ps * 1e-3);
  auto t = code_range(t_lo, t_hi, f.temperature_lsb_c);
  std::vector<FixedPointInput> out(n);
  for (auto& c : out) {
    c.tof_code = tof(rng);
    c.pulse_width_code = pw(rng);
    c.temperature_code = t(rng);
  }
  return out;
}

double max_fixed_float_difference_m(const Pipeline& p, const FixedPointChain& chain,
                                    const std::vector<FixedPointInput>& codes) {
  std::vector<FixedPointOutput> fixed(codes.size());
  chain.apply(codes, fixed);
  std::vector<RawMeasurement> raw;
  for (const auto& c : codes) raw.push_back(chain.to_raw(c));
  std::vector<Range> floating(raw.size());
  p.apply(raw, floating);
  double worst = 0;
  for (std::size_t i = 0; i < codes.size(); ++i) {
    worst = std::max(worst, std::fabs(fixed[i].distance_um * 1e-6 - floating[i].distance_m));
  }
  return worst;
}

TEST(FixedPointChain, AgreesWithTheFloatChainOverTheDomain) {
  const Pipeline p = paper_pipeline();
  const FixedPointFormat format;  // 60 ps TDC and pulse width, 1/16 C, F = 16, K = 12
  const FixedPointChain chain = FixedPointChain::from_pipeline(p, format);
  const double worst = max_fixed_float_difference_m(p, chain, random_codes(format, 20000, 2));
  EXPECT_LT(worst, 0.5e-3);   // the requirement
  EXPECT_LT(worst, 0.01e-3);  // what integer micrometres with 16 fraction bits achieve
  // A coarser TDC LSB and fewer fraction bits still meet the requirement.
  FixedPointFormat coarse;
  coarse.tdc_lsb_ps = 250;
  coarse.pulse_width_lsb_ps = 250;
  coarse.temperature_lsb_c = 0.5;
  coarse.fraction_bits = 8;
  coarse.knot_fraction_bits = 4;
  const FixedPointChain coarse_chain = FixedPointChain::from_pipeline(p, coarse);
  EXPECT_LT(max_fixed_float_difference_m(p, coarse_chain, random_codes(coarse, 20000, 3)), 0.5e-3);
}

TEST(FixedPointChain, FlagsAndNoEcho) {
  const Pipeline p = paper_pipeline();
  const FixedPointFormat format;
  const FixedPointChain chain = FixedPointChain::from_pipeline(p, format);
  // 2 - 14 ns pulse widths and -10 - 50 C cover inside and outside the domain.
  auto codes = random_codes(format, 4000, 4, 2.0, 14.0, -10.0, 50.0);
  codes[0].flags = kRawNoEcho;
  std::vector<FixedPointOutput> fixed(codes.size());
  chain.apply(codes, fixed);
  EXPECT_EQ(fixed[0].distance_um, kFixedNoDistance);
  EXPECT_EQ(fixed[0].correction_flags, kCorrNoEcho);
  std::size_t compared = 0, flagged = 0;
  for (std::size_t i = 1; i < codes.size(); ++i) {
    const RawMeasurement m = chain.to_raw(codes[i]);
    const Range r = p.apply(m);
    const double pw_edge =
        std::min(std::fabs(m.pulse_width_ns - 3.0), std::fabs(m.pulse_width_ns - 12.0));
    const double t_edge = std::min(std::fabs(m.temperature_c), std::fabs(m.temperature_c - 40.0));
    if (pw_edge < 0.03 || t_edge < 0.03) continue;  // within half an LSB of a bound
    ++compared;
    flagged += r.correction_flags != 0 ? 1 : 0;
    EXPECT_EQ(fixed[i].correction_flags, r.correction_flags) << i;
    EXPECT_NEAR(fixed[i].distance_um * 1e-6, r.distance_m, 1e-5);  // linear continuation too
  }
  EXPECT_GT(compared, 3500u);
  EXPECT_GT(flagged, 500u);
  // Codes round-trip through to_codes.
  EXPECT_EQ(chain.to_codes(chain.to_raw(codes[5])).tof_code, codes[5].tof_code);
  // A reading the 32-bit registers cannot hold (NaN, 1e300) is no echo, not a
  // wrapped code.
  for (double tof : {std::nan(""), 1e300, -1e300}) {
    RawMeasurement m = chain.to_raw(codes[5]);
    m.tof_ns = tof;
    const FixedPointInput c = chain.to_codes(m);
    EXPECT_NE(c.flags & kRawNoEcho, 0u) << tof;
    const FixedPointOutput out = chain.apply(c);
    EXPECT_EQ(out.distance_um, kFixedNoDistance) << tof;
    EXPECT_EQ(out.correction_flags, kCorrNoEcho) << tof;
  }
}

TEST(FixedPointChain, RejectsWhatItCannotRepresent) {
  Pipeline p = paper_pipeline();
  FixedPointFormat format;
  format.tdc_lsb_ps = 1000;
  format.fraction_bits = 30;
  try {
    (void)FixedPointChain::from_pipeline(p, format);
    FAIL();
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("tof_scale_q"), std::string::npos) << e.what();
  }
  p.add_step(make_surface_step(std::make_shared<LinearSurface>()));
  EXPECT_THROW((void)FixedPointChain::from_pipeline(p, FixedPointFormat{}), std::invalid_argument);
  FixedPointFormat bad;
  bad.temperature_lsb_c = 0;
  EXPECT_THROW(bad.validate(), std::invalid_argument);
}

// ---- model file and firmware export ----

TEST(ModelJson, RoundTripsTheChainBitExactly) {
  const fs::path dir = scratch_dir("model");
  const Pipeline p = paper_pipeline();
  io::save_pipeline(dir / "model.json", p, {{"command", "test"}});
  const Pipeline q = io::load_pipeline(dir / "model.json");
  ASSERT_EQ(q.steps().size(), 3u);
  EXPECT_EQ(q.residual_rms_m(), 0.003);
  std::vector<RawMeasurement> in{measurement(20, 5, 20), measurement(33.3, 11.9, 39),
                                 measurement(20, 15, -5)};
  std::vector<Range> a(in.size()), b(in.size());
  p.apply(in, a);
  q.apply(in, b);
  for (std::size_t i = 0; i < in.size(); ++i) {
    EXPECT_EQ(a[i].distance_m, b[i].distance_m);
    EXPECT_EQ(a[i].correction_flags, b[i].correction_flags);
  }
  fs::remove_all(dir);
}

TEST(ModelJson, RoundTripsSurfaceAndConfidence) {
  // A real polynomial surface and thesis confidence (calib/, io/surface_json).
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<double> r(1, 5), a(0.1, 1);
  std::normal_distribution<double> noise(0, 0.002);
  std::vector<double> range, amplitude, error, residual;
  for (int i = 0; i < 400; ++i) {
    range.push_back(r(rng));
    amplitude.push_back(a(rng));
    error.push_back(0.01 * range.back() - 0.02 * amplitude.back() + noise(rng));
    residual.push_back(noise(rng) * (1 + amplitude.back()));
  }
  calib::PolynomialFitOptions poly;
  poly.order = 2;
  const auto fit = calib::fit_polynomial_surface({{range, amplitude, {}}, error}, poly);
  Pipeline p;
  p.add_step(make_offset_step(0.01));
  p.add_step(make_surface_step(fit.surface));
  p.set_confidence(calib::fit_thesis_confidence({range, amplitude, residual}));
  p.set_residual_rms_m(fit.residual_rms_m);
  const nlohmann::json j = io::pipeline_to_json(p);
  EXPECT_EQ(j["steps"][1]["kind"], "surface");
  EXPECT_TRUE(j.contains("confidence"));
  const Pipeline q = io::pipeline_from_json(nlohmann::json::parse(j.dump()), "model.json");
  const double k = metres_per_ns(p.time_to_distance());
  std::vector<RawMeasurement> in;
  for (int i = 0; i < 50; ++i)
    in.push_back(measurement((1.0 + 0.1 * i) / k, 5, 20, 0.1 + 0.02 * i));
  std::vector<Range> x(in.size()), y(in.size());
  p.apply(in, x);
  q.apply(in, y);
  for (std::size_t i = 0; i < in.size(); ++i) {
    EXPECT_EQ(x[i].distance_m, y[i].distance_m) << i;
    EXPECT_EQ(x[i].sigma_m, y[i].sigma_m) << i;
    EXPECT_EQ(x[i].correction_flags, y[i].correction_flags) << i;
  }
}

std::string load_error(const std::string& text) {
  try {
    (void)io::pipeline_from_json(nlohmann::json::parse(text), "model.json");
  } catch (const std::runtime_error& e) {
    return e.what();
  }
  return "";
}

TEST(ModelJson, ErrorsNameTheFileAndField) {
  nlohmann::json j = io::pipeline_to_json(paper_pipeline());
  j["steps"][1]["function"]["knots"][0] = "six";
  EXPECT_NE(load_error(j.dump()).find("model.json.steps[1].function.knots[0]: expected a number"),
            std::string::npos)
      << load_error(j.dump());
  j = io::pipeline_to_json(paper_pipeline());
  j["version"] = 7;
  EXPECT_NE(load_error(j.dump()).find("model.json.version: unsupported version 7"),
            std::string::npos);
  j = io::pipeline_to_json(paper_pipeline());
  j["steps"][0]["kind"] = "tilt";
  EXPECT_NE(load_error(j.dump()).find("model.json.steps[0].kind"), std::string::npos);
  j = io::pipeline_to_json(paper_pipeline());
  j["steps"][2]["function"]["slopes"] = nlohmann::json::array();
  EXPECT_NE(load_error(j.dump()).find("model.json.steps[2]"), std::string::npos);
  j = io::pipeline_to_json(paper_pipeline());
  j.erase("time_to_distance");
  EXPECT_NE(load_error(j.dump()).find("missing field 'time_to_distance'"), std::string::npos);
  const fs::path dir = scratch_dir("bad");
  std::ofstream(dir / "broken.json") << "{ not json";
  try {
    (void)io::load_pipeline(dir / "broken.json");
    FAIL();
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("broken.json: not valid JSON"), std::string::npos);
  }
  EXPECT_THROW((void)io::load_pipeline(dir / "missing.json"), std::runtime_error);
  fs::remove_all(dir);
}

// Values a model file may not hold, each of which would turn every corrected
// row into a wrong number or inf with exit 0: a speed of light that disagrees
// with the air it is derived from (it was ignored), an input other than the
// step's (it was ignored), slopes that overflow, a log-variance of 1e300.
TEST(ModelJson, ValuesThatWouldCorruptEveryRowAreRefused) {
  nlohmann::json j = io::pipeline_to_json(paper_pipeline());
  j["time_to_distance"]["metres_per_ns"] = 0;
  EXPECT_NE(load_error(j.dump()).find("model.json.time_to_distance.metres_per_ns: 0 disagrees"),
            std::string::npos)
      << load_error(j.dump());
  j = io::pipeline_to_json(paper_pipeline());
  j["steps"][1]["input"] = "colour";
  EXPECT_NE(load_error(j.dump()).find("model.json.steps[1].input: a grayvalue step's input is"),
            std::string::npos)
      << load_error(j.dump());
  j = io::pipeline_to_json(paper_pipeline());
  j["steps"][2]["function"]["slope0"] = 1e308;
  EXPECT_NE(load_error(j.dump()).find("temperature step: the function is not finite"),
            std::string::npos)
      << load_error(j.dump());
  EXPECT_EQ(load_error(io::pipeline_to_json(paper_pipeline()).dump()), "");

  CalibratedConfidenceParams p;
  p.exponents = {{0, 0}, {1, 0}};
  p.coefficients = {-12.0, 1.0};
  p.amplitude_scaling = AxisScaling::over(std::log(0.01), std::log(4.0));
  p.range_scaling = AxisScaling::over(0.5, 9.0);
  p.domain.range_min_m = 0.5;
  p.domain.range_max_m = 9.0;
  p.domain.amplitude_min = 0.01;
  p.domain.amplitude_max = 4.0;
  p.band_coordinate = {0.0};
  p.band_scale = {1.0};
  EXPECT_NO_THROW(CalibratedConfidence{p});
  p.coefficients[1] = 1e300;
  try {
    CalibratedConfidence{p};
    FAIL() << "a sigma of exp(1e300) was accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("is not finite and positive"), std::string::npos)
        << e.what();
  }
}

TEST(FirmwareExport, JsonReadsBackBitExactly) {
  const FixedPointChain chain =
      FixedPointChain::from_pipeline(paper_pipeline(), FixedPointFormat{});
  const fs::path dir = scratch_dir("firmware");
  io::save_fixed_point_json(dir / "firmware.json", chain);
  const FixedPointChain back = io::load_fixed_point_json(dir / "firmware.json");
  const auto& a = chain.coefficients();
  const auto& b = back.coefficients();
  EXPECT_EQ(a.constant_q, b.constant_q);
  EXPECT_EQ(a.tof_scale_q, b.tof_scale_q);
  EXPECT_EQ(a.grayvalue.knots_q, b.grayvalue.knots_q);
  EXPECT_EQ(a.temperature.slopes_q, b.temperature.slopes_q);
  const auto codes = random_codes(FixedPointFormat{}, 5000, 6, 2.0, 14.0, -10.0, 50.0);
  std::vector<FixedPointOutput> x(codes.size()), y(codes.size());
  chain.apply(codes, x);
  back.apply(codes, y);
  for (std::size_t i = 0; i < codes.size(); ++i) {
    ASSERT_EQ(x[i].distance_um, y[i].distance_um);
    ASSERT_EQ(x[i].correction_flags, y[i].correction_flags);
  }
  nlohmann::json j = io::fixed_point_to_json(chain);
  j["grayvalue"]["knots_q"][0] = 1.5;
  try {
    (void)io::fixed_point_from_json(j, "fw.json");
    FAIL();
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("fw.json.grayvalue.knots_q[0]: expected an integer"),
              std::string::npos)
        << e.what();
  }
  fs::remove_all(dir);
}

TEST(FirmwareExport, CHeaderReproducesTheChain) {
  const FixedPointChain chain =
      FixedPointChain::from_pipeline(paper_pipeline(), FixedPointFormat{});
  const std::string header = io::fixed_point_c_header(chain, "rf");
  const auto& c = chain.coefficients();
  EXPECT_NE(
      header.find("static const int32_t rf_tof_scale_q = " + std::to_string(c.tof_scale_q) + ";"),
      std::string::npos);
  EXPECT_NE(
      header.find("rf_grayvalue_knots_q[] = {" + std::to_string(c.grayvalue.knots_q[0]) + "}"),
      std::string::npos);
  EXPECT_THROW((void)io::fixed_point_c_header(chain, "9bad"), std::invalid_argument);
  // Oracle: compile the header with the system C compiler and compare outputs.
  if (std::system("cc --version > /dev/null 2>&1") != 0) GTEST_SKIP() << "no C compiler";
  const fs::path dir = scratch_dir("header");
  std::ofstream(dir / "chain.h") << header;
  const auto codes = random_codes(FixedPointFormat{}, 200, 7, 2.0, 14.0, -10.0, 50.0);
  {
    std::ofstream main_c(dir / "main.c");
    main_c << "#include <stdio.h>\n#include \"chain.h\"\nint main(void) {\n"
           << "  static const int32_t in[][3] = {";
    for (const auto& x : codes) {
      main_c << "{" << x.tof_code << "," << x.pulse_width_code << "," << x.temperature_code << "},";
    }
    main_c << "};\n  for (unsigned i = 0; i < sizeof in / sizeof in[0]; ++i) {\n"
           << "    uint32_t ood;\n    int32_t d = rf_distance_um(in[i][0], in[i][1], in[i][2], "
              "&ood);\n"
           << "    printf(\"%ld %u\\n\", (long)d, ood);\n  }\n  return 0;\n}\n";
  }
  const std::string cmd = "cc -std=c99 -Wall -Werror -o " + (dir / "chain").string() + " " +
                          (dir / "main.c").string() + " && " + (dir / "chain").string() + " > " +
                          (dir / "out.txt").string();
  ASSERT_EQ(std::system(cmd.c_str()), 0) << cmd;
  std::ifstream out(dir / "out.txt");
  std::vector<FixedPointOutput> expected(codes.size());
  chain.apply(codes, expected);
  for (std::size_t i = 0; i < codes.size(); ++i) {
    long d = 0;
    unsigned ood = 0;
    ASSERT_TRUE(out >> d >> ood);
    EXPECT_EQ(d, expected[i].distance_um) << i;
    EXPECT_EQ(ood != 0, expected[i].correction_flags != 0) << i;
  }
  fs::remove_all(dir);
}

// The periodic step adds a_1 cos(2 pi t / T) + b_1 sin(2 pi t / T) + ... with
// t the raw time of flight (closed form at chosen times: a quarter period
// apart the terms swap), leaves rows without a tof alone, keeps its
// coefficients through the model file, and refuses bad coefficients and the
// fixed-point export.
TEST(PeriodicStep, AddsItsFourierSeriesInTheTimeOfFlight) {
  const double period = 5.0;
  Pipeline p;
  p.add_step(make_periodic_step(period, {0.001, 0.0005, 0.0002, 0.0}));
  RawMeasurement raw;
  raw.shots_valid = 100;
  raw.pulse_width_ns = 5.0;
  raw.amplitude = 1.0;
  raw.temperature_c = 25.0;
  const double mpn = metres_per_ns(TimeToDistance{});
  // t = 20 ns: phase 0 -> a_1 + a_2; t = 21.25 ns: a quarter period -> b_1 - a_2.
  raw.tof_ns = 20.0;
  EXPECT_NEAR(p.apply(raw).distance_m, 20.0 * mpn + 0.0012, 1e-12);
  raw.tof_ns = 21.25;
  EXPECT_NEAR(p.apply(raw).distance_m, 21.25 * mpn + 0.0005 - 0.0002, 1e-12);
  // One period later, the same correction.
  raw.tof_ns = 26.25;
  EXPECT_NEAR(p.apply(raw).distance_m - 26.25 * mpn, 0.0003, 1e-12);
  raw.tof_ns = kNaN;
  raw.distance_raw_m = 3.0;
  EXPECT_NEAR(p.apply(raw).distance_m, 3.0, 1e-12);

  const Pipeline loaded = io::pipeline_from_json(io::pipeline_to_json(p), "model.json");
  ASSERT_EQ(loaded.steps().size(), 1u);
  EXPECT_EQ(loaded.steps()[0].kind, StepKind::kPeriodic);
  EXPECT_EQ(loaded.steps()[0].harmonics_m, p.steps()[0].harmonics_m);
  EXPECT_EQ(loaded.steps()[0].period_ns, period);

  EXPECT_THROW(p.add_step(make_periodic_step(0.0, {0.001, 0.0})), std::invalid_argument);
  EXPECT_THROW(p.add_step(make_periodic_step(period, {0.001})), std::invalid_argument);
  EXPECT_THROW((void)FixedPointChain::from_pipeline(p, FixedPointFormat{}), std::invalid_argument);
}

// At both stops the series is the TDC's error at a stop: the time of flight
// (the rising edge's stop) gets C(tof), the pulse width (the falling edge's
// stop less the rising one's) C(tof + width) - C(tof), and a gray-value step
// after it reads the corrected width (closed form: one harmonic, a linear
// gray value). Old model files (no "stops") keep the rising stop alone.
TEST(PeriodicStep, AtBothStopsCorrectsTheWidthTheLaterStepsRead) {
  const double period = 5.0, a1 = 0.001, slope_m_per_ns = 0.02;
  const double mpn = metres_per_ns(TimeToDistance{});
  Pipeline p;
  p.add_step(make_periodic_step(period, {a1, 0.0}, true));
  PiecewiseLinear g;
  g.x0 = 4.0;
  g.slope0 = slope_m_per_ns;
  p.add_step(make_grayvalue_step(g, {0.0, 20.0}));
  RawMeasurement raw;
  raw.shots_valid = 100;
  raw.amplitude = 1.0;
  raw.temperature_c = 25.0;
  raw.tof_ns = 20.0;          // phase 0: C = a1
  raw.pulse_width_ns = 6.25;  // the fall a quarter period on: C = 0
  const double rise = a1, fall = 0.0;
  const double width = raw.pulse_width_ns + (fall - rise) / mpn;
  EXPECT_NEAR(p.apply(raw).distance_m, 20.0 * mpn + rise + slope_m_per_ns * (width - 4.0), 1e-12);
  // No width: the rising stop alone.
  raw.pulse_width_ns = kNaN;
  Pipeline alone;
  alone.add_step(make_periodic_step(period, {a1, 0.0}, true));
  EXPECT_NEAR(alone.apply(raw).distance_m, 20.0 * mpn + a1, 1e-12);
  // The model file keeps it; an old one (no "stops") reads the rising stop only.
  nlohmann::json j = io::pipeline_to_json(p);
  EXPECT_TRUE(io::pipeline_from_json(j, "model.json").steps()[0].both_stops);
  j["steps"][0].erase("stops");
  EXPECT_FALSE(io::pipeline_from_json(j, "model.json").steps()[0].both_stops);
  j["steps"][0]["stops"] = "fall";
  EXPECT_THROW((void)io::pipeline_from_json(j, "model.json"), std::runtime_error);
}

// With temperature slopes the coefficients are a + a' (T - T_ref) (closed
// form at phase 0: a_1 + a_2 and their slopes times the departure); a row
// without a reading gets a alone; the model file keeps the slopes and their
// reference, an old one (none) reads none; slopes of another length, or not
// finite, are refused.
TEST(PeriodicStep, ItsCoefficientsMoveWithTheTemperatureReading) {
  const double period = 5.0, mpn = metres_per_ns(TimeToDistance{});
  Step step = make_periodic_step(period, {0.001, 0.0005, 0.0002, 0.0});
  step.harmonics_per_c_m = {2e-5, 0.0, -1e-5, 0.0};
  step.reference_temperature_c = 30.0;
  Pipeline p;
  p.add_step(step);
  RawMeasurement raw;
  raw.shots_valid = 100;
  raw.pulse_width_ns = 5.0;
  raw.amplitude = 1.0;
  raw.tof_ns = 20.0;  // phase 0
  raw.temperature_c = 40.0;
  EXPECT_NEAR(p.apply(raw).distance_m, 20.0 * mpn + 0.0012 + 10 * (2e-5 - 1e-5), 1e-12);
  raw.temperature_c = 30.0;
  EXPECT_NEAR(p.apply(raw).distance_m, 20.0 * mpn + 0.0012, 1e-12);
  raw.temperature_c = kNaN;
  EXPECT_NEAR(p.apply(raw).distance_m, 20.0 * mpn + 0.0012, 1e-12);
  nlohmann::json j = io::pipeline_to_json(p);
  const Pipeline loaded = io::pipeline_from_json(j, "model.json");
  EXPECT_EQ(loaded.steps()[0].harmonics_per_c_m, step.harmonics_per_c_m);
  EXPECT_EQ(loaded.steps()[0].reference_temperature_c, 30.0);
  j["steps"][0].erase("harmonics_per_c_m");
  EXPECT_TRUE(io::pipeline_from_json(j, "model.json").steps()[0].harmonics_per_c_m.empty());
  j["steps"][0]["harmonics_per_c_m"] = {1e-5, 0.0};
  EXPECT_THROW((void)io::pipeline_from_json(j, "model.json"), std::runtime_error);
  step.harmonics_per_c_m = {kNaN, 0.0, 0.0, 0.0};
  EXPECT_THROW(p.add_step(step), std::invalid_argument);
}

}  // namespace
}  // namespace tofkit::ranging
