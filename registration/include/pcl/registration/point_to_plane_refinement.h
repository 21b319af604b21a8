#pragma once
/// \file point_to_plane_refinement.h
/// \brief Dense refinement: robust plane-to-plane (GICP-style) or point-to-plane ICP of a
/// voxelized source scan against a prepared target (voxelized scan or local map with
/// normals, indexed once in a voxel hash map). See doc/registration.md for the choices.
/// \ingroup registration

#include <pcl/point_cloud.h>
#include <pcl/registration/point_to_plane_system.h>
#include <pcl/point_types.h>

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <Eigen/StdVector>

#include <memory>
#include <string>
#include <vector>

namespace pcl {
namespace rast {

/// \brief 3D points as plain data (metres).
using PointVector = std::vector<Eigen::Vector3d, Eigen::aligned_allocator<Eigen::Vector3d>>;

/// \brief Cost minimised by the refinement.
enum class RefinementCost
{
  /// r = n_q . (T p - q): the classic point-to-plane distance (source normals unused).
  kPointToPlane,
  /// GICP with plane-normalised covariances (small_gicp's default): e = T p - q weighted
  /// by (C_q + R C_p R^T)^-1, C = I - (1 - eps) n n^T. Uses the source normals too; falls
  /// back to point-to-plane for a source without normals.
  kPlaneToPlane
};

/// \brief Parameters of point-to-plane refinement.
struct PointToPlaneParams
{
  /// Source scan keeps one point per voxel of this size (metres); 0: no downsampling.
  double source_voxel_size_m = 0.5;
  /// Target scan keeps one point per voxel of this size before normals (metres); 0: none.
  double target_voxel_size_m = 0.3;
  /// Each plane is fitted to the raw points of the 3x3x3 voxel block around its voxel;
  /// fewer raw points than this (>= 3): no plane there.
  int normal_neighbours = 10;
  /// A target point is unused when its neighbourhood's surface variation
  /// lambda_min / (lambda_0 + lambda_1 + lambda_2) exceeds this (not a plane), [0, 1/3].
  double max_surface_variation = 0.1;
  /// Source points farther than this from their nearest target point are unpaired (metres).
  double max_correspondence_distance_m = 1.0;
  /// Cost (see RefinementCost); plane-to-plane is the measured best (doc/registration.md).
  RefinementCost cost = RefinementCost::kPlaneToPlane;
  /// Plane-to-plane: covariance along the normal relative to the in-plane one, (0, 1].
  double plane_covariance_epsilon = 1e-3;
  /// At most this many source points are used, taken evenly spread from the voxelized
  /// source (scan order); 0: all. prepareSource() fits planes on ~2x as many voxels only.
  int max_source_points = 1500;
  /// Robust kernel on point-to-plane residuals. Huber: the most stable result on the real
  /// pairs (Geman-McClure flips between two minima 0.35 deg apart, doc/registration.md).
  RobustKernel kernel = RobustKernel::kHuber;
  /// Kernel scale (metres); 0: adaptive, at iteration k the larger of 1.4826 * median |r|
  /// (a robust sigma of the current residuals) and (max_correspondence_distance_m / 3)
  /// / 2^k (graduated: wide first), clamped to [min_kernel_scale_m,
  /// max_correspondence_distance_m / 3].
  double kernel_scale_m = 0.0;
  /// Lower bound of the adaptive kernel scale (metres), about the sensor noise.
  double min_kernel_scale_m = 0.03;
  /// Gauss-Newton iterations at most.
  int max_iterations = 30;
  /// Converged when an update moves less than this (metres) ...
  double convergence_translation_m = 1e-4;
  /// ... and rotates less than this (radians).
  double convergence_rotation_rad = 1e-5;
  /// Fewer paired source points than this: failure.
  int min_correspondences = 50;
  /// Failure ("diverged") when fewer than this fraction of the source points are paired
  /// at the end, (0, 1].
  double min_overlap_ratio = 0.2;
  /// Failure ("diverged") when the result differs from the initial guess by more than
  /// this translation (metres) ...
  double max_correction_m = 3.0;
  /// ... or this rotation (radians, default 30 deg).
  double max_correction_rad = 0.5235987755982988;
  /// Threads preparing a scan (PointToPlaneTarget::build(), prepareSource()): 1, or 2
  /// for the voxel statistics and the plane fits in two halves. The result is the same
  /// up to the summation order of the voxel sums. For a caller that has a core to spare
  /// (pcl_rast_localize); the SLAM's threads keep both cores busy already.
  int threads = 1;
  /// Degeneracy-aware steps: an eigen-direction of the normal equations whose eigenvalue
  /// is at most this share of the total weight (rotations in radians about the target's
  /// origin) is not updated, so the pose keeps the guess's value along it (a corridor's
  /// axis, which noise and plane-fitting artefacts would otherwise decide). 0: plain
  /// steps, as before (bit-identical). See PointToPlaneResult::degenerate_directions.
  double degeneracy_min_ratio = 0.0;

