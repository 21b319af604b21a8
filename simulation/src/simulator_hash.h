#pragma once
/// \file simulator_hash.h
/// \brief The simulator's portable hash (private to simulation/src): the world, its noise
/// and every ray's randomness derive from it, so results depend only on the seed. Also the
/// one definition of pi that the simulator's units share.

#include <cstdint>

namespace pcl {
namespace rast {
namespace simulator_detail {

constexpr double kPi = 3.14159265358979323846;

/// SplitMix64 finalizer: a well-mixed 64-bit hash of \a x.
inline std::uint64_t
splitmix64(std::uint64_t x)
{
  x += 0x9E3779B97F4A7C15ULL;
  x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ULL;
  x = (x ^ (x >> 27)) * 0x94D049BB133111EBULL;
  return x ^ (x >> 31);
}

} // namespace simulator_detail
} // namespace rast
} // namespace pcl
