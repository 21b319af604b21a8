#pragma once
/// \file stage_util.h
/// \brief Internal to the slam library: the stopwatch of its stages' timings and the
/// rotation angle of a pose, shared by tracking, loop detection and the threads. Not
/// installed.

#include <Eigen/Geometry>
#include <chrono>
#include <pcl/rast/rigid_pose.h>

namespace pcl {
namespace rast {
namespace slam_detail {

using Clock = std::chrono::steady_clock;

/// Milliseconds since \a start.
inline double
msSince(Clock::time_point start)
{
  return std::chrono::duration<double, std::milli>(Clock::now() - start).count();
}

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
