/// \file test_fast_math.cpp
/// \brief The slam library's branch-free helpers (slam/src/fast_math.h) against the
/// standard functions they stand for.

#include "../../slam/src/fast_math.h"

#include <cmath>
#include <cstdint>
#include <gtest/gtest.h>
#include <random>

namespace {

using pcl::rast::fast_math::roundSmall;

TEST(FastMath, RoundSmallIsLrintfOnTies)
{
  // Halves round to the even neighbour, as lrintf does in the default mode.
  for (const float v : {0.5f, 1.5f, 2.5f, -0.5f, -1.5f, -2.5f, 32767.5f, -32768.5f,
                        65534.5f, 0.0f, -0.0f, 0.49999997f, -0.49999997f})
    EXPECT_EQ(roundSmall(v), std::lrintf(v)) << v;
  EXPECT_EQ(roundSmall(2.5f), 2);
  EXPECT_EQ(roundSmall(3.5f), 4);
  EXPECT_EQ(roundSmall(-2.5f), -2);
}

TEST(FastMath, RoundSmallIsLrintfOverItsRange)
{
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> centimetres(-32700.0f, 32700.0f);
  std::uniform_real_distribution<float> wide(-4.0e6f, 4.0e6f); // |v| < 2^22
  for (int i = 0; i < 200000; ++i) {
    const float a = centimetres(rng), b = wide(rng);
    ASSERT_EQ(roundSmall(a), std::lrintf(a)) << a;
    ASSERT_EQ(roundSmall(b), std::lrintf(b)) << b;
  }
}

} // namespace