  /// \brief True when all values are in range; otherwise says why in *why (if given).
  bool
  isValid(std::string* why = nullptr) const;
};

/// \brief Outcome of point-to-plane refinement.
struct PointToPlaneResult
{
  /// True when enough points were paired and the solution did not run away.
  bool success = false;
  /// True when the last update was below the convergence thresholds.
  bool converged = false;
  /// Refined transform (the initial guess when nothing could be done).
  Eigen::Isometry3d T_target_source = Eigen::Isometry3d::Identity();
  /// Gauss-Newton iterations run.
  int iterations = 0;
  /// Source points used (after voxelization).
  int num_source_points = 0;
  /// Source points paired with a target plane in the last iteration.
  int num_correspondences = 0;
  /// RMS point-to-plane distance (metres) in the last iteration over the paired points
  /// whose |residual| is within 3 kernel scales (the inliers).
  double rmse_m = 0.0;
  /// Why it failed, or a short summary.
  std::string message;
  /// With PointToPlaneParams::degeneracy_min_ratio > 0: eigen-directions of the last
  /// iteration left at the guess (0: the scan constrained every direction), and the
  /// smallest eigenvalue over the total weight.
  int degenerate_directions = 0;
  double weakest_ratio = 0.0;
};

/// \brief One point per occupied voxel (the first one met, a real measurement, as in
/// KISS-ICP; VoxelOccupancy); non-finite points are dropped. voxel_size_m <= 0 keeps all
/// finite points.
PointVector
voxelDownsample(const PointVector& points, double voxel_size_m);

/// \brief Finite points of a PCL cloud as plain data.
PointVector
toPointVector(const pcl::PointCloud<pcl::PointXYZI>& cloud);

/// \brief A registration target prepared once (voxelized points, normals, voxel hash map)
/// and reused for many sources, e.g. a key-frame scan or a local map. A source scan can be
/// prepared the same way (with source_voxel_size_m) for the plane-to-plane cost.
class PointToPlaneTarget
{
public:
  using Ptr = std::shared_ptr<PointToPlaneTarget>;
  using ConstPtr = std::shared_ptr<const PointToPlaneTarget>;

  PointToPlaneTarget();
  ~PointToPlaneTarget();
  PointToPlaneTarget(PointToPlaneTarget&&) noexcept;
  PointToPlaneTarget&
  operator=(PointToPlaneTarget&&) noexcept;

  /// \brief Prepare from a raw scan: voxelize (target_voxel_size_m; one point per voxel,
  /// the mean of its raw points), fit a plane per voxel to the raw points of its 3x3x3
  /// voxel block (normal_neighbours, max_surface_variation), index the planar points.
  /// \throws std::invalid_argument on invalid params or fewer than normal_neighbours points
  void
  build(const PointVector& points, const PointToPlaneParams& params = PointToPlaneParams());
  /// \overload
  void
  build(const pcl::PointCloud<pcl::PointXYZI>& cloud,
        const PointToPlaneParams& params = PointToPlaneParams());
  /// \brief Prepare from points that carry normals already (e.g. a local map); points
  /// with non-finite or zero normals are dropped. No voxelization.
  /// \throws std::invalid_argument when no point has a valid normal
  void
  build(const pcl::PointCloud<pcl::PointNormal>& cloud_with_normals);

  /// \brief Nearest planar target point within max_distance_m of query, searched in the
  /// 27 hash-map cells around it (cells of max(voxel size, max_distance_m / 2) for a
  /// prepared scan): exact within one cell size, approximate beyond, as in KISS-ICP.
  /// \return false when there is none
  bool
  nearest(const Eigen::Vector3d& query,
          double max_distance_m,
          Eigen::Vector3d& point,
          Eigen::Vector3d& normal) const;

  /// \brief What nearest() found in the hash map around one query: the query's cell
  /// and the slots of the 27 cells around it, each looked up when first needed. Between
  /// two Gauss-Newton iterations a source point moves by millimetres and nearly always
  /// stays in its cell, so the next search skips the hash look-ups (most of its time).
  /// Given to another target, it is filled afresh.
  struct CellLookup
  {
    const void* target = nullptr;           ///< the index that filled it
    std::uint64_t cell = ~std::uint64_t(0); ///< packed cell key; none yet
    std::array<int, 27> slots{};            ///< kUnknown, -1 (empty) or a cell's slot
  };
  /// \brief nearest(), reusing \a lookup when the query is in the cell it holds (and
  /// filling it otherwise): the same point and normal as a fresh search.
  bool nearest(const Eigen::Vector3d& query,
               double max_distance_m,
               Eigen::Vector3d& point,
               Eigen::Vector3d& normal,
               CellLookup& lookup) const;

