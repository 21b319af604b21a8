#pragma once
/// \file stage_util.h
/// \brief Internal to the slam library: the rotation angle of a pose, shared by
/// tracking, loop detection and the threads, and pcl::StopWatch, which times their
/// stages. Not installed.

#include <Eigen/Geometry>
#include <pcl/common/time.h>
#include <pcl/rast/rigid_pose.h>

namespace pcl {
namespace rast {
namespace slam_detail {

constexpr double kDegPerRad = 180.0 / 3.14159265358979323846;

/// The rotation angle of \a T [deg].
inline double
rotationDeg(const Pose3d& T)
{
  return Eigen::AngleAxisd(T.rotation()).angle() * kDegPerRad;
}

} // namespace slam_detail
} // namespace rast
} // namespace pcl
