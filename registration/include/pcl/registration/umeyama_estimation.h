#pragma once
/// \file umeyama_estimation.h
/// \brief Closed-form rigid transformation from known correspondences (SVD / Umeyama):
/// the least-squares solution of the paper's eq. 4,
/// argmin_{R,t} sum_i w_i ||p_target_i - R p_source_i - t||^2.
/// \ingroup registration

#include <pcl/features/raster_feature_types.h>

#include <pcl/correspondence.h>
#include <pcl/point_cloud.h>

#include <Eigen/Core>
#include <Eigen/Geometry>

namespace pcl {
namespace rast {

/// \brief A rigid transform estimated from paired points.
struct RigidTransformEstimate
{
  /// Maps source points into the target frame: p_target = T_target_source * p_source.
  Eigen::Isometry3d T_target_source = Eigen::Isometry3d::Identity();
  /// False when the source points are (nearly) coincident or collinear: the rotation
  /// about their line is then undetermined and T_target_source is one arbitrary solution.
  bool well_conditioned = false;
  /// Weighted root-mean-square of ||p_target - T p_source|| after alignment (metres).
  double rmse_m = 0.0;
};

/// \brief Umeyama / Kabsch solution of eq. 4 for paired columns source.col(i) <-> target.col(i).
/// \param[in] source points in the source frame (3 x N, N >= 3)
/// \param[in] target the same points seen in the target frame (3 x N)
/// \param[in] weights optional non-negative weights (size N, positive sum); empty: all 1
/// \return the transform, whether it is well conditioned, and the residual RMS
/// \throws std::invalid_argument on size mismatch, N < 3, or invalid weights
RigidTransformEstimate
estimateRigidTransform(const Eigen::Matrix3Xd& source,
                       const Eigen::Matrix3Xd& target,
                       const Eigen::VectorXd& weights = Eigen::VectorXd());

/// \brief Eq. 4 on feature clouds paired by correspondences
/// (index_query: source point, index_match: target point).
/// \throws std::invalid_argument on out-of-range indices or fewer than 3 correspondences
RigidTransformEstimate
estimateRigidTransform(const pcl::PointCloud<RasterFeaturePoint>& source,
                       const pcl::PointCloud<RasterFeaturePoint>& target,
                       const pcl::Correspondences& correspondences);

/// \brief Standard deviation of the points along their second principal axis (metres):
/// near 0 for coincident or collinear points, which do not determine a rotation.
double
secondaryExtent(const Eigen::Matrix3Xd& points);

} // namespace rast
} // namespace pcl
