#pragma once
/// \file xyz_point_types.h
/// \brief The point types of PCL_RAST_XYZ_POINT_TYPES as a GoogleTest type list, for
/// typed tests of the templated classes.

#include <gtest/gtest.h>
#include <pcl/point_types.h>
#include <pcl/rast/point_types.h>

namespace pcl_rast_test {

using XyzPointTypes = ::testing::Types<pcl::PointXYZ,
                                       pcl::PointXYZI,
                                       pcl::PointXYZINormal,
                                       pcl::rast::PointXYZIRT,
                                       pcl::rast::PointOuster>;

} // namespace pcl_rast_test
