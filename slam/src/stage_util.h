#pragma once
/// \file stage_util.h
/// \brief Internal to the slam library: the rotation angle of a pose, shared by
/// tracking, loop detection and the threads, the ORB-rotation histogram of appearance
/// votes and placement matches, and pcl::StopWatch, which times their stages. Not
/// installed.

#include <Eigen/Geometry>

#include <cmath>
#include <utility>
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

/// The bin (of \a bins over 360 degrees) of the image rotation \a delta_deg between
/// two matched ORB features (the difference of their angles): a true revisit's matches
/// pile up in one bin.
inline int
rotationBin(double delta_deg, int bins)
{
  double d = delta_deg;
  d -= 360.0 * std::floor(d / 360.0);
  return static_cast<int>(d / 360.0 * bins) % bins;
}

/// The best window of three neighbouring bins of a rotation \a histogram (wrapping
/// around): its centre bin (the first of equals) and its count.
template <typename T>
std::pair<int, T>
bestRotationWindow(const T* histogram, int bins)
{
  std::pair<int, T> best{0, T(-1)};
  for (int b = 0; b < bins; ++b) {
    const T count =
        histogram[(b + bins - 1) % bins] + histogram[b] + histogram[(b + 1) % bins];
    if (count > best.second)
      best = {b, count};
  }
  return best;
}

} // namespace slam_detail
} // namespace rast
} // namespace pcl
