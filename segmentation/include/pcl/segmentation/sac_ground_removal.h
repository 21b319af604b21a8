#pragma once
/// \file sac_ground_removal.h
/// \brief Pre-processing of the paper (Sec. "Pre-processing"): RANSAC plane fitting
/// finds the ground plane and removes it, so the rings a spinning LiDAR draws on the
/// road do not end up in the rasterized image.
/// \ingroup segmentation

#include <pcl/filters/filter_indices.h>
#include <pcl/point_cloud.h>
#include <pcl/point_types.h>
#include <pcl/types.h>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>

namespace pcl {
namespace rast {

/// \brief Parameters of SACGroundRemoval. Distances in metres, angles in degrees,
/// all expressed in the frame of the input cloud (the LiDAR frame).
/// \ingroup segmentation
struct SACGroundRemovalParams
{
  /// Maximum point-to-plane distance of a ground inlier [m].
  double distance_threshold_m = 0.2;
  /// Maximum angle between the plane normal and \a up_axis [deg]: only
  /// near-horizontal planes are ground (walls and slopes steeper than this are not).
  double max_tilt_deg = 15.0;
  /// Expected up direction in the LiDAR frame (need not be unit length). A tilted or
  /// handheld sensor can pass a prior here, e.g. from an IMU.
  Eigen::Vector3f up_axis = Eigen::Vector3f::UnitZ();
  /// The plane must pass below the sensor: its height relative to the origin, along
  /// \a up_axis, is at most this [m]. Rejects ceilings and roofs above the sensor.
  double max_plane_height_m = 0.0;
  /// RANSAC hypotheses (3-point samples).
  int max_iterations = 100;
  /// RANSAC scores hypotheses on a seeded random subsample of at most this many points;
  /// the final classification uses every point.
  std::size_t max_sample_points = 5000;
  /// The subsample prefers points lower than this along \a up_axis [m] (below the
  /// sensor); when fewer than 3 such points exist, all points are used.
  double sample_max_height_m = 0.0;
  /// Ground is reported only with at least this many inliers...
  std::size_t min_inliers = 100;
  /// ...and at least this fraction of the finite input points.
  double min_inlier_ratio = 0.05;
  /// Ground must be flat: the RMS inlier distance is at most this fraction of
  /// distance_threshold_m. A slab cutting through walls is filled uniformly
  /// (RMS = 1/sqrt(3) = 0.58 of the threshold); a KITTI road scores ~0.37.
  double max_rms_ratio = 0.5;
  /// Refine the RANSAC plane by least squares on its inliers (then re-classify).
  bool refine = true;
  /// Rotate the non-ground cloud so the ground normal becomes +z (about the sensor
  /// origin, no translation); the result's T_level_lidar holds that rotation. Gives a
  /// top-down raster for tilted or handheld sensors.
  bool level_cloud = false;
  /// Seed of the random subsample and of the RANSAC samples (deterministic results).
  std::uint32_t seed = 42;

