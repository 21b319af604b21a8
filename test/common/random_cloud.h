#pragma once
/// \file random_cloud.h
/// \brief A seeded random x y z intensity cloud for the reader and writer tests.

#include <pcl/point_cloud.h>
#include <pcl/point_types.h>
#include <random>

namespace pcl_rast_test {

/// \brief \a n points uniform in a 120 m cube around the origin, intensity in [0, 1].
inline pcl::PointCloud<pcl::PointXYZI>
randomCloud(std::size_t n, unsigned seed)
{
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> coord(-60.0f, 60.0f);
  std::uniform_real_distribution<float> unit(0.0f, 1.0f);
  pcl::PointCloud<pcl::PointXYZI> cloud;
  for (std::size_t i = 0; i < n; ++i) {
    pcl::PointXYZI p;
    p.x = coord(rng);
    p.y = coord(rng);
    p.z = coord(rng);
    p.intensity = unit(rng);
    cloud.push_back(p);
  }
  return cloud;
}

} // namespace pcl_rast_test
