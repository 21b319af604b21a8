/// \file correspondence_rigid_registration.cpp
/// \brief The registration chain, step by step: match, reject, estimate, refine.

#include <pcl/registration/correspondence_rigid_registration.h>

#include <stdexcept>

namespace pcl {
namespace rast {

bool
RegistrationParams::isValid(std::string* why) const
{
  std::string reason;
  if (!matching.isValid(&reason))
    reason = "matching." + reason;
  else if (!ransac.isValid(&reason))
    reason = "ransac." + reason;
  else if (!refinement.isValid(&reason))
    reason = "refinement." + reason;
  else if (min_correspondences < 3)
    reason = "min_correspondences must be >= 3, got " + std::to_string(min_correspondences);
  if (why)
    *why = reason;
  return reason.empty();
}

CorrespondenceRigidRegistration::CorrespondenceRigidRegistration(const RegistrationParams& params)
{
  setParams(params);
}

void
CorrespondenceRigidRegistration::setParams(const RegistrationParams& params)
{
  std::string why;
  if (!params.isValid(&why))
    throw std::invalid_argument("CorrespondenceRigidRegistration::setParams: " + why);
  params_ = params;
  source_voxels_ready_ = false;
  if (!target_given_prepared_)
    prepared_target_.reset();
}

void
CorrespondenceRigidRegistration::setInputSource(const FeatureSetConstPtr& features,
                                                const CloudConstPtr& cloud)
{
  source_features_ = features;
  source_cloud_ = cloud;
  source_voxels_ready_ = false;
}

void
CorrespondenceRigidRegistration::setInputTarget(const FeatureSetConstPtr& features,
                                                const CloudConstPtr& cloud)
{
  target_features_ = features;
  target_cloud_ = cloud;
  prepared_target_.reset();
  target_given_prepared_ = false;
}

void
CorrespondenceRigidRegistration::setInputTarget(
    const FeatureSetConstPtr& features, const PointToPlaneTarget::ConstPtr& prepared_target)
{
  target_features_ = features;
  target_cloud_.reset();
  prepared_target_ = prepared_target;
  target_given_prepared_ = static_cast<bool>(prepared_target);
}

RegistrationResult
CorrespondenceRigidRegistration::align(const Eigen::Isometry3d& T_target_source_guess)
{
  if (!source_features_ || !target_features_)
    throw std::invalid_argument(std::string("CorrespondenceRigidRegistration::align: no ") +
                                (source_features_ ? "target" : "source") + " features set");
  RegistrationResult result;
  result.T_target_source = T_target_source_guess;
  correspondences_.clear();
  inliers_.clear();

  // 1. Data association in descriptor space.
  correspondences_ = matchHamming(*source_features_, *target_features_, params_.matching,
                                  T_target_source_guess);
  result.num_correspondences = static_cast<int>(correspondences_.size());
  if (result.num_correspondences < params_.min_correspondences) {
    result.message = "too few correspondences: " + std::to_string(result.num_correspondences) +
                     " < min_correspondences " + std::to_string(params_.min_correspondences);
    return result;
  }

  // 2. Outlier rejection and the least-squares estimate of eq. 4 on the inliers.
  const RigidRansacResult ransac = estimateRigidRansac(
      source_features_->points, target_features_->points, correspondences_, params_.ransac);
  if (!ransac.success) {
    result.num_inliers = static_cast<int>(ransac.inlier_indices.size());
    result.message = ransac.message;
    return result;
  }
  for (const int i : ransac.inlier_indices)
    inliers_.push_back(correspondences_[i]);
  result.T_target_source = ransac.T_target_source;
  result.num_inliers = static_cast<int>(inliers_.size());
  result.inlier_rmse_m = ransac.inlier_rmse_m;
  result.success = true;
  result.message = "feature estimate: " + ransac.message;

  // 3. Optional dense refinement from the feature estimate.
  const bool have_target = prepared_target_ || target_cloud_;
  if (!params_.refine || !source_cloud_ || !have_target)
    return result;
  if (!prepared_target_) {
    auto target = std::make_shared<PointToPlaneTarget>();
    target->build(*target_cloud_, params_.refinement);
    prepared_target_ = target;
  }
  if (!source_voxels_ready_) {
    source_voxels_ =
        voxelDownsample(toPointVector(*source_cloud_), params_.refinement.source_voxel_size_m);
    source_voxels_ready_ = true;
  }
  const PointToPlaneResult refined = refinePointToPlane(
      source_voxels_, *prepared_target_, ransac.T_target_source, params_.refinement);
  result.refinement_iterations = refined.iterations;
  result.refinement_converged = refined.converged;
  if (!refined.success) {
    result.success = false;
    result.message = refined.message + " (feature estimate: " + ransac.message + ")";
    return result;
  }
  result.T_target_source = refined.T_target_source;
  result.refined = true;
  result.inlier_rmse_m = refined.rmse_m;
  result.message += "; refined: " + refined.message;
  return result;
}

} // namespace rast
} // namespace pcl
