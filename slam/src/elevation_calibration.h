#pragma once
/// \file elevation_calibration.h
/// \brief Internal to the slam library: the odometry's self-calibration of the beams'
/// elevation angles (ElevationCalibrationParams). Not installed.

#include "odometry_local_map.h"

#include <Eigen/Geometry>
#include <cstdint>
#include <memory>
#include <pcl/point_cloud.h>
#include <pcl/point_types.h>
#include <pcl/slam/odometry.h>
#include <vector>

namespace pcl {
namespace rast {
namespace odometry_detail {

/// \brief The corrections in effect: bin b covers elevations [min_deg + b * bin_deg,
/// min_deg + (b + 1) * bin_deg) in the sensor frame; a point in it is turned up by
/// delta_rad[b] about the horizontal axis across its azimuth. Immutable once made, so
/// a look-ahead thread may hold one while the odometry makes the next.
struct ElevationTable
{
  static constexpr float kMinDeg = -45.0f, kMaxDeg = 45.0f;
  /// Steps of the look-up from tan(elevation) in [-1, 1) to the bin (0.007 deg at the
  /// horizon, finer than any bin): no arc tangent per point.
  static constexpr int kTanSteps = 16384;

  /// A table of \a bin_deg wide bins that corrects nothing.
  explicit ElevationTable(float bin_deg = 0.05f);

  float bin_deg = 0.05f;
  std::vector<float> delta_rad, cos_delta, sin_delta;
  std::shared_ptr<const std::vector<std::int16_t>> bin_of_tan; ///< kTanSteps entries

  int bins() const { return static_cast<int>(delta_rad.size()); }
  /// The bin of a point of slope \a tan_elevation (z over the horizontal distance);
  /// -1 outside [kMinDeg, kMaxDeg).
  int binOfTan(float tan_elevation) const
  {
    const float f = (tan_elevation + 1.0f) * (0.5f * kTanSteps);
    if (!(f >= 0.0f && f < static_cast<float>(kTanSteps)))
      return -1;
    return (*bin_of_tan)[static_cast<std::size_t>(f)];
  }
  /// The bin of a point in the sensor frame; -1 outside [kMinDeg, kMaxDeg) or on the
  /// spin axis.
  int binOf(float x, float y, float z) const
  {
    const float rho_sq = x * x + y * y;
    return rho_sq > 0.0f ? binOfTan(z / std::sqrt(rho_sq)) : -1;
  }
  /// The centre of bin \a b [deg].
  double centreDeg(int b) const { return kMinDeg + (b + 0.5) * bin_deg; }
  /// Set bin \a b's correction.
  void set(int b, double delta);
};

/// \brief \a scan with every point turned by its bin's correction (the fields other than
/// x, y and z, the order and the non-finite points as they are).
pcl::PointCloud<pcl::PointXYZI>::Ptr
applyElevationTable(const ElevationTable& table,
                    const pcl::PointCloud<pcl::PointXYZI>& scan);

/// \brief The estimator: residuals of tracked frames against the local map, a least
/// squares update of the table per window of frames.
class ElevationCalibration
{
public:
  explicit ElevationCalibration(const ElevationCalibrationParams& params);

  /// \brief The table to correct the next scans with; null while nothing is corrected.
  std::shared_ptr<const ElevationTable> table() const { return table_; }

  /// \brief Add the residuals of a tracked frame: \a source (compensated, sensor frame)
  /// at \a T_world_lidar against \a map, each point binned by its scan point
  /// raw[indices[k]] as the sensor placed it (before any correction).
  void observe(const pcl::PointCloud<pcl::PointXYZI>& raw,
               const std::vector<int>& indices,
               const Points3f& source,
               const Eigen::Isometry3f& T_world_lidar,
               const VoxelPlaneMap& map);

  ElevationCalibrationState state() const;

private:
  void update();

  ElevationCalibrationParams params_;
  ElevationTable layout_;         ///< bin width and count (the corrections in table_)
  std::vector<double> total_rad_; ///< the corrections so far, per bin
  std::vector<double> info_;      ///< sum of den_ over all windows, per bin
  std::vector<double> num_, den_; ///< this window's normal equations, per bin
  std::vector<double> lever_;     ///< this window's sum of |lever|, per bin
  std::vector<double> sq_;        ///< this window's sum of squared residuals, per bin
  std::vector<int> pairs_;        ///< this window's pairs, per bin
  int frames_ = 0;                ///< observed in this window
  int updates_ = 0;
  std::shared_ptr<const ElevationTable> table_;
};

} // namespace odometry_detail
} // namespace rast
} // namespace pcl
