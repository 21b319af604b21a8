#include <cmath>
#include <pcl/filters/impl/filter_indices.hpp>
#include <pcl/impl/instantiate.hpp>
#include <pcl/impl/pcl_base.hpp>
#include <pcl/rast/point_types.h>
#include <pcl/segmentation/impl/sac_ground_removal.hpp>
#include <string>

namespace pcl {
namespace rast {

bool
SACGroundRemovalParams::isValid(std::string* why) const
{
  auto fail = [why](const std::string& msg) {
    if (why)
      *why = msg;
    return false;
  };
  if (!(distance_threshold_m > 0.0) || !std::isfinite(distance_threshold_m))
    return fail("distance_threshold_m must be > 0, got " +
                std::to_string(distance_threshold_m));
  if (!(max_tilt_deg >= 0.0 && max_tilt_deg < 90.0))
    return fail("max_tilt_deg must be in [0, 90), got " + std::to_string(max_tilt_deg));
  if (!up_axis.allFinite() || up_axis.norm() < 1e-6f)
    return fail("up_axis must be a finite non-zero vector");
  if (!std::isfinite(max_plane_height_m))
    return fail("max_plane_height_m must be finite");
  if (!std::isfinite(sample_max_height_m))
    return fail("sample_max_height_m must be finite");
  if (max_iterations < 1)
    return fail("max_iterations must be >= 1, got " + std::to_string(max_iterations));
  if (max_sample_points < 3)
    return fail("max_sample_points must be >= 3, got " +
                std::to_string(max_sample_points));
  if (min_inliers < 3)
    return fail("min_inliers must be >= 3, got " + std::to_string(min_inliers));
  if (!(max_rms_ratio > 0.0 && max_rms_ratio <= 1.0))
    return fail("max_rms_ratio must be in (0, 1], got " + std::to_string(max_rms_ratio));
  if (!(min_inlier_ratio >= 0.0 && min_inlier_ratio <= 1.0))
    return fail("min_inlier_ratio must be in [0, 1], got " +
                std::to_string(min_inlier_ratio));
  return true;
}

} // namespace rast
} // namespace pcl

// PCL's libraries hold its base classes for PCL's own point types only.
PCL_INSTANTIATE(PCLBase, PCL_RAST_TIME_POINT_TYPES)
PCL_INSTANTIATE(FilterIndices, PCL_RAST_TIME_POINT_TYPES)

// One translation unit compiles the template for every point type of
// PCL_RAST_XYZ_POINT_TYPES (PCL's explicit-instantiation style).
PCL_INSTANTIATE(SACGroundRemoval, PCL_RAST_XYZ_POINT_TYPES)
PCL_INSTANTIATE(fitPlaneLeastSquares, PCL_RAST_XYZ_POINT_TYPES)
