#pragma once
/// \file voxel_hash_map.h
/// \brief The voxel part of the dense-registration core, shared by the point-to-plane
/// refinement, the odometry's local map, the loop verification and the map builder:
/// one voxel key, one open-addressing hash map from voxel to index, and one
/// first-point-per-voxel downsampler (as KISS-ICP's). See doc/registration.md.
/// \ingroup registration

#include <Eigen/Core>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

namespace pcl {
namespace rast {

/// \brief Integer voxel coordinates packed in 21 bits per axis: +-2^20 voxels (+-52 km
/// at 5 cm, +-1000 km at 1 m); beyond that the coordinates wrap, which merges voxels a
/// whole range apart. Keys order as the coordinates do (x, then y, then z).
using VoxelKey = std::uint64_t;

/// \brief The key of voxel (x, y, z).
inline VoxelKey
packVoxelKey(std::int64_t x, std::int64_t y, std::int64_t z)
{
  constexpr std::int64_t kOffset = std::int64_t(1) << 20;
  constexpr std::uint64_t kMask = 0x1FFFFF;
  return ((static_cast<std::uint64_t>(x + kOffset) & kMask) << 42) |
         ((static_cast<std::uint64_t>(y + kOffset) & kMask) << 21) |
         (static_cast<std::uint64_t>(z + kOffset) & kMask);
}

/// \brief floor(v * inverse_size) for |v * inverse_size| < 2^20, by truncating a
/// positive biased value: several times cheaper than std::floor without SSE4.1.
inline std::int64_t
voxelCoordinate(double v, double inverse_size)
{
  constexpr double kBias = double(1 << 20);
  return static_cast<std::int64_t>(v * inverse_size + kBias) -
         static_cast<std::int64_t>(kBias);
}

/// \brief The key of the voxel of side 1 / inverse_size holding \a p.
template <typename Derived>
inline VoxelKey
voxelKeyOf(const Eigen::MatrixBase<Derived>& p, double inverse_size)
{
  return packVoxelKey(voxelCoordinate(p[0], inverse_size),
                      voxelCoordinate(p[1], inverse_size),
                      voxelCoordinate(p[2], inverse_size));
}

/// \brief Open-addressing hash map VoxelKey -> int (linear probing, power-of-two
/// capacity, grown at half load). Several times faster than std::unordered_map for the
/// millions of look-ups of a registration, and small enough to stay in cache.
class VoxelHashMap
{
public:
  /// \brief Empty, with room for about \a expected keys before it grows.
  void reset(std::size_t expected)
  {
    std::size_t capacity = 16;
    while (capacity < 2 * expected)
      capacity *= 2;
    keys_.assign(capacity, kEmpty);
    values_.assign(capacity, -1);
    mask_ = capacity - 1;
    size_ = 0;
  }
  /// \brief The value of \a key, inserting \a value when absent: (value, inserted).
  std::pair<int, bool> insert(VoxelKey key, int value)
  {
    if (keys_.empty())
      reset(8);
    for (std::size_t i = slot(key);; i = (i + 1) & mask_) {
      if (keys_[i] == key)
        return {values_[i], false};
      if (keys_[i] == kEmpty) {
        if (2 * (size_ + 1) > keys_.size()) {
          grow();
          return insert(key, value);
        }
        keys_[i] = key;
        values_[i] = value;
        ++size_;
        return {value, true};
      }
    }
  }
  /// \brief The value of \a key, or -1.
  int find(VoxelKey key) const
  {
    if (keys_.empty())
      return -1;
    for (std::size_t i = slot(key);; i = (i + 1) & mask_) {
      if (keys_[i] == key)
        return values_[i];
      if (keys_[i] == kEmpty)
        return -1;
    }
  }
  std::size_t size() const { return size_; }

private:
  /// Marks an empty slot; the key of voxel (2^20-1, 2^20-1, 2^20-1), never used.
  static constexpr VoxelKey kEmpty = ~VoxelKey(0);

  void grow()
  {
    std::vector<VoxelKey> keys = std::move(keys_);
    std::vector<int> values = std::move(values_);
    reset(keys.size()); // twice the capacity
    for (std::size_t i = 0; i < keys.size(); ++i)
      if (keys[i] != kEmpty)
        insert(keys[i], values[i]);
  }
  std::size_t slot(VoxelKey key) const
  {
    // MurmurHash3's finalizer: every bit of x, y and z reaches the low bits the mask
    // keeps (a plain multiplicative hash leaves most of x out of them).
    key ^= key >> 33;
    key *= 0xff51afd7ed558ccdull;
    key ^= key >> 33;
    return static_cast<std::size_t>(key) & mask_;
  }

  std::vector<VoxelKey> keys_;
  std::vector<int> values_;
  std::size_t mask_ = 0;
  std::size_t size_ = 0;
};

/// \brief The downsampler: keeps the first point met in each voxel (a real
/// measurement, not a mean, as in KISS-ICP), so the caller keeps its points' order and
/// their attributes. Consecutive scan points often share a voxel, so a repeat of the
/// last key skips the table.
class VoxelOccupancy
{
public:
  /// \throws std::invalid_argument when voxel_size_m is not finite and positive
  explicit VoxelOccupancy(double voxel_size_m, std::size_t expected_voxels = 8192)
      : inverse_size_(1.0 / voxel_size_m)
  {
    if (!(voxel_size_m > 0.0) || !std::isfinite(voxel_size_m))
      throw std::invalid_argument("VoxelOccupancy: voxel_size_m must be finite and > 0, got " +
                                  std::to_string(voxel_size_m));
    occupied_.reset(expected_voxels);
  }
  /// \brief True when \a p is the first point of its voxel (which is now occupied).
  template <typename Derived> bool insert(const Eigen::MatrixBase<Derived>& p)
  {
    const VoxelKey key = voxelKeyOf(p, inverse_size_);
    if (key == last_key_)
      return false;
    last_key_ = key;
    return occupied_.insert(key, 0).second;
  }
  /// \brief Voxels occupied so far.
  std::size_t size() const { return occupied_.size(); }

private:
  double inverse_size_;
  VoxelHashMap occupied_;
  VoxelKey last_key_ = ~VoxelKey(0);
};

} // namespace rast
} // namespace pcl
