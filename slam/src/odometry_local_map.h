#pragma once
/// \file odometry_local_map.h
/// \brief Internal to the odometry: fast voxel downsampling, the local voxel-plane map
/// (KISS-ICP-like voxel hash of key-frame points, one plane per voxel) and the robust,
/// degeneracy-aware point-to-plane Gauss-Newton that registers a scan to it.
/// Plain data and free functions; not installed.

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <array>
#include <cstdint>
#include <pcl/registration/voxel_hash_map.h>
#include <pcl/slam/odometry.h>
#include <string>
#include <vector>

namespace pcl {
namespace rast {
namespace odometry_detail {

using Points3f = std::vector<Eigen::Vector3f, Eigen::aligned_allocator<Eigen::Vector3f>>;

/// \brief Whether a point is finite and within [min_range_m, max_range_m] of the sensor.
struct RangeFilter
{
  float min_sq = 0.0f, max_sq = 0.0f;
  RangeFilter(double min_range_m, double max_range_m)
      : min_sq(static_cast<float>(min_range_m * min_range_m)),
        max_sq(static_cast<float>(max_range_m * max_range_m))
  {}
  bool operator()(const pcl::PointXYZI& p) const
  {
    const float r_sq = p.x * p.x + p.y * p.y + p.z * p.z; // NaN/Inf fail both tests
    return r_sq >= min_sq && r_sq <= max_sq;
  }
};

/// \brief Number of points of \a cloud that pass \a filter.
std::size_t countInRange(const pcl::PointCloud<pcl::PointXYZI>& cloud,
                         const RangeFilter& filter);

/// \brief Indices of one point per voxel (the first met, a real measurement) among the
/// points passing \a filter, in input order. Open addressing: several times faster
/// than std::unordered_set on 100k points.
std::vector<int> voxelDownsampleIndices(const pcl::PointCloud<pcl::PointXYZI>& cloud,
                                        double voxel_size_m,
                                        const RangeFilter& filter);

/// \brief The points at \a indices as plain data.
Points3f toPoints(const pcl::PointCloud<pcl::PointXYZI>& cloud,
                  const std::vector<int>& indices);
/// \brief All points of \a cloud as plain data.
Points3f toPoints(const pcl::PointCloud<pcl::PointXYZI>& cloud);

/// \brief Every k-th index so that at most \a max_points remain (k = ceil(n / max)).
std::vector<int> strideSubsample(const std::vector<int>& indices, std::size_t max_points);

/// \brief A spherical range image of one scan (azimuth x elevation cells, the nearest
/// return per cell), to ask whether the scan saw past a point: free space where a point
/// now is (or was) means that the point moved.
class VisibilityImage
{
public:
  VisibilityImage() = default;
  /// \brief The image of \a points (sensor frame).
  explicit VisibilityImage(const pcl::PointCloud<pcl::PointXYZI>& points);
  bool empty() const { return range_.empty(); }
  /// \brief True when the scan saw through where \a p (sensor frame) lies: the nearest
  /// return in the cell of its direction and the eight around it lies more than
  /// \a margin_m beyond |p|. Cells without a return (sky; the ground, which the image
  /// leaves out) do not count; when none of the nine has one, false.
  bool seenPast(const Eigen::Vector3f& p, float margin_m) const;

private:
  static constexpr int kCols = 1024, kRows = 100;
  static constexpr float kMinElevationDeg = -30.0f, kRowDeg = 0.5f;
  /// The cell of (x, y, z) and its range; -1 outside the image.
  static int cellOf(float x, float y, float z, float& range);
  std::vector<float> range_; ///< kRows x kCols, +inf: no return
};

/// \brief The local map: voxels of the key-frames' points in the world frame, each with
/// a plane (centroid, unit normal) fitted when the voxel changes.
class VoxelPlaneMap
{
public:
  explicit VoxelPlaneMap(const DenseTrackingParams& params = DenseTrackingParams());

  /// \brief Add world-frame points (up to map_max_points_per_voxel per voxel), refit the
  /// touched voxels' planes and drop voxels farther than map_radius_m from \a center.
  void insert(const Points3f& points_world, const Eigen::Vector3f& center);

  /// \brief What plane() looked up for a query's voxel, kept by the caller for the
  /// next query of the same source point: between two Gauss-Newton iterations a point
  /// mostly stays in its voxel, and the hash lookups (its own voxel and six
  /// neighbours, cache misses in a map of 10^5 voxels) were a quarter of the
  /// odometry's time off the map (session 29). Valid while the map is unchanged.
  struct PlaneLookup
  {
    VoxelKey key = ~VoxelKey(0); ///< the voxel looked up (none yet)
    bool own = false;            ///< the voxel's own plane: voxels[0]
    std::uint8_t count = 0;      ///< planes in voxels
    std::array<int, 6> voxels{}; ///< own, or the planar face-neighbours in order
  };

  /// \brief The plane for a query point: its own voxel's, else the nearest planar
  /// face-neighbour's. False when there is none.
  bool plane(const Eigen::Vector3f& query,
             Eigen::Vector3f& centroid,
             Eigen::Vector3f& normal) const;
  /// \brief plane(), reusing \a lookup when the query is in the voxel it was made for
  /// (the same result as without it).
  bool plane(const Eigen::Vector3f& query,
             PlaneLookup& lookup,
             Eigen::Vector3f& centroid,
             Eigen::Vector3f& normal) const;

