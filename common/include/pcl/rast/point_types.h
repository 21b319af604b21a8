#pragma once
/// \file point_types.h
/// \brief Point types of spinning LiDAR drivers with a per-point time, registered
/// with PCL so that clouds of them load from and save to PCD, and every pcl_rast
/// module is explicitly instantiated for them (PCL_RAST_XYZ_POINT_TYPES).
/// \ingroup common

#include <cstdint>
#include <pcl/point_types.h>
#include <pcl/register_point_struct.h>

namespace pcl {
namespace rast {

/// \brief A Velodyne-style point (velodyne_pointcloud, rslidar, Hesai): intensity,
/// ring, and the point's time in seconds relative to the frame time.
struct EIGEN_ALIGN16 PointXYZIRT
{
  PCL_ADD_POINT4D;
  float intensity;
  std::uint16_t ring;
  float time; ///< [s], relative to the frame's timestamp
  PCL_MAKE_ALIGNED_OPERATOR_NEW
};

/// \brief An Ouster point (ouster_ros): t is nanoseconds since the start of the sweep.
struct EIGEN_ALIGN16 PointOuster
{
  PCL_ADD_POINT4D;
  float intensity;
  std::uint32_t t; ///< [ns] since the sweep's first column
  std::uint16_t reflectivity;
  std::uint16_t ring;
  std::uint16_t ambient;
  std::uint32_t range; ///< [mm]
  PCL_MAKE_ALIGNED_OPERATOR_NEW
};

} // namespace rast
} // namespace pcl

POINT_CLOUD_REGISTER_POINT_STRUCT(pcl::rast::PointXYZIRT,
                                  (float, x, x)(float, y, y)(float, z, z)(float,
                                                                          intensity,
                                                                          intensity)(
                                      std::uint16_t, ring, ring)(float, time, time))

POINT_CLOUD_REGISTER_POINT_STRUCT(
    pcl::rast::PointOuster,
    (float, x, x)(float, y, y)(float, z, z)(float, intensity, intensity)(
        std::uint32_t, t, t)(std::uint16_t, reflectivity, reflectivity)(
        std::uint16_t, ring, ring)(std::uint16_t, ambient, ambient)(std::uint32_t,
                                                                    range,
                                                                    range))

/// The point types every templated pcl_rast class is instantiated for (PCL style:
/// PCL_INSTANTIATE(Class, PCL_RAST_XYZ_POINT_TYPES)). Other types with x, y, z work by
/// including the class's .hpp.
#define PCL_RAST_XYZ_POINT_TYPES                                                         \
  (pcl::PointXYZ)(pcl::PointXYZI)(pcl::PointXYZINormal)(pcl::rast::PointXYZIRT)(         \
      pcl::rast::PointOuster)

/// The types of PCL_RAST_XYZ_POINT_TYPES that PCL does not know: PCL's own templates
/// that pcl_rast's classes derive from or use (PCLBase, FilterIndices, search) are
/// instantiated for them in pcl_rast's libraries.
#define PCL_RAST_TIME_POINT_TYPES (pcl::rast::PointXYZIRT)(pcl::rast::PointOuster)
