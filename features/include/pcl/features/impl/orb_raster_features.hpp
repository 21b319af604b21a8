#pragma once
/// \file impl/orb_raster_features.hpp
/// \brief Template part of OrbRasterFeatureEstimator: rasterize, detect
/// (OrbRasterDetector, compiled once) and lift every keypoint to its input point.

#include <chrono>
#include <pcl/features/impl/range_raster_image.hpp>
#include <pcl/features/orb_raster_features.h>
#include <sstream>
#include <stdexcept>

namespace pcl {
namespace rast {

template <typename PointInT>
void
OrbRasterFeatureEstimator<PointInT>::setInputCloud(const PointCloudConstPtr& cloud)
{
  if (!cloud)
    throw std::invalid_argument(
        "OrbRasterFeatureEstimator::setInputCloud: cloud is null");
  pcl::PCLBase<PointInT>::setInputCloud(cloud);
  raster_given_ = false;
}

template <typename PointInT>
void
OrbRasterFeatureEstimator<PointInT>::setInputRaster(
    const RangeRasterImage<PointInT>& raster)
{
  if (!raster.isComputed())
    throw std::invalid_argument("OrbRasterFeatureEstimator::setInputRaster: raster not "
                                "computed (call compute())");
  raster_ = raster;
  pcl::PCLBase<PointInT>::setInputCloud(raster.getInputCloud());
  raster_given_ = true;
}

template <typename PointInT>
void
OrbRasterFeatureEstimator<PointInT>::extract(
    std::vector<OrbRasterDetector::RasterKeypoint>& keypoints)
{
  double raster_ms = 0.0;
  if (!raster_given_) {
    if (!input_)
      throw std::invalid_argument("OrbRasterFeatureEstimator::compute: no input (call "
                                  "setInputCloud or setInputRaster)");
    const auto start = std::chrono::steady_clock::now();
    raster_.setParams(raster_params_);
    raster_.setInputCloud(input_);
    if (indices_ && !fake_indices_)
      raster_.setIndices(indices_);
    raster_.compute();
    raster_ms = std::chrono::duration<double, std::milli>(
                    std::chrono::steady_clock::now() - start)
                    .count();
  }
  result_ = detect(raster_, keypoints);
  result_.raster_ms = raster_ms;
  result_.success = result_.num_features > 0;
  std::ostringstream msg;
  msg << result_.num_features << " features (" << result_.num_detected
      << " detected at FAST " << result_.fast_threshold << ", " << result_.num_bucketed
      << " after bucketing, " << result_.num_unlifted << " without 3D point)";
  result_.message = msg.str();
}

namespace detail {

/// A raster keypoint lifted to its input point: x, y, z of the point, w = 1, and the
/// keypoint fields (RasterFeaturePoint and ORBSignature256 alike).
template <typename PointInT, typename FeaturePoint>
void
lift(const OrbRasterDetector::RasterKeypoint& kp,
     const pcl::PointCloud<PointInT>& cloud,
     FeaturePoint& point)
{
  point.getVector3fMap() = cloud[kp.index].getVector3fMap();
  point.data[3] = 1.0f;
  point.u = kp.u;
  point.v = kp.v;
  point.response = kp.response;
  point.angle_deg = kp.angle_deg;
  point.octave = kp.octave;
}

} // namespace detail

template <typename PointInT>
OrbRasterFeatureResult
OrbRasterFeatureEstimator<PointInT>::compute(RasterFeatureSet& features)
{
  extract(keypoints_);
  const PointCloud& cloud = *input_;
  features.points.clear();
  features.descriptors.clear();
  features.points.reserve(keypoints_.size());
  features.descriptors.reserve(keypoints_.size());
  for (const auto& kp : keypoints_) {
    RasterFeaturePoint point;
    detail::lift(kp, cloud, point);
    features.points.push_back(point);
    features.descriptors.push_back(kp.descriptor);
  }
  features.points.width = static_cast<std::uint32_t>(features.points.size());
  features.points.height = 1;
  features.points.is_dense = true;
  features.points.header = cloud.header;
  return result_;
}

template <typename PointInT>
bool
OrbRasterFeatureEstimator<PointInT>::initCompute()
{
  if (!pcl::PCLBase<PointInT>::initCompute())
    return false;
  keypoints_indices_.reset(new pcl::PointIndices);
  return true;
}

template <typename PointInT>
void
OrbRasterFeatureEstimator<PointInT>::detectKeypoints(PointCloudOut& output)
{
  extract(keypoints_);
  const PointCloud& cloud = *input_;
  output.resize(keypoints_.size());
  keypoints_indices_->indices.resize(keypoints_.size());
  for (std::size_t k = 0; k < keypoints_.size(); ++k) {
    const auto& kp = keypoints_[k];
    ORBSignature256& q = output[k];
    detail::lift(kp, cloud, q);
    std::copy(kp.descriptor.begin(), kp.descriptor.end(), q.descriptor);
    keypoints_indices_->indices[k] = kp.index;
  }
  output.width = static_cast<std::uint32_t>(output.size());
  output.height = 1;
  output.is_dense = true;
  output.header = cloud.header;
}

} // namespace rast
} // namespace pcl

#define PCL_INSTANTIATE_OrbRasterFeatureEstimator(T)                                     \
  template class PCL_EXPORTS pcl::rast::OrbRasterFeatureEstimator<T>;
