#pragma once
/// \file deskew.h
/// \brief Motion compensation (deskewing) of a spinning LiDAR's raw sweep.
/// \ingroup slam
///
/// A raw sweep holds each point in the sensor frame at the moment it fired. With the
/// sensor moving at constant velocity over the sweep (twist xi per second, in the frame
/// of the sweep's reference time), a point fired tau seconds after the reference time
/// is brought into the reference frame by
///
///     p_ref = exp(tau * xi) * p                                             (1)
///
/// where exp is the SE(3) exponential. The twist comes from the motion between two
/// frames: xi = log(T_previous_current) / dt.
///
/// Time conventions (doc/odometry.md, Motion compensation):
/// - a time field of the scan (ScanFrame::point_times_s) is relative to the middle of
///   its sweep, which is then the pose the frame gets;
/// - without one, times follow from the azimuth of a head spinning clockwise seen from
///   above (KITTI / Velodyne), with the forward column (+x) firing at the frame time:
///   tau(a) = -wrap(a - reference) / (2 pi) * period.

#include <Eigen/Core>
#include <Eigen/StdVector>
#include <pcl/point_cloud.h>
#include <pcl/point_types.h>
#include <pcl/rast/rigid_pose.h>
#include <string>
#include <vector>

namespace pcl {
namespace rast {

/// \brief A twist (v, w): translation velocity and rotation vector, per unit of time.
using Twist = Eigen::Matrix<double, 6, 1>;

/// \brief SE(3) logarithm: the twist (v, w) with exp(twist) = T.
Twist logSE3(const Pose3d& T);

/// \brief SE(3) exponential of the twist (v, w).
Pose3d expSE3(const Twist& twist);

/// \brief How a spinning head sweeps, for times derived from the azimuth.
struct SweepParams
{
  /// true: the head turns clockwise seen from above (azimuth decreasing), as a
  /// Velodyne, an Ouster and KITTI's HDL-64 do; false: counter-clockwise.
  bool clockwise = true;
  /// The azimuth (deg, atan2(y, x) in the sensor frame) of the column that fires at the
  /// frame time: 0 (the forward column) for KITTI-style data; 180 for sweeps stamped at
  /// their start behind the sensor.
  double reference_azimuth_deg = 0.0;

  bool isValid(std::string* why = nullptr) const;
};

/// \brief Per point, its firing time relative to the frame time [s] from its azimuth:
/// in [-period/2, period/2] (see the file comment).
/// \throws std::invalid_argument when period_s is not positive and finite.
std::vector<float> azimuthTimes(const pcl::PointCloud<pcl::PointXYZI>& cloud,
                                double period_s,
                                const SweepParams& sweep = SweepParams());

/// \brief The same for the points \a indices of \a cloud only: times[k] belongs to
/// cloud[indices[k]].
/// \throws std::invalid_argument when period_s is not positive and finite,
/// std::out_of_range when an index is outside the cloud.
std::vector<float> azimuthTimes(const pcl::PointCloud<pcl::PointXYZI>& cloud,
                                const pcl::Indices& indices,
                                double period_s,
                                const SweepParams& sweep = SweepParams());

/// \brief Motion-compensate \a cloud: each point moved by eq. (1) with its time from
/// \a times_s (relative to the reference time) and the twist \a xi_per_s.
/// Times are grouped into \a bins equal intervals over their range, each with one
/// transform: a point is then at most half a bin off in time (512 bins over a 0.1 s
/// sweep: 0.1 ms, 1 mm at 10 m/s, plus 2.5 mm for a point 50 m away at 0.5 rad/s).
/// Points with a non-finite time are left as they are (non-finite points stay
/// non-finite); a non-finite twist leaves the whole cloud as it is.
/// \throws std::invalid_argument when the sizes differ or bins < 1.
pcl::PointCloud<pcl::PointXYZI>::Ptr
deskewCloud(const pcl::PointCloud<pcl::PointXYZI>& cloud,
            const std::vector<float>& times_s,
            const Twist& xi_per_s,
            int bins = 512);

/// \brief deskewCloud on \a cloud itself, without a copy (same rules and errors).
void deskewCloudInPlace(pcl::PointCloud<pcl::PointXYZI>& cloud,
                        const std::vector<float>& times_s,
                        const Twist& xi_per_s,
                        int bins = 512);

/// \brief Motion-compensate points and their unit normals (e.g. a source prepared from a
/// raw sweep, pcl::rast::prepareSource() with times): each point moved by eq. (1) with
/// its time from \a times_s, each normal rotated by the same transform; binned like
/// deskewCloud(). Points with a non-finite time are left as they are.
/// \throws std::invalid_argument when the sizes differ (\a normals may be empty) or
/// bins < 1.
void deskewPointsAndNormals(
    std::vector<Eigen::Vector3d, Eigen::aligned_allocator<Eigen::Vector3d>>& points,
    std::vector<Eigen::Vector3d, Eigen::aligned_allocator<Eigen::Vector3d>>& normals,
    const std::vector<float>& times_s,
    const Twist& xi_per_s,
    int bins = 512);

} // namespace rast
} // namespace pcl
