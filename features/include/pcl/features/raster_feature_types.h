#pragma once
/// \file raster_feature_types.h
/// \brief Plain data shared by the rasterized-ORB pipeline: the feature point type
/// (3D position in the LiDAR frame plus its raster pixel) and 32-byte ORB descriptors.
/// \ingroup features

#include <pcl/point_cloud.h>
#include <pcl/point_types.h>
#include <pcl/register_point_struct.h>

#include <array>
#include <cstdint>
#include <vector>

namespace pcl {
namespace rast {

/// \brief One ORB keypoint of a raster image, lifted back to 3D.
/// x, y, z: the LiDAR point behind the keypoint's pixel (LiDAR frame, metres).
struct EIGEN_ALIGN16 RasterFeaturePoint
{
  PCL_ADD_POINT4D;
  float u;         ///< pixel column of the keypoint in the raster image
  float v;         ///< pixel row of the keypoint in the raster image
  float response;  ///< FAST/Harris corner response
  float angle_deg; ///< ORB orientation in degrees, [0, 360)
  int octave;      ///< pyramid level the keypoint was found on
  PCL_MAKE_ALIGNED_OPERATOR_NEW
};

/// \brief A 256-bit ORB (rBRIEF) descriptor.
using OrbDescriptor = std::array<std::uint8_t, 32>;

/// \brief Hamming distance between two ORB descriptors (0..256).
inline int
hammingDistance(const OrbDescriptor& a, const OrbDescriptor& b)
{
  int distance = 0;
  for (std::size_t i = 0; i < a.size(); i += 8) {
    std::uint64_t wa, wb;
    __builtin_memcpy(&wa, a.data() + i, 8);
    __builtin_memcpy(&wb, b.data() + i, 8);
#if defined(__POPCNT__)
    distance += __builtin_popcountll(wa ^ wb);
#else
    // Without -mpopcnt, __builtin_popcountll is a libgcc call (~3x slower than this).
    std::uint64_t x = wa ^ wb;
    x = x - ((x >> 1) & 0x5555555555555555ULL);
    x = (x & 0x3333333333333333ULL) + ((x >> 2) & 0x3333333333333333ULL);
    x = (x + (x >> 4)) & 0x0F0F0F0F0F0F0F0FULL;
    distance += static_cast<int>((x * 0x0101010101010101ULL) >> 56);
#endif
  }
  return distance;
}

/// \brief Features of one scan: points[i] has descriptors[i].
struct RasterFeatureSet
{
  pcl::PointCloud<RasterFeaturePoint> points;
  std::vector<OrbDescriptor> descriptors;

  std::size_t
  size() const
  {
    return descriptors.size();
  }
  bool
  empty() const
  {
    return descriptors.empty();
  }
};

} // namespace rast
} // namespace pcl

POINT_CLOUD_REGISTER_POINT_STRUCT(pcl::rast::RasterFeaturePoint,
                                  (float, x, x)(float, y, y)(float, z, z)(float, u, u)(
                                      float, v, v)(float, response, response)(
                                      float, angle_deg, angle_deg)(int, octave, octave))
