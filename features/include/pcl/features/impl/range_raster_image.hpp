#pragma once
/// \file impl/range_raster_image.hpp
/// \brief Template part of RangeRasterImage; the rasterization itself is RasterGrid's,
/// compiled once for all point types.

#include <pcl/features/range_raster_image.h>
#include <stdexcept>

namespace pcl {
namespace rast {

template <typename PointT>
void
RangeRasterImage<PointT>::setInputCloud(const PointCloudConstPtr& cloud)
{
  if (!cloud)
    throw std::invalid_argument("RangeRasterImage::setInputCloud: cloud is null");
  pcl::PCLBase<PointT>::setInputCloud(cloud);
  invalidate();
}

template <typename PointT>
void
RangeRasterImage<PointT>::compute()
{
  if (!input_)
    throw std::invalid_argument(
        "RangeRasterImage::compute: no input cloud (call setInputCloud)");
  const pcl::Indices* indices = (indices_ && !fake_indices_) ? indices_.get() : nullptr;
  // Every PCL point type with PCL_ADD_POINT4D stores x, y, z as consecutive floats.
  const float* xyz = input_->empty() ? nullptr : &(*input_)[0].x;
  rasterize(xyz, sizeof(PointT), input_->size(), indices);
}

template <typename PointT>
bool
RangeRasterImage<PointT>::pixelToPoint(int col, int row, PointT& point) const
{
  const int index = pixelIndex(col, row);
  if (index < 0)
    return false;
  point = (*input_)[index];
  return true;
}

} // namespace rast
} // namespace pcl

#define PCL_INSTANTIATE_RangeRasterImage(T)                                              \
  template class PCL_EXPORTS pcl::rast::RangeRasterImage<T>;
