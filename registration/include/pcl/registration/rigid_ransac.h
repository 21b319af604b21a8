#pragma once
/// \file rigid_ransac.h
/// \brief Outlier rejection with a rigid model: RANSAC over minimal 3-point samples,
/// then a least-squares re-estimate (eq. 4) on all inliers.
/// \ingroup registration

#include <pcl/features/raster_feature_types.h>

#include <pcl/correspondence.h>
#include <pcl/point_cloud.h>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <cstdint>
#include <memory>
#include <string>

namespace pcl {
namespace rast {

/// \brief Parameters of rigid RANSAC.
struct RigidRansacParams
{
  /// A pair is an inlier when ||p_target - T p_source|| is below this (metres).
  double inlier_threshold_m = 0.5;
  /// Probability that at least one drawn sample is outlier-free; sets the adaptive
  /// number of iterations log(1 - confidence) / log(1 - w^3), w = inlier ratio. (0, 1)
  double confidence = 0.999;
  /// Upper bound on drawn samples, degenerate ones included.
  int max_iterations = 10000;
  /// Fewer inliers than this (>= 3) is a failure.
  int min_inliers = 10;
  /// A sample is degenerate (coincident / near-collinear) when a side or an altitude of
  /// its triangle is shorter than this (metres); such samples are skipped, and an
  /// inlier set whose second principal extent is below this fails as degenerate.
  double min_sample_extent_m = 0.5;
  /// Seed of the sample generator: equal seeds give equal results.
  std::uint32_t seed = 42;

  /// \brief True when all values are in range; otherwise says why in *why (if given).
  bool
  isValid(std::string* why = nullptr) const;
};

/// \brief Outcome of rigid RANSAC.
struct RigidRansacResult
{
  /// True when a well-conditioned model with at least min_inliers inliers was found.
  bool success = false;
  /// Least-squares estimate on all inliers (identity when nothing was found).
  Eigen::Isometry3d T_target_source = Eigen::Isometry3d::Identity();
  /// Indices (into the input pairs) of the inliers of T_target_source, ascending.
  std::vector<int> inlier_indices;
  /// RMS of ||p_target - T p_source|| over the inliers (metres).
  double inlier_rmse_m = 0.0;
  /// Samples drawn, degenerate ones included.
  int iterations = 0;
  /// Samples skipped as coincident / collinear / not distance-preserving.
  int degenerate_samples = 0;
  /// True when failure came from degenerate geometry (collinear points).
  bool degenerate = false;
  /// Why it failed, or a short summary.
  std::string message;
};

/// \brief Rigid RANSAC on paired columns source.col(i) <-> target.col(i).
/// \throws std::invalid_argument on invalid params or size mismatch
RigidRansacResult
estimateRigidRansac(const Eigen::Matrix3Xd& source,
                    const Eigen::Matrix3Xd& target,
                    const RigidRansacParams& params = RigidRansacParams());

/// \brief Rigid RANSAC on feature clouds paired by correspondences
/// (index_query: source, index_match: target); inlier_indices index the correspondences.
/// \throws std::invalid_argument on invalid params or out-of-range indices
RigidRansacResult
estimateRigidRansac(const pcl::PointCloud<RasterFeaturePoint>& source,
                    const pcl::PointCloud<RasterFeaturePoint>& target,
                    const pcl::Correspondences& correspondences,
                    const RigidRansacParams& params = RigidRansacParams());

/// \brief PCL-style correspondence rejector over estimateRigidRansac().
class RigidRansacRejector
{
public:
  using Ptr = std::shared_ptr<RigidRansacRejector>;
  using ConstPtr = std::shared_ptr<const RigidRansacRejector>;
  using CloudConstPtr = pcl::PointCloud<RasterFeaturePoint>::ConstPtr;

  /// \throws std::invalid_argument when params are invalid
  explicit RigidRansacRejector(const RigidRansacParams& params = RigidRansacParams());

  /// \throws std::invalid_argument when params are invalid
  void
  setParams(const RigidRansacParams& params);
  const RigidRansacParams&
  getParams() const
  {
    return params_;
  }
  void
  setInputSource(const CloudConstPtr& source)
  {
    source_ = source;
  }
  void
  setInputTarget(const CloudConstPtr& target)
  {
    target_ = target;
  }

  /// \brief Keep the correspondences consistent with one rigid motion.
  /// \param[in] original all correspondences
  /// \param[out] remaining the inliers (empty on failure)
  /// \return the full result, including T_target_source and success
  /// \throws std::invalid_argument when an input is missing or indices are out of range
  RigidRansacResult
  getRemainingCorrespondences(const pcl::Correspondences& original,
                              pcl::Correspondences& remaining) const;

private:
  RigidRansacParams params_;
  CloudConstPtr source_;
  CloudConstPtr target_;
};

} // namespace rast
} // namespace pcl
