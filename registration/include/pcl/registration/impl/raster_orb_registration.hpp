#pragma once
/// \file impl/raster_orb_registration.hpp
/// \brief Template part of RasterORBRegistration.

#include <pcl/common/io.h>
#include <pcl/common/transforms.h>
#include <pcl/registration/raster_orb_registration.h>
#include <stdexcept>

namespace pcl {
namespace rast {

template <typename PointSource, typename PointTarget, typename Scalar>
RasterORBRegistration<PointSource, PointTarget, Scalar>::RasterORBRegistration(
    const RasterORBRegistrationParams& params)
{
  this->reg_name_ = "RasterORBRegistration";
  setParams(params);
}

template <typename PointSource, typename PointTarget, typename Scalar>
void
RasterORBRegistration<PointSource, PointTarget, Scalar>::setParams(
    const RasterORBRegistrationParams& params)
{
  std::string why;
  if (!params.isValid(&why))
    throw std::invalid_argument("RasterORBRegistration::setParams: " + why);
  params_ = params;
  registration_.setParams(params.registration);
  target_prepared_ = false;
}

template <typename PointSource, typename PointTarget, typename Scalar>
void
RasterORBRegistration<PointSource, PointTarget, Scalar>::setInputTarget(
    const typename PointCloudTarget::ConstPtr& cloud)
{
  if (!cloud || cloud->empty())
    throw std::invalid_argument(std::string("RasterORBRegistration::setInputTarget: the "
                                            "target cloud is ") +
                                (cloud ? "empty" : "null"));
  Base::setInputTarget(cloud);
  target_prepared_ = false;
}

template <typename PointSource, typename PointTarget, typename Scalar>
void
RasterORBRegistration<PointSource, PointTarget, Scalar>::setInputSource(
    const typename PointCloudSource::ConstPtr& cloud)
{
  if (!cloud || cloud->empty())
    throw std::invalid_argument(std::string("RasterORBRegistration::setInputSource: the "
                                            "source cloud is ") +
                                (cloud ? "empty" : "null"));
  Base::setInputSource(cloud);
}

template <typename PointSource, typename PointTarget, typename Scalar>
template <typename PointT>
void
RasterORBRegistration<PointSource, PointTarget, Scalar>::extractFeatures(
    const typename pcl::PointCloud<PointT>::ConstPtr& cloud,
    const pcl::IndicesConstPtr& indices,
    RasterFeatureSet& features)
{
  OrbRasterFeatureEstimator<PointT> orb;
  orb.setParams(params_.orb);
  orb.setRasterParams(params_.raster);
  orb.setInputCloud(cloud);
  if (params_.remove_ground) {
    SACGroundRemoval<PointT> ground(params_.ground);
    ground.setInputCloud(cloud);
    if (indices)
      ground.setIndices(indices);
    auto non_ground = std::make_shared<pcl::Indices>();
    ground.filter(*non_ground);
    orb.setIndices(non_ground);
  } else if (indices) {
    orb.setIndices(std::make_shared<pcl::Indices>(*indices));
  }
  orb.compute(features);
}

template <typename PointSource, typename PointTarget, typename Scalar>
void
RasterORBRegistration<PointSource, PointTarget, Scalar>::computeTransformation(
    PointCloudSource& output, const Matrix4& guess)
{
  // setIndices on the source restricts its features and its dense points, as in ICP.
  const bool source_indexed = indices_ && indices_->size() != input_->size();
  source_features_ = std::make_shared<RasterFeatureSet>();
  extractFeatures<PointSource>(
      input_, source_indexed ? indices_ : nullptr, *source_features_);
  // The dense refinement works on x, y, z only.
  auto source_xyz = std::make_shared<pcl::PointCloud<pcl::PointXYZI>>();
  pcl::copyPointCloud(*input_, *indices_, *source_xyz);
  registration_.setInputSource(source_features_, source_xyz);
  if (!target_prepared_) {
    target_features_ = std::make_shared<RasterFeatureSet>();
    extractFeatures<PointTarget>(target_, nullptr, *target_features_);
    auto target_xyz = std::make_shared<pcl::PointCloud<pcl::PointXYZI>>();
    pcl::copyPointCloud(*target_, *target_xyz);
    registration_.setInputTarget(target_features_, target_xyz);
    target_prepared_ = true;
  }

  Eigen::Isometry3d T_guess;
  T_guess.matrix() = guess.template cast<double>();
  result_ = registration_.align(T_guess);
  inliers_ = registration_.getInliers();

  converged_ = result_.success;
  transformation_ = final_transformation_ =
      result_.T_target_source.matrix().cast<Scalar>();
  pcl::transformPointCloud(*input_, *indices_, output, final_transformation_, true);
}

} // namespace rast
} // namespace pcl

#define PCL_INSTANTIATE_RasterORBRegistration(T)                                         \
  template class PCL_EXPORTS pcl::rast::RasterORBRegistration<T, T, float>;
