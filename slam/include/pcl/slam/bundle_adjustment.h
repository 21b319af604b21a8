#pragma once
/// \file bundle_adjustment.h
/// \brief Bundle adjustment of key-frame poses and map points on the raster image
/// (the paper's section 8.2, eq. 5-7), with Ceres: plain data in, optimized data out.
/// Used by local mapping (the newest n key-frames) and by the optional global BA.
/// \ingroup slam

#include <pcl/features/range_raster_image.h>
#include <pcl/slam/keyframe.h>
#include <pcl/rast/rigid_pose.h>

#include <Eigen/Core>

#include <cstddef>
#include <map>
#include <set>
#include <string>
#include <vector>

namespace pcl {
namespace rast {

/// \brief One observation: map point \a point seen by key-frame \a keyframe at the 3D
/// feature position \a p_keyframe (the key-frame's LiDAR frame, metres).
struct BundleAdjustmentObservation
{
  KeyFrameId keyframe = 0;
  MapPointId point = 0;
  Eigen::Vector3d p_keyframe = Eigen::Vector3d::Zero();
};

/// \brief A relative-pose constraint T_a_b with the square root of its 6x6 information
/// (translation then rotation, as the pose graph), e.g. a loop closure in global BA.
struct BundleAdjustmentPoseConstraint
{
  KeyFrameId a = 0;
  KeyFrameId b = 0;
  Pose3d T_a_b = Pose3d::Identity();
  Eigen::Matrix<double, 6, 6> sqrt_information = Eigen::Matrix<double, 6, 6>::Identity();
};

/// \brief A bundle-adjustment problem: key-frame poses T_world_keyframe (some held
/// constant), map point positions (world) and observations. Solved in place.
struct BundleAdjustmentProblem
{
  std::map<KeyFrameId, Pose3d> poses;
  std::set<KeyFrameId> fixed; ///< poses held constant (gauge, window border)
  std::map<MapPointId, Eigen::Vector3d> points;
  std::vector<BundleAdjustmentObservation> observations;
  std::vector<BundleAdjustmentPoseConstraint> pose_constraints;
};

/// \brief Settings of bundleAdjust().
struct BundleAdjustmentParams
{
  /// The raster projection C of eq. 5: orthographic (metric bird's-eye view: residual
  /// x, y in pixels = metres / resolution) or the paper's pinhole model (eq. 7).
  RangeRasterParams raster;
  /// Standard deviation of a feature's height (the max-height pixel value) [m]; the
  /// third residual is dz / z_sigma_m, in "pixel" units like the other two.
  double z_sigma_m = 0.2;
  /// Huber threshold on the whitened residual [pixels].
  double huber_delta_px = 2.0;
  int max_iterations = 10;     ///< Levenberg-Marquardt iterations, >= 1
  int num_threads = 1;         ///< Ceres threads (1: deterministic)
  double function_tolerance = 1e-4; ///< relative cost change to stop, > 0

  bool isValid(std::string* why = nullptr) const;
};

/// \brief Outcome of bundleAdjust().
struct BundleAdjustmentSummary
{
  bool success = false; ///< a usable solution was written back
  double initial_cost = 0.0;
  double final_cost = 0.0;
  int iterations = 0;
  int num_poses = 0;       ///< free poses
  int num_fixed_poses = 0; ///< constant poses
  int num_points = 0;
  int num_residuals = 0;
  double solve_time_ms = 0.0;
  std::string message;
};

/// \brief Reprojection error of \a problem's observations at the current estimate:
/// RMS of the whitened residual [pixels].
double reprojectionRmsPx(const BundleAdjustmentProblem& problem,
                         const BundleAdjustmentParams& params);

/// \brief Minimize the robust reprojection error over free poses and all points
/// (Levenberg-Marquardt, Schur complement). Poses in problem.fixed stay constant; when
/// none is fixed, the smallest id is held constant to fix the gauge.
/// \throws std::invalid_argument on invalid params or an observation of an unknown
/// key-frame / point.
BundleAdjustmentSummary bundleAdjust(BundleAdjustmentProblem& problem,
                                     const BundleAdjustmentParams& params);

} // namespace rast
} // namespace pcl
