/// \file instantiate.cpp
/// \brief Explicit instantiations of the features module for PCL_RAST_XYZ_POINT_TYPES,
/// in one unit so PCL's search templates are compiled once.

// pcl::Keypoint's initCompute (overridden here, but virtual, so still instantiated)
// names PCL's k-d tree and organized search; PCL compiles those for its own types only,
// so the unit needs their implementations for pcl::rast's types with a time field.
#include <pcl/features/impl/orb_raster_features.hpp>
#include <pcl/features/impl/range_raster_image.hpp>
#include <pcl/impl/instantiate.hpp>
#include <pcl/kdtree/impl/kdtree_flann.hpp>
#include <pcl/rast/point_types.h>
#include <pcl/search/impl/kdtree.hpp>
#include <pcl/search/impl/organized.hpp>
#include <pcl/search/impl/search.hpp>

// PCL's search classes for the time-field types, so users of the estimator on those
// types link (PCL's own libraries hold them for PCL's types).
PCL_INSTANTIATE(Search, PCL_RAST_TIME_POINT_TYPES)
PCL_INSTANTIATE(KdTree, PCL_RAST_TIME_POINT_TYPES)
PCL_INSTANTIATE(KdTreeFLANN, PCL_RAST_TIME_POINT_TYPES)
PCL_INSTANTIATE(OrganizedNeighbor, PCL_RAST_TIME_POINT_TYPES)

PCL_INSTANTIATE(RangeRasterImage, PCL_RAST_XYZ_POINT_TYPES)
PCL_INSTANTIATE(OrbRasterFeatureEstimator, PCL_RAST_XYZ_POINT_TYPES)
