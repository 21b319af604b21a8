#pragma once
/// \file fast_math.h
/// \brief Internal to the slam library: branch-free single-precision helpers that let
/// per-point loops vectorize (motion compensation's azimuth times, the odometry's
/// visibility image). Not installed.

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>

namespace pcl {
namespace rast {
namespace fast_math {

/// \a u where \a c holds, else \a v, in integer operations on the bits.
///
/// `c ? u : v` on floats leaves a loop scalar: gcc sinks the computation of \a u into
/// a branch, and under -ftrapping-math (its default) it will not speculate a
/// floating-point operation out of one again ("control flow in loop"). A select
/// whose operands are both used unconditionally, through integer masks, vectorizes.
inline float
pick(bool c, float u, float v)
{
  std::uint32_t bu, bv;
  std::memcpy(&bu, &u, sizeof bu);
  std::memcpy(&bv, &v, sizeof bv);
  const std::uint32_t mask = 0u - static_cast<std::uint32_t>(c);
  const std::uint32_t out = bv ^ ((bv ^ bu) & mask);
  float f;
  std::memcpy(&f, &out, sizeof f);
  return f;
}

/// atan2 in single precision to ~1e-5 rad (1.6e-7 s of a 0.1 s sweep; 0.5 mm at
/// 30 m/s): the degree-9 polynomial of atan on [0, 1] of Abramowitz & Stegun 4.4.47,
/// then the octant. Branch-free (pick), so the compiler vectorizes the loop.
inline float
fastAtan2(float y, float x)
{
  constexpr float kPiF = 3.14159265f;
  const float ax = std::abs(x), ay = std::abs(y);
  const float mx = std::max(ax, ay);
  // 0 / tiny is 0: the origin maps to azimuth 0 like std::atan2(0, 0).
  const float a = std::min(ax, ay) / std::max(mx, std::numeric_limits<float>::min());
  const float s = a * a;
  float r =
      a * (0.9998660f +
           s * (-0.3302995f + s * (0.1801410f + s * (-0.0851330f + s * 0.0208351f))));
  r = pick(ay > ax, 0.5f * kPiF - r, r);
  r = pick(x < 0.0f, kPiF - r, r);
  return pick(y < 0.0f, -r, r);
}

/// sqrt(v) for v >= 0 to a relative ~5e-6 (0.5 mm at 100 m), without the branch that
/// std::sqrt keeps for errno (-fmath-errno, gcc's default) and that leaves a loop
/// scalar: the bit-level first guess of 1 / sqrt(v), two Newton steps, times v.
inline float
fastSqrt(float v)
{
  std::uint32_t bits;
  std::memcpy(&bits, &v, sizeof bits);
  bits = 0x5f3759dfu - (bits >> 1);
  float inv;
  std::memcpy(&inv, &bits, sizeof inv);
  inv *= 1.5f - 0.5f * v * inv * inv;
  inv *= 1.5f - 0.5f * v * inv * inv;
  return v * inv;
}

/// std::lrintf(v) for |v| < 2^22, without the library call that gcc keeps for it
/// (-fmath-errno): the nearest integer, ties to even. Adding 1.5 * 2^23 leaves no
/// fraction to a float, so the sum itself is rounded so, as lrintf rounds in the
/// default mode.
inline std::int32_t
roundSmall(float v)
{
  constexpr float kShift = 12582912.0f; // 1.5 * 2^23
  return static_cast<std::int32_t>((v + kShift) - kShift);
}

} // namespace fast_math
} // namespace rast
} // namespace pcl
