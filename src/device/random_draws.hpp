#pragma once
/// \file Internal to device/: the random draws, footprint quadrature and
/// sunlit-background floor the pulsed core (virtual_rangefinder.cpp) and the
/// oscillator loop share.

#include <Random123/philox.h>

#include <array>
#include <cmath>
#include <cstdint>

#include "tofkit/physics/constants.hpp"

namespace tofkit::device::detail {

using physics::kPi;
constexpr int kFootprintNodes = 5;  // Gauss-Chebyshev nodes across a tilted footprint

/// Counter-based random numbers (Random123 Philox4x32-10): the draw for
/// (seed, stream, shot, block) is fixed whatever thread computes it.
class CounterRng {
 public:
  explicit CounterRng(std::uint64_t seed)
      : seed_(seed),
        key_{{static_cast<std::uint32_t>(seed), static_cast<std::uint32_t>(seed >> 32)}} {}
  [[nodiscard]] std::uint64_t seed() const { return seed_; }
  [[nodiscard]] std::array<std::uint32_t, 4> draw(std::uint64_t stream, std::uint32_t shot,
                                                  std::uint32_t block) const {
    const r123::Philox4x32::ctr_type ctr{{shot, block, static_cast<std::uint32_t>(stream),
                                          static_cast<std::uint32_t>(stream >> 32)}};
    const auto r = r123::Philox4x32{}(ctr, key_);
    return {r[0], r[1], r[2], r[3]};
  }

  /// Word j of the draws (stream0 + i, shot, block) for i < n <= N, in
  /// words[j][i]: the same numbers as draw(). Philox4x32-10's rounds run over
  /// the streams (32 x 32 -> 64-bit products lane by lane), so they vectorize.
  template <std::size_t N>
  void draw_streams(std::uint64_t stream0, std::uint32_t shot, std::uint32_t block, std::size_t n,
                    std::array<std::array<std::uint32_t, N>, 4>& words) const {
    auto& [x0, x1, x2, x3] = words;
    for (std::size_t i = 0; i < n; ++i) {
      const std::uint64_t stream = stream0 + i;
      x0[i] = shot;
      x1[i] = block;
      x2[i] = static_cast<std::uint32_t>(stream);
      x3[i] = static_cast<std::uint32_t>(stream >> 32);
    }
    std::uint32_t k0 = key_[0], k1 = key_[1];
    for (int round = 0; round < 10; ++round) {
      for (std::size_t i = 0; i < n; ++i) {
        const std::uint64_t p0 = std::uint64_t{0xD2511F53u} * x0[i];
        const std::uint64_t p1 = std::uint64_t{0xCD9E8D57u} * x2[i];
        x0[i] = static_cast<std::uint32_t>(p1 >> 32) ^ x1[i] ^ k0;
        x1[i] = static_cast<std::uint32_t>(p1);
        x2[i] = static_cast<std::uint32_t>(p0 >> 32) ^ x3[i] ^ k1;
        x3[i] = static_cast<std::uint32_t>(p0);
      }
      k0 += 0x9E3779B9u;  // the key schedule (Weyl sequence)
      k1 += 0xBB67AE85u;
    }
  }

 private:
  std::uint64_t seed_;
  r123::Philox4x32::key_type key_;
};

/// Uniform in the open interval (0, 1).
inline double unit_open(std::uint32_t u) {
  return (static_cast<double>(u >> 8) + 0.5) * (1.0 / 16777216.0);
}

/// sin and cos of the phase 2 pi unit_open(b): unit_open keeps 24 bits k, and
/// 2 pi (k + 1/2) / 2^24 = a + c with a from the top 12 bits, c from the low
/// 12 (and the half): two 4096-entry tables and the angle-addition formula,
/// within a few ulp of sincos.
struct PhaseTables {
  struct SinCos {
    double s, c;
  };
  std::array<SinCos, 4096> coarse, fine;
  PhaseTables() {
    for (std::size_t i = 0; i < 4096; ++i) {
      ::sincos(2.0 * kPi * static_cast<double>(i) / 4096.0, &coarse[i].s, &coarse[i].c);
      ::sincos(2.0 * kPi * (static_cast<double>(i) + 0.5) / 16777216.0, &fine[i].s, &fine[i].c);
    }
  }
};

inline const PhaseTables phase_tables;  // (built at load: no guard on every draw)

inline void sincos_of_phase(std::uint32_t b, double& s, double& c) {
  const std::uint32_t k = b >> 8;
  const auto& a = phase_tables.coarse[k >> 12];
  const auto& f = phase_tables.fine[k & 4095u];
  s = a.s * f.c + a.c * f.s;
  c = a.c * f.c - a.s * f.s;
}

/// Two independent standard normals (Box-Muller).
inline std::array<double, 2> normal_pair(std::uint32_t a, std::uint32_t b) {
  const double r = std::sqrt(-2.0 * std::log(unit_open(a)));
  double sin_phase = 0, cos_phase = 0;
  sincos_of_phase(b, sin_phase, cos_phase);
  return {r * cos_phase, r * sin_phase};
}

/// Gauss-Chebyshev nodes across a tilted footprint (uniform disk -> semicircle
/// weights): offsets u_k (in units of the half depth) and normalized weights.
struct FootprintNodes {
  std::array<double, kFootprintNodes> u{}, w{};
  FootprintNodes() {
    double weight_sum = 0;
    for (int k = 0; k < kFootprintNodes; ++k) {
      const double x = kPi * (k + 1) / (kFootprintNodes + 1);
      u[static_cast<std::size_t>(k)] = std::cos(x);
      w[static_cast<std::size_t>(k)] = std::sin(x) * std::sin(x);
      weight_sum += w[static_cast<std::size_t>(k)];
    }
    for (auto& v : w) v /= weight_sum;
  }
};

inline const FootprintNodes& footprint_nodes() {
  static const FootprintNodes nodes;
  return nodes;
}

/// The sunlit background (paper Eq. 9) of a surface at grazing incidence is
/// taken at 89.9 degrees: cos phi held at that angle's.
inline const double kBackgroundCosFloor = std::cos(physics::deg_to_rad(89.9));

}  // namespace tofkit::device::detail