  /// \brief Whether all values are usable; on failure \a why (if not null) says which.
  bool
  isValid(std::string* why = nullptr) const;
};

/// \brief Output of SACGroundRemoval::segment.
/// \ingroup segmentation
template <typename PointT>
struct GroundRemovalResult
{
  /// The input was processed (false only for an empty or all-non-finite input).
  bool success = false;
  /// A ground plane satisfying the constraints was found. When false the non-ground
  /// cloud holds every finite input point and no ground indices.
  bool ground_found = false;
  /// Ground plane a*x + b*y + c*z + d = 0 in the LiDAR frame, (a, b, c) unit length and
  /// pointing up (positive dot product with the up axis); d is then the height of the
  /// sensor above the ground. Zero when no ground was found.
  Eigen::Vector4f plane_coefficients = Eigen::Vector4f::Zero();
  /// Indices (into the input cloud) of the ground inliers.
  pcl::Indices ground_indices;
  /// Indices (into the input cloud) of the finite points that are not ground.
  pcl::Indices non_ground_indices;
  /// The non-ground points: in the LiDAR frame, or in the levelled frame
  /// (p_level = T_level_lidar * p_lidar) when level_cloud was set and ground was found.
  typename pcl::PointCloud<PointT>::Ptr non_ground;
  /// Rotation levelling the cloud (ground normal -> +z); identity when not levelled.
  Eigen::Isometry3f T_level_lidar = Eigen::Isometry3f::Identity();
  /// Number of input points that were skipped because they are not finite.
  std::size_t num_non_finite = 0;
  /// Human-readable summary or reason of failure.
  std::string message;
};

/// \brief Fit a plane to points by least squares (smallest eigenvector of the
/// covariance, accumulated in double). Returns false when fewer than 3 indices are given.
/// \param[in] cloud the points
/// \param[in] indices the points to fit
/// \param[out] plane (a, b, c, d) with unit normal; its sign is arbitrary
/// \ingroup segmentation
template <typename PointT>
bool
fitPlaneLeastSquares(const pcl::PointCloud<PointT>& cloud,
                     const pcl::Indices& indices,
                     Eigen::Vector4f& plane);

/// \brief RANSAC ground removal, constrained to near-horizontal planes below the
/// sensor, as a PCL filter: it keeps the points that are not ground.
///
/// As a pcl::FilterIndices<PointT> it stands wherever a PCL filter does:
/// \code
/// pcl::FilterIndices<pcl::PointXYZ>::Ptr filter(
///     new pcl::rast::SACGroundRemoval<pcl::PointXYZ>(true)); // keep removed indices
/// filter->setInputCloud(cloud);
/// filter->filter(*objects);               // the non-ground points
/// filter->setNegative(true);
/// filter->filter(ground_indices);         // the ground points instead
/// const auto& removed = *filter->getRemovedIndices();
/// \endcode
/// With setKeepOrganized(true) the output keeps the input's size and layout, the
/// removed points set to NaN (setUserFilterValue). setIndices() restricts both the
/// fit and the output to a subset (an index outside the cloud: std::out_of_range from
/// filter() and segment(), naming it).
/// After filter(), groundFound(), getGroundPlane(),
/// getLevellingTransform() and getMessage() describe the plane; when no ground is
/// found, filter() keeps every finite point (negative: none) and groundFound() says so.
///
/// segment() gives every output of one fit at once (ground and non-ground indices,
/// the non-ground cloud, levelled on request), as the odometry uses it.
///
/// The plane is hypothesised on a seeded subsample of points below the sensor
/// (\a max_sample_points) by PCL's SampleConsensusModelPlane, scored
/// there, then every point is classified by its distance and the plane is refined by
/// least squares (in double) on the inliers over the whole cloud.
/// Instantiated for PCL_RAST_XYZ_POINT_TYPES (pcl/rast/point_types.h); other point
/// types with x, y, z: include pcl/segmentation/impl/sac_ground_removal.hpp.
/// \ingroup segmentation
template <typename PointT>
class SACGroundRemoval : public pcl::FilterIndices<PointT>
{
public:
  using Ptr = std::shared_ptr<SACGroundRemoval<PointT>>;
  using ConstPtr = std::shared_ptr<const SACGroundRemoval<PointT>>;
  using PointCloud = pcl::PointCloud<PointT>;
  using PointCloudConstPtr = typename PointCloud::ConstPtr;

  /// \param[in] extract_removed_indices keep the removed indices (getRemovedIndices)
  explicit SACGroundRemoval(bool extract_removed_indices = false);
  /// \throws std::invalid_argument when !params.isValid().
  explicit SACGroundRemoval(const SACGroundRemovalParams& params,
                            bool extract_removed_indices = false);

  /// \brief Set the cloud to segment. \throws std::invalid_argument when null.
  void
  setInputCloud(const PointCloudConstPtr& cloud) override;

  /// \brief \throws std::invalid_argument when !params.isValid().
  void
  setParams(const SACGroundRemovalParams& params);
  const SACGroundRemovalParams&
  getParams() const
  {
    return params_;
  }

  /// \brief Find the ground and give every output of the fit at once.
  /// \param[out] result plane, inliers, non-ground cloud, flags and message
  /// \throws std::invalid_argument when no input cloud was set.
  void
  segment(GroundRemovalResult<PointT>& result) const;

  /// \brief Whether the last filter() found a ground plane.
  bool
  groundFound() const
  {
    return ground_found_;
  }
  /// \brief The last filter()'s ground plane (see GroundRemovalResult); zero when none.
  const Eigen::Vector4f&
  getGroundPlane() const
  {
    return plane_;
  }
  /// \brief The rotation that levels the last filter()'s ground (normal -> +z), for a
  /// top-down raster of a tilted sensor; identity when no ground was found. filter()
  /// itself never moves points.
  Eigen::Isometry3f
  getLevellingTransform() const;
  /// \brief What the last filter() found, or why it found no ground.
  const std::string&
  getMessage() const
  {
    return message_;
  }

protected:
  using pcl::FilterIndices<PointT>::input_;
  using pcl::FilterIndices<PointT>::indices_;
  using pcl::FilterIndices<PointT>::negative_;
  using pcl::FilterIndices<PointT>::removed_indices_;
  using pcl::FilterIndices<PointT>::extract_removed_indices_;
  using pcl::FilterIndices<PointT>::filter_name_;
  using pcl::FilterIndices<PointT>::applyFilter;

  void
  applyFilter(pcl::Indices& indices) override;

private:
  /// One fit on \a candidates (finite or not) of the input: ground and non-ground
  /// indices, plane and message in \a result (its cloud untouched).
  void
  fit(const pcl::Indices* indices, GroundRemovalResult<PointT>& result) const;

  SACGroundRemovalParams params_;
  bool ground_found_ = false;
  Eigen::Vector4f plane_ = Eigen::Vector4f::Zero();
  std::string message_;
};

} // namespace rast
} // namespace pcl

#ifdef PCL_NO_PRECOMPILE
#include <pcl/segmentation/impl/sac_ground_removal.hpp>
#endif
