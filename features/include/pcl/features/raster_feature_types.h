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

/// The raster keypoint of a lifted feature: pixel column u and row v in the raster
/// image, the FAST/Harris corner response, the ORB orientation in degrees [0, 360) and
/// the pyramid level it was found on.
#define PCL_RAST_ADD_RASTER_KEYPOINT                                                     \
  float u;                                                                               \
  float v;                                                                               \
  float response;                                                                        \
  float angle_deg;                                                                       \
  int octave

namespace pcl {
namespace rast {

/// \brief One ORB keypoint of a raster image, lifted back to 3D.
/// x, y, z: the LiDAR point behind the keypoint's pixel (LiDAR frame, metres).
struct EIGEN_ALIGN16 RasterFeaturePoint
{
  PCL_ADD_POINT4D;
  PCL_RAST_ADD_RASTER_KEYPOINT;
  PCL_MAKE_ALIGNED_OPERATOR_NEW
};

/// \brief A 256-bit ORB (rBRIEF) descriptor.
using OrbDescriptor = std::array<std::uint8_t, 32>;

/// \brief One ORB feature as a PCL point: the lifted 3D point, its raster keypoint and
/// its 256-bit descriptor, like PCL's BRISKSignature512. A
/// `pcl::PointCloud<ORBSignature256>` saves to PCD and loads back (the descriptor is a
/// 32-count unsigned 8-bit field). The SLAM keeps RasterFeatureSet instead, whose
/// descriptors sit contiguously for brute-force matching; toSignatureCloud and
/// fromSignatureCloud convert.
struct EIGEN_ALIGN16 ORBSignature256
{
  PCL_ADD_POINT4D;
  PCL_RAST_ADD_RASTER_KEYPOINT;
  std::uint8_t descriptor[32]; ///< rBRIEF bits, OpenCV's byte order
  PCL_MAKE_ALIGNED_OPERATOR_NEW
};

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

/// \brief The features of \a set as one cloud of ORBSignature256 (header copied).
/// \throws std::invalid_argument when the set's points and descriptors differ in number.
void
toSignatureCloud(const RasterFeatureSet& set, pcl::PointCloud<ORBSignature256>& cloud);

/// \brief The inverse of toSignatureCloud.
void
fromSignatureCloud(const pcl::PointCloud<ORBSignature256>& cloud, RasterFeatureSet& set);

} // namespace rast
} // namespace pcl

POINT_CLOUD_REGISTER_POINT_STRUCT(pcl::rast::ORBSignature256,
                                  (float, x, x)(float, y, y)(float, z, z)(float, u, u)(
                                      float, v, v)(float, response, response)(
                                      float, angle_deg, angle_deg)(int, octave, octave)(
                                      std::uint8_t[32], descriptor, descriptor))

POINT_CLOUD_REGISTER_POINT_STRUCT(pcl::rast::RasterFeaturePoint,
                                  (float, x, x)(float, y, y)(float, z, z)(float, u, u)(
                                      float, v, v)(float, response, response)(
                                      float, angle_deg, angle_deg)(int, octave, octave))