  /// \brief Planar target points (metres) and their unit normals, index-aligned.
  const PointVector&
  points() const
  {
    return points_;
  }
  const PointVector&
  normals() const
  {
    return normals_;
  }
  std::size_t
  size() const
  {
    return points_.size();
  }
  bool
  empty() const
  {
    return points_.empty();
  }

private:
  friend PointToPlaneTarget
  prepareSource(const pcl::PointCloud<pcl::PointXYZI>& cloud, const PointToPlaneParams& params);
  friend PointToPlaneTarget prepareSource(const pcl::PointCloud<pcl::PointXYZI>& cloud,
                                          const std::vector<float>& times_s,
                                          const PointToPlaneParams& params,
                                          std::vector<float>& prepared_times_s);
  /// Per-point times of build(): the raw points' (index-aligned) in, the mean time of
  /// each planar point's voxel out.
  struct Times
  {
    const std::vector<float>* in = nullptr;
    std::vector<float>* out = nullptr;
  };
  /// build() fitting planes on about 2 * max_planes evenly spread voxels only (0: all),
  /// with the points' times when \a times has them.
  void build(const PointVector& points,
             const PointToPlaneParams& params,
             std::size_t max_planes,
             const Times& times);
  void
  buildIndex(double cell_size_m);

  PointVector points_;
  PointVector normals_;
  struct Index;
  std::unique_ptr<Index> index_;
};

/// \brief Robust point-to-plane Gauss-Newton: minimise sum_i w(r_i) r_i^2 with
/// r_i = n_i . (T p_i - q_i), q_i the nearest planar target point of T p_i.
/// \param[in] source source points (already voxelized; see voxelDownsample())
/// \param[in] target prepared target
/// \param[in] T_target_source_guess starting point, e.g. the feature-based estimate
/// \param[in] params parameters (the voxel sizes are not used here)
/// \throws std::invalid_argument on invalid params or an empty target
PointToPlaneResult
refinePointToPlane(const PointVector& source,
                   const PointToPlaneTarget& target,
                   const Eigen::Isometry3d& T_target_source_guess,
                   const PointToPlaneParams& params = PointToPlaneParams());

/// \brief Refine with a prepared source (PointToPlaneTarget::build() with the source voxel
/// size, see prepareSource()): its points and normals, so the plane-to-plane cost
/// applies. Same parameters and result as the overload on points.
PointToPlaneResult
refinePointToPlane(const PointToPlaneTarget& source,
                   const PointToPlaneTarget& target,
                   const Eigen::Isometry3d& T_target_source_guess,
                   const PointToPlaneParams& params = PointToPlaneParams());

/// \brief Prepare a source scan: PointToPlaneTarget::build() with target_voxel_size_m
/// replaced by source_voxel_size_m.
/// \throws std::invalid_argument on invalid params or too few points
PointToPlaneTarget
prepareSource(const pcl::PointCloud<pcl::PointXYZI>& cloud,
              const PointToPlaneParams& params = PointToPlaneParams());

/// \brief prepareSource() of a raw sweep whose points were measured at different times
/// (seconds, \a times_s index-aligned with \a cloud): \a prepared_times_s gets,
/// index-aligned with the result's points(), the mean time of the raw points whose mean
/// each prepared point is.
///
/// Moving each prepared point and its normal by the sensor's motion at that time (motion
/// compensation after the preparation, e.g. deskewPointsAndNormals()) then stands in for
/// preparing the compensated scan: the scan can be prepared before its motion is known
/// (on another thread while the scan before it is registered), and only the few prepared
/// points are moved. For a voxel's mean this is exact for a translation, which is linear
/// in time; a rotation rate w adds at most about |w| x the voxel's size x the spread of
/// its points' times (under 1 cm at 0.5 rad/s for 0.5 m voxels and a 10 Hz sweep).
/// \throws std::invalid_argument on invalid params, a time count that is not the point
/// count, or too few points
PointToPlaneTarget prepareSource(const pcl::PointCloud<pcl::PointXYZI>& cloud,
                                 const std::vector<float>& times_s,
                                 const PointToPlaneParams& params,
                                 std::vector<float>& prepared_times_s);

/// \brief Refine a prepared source given as its points and their unit normals
/// (index-aligned; e.g. the points() and normals() of prepareSource(), moved), as the
/// overload on a prepared source does.
/// \throws std::invalid_argument on invalid params, an empty target or a normal count
/// that is not the point count
PointToPlaneResult
refinePointToPlane(const PointVector& source,
                   const PointVector& source_normals,
                   const PointToPlaneTarget& target,
                   const Eigen::Isometry3d& T_target_source_guess,
                   const PointToPlaneParams& params = PointToPlaneParams());

/// \brief Prepare the source scan (prepareSource()), then refine with both normals; when
/// the source has no planar points, refine its voxelized points instead.
PointToPlaneResult
refinePointToPlane(const pcl::PointCloud<pcl::PointXYZI>& source,
                   const PointToPlaneTarget& target,
                   const Eigen::Isometry3d& T_target_source_guess,
                   const PointToPlaneParams& params = PointToPlaneParams());

} // namespace rast
} // namespace pcl
