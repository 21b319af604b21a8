#pragma once
/// \file raster_orb_registration.h
/// \brief The paper's scan-to-scan registration behind PCL's pcl::Registration interface:
/// ground removal, rasterized ORB features of both clouds, Hamming matching, rigid
/// RANSAC, least squares (eq. 4) and a point-to-plane refinement on the dense clouds.
/// \ingroup registration

#include <memory>
#include <pcl/features/orb_raster_features.h>
#include <pcl/registration/correspondence_rigid_registration.h>
#include <pcl/registration/registration.h>
#include <pcl/segmentation/sac_ground_removal.h>
#include <string>

namespace pcl {
namespace rast {

/// \brief Parameters of RasterORBRegistration.
struct RasterORBRegistrationParams
{
  /// Remove the ground plane before rasterizing (the paper's first step). The dense
  /// refinement still uses every point: the road fixes height, roll and pitch.
  bool remove_ground = true;
  SACGroundRemovalParams ground; ///< ground removal
  RangeRasterParams raster;      ///< rasterization of the non-ground points
  OrbRasterFeatureParams orb;    ///< ORB detection and description
  /// Matching, RANSAC and refinement. The spatial gate of the matching stays off by
  /// default: the point of features is to register without a good guess.
  RegistrationParams registration;

  /// \brief True when all values are in range; otherwise says why in *why (if given).
  bool isValid(std::string* why = nullptr) const;
};

/// \brief Feature-based registration of a source cloud to a target cloud, usable
/// wherever PCL expects a pcl::Registration (e.g. in place of
/// pcl::GeneralizedIterativeClosestPoint):
/// \code
/// pcl::Registration<pcl::PointXYZ, pcl::PointXYZ>::Ptr reg(
///     new pcl::rast::RasterORBRegistration<pcl::PointXYZ, pcl::PointXYZ>);
/// reg->setInputSource(source);
/// reg->setInputTarget(target);
/// pcl::PointCloud<pcl::PointXYZ> aligned;
/// reg->align(aligned);
/// if (reg->hasConverged()) use(reg->getFinalTransformation());
/// \endcode
/// Unlike ICP it needs no initial guess: the guess given to align() is used only when
/// the matching's spatial gate is enabled, and never returned silently on failure
/// (hasConverged() is false and getResult().message says why). Both clouds are in their
/// sensor frames, z up, as the rasterization assumes.
///
/// getFitnessScore() is PCL's (mean squared nearest-neighbour distance). Instantiated
/// for PointSource = PointTarget in PCL_RAST_XYZ_POINT_TYPES.
/// \ingroup registration
template <typename PointSource, typename PointTarget, typename Scalar = float>
class RasterORBRegistration : public pcl::Registration<PointSource, PointTarget, Scalar>
{
public:
  using Base = pcl::Registration<PointSource, PointTarget, Scalar>;
  using Ptr = std::shared_ptr<RasterORBRegistration<PointSource, PointTarget, Scalar>>;
  using ConstPtr =
      std::shared_ptr<const RasterORBRegistration<PointSource, PointTarget, Scalar>>;
  using typename Base::Matrix4;
  using typename Base::PointCloudSource;
  using typename Base::PointCloudTarget;

  /// \throws std::invalid_argument when params are invalid
  explicit RasterORBRegistration(
      const RasterORBRegistrationParams& params = RasterORBRegistrationParams());

  /// \throws std::invalid_argument when params are invalid
  void setParams(const RasterORBRegistrationParams& params);
  const RasterORBRegistrationParams& getParams() const { return params_; }

  /// \brief Counts, residual and message of the last align().
  const RegistrationResult& getResult() const { return result_; }

  /// \brief The cloud to align. Unlike PCL's registrations, which print an error and
  /// keep the previous cloud, a null or empty cloud throws.
  /// \throws std::invalid_argument when \a cloud is null or empty
  void setInputSource(const typename PointCloudSource::ConstPtr& cloud) override;

  /// \brief A new target: its features and dense target are prepared on the next
  /// align() and then reused while the target stays (many sources, one map).
  /// \throws std::invalid_argument when \a cloud is null or empty
  void setInputTarget(const typename PointCloudTarget::ConstPtr& cloud) override;

  /// \brief The ORB features of the last align(): source, then target.
  const RasterFeatureSet& getSourceFeatures() const { return *source_features_; }
  const RasterFeatureSet& getTargetFeatures() const { return *target_features_; }
  /// \brief RANSAC inliers of the last align() (indices into the feature sets).
  const pcl::Correspondences& getFeatureInliers() const { return inliers_; }

protected:
  void computeTransformation(PointCloudSource& output, const Matrix4& guess) override;

  using Base::converged_;
  using Base::final_transformation_;
  using Base::indices_;
  using Base::input_;
  using Base::target_;
  using Base::transformation_;

private:
  /// Ground removal (when enabled), rasterization and ORB features of \a cloud (of
  /// \a indices when not null).
  template <typename PointT>
  void extractFeatures(const typename pcl::PointCloud<PointT>::ConstPtr& cloud,
                       const pcl::IndicesConstPtr& indices,
                       RasterFeatureSet& features);

  RasterORBRegistrationParams params_;
  std::shared_ptr<RasterFeatureSet> source_features_ =
      std::make_shared<RasterFeatureSet>();
  std::shared_ptr<RasterFeatureSet> target_features_ =
      std::make_shared<RasterFeatureSet>();
  /// Matching, RANSAC and refinement; holds the prepared dense target between aligns.
  CorrespondenceRigidRegistration registration_;
  bool target_prepared_ = false; ///< target features and dense target are current
  pcl::Correspondences inliers_;
  RegistrationResult result_;
};

} // namespace rast
} // namespace pcl

#ifdef PCL_NO_PRECOMPILE
#include <pcl/registration/impl/raster_orb_registration.hpp>
#endif
