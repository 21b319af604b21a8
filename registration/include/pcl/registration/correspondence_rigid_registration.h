#pragma once
/// \file correspondence_rigid_registration.h
/// \brief The registration box of the pipeline: Hamming correspondences -> rigid RANSAC
/// -> least squares (eq. 4) -> optional point-to-plane refinement on the dense scans.
/// \ingroup registration

#include <pcl/features/raster_feature_types.h>
#include <pcl/registration/hamming_matching.h>
#include <pcl/registration/point_to_plane_refinement.h>
#include <pcl/registration/rigid_ransac.h>

#include <pcl/correspondence.h>
#include <pcl/point_cloud.h>
#include <pcl/point_types.h>

#include <Eigen/Geometry>

#include <memory>
#include <string>

namespace pcl {
namespace rast {

/// \brief Parameters of the whole registration chain.
struct RegistrationParams
{
  HammingMatchParams matching;      ///< descriptor matching
  RigidRansacParams ransac;         ///< outlier rejection and feature-based estimate
  PointToPlaneParams refinement;    ///< dense refinement
  /// Run the point-to-plane refinement when both dense clouds (or a prepared target
  /// and a source cloud) are given.
  bool refine = true;
  /// Fewer Hamming correspondences than this (>= 3) fail before RANSAC.
  int min_correspondences = 12;

  /// \brief True when all values are in range; otherwise says why in *why (if given).
  bool
  isValid(std::string* why = nullptr) const;
};

/// \brief Outcome of CorrespondenceRigidRegistration::align().
struct RegistrationResult
{
  /// p_target = T_target_source * p_source. Meaningful only when success; on failure
  /// it holds the last stage's estimate, or the initial guess.
  Eigen::Isometry3d T_target_source = Eigen::Isometry3d::Identity();
  bool success = false;          ///< every stage that ran succeeded
  int num_correspondences = 0;   ///< Hamming correspondences
  int num_inliers = 0;           ///< RANSAC inliers
  /// RMS residual (metres): point-to-plane over paired dense points when refined,
  /// otherwise point-to-point over the feature inliers.
  double inlier_rmse_m = 0.0;
  bool refined = false;          ///< the dense refinement ran and succeeded
  int refinement_iterations = 0; ///< Gauss-Newton iterations of the refinement
  bool refinement_converged = false; ///< the refinement met its convergence thresholds
  std::string message;           ///< why it failed, or a short summary
};

/// \brief Feature-based rigid registration of a source scan to a target scan, chaining
/// HammingCorrespondenceEstimation, RigidRansacRejector and refinePointToPlane().
///
/// \code
/// pcl::rast::CorrespondenceRigidRegistration reg(params);
/// reg.setInputTarget(target_features, target_cloud);  // prepared once per key-frame
/// reg.setInputSource(source_features, source_cloud);
/// const pcl::rast::RegistrationResult r = reg.align(T_target_source_prior);
/// if (!r.success) std::cerr << r.message << '\n';
/// \endcode
/// Feature points and the dense cloud of a scan must be in the same (LiDAR) frame.
class CorrespondenceRigidRegistration
{
public:
  using Ptr = std::shared_ptr<CorrespondenceRigidRegistration>;
  using ConstPtr = std::shared_ptr<const CorrespondenceRigidRegistration>;
  using FeatureSetConstPtr = std::shared_ptr<const RasterFeatureSet>;
  using CloudConstPtr = pcl::PointCloud<pcl::PointXYZI>::ConstPtr;

  /// \throws std::invalid_argument when params are invalid
  explicit CorrespondenceRigidRegistration(const RegistrationParams& params = RegistrationParams());

  /// \throws std::invalid_argument when params are invalid; drops a prepared target
  /// built from a cloud, since its voxel/normal parameters may have changed
  void
  setParams(const RegistrationParams& params);
  const RegistrationParams&
  getParams() const
  {
    return params_;
  }

  /// \brief Source features and, for refinement, the dense source scan (may be null).
  void
  setInputSource(const FeatureSetConstPtr& features, const CloudConstPtr& cloud = nullptr);
  /// \brief Target features and, for refinement, the dense target scan (may be null);
  /// the point-to-plane target is built on the first align() that needs it.
  void
  setInputTarget(const FeatureSetConstPtr& features, const CloudConstPtr& cloud = nullptr);
  /// \brief Target features and an already prepared dense target (e.g. a local map).
  void
  setInputTarget(const FeatureSetConstPtr& features,
                 const PointToPlaneTarget::ConstPtr& prepared_target);

  /// \brief Register the source to the target.
  /// \param[in] T_target_source_guess motion prior; used by the spatial gate of the
  ///   matching (if enabled) only: the result never falls back to it silently
  /// \throws std::invalid_argument when the source or target features are missing
  RegistrationResult
  align(const Eigen::Isometry3d& T_target_source_guess = Eigen::Isometry3d::Identity());

  /// \brief Hamming correspondences of the last align().
  const pcl::Correspondences&
  getCorrespondences() const
  {
    return correspondences_;
  }
  /// \brief RANSAC inliers of the last align().
  const pcl::Correspondences&
  getInliers() const
  {
    return inliers_;
  }
  /// \brief The prepared dense target (null until built), to reuse elsewhere.
  PointToPlaneTarget::ConstPtr
  getPreparedTarget() const
  {
    return prepared_target_;
  }

private:
  RegistrationParams params_;
  FeatureSetConstPtr source_features_;
  FeatureSetConstPtr target_features_;
  CloudConstPtr source_cloud_;
  CloudConstPtr target_cloud_;
  PointVector source_voxels_;
  bool source_voxels_ready_ = false;
  PointToPlaneTarget::ConstPtr prepared_target_;
  bool target_given_prepared_ = false;
  pcl::Correspondences correspondences_;
  pcl::Correspondences inliers_;
};

} // namespace rast
} // namespace pcl