  /// \brief Hide the planar voxels within \a radius_m of the sensor that \a image
  /// (taken at \a T_world_lidar) sees through by more than \a margin_m (moving
  /// objects the map holds) until the next call or insert; returns how many. Level
  /// planes (the ground, roofs) are never hidden. Null \a image: only the last call's
  /// voxels are shown again.
  int hideSeenThrough(const VisibilityImage* image,
                      const Eigen::Isometry3f& T_world_lidar,
                      float radius_m,
                      float margin_m);

  std::size_t size() const { return voxels_.size() - num_dropped_; }
  bool empty() const { return size() == 0; }

private:
  struct Voxel
  {
    Points3f points;
    /// Squared range of each point from the sensor that saw it (map_nearer_ratio > 0)
    std::vector<float> ranges_sq;
    Eigen::Vector3f centroid = Eigen::Vector3f::Zero();
    Eigen::Vector3f normal = Eigen::Vector3f::Zero();
    bool planar = false;
    bool hidden = false; ///< hideSeenThrough
  };
  VoxelKey key(const Eigen::Vector3f& p) const;
  /// Undo the last hideSeenThrough.
  void showHidden();
  /// The voxel at (x, y, z) when it holds a plane, else -1.
  int planarVoxel(std::int64_t x, std::int64_t y, std::int64_t z) const;
  void fitPlane(Voxel& voxel) const;

  DenseTrackingParams params_;
  float inv_voxel_size_;
  std::vector<Voxel> voxels_;   ///< insertion order; dropped ones empty until compacted
  VoxelHashMap index_;          ///< voxel key -> position in voxels_
  std::size_t num_dropped_ = 0; ///< voxels dropped by the radius crop, not compacted yet
  std::vector<int> hidden_;     ///< voxels hidden by the last hideSeenThrough
};

/// \brief Outcome of registerToMap.
struct DenseResult
{
  bool success = false;
  Eigen::Isometry3d T_world_lidar = Eigen::Isometry3d::Identity();
  int iterations = 0;
  int num_source_points = 0;
  int num_correspondences = 0;   ///< paired in the last iteration
  int degenerate_directions = 0; ///< eigen-directions not updated (last iteration)
  double rmse_m = 0.0;           ///< RMS residual of the pairs within 3 kernel scales
  /// The normal equations of the last iteration per unit weight, H / sum(w), in the
  /// tangent of denseTangent: delta^T information delta is the mean squared residual
  /// a displacement delta adds, i.e. how well the scan tells two poses apart.
  Eigen::Matrix<double, 6, 6> information = Eigen::Matrix<double, 6, 6>::Zero();
  /// The smallest eigenvalue of the normal equations over the total weight (the
  /// direction the scan constrains least).
  double weakest_ratio = 0.0;
  /// Least support of a direction that passed the eigenvalue test (-1: no test).
  double least_support = -1.0;
  std::string message;
};

/// \brief Options of one registerToMap call.
struct DenseOptions
{
  /// > 0: the annealing starts at this kernel scale instead of at
  /// max_correspondence_distance_m / 3; a guess already within centimetres (a second
  /// deskew pass) then takes two or three iterations instead of five or more.
  double initial_kernel_scale_m = 0.0;
  /// Along the degenerate directions the result takes this pose's value (e.g. the
  /// constant-velocity prior) instead of keeping the guess's. Null: the guess's.
  const Eigen::Isometry3d* T_world_anchor = nullptr;
  /// > 0 (with an anchor): every step is also pulled toward the anchor with this
  /// fraction of the pairs' total weight (PointToPlaneSystem::setStepPrior), so that a
  /// direction the scan constrains only weakly (a tunnel's axis, 0.3-1 % of the
  /// weight) follows the anchor rather than noise and moving cars.
  double prior_ratio = 0.0;
  /// ... but only while the iterate is within these of the anchor [m], [deg]: a prior
  /// far off (a turn the features caught) must not bias the fit.
  double prior_within_m = 0.0, prior_within_deg = 0.0;
};

/// \brief The displacement from \a from to \a to in registerToMap's tangent: rotation
/// omega (R_to = Exp(omega) R_from) times 10 m, then t_to - t_from (metres both).
Eigen::Matrix<double, 6, 1> denseTangent(const Eigen::Isometry3d& from,
                                         const Eigen::Isometry3d& to);

/// \brief The RMS residual change [m] the scan of \a dense sees between its result and
/// \a other: sqrt(delta^T information delta). Below the sensor noise the scan cannot
/// tell the two poses apart.
double denseSeparation(const DenseResult& dense, const Eigen::Isometry3d& other);

/// \brief Robust point-to-plane Gauss-Newton of \a source (LiDAR frame) against \a map:
/// minimise sum_i w(r_i) r_i^2, r_i = n_i . (T p_i - c_i) (Geman-McClure weights,
/// annealed scale). The update is solved in the eigenbasis of the normal equations and
/// left at zero along directions whose eigenvalue is below degeneracy_min_ratio of the
/// total weight (Zhang et al., ICRA 2016), so that an unconstrained direction keeps
/// the initial guess (or DenseOptions::T_world_anchor's value) instead of following
/// noise.
DenseResult registerToMap(const Points3f& source,
                          const VoxelPlaneMap& map,
                          const Eigen::Isometry3d& T_world_lidar_guess,
                          const DenseTrackingParams& params,
                          const DenseOptions& options = {});

} // namespace odometry_detail
} // namespace rast
} // namespace pcl
