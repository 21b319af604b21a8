/// \file odometry_local_map.cpp
/// \brief The dense half of the odometry: voxel downsampling, the voxel-plane local map
/// and the point-to-plane Gauss-Newton against it (see odometry_local_map.h).

#include "odometry_local_map.h"

#include "fast_math.h"

#include <pcl/registration/point_to_plane_system.h>

#include <Eigen/Eigenvalues> // fitPlane
#include <algorithm>
#include <cmath>
#include <limits>
#include <memory>

namespace pcl {
namespace rast {
namespace odometry_detail {

namespace {

/// Characteristic length turning rotation rows of the Jacobian into metres, so that
/// the eigenvalues of the 6x6 normal equations are comparable (a rotation of 1/L rad
/// moves a point at L metres by 1 m).
constexpr double kRotationLengthM = 10.0;

} // namespace

std::size_t
countInRange(const pcl::PointCloud<pcl::PointXYZI>& cloud, const RangeFilter& filter)
{
  return static_cast<std::size_t>(
      std::count_if(cloud.points.begin(), cloud.points.end(), filter));
}

std::vector<int>
voxelDownsampleIndices(const pcl::PointCloud<pcl::PointXYZI>& cloud,
                       double voxel_size_m,
                       const RangeFilter& filter)
{
  std::vector<int> out;
  out.reserve(cloud.size() / 8);
  VoxelOccupancy occupancy(voxel_size_m, 1 << 13);
  for (std::size_t i = 0; i < cloud.size(); ++i) {
    const auto& p = cloud.points[i];
    if (filter(p) && occupancy.insert(p.getVector3fMap()))
      out.push_back(static_cast<int>(i));
  }
  return out;
}

Points3f
toPoints(const pcl::PointCloud<pcl::PointXYZI>& cloud, const std::vector<int>& indices)
{
  Points3f out;
  out.reserve(indices.size());
  for (const int i : indices)
    out.push_back(cloud.points[i].getVector3fMap());
  return out;
}

Points3f
toPoints(const pcl::PointCloud<pcl::PointXYZI>& cloud)
{
  Points3f out;
  out.reserve(cloud.size());
  for (const auto& p : cloud.points)
    out.push_back(p.getVector3fMap());
  return out;
}

std::vector<int>
strideSubsample(const std::vector<int>& indices, std::size_t max_points)
{
  if (max_points == 0 || indices.size() <= max_points)
    return indices;
  const std::size_t stride = (indices.size() + max_points - 1) / max_points;
  std::vector<int> out;
  out.reserve(indices.size() / stride + 1);
  for (std::size_t i = 0; i < indices.size(); i += stride)
    out.push_back(indices[i]);
  return out;
}

// ---------------------------------------------------------------------------
// VoxelPlaneMap

VoxelPlaneMap::VoxelPlaneMap(const DenseTrackingParams& params)
    : params_(params), inv_voxel_size_(static_cast<float>(1.0 / params.map_voxel_size_m))
{}

VoxelKey
VoxelPlaneMap::key(const Eigen::Vector3f& p) const
{
  return packVoxelKey(static_cast<std::int64_t>(std::floor(p.x() * inv_voxel_size_)),
                 static_cast<std::int64_t>(std::floor(p.y() * inv_voxel_size_)),
                 static_cast<std::int64_t>(std::floor(p.z() * inv_voxel_size_)));
}

void
VoxelPlaneMap::fitPlane(Voxel& voxel) const
{
  voxel.planar = false;
  if (voxel.points.size() < 5)
    return;
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  for (const auto& p : voxel.points)
    mean += p.cast<double>();
  mean /= static_cast<double>(voxel.points.size());
  Eigen::Matrix3d covariance = Eigen::Matrix3d::Zero();
  for (const auto& p : voxel.points) {
    const Eigen::Vector3d d = p.cast<double>() - mean;
    covariance += d * d.transpose();
  }
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(covariance);
  const Eigen::Vector3d lambda = eig.eigenvalues().cwiseMax(0.0); // ascending
  const double sum = lambda.sum();
  // A plane: thin (small lambda_0) but spread in two directions (not one scan line).
  if (sum <= 0.0 || lambda(0) > params_.max_surface_variation * sum ||
      lambda(1) < 0.05 * lambda(2))
    return;
  voxel.centroid = mean.cast<float>();
  voxel.normal = eig.eigenvectors().col(0).normalized().cast<float>();
  voxel.planar = true;
}

void
VoxelPlaneMap::insert(const Points3f& points_world, const Eigen::Vector3f& center)
{
  const std::size_t max_points =
      static_cast<std::size_t>(params_.map_max_points_per_voxel);
  const float nearer_sq =
      static_cast<float>(params_.map_nearer_ratio * params_.map_nearer_ratio);
  showHidden();
  std::vector<int> touched;
  for (const auto& p : points_world) {
    const auto [v, inserted] = index_.insert(key(p), static_cast<int>(voxels_.size()));
    if (inserted)
      voxels_.emplace_back();
    Voxel& voxel = voxels_[v];
    if (voxel.points.size() >= max_points) {
      // Full: the first points stay, unless a point seen from much nearer takes the
      // place of the one seen from farthest.
      if (nearer_sq <= 0.0f)
        continue;
      const float range_sq = (p - center).squaredNorm();
      const auto far = std::max_element(voxel.ranges_sq.begin(), voxel.ranges_sq.end());
      if (!(range_sq < nearer_sq * *far))
        continue;
      const std::size_t i = static_cast<std::size_t>(far - voxel.ranges_sq.begin());
      voxel.points[i] = p;
      voxel.ranges_sq[i] = range_sq;
      touched.push_back(v);
      continue;
    }
    if (voxel.points.empty()) { // new, or dropped before and now back
      voxel.points.reserve(max_points);
      if (nearer_sq > 0.0f)
        voxel.ranges_sq.reserve(max_points);
      if (!inserted)
        --num_dropped_;
    }
    voxel.points.push_back(p);
    if (nearer_sq > 0.0f) // only the replacement reads them
      voxel.ranges_sq.push_back((p - center).squaredNorm());
    touched.push_back(v);
  }
  std::sort(touched.begin(), touched.end());
  touched.erase(std::unique(touched.begin(), touched.end()), touched.end());
  for (const int v : touched)
    fitPlane(voxels_[v]);

  // Keep the map local: drop voxels far from the newest key-frame. A dropped voxel
  // stays indexed, empty and not planar (as if absent), until they are half the map.
  const float radius_sq = static_cast<float>(params_.map_radius_m * params_.map_radius_m);
  for (Voxel& voxel : voxels_)
    if (!voxel.points.empty() && (voxel.points.front() - center).squaredNorm() > radius_sq) {
      Points3f().swap(voxel.points);
      std::vector<float>().swap(voxel.ranges_sq);
      voxel.planar = false;
      ++num_dropped_;
    }
  if (2 * num_dropped_ > voxels_.size()) {
    voxels_.erase(std::remove_if(voxels_.begin(),
                                 voxels_.end(),
                                 [](const Voxel& voxel) { return voxel.points.empty(); }),
                  voxels_.end());
    num_dropped_ = 0;
    index_.reset(voxels_.size());
    for (std::size_t v = 0; v < voxels_.size(); ++v)
      index_.insert(key(voxels_[v].points.front()), static_cast<int>(v));
  }
}

void
VoxelPlaneMap::showHidden()
{
  for (const int v : hidden_)
    voxels_[v].hidden = false;
  hidden_.clear();
}

/// Planes whose normal is steeper than this (about 45 deg from vertical) are level.
constexpr float kLevelNormalZ = 0.7f;

int
VoxelPlaneMap::hideSeenThrough(const VisibilityImage* image,
                               const Eigen::Isometry3f& T_world_lidar,
                               float radius_m,
                               float margin_m)
{
  showHidden();
  if (!image || image->empty())
    return 0;
  const Eigen::Isometry3f T_lidar_world = T_world_lidar.inverse();
  const Eigen::Vector3f origin = T_world_lidar.translation();
  const float radius_sq = radius_m * radius_m;
  for (std::size_t v = 0; v < voxels_.size(); ++v) {
    Voxel& voxel = voxels_[v];
    // Level planes (the ground, roofs) hold no motion along the road, and the image,
    // made without the ground, cannot tell where the ground stops a ray.
    if (!voxel.planar || std::abs(voxel.normal.z()) > kLevelNormalZ ||
        (voxel.centroid - origin).squaredNorm() > radius_sq)
      continue;
    if (image->seenPast(T_lidar_world * voxel.centroid, margin_m)) {
      voxel.hidden = true;
      hidden_.push_back(static_cast<int>(v));
    }
  }
  return static_cast<int>(hidden_.size());
}

inline int
VisibilityImage::cellOf(float x, float y, float z, float& range)
{
  constexpr float kPiF = 3.14159265f;
  const float xy_sq = x * x + y * y;
  const float xy = fast_math::fastSqrt(xy_sq);
  range = fast_math::fastSqrt(xy_sq + z * z);
  const float az = fast_math::fastAtan2(y, x);
  const float el_deg = fast_math::fastAtan2(z, xy) * (180.0f / kPiF);
  const int col = std::min(
      kCols - 1, std::max(0, static_cast<int>((az + kPiF) * (kCols / (2.0f * kPiF)))));
  const float row_f = (el_deg - kMinElevationDeg) / kRowDeg;
  const int row = static_cast<int>(row_f); // row_f < 0: rejected below
  // Without branches (bitwise & and a mask), so that the loop over points vectorizes.
  const bool valid = (range > 0.5f) & (row_f >= 0.0f) & (row < kRows);
  const int mask = -static_cast<int>(valid);
  return ((row * kCols + col) & mask) | ~mask;
}

VisibilityImage::VisibilityImage(const pcl::PointCloud<pcl::PointXYZI>& points)
    : range_(static_cast<std::size_t>(kRows) * kCols,
             std::numeric_limits<float>::infinity())
{
  // Blocks of coordinates copied out of the points, their cells computed in a loop
  // over local arrays that the compiler vectorizes (fast_math), then the minima.
  constexpr std::size_t kBlock = 256;
  float xs[kBlock], ys[kBlock], zs[kBlock], ranges[kBlock];
  int cells[kBlock];
  const std::size_t n = points.size();
  for (std::size_t i0 = 0; i0 < n; i0 += kBlock) {
    const std::size_t m = std::min(kBlock, n - i0);
    for (std::size_t k = 0; k < m; ++k) {
      xs[k] = points.points[i0 + k].x;
      ys[k] = points.points[i0 + k].y;
      zs[k] = points.points[i0 + k].z;
    }
    for (std::size_t k = 0; k < m; ++k)
      cells[k] = cellOf(xs[k], ys[k], zs[k], ranges[k]);
    for (std::size_t k = 0; k < m; ++k)
      if (cells[k] >= 0)
        range_[static_cast<std::size_t>(cells[k])] =
            std::min(range_[static_cast<std::size_t>(cells[k])], ranges[k]);
  }
}

bool
VisibilityImage::seenPast(const Eigen::Vector3f& p, float margin_m) const
{
  float range = 0.0f;
  const int cell = empty() ? -1 : cellOf(p.x(), p.y(), p.z(), range);
  if (cell < 0)
    return false;
  const int row = cell / kCols, col = cell % kCols;
  if (row == 0 || row == kRows - 1)
    return false;
  float nearest = std::numeric_limits<float>::infinity();
  for (int dr = -1; dr <= 1; ++dr)
    for (int dc = -1; dc <= 1; ++dc)
      nearest = std::min(nearest,
                         range_[static_cast<std::size_t>(row + dr) * kCols +
                                (col + dc + kCols) % kCols]);
  return std::isfinite(nearest) && nearest > range + margin_m;
}

int
VoxelPlaneMap::planarVoxel(std::int64_t x, std::int64_t y, std::int64_t z) const
{
  const int v = index_.find(packVoxelKey(x, y, z));
  return v >= 0 && voxels_[v].planar && !voxels_[v].hidden ? v : -1;
}

bool
VoxelPlaneMap::plane(const Eigen::Vector3f& query,
                     Eigen::Vector3f& centroid,
                     Eigen::Vector3f& normal) const
{
  PlaneLookup lookup;
  return plane(query, lookup, centroid, normal);
}

bool
VoxelPlaneMap::plane(const Eigen::Vector3f& query,
                     PlaneLookup& lookup,
                     Eigen::Vector3f& centroid,
                     Eigen::Vector3f& normal) const
{
  const auto x = static_cast<std::int64_t>(std::floor(query.x() * inv_voxel_size_));
  const auto y = static_cast<std::int64_t>(std::floor(query.y() * inv_voxel_size_));
  const auto z = static_cast<std::int64_t>(std::floor(query.z() * inv_voxel_size_));
  const VoxelKey key = packVoxelKey(x, y, z);
  if (lookup.key != key) {
    lookup = PlaneLookup();
    lookup.key = key;
    if (const int v = index_.find(key); v >= 0) {
      const Voxel& own = voxels_[v];
      if (own.hidden)
        return false; // what moved out of it must not pair through a neighbour either
      if (own.planar) {
        lookup.own = true;
        lookup.count = 1;
        lookup.voxels[0] = v;
      }
    }
    // The point may sit just off its surface's voxel: the face neighbours.
    static const int kFaces[6][3] = {
        {1, 0, 0}, {-1, 0, 0}, {0, 1, 0}, {0, -1, 0}, {0, 0, 1}, {0, 0, -1}};
    for (int f = 0; f < 6 && !lookup.own; ++f) {
      const int v = planarVoxel(x + kFaces[f][0], y + kFaces[f][1], z + kFaces[f][2]);
      if (v >= 0)
        lookup.voxels[lookup.count++] = v;
    }
  }
  if (lookup.count == 0)
    return false;
  int best = lookup.voxels[0];
  if (!lookup.own) {
    // The nearest centroid; the first of equals, in the faces' order.
    float best_sq = (voxels_[best].centroid - query).squaredNorm();
    for (int k = 1; k < lookup.count; ++k) {
      const float d_sq = (voxels_[lookup.voxels[k]].centroid - query).squaredNorm();
      if (d_sq < best_sq) {
        best_sq = d_sq;
        best = lookup.voxels[k];
      }
    }
  }
  centroid = voxels_[best].centroid;
  normal = voxels_[best].normal;
  return true;
}

// ---------------------------------------------------------------------------
// Point-to-plane Gauss-Newton

Eigen::Matrix<double, 6, 1>
denseTangent(const Eigen::Isometry3d& from, const Eigen::Isometry3d& to)
{
  return PointToPlaneSystem(kRotationLengthM).tangent(from, to);
}

double
denseSeparation(const DenseResult& dense, const Eigen::Isometry3d& other)
{
  const Eigen::Matrix<double, 6, 1> delta = denseTangent(dense.T_world_lidar, other);
  return std::sqrt(std::max(0.0, delta.dot(dense.information * delta)));
}

namespace {

/// The point-to-plane normal equations of \a source at (R, t) against \a map.
struct Linearisation
{
  PointToPlaneSystem system{kRotationLengthM};
  int paired = 0;  ///< points paired with a map plane
  int inliers = 0; ///< ... with |r| within 3 kernel scales
  double sum_sq = 0.0;
};

Linearisation
linearise(const Points3f& source,
          const VoxelPlaneMap& map,
          std::vector<VoxelPlaneMap::PlaneLookup>& lookups,
          const Eigen::Matrix3d& R,
          const Eigen::Vector3d& t,
          double scale_m,
          double max_distance_m,
          bool keep_rows)
{
  // r = n . (q - c), q = R p + t; perturbation about the sensor position:
  // R <- Exp(omega) R, t <- t + dt, so the lever of q is q - t.
  Linearisation l;
  l.system.keepRows(keep_rows);
  const Eigen::Matrix3f R_f = R.cast<float>();
  const Eigen::Vector3f t_f = t.cast<float>();
  Eigen::Vector3f c, n;
  for (std::size_t i = 0; i < source.size(); ++i) {
    const Eigen::Vector3f q = R_f * source[i] + t_f;
    if (!map.plane(q, lookups[i], c, n))
      continue;
    const double r = n.dot(q - c);
    if (std::abs(r) > max_distance_m)
      continue;
    ++l.paired;
    l.system.addPointToPlane((q - t_f).cast<double>(), n.cast<double>(), r,
                             robustWeight(RobustKernel::kGemanMcClure, r, scale_m));
    if (std::abs(r) <= 3.0 * scale_m) {
      l.sum_sq += r * r;
      ++l.inliers;
    }
  }
  return l;
}

/// The final checks of registerToMap on its result: a run-away correction fails.
void
finish(DenseResult& result,
       const Eigen::Isometry3d& T_world_lidar_guess,
       const DenseTrackingParams& params)
{
  const Eigen::Isometry3d correction =
      T_world_lidar_guess.inverse() * result.T_world_lidar;
  const double correction_m = correction.translation().norm();
  const double correction_deg =
      Eigen::AngleAxisd(correction.rotation()).angle() * 180.0 / M_PI;
  if (correction_m > params.max_correction_m ||
      correction_deg > params.max_correction_deg) {
    result.message = "dense: diverged, moved " + std::to_string(correction_m) + " m / " +
                     std::to_string(correction_deg) + " deg from its start";
    return;
  }
  result.success = true;
  result.message = "dense: " + std::to_string(result.iterations) + " iterations, " +
                   std::to_string(result.num_correspondences) + "/" +
                   std::to_string(result.num_source_points) + " paired, rmse " +
                   std::to_string(result.rmse_m) + " m" + ", weakest direction " +
                   std::to_string(result.weakest_ratio) + " of the weight" +
                   (result.least_support >= 0.0
                        ? ", least support " + std::to_string(result.least_support)
                        : std::string()) +
                   (result.degenerate_directions > 0
                        ? ", " + std::to_string(result.degenerate_directions) +
                              " degenerate direction(s) kept at the guess"
                        : std::string());
}

} // namespace

DenseResult
registerToMap(const Points3f& source,
              const VoxelPlaneMap& map,
              const Eigen::Isometry3d& T_world_lidar_guess,
              const DenseTrackingParams& params,
              const DenseOptions& options)
{
  using Vector6d = Eigen::Matrix<double, 6, 1>;
  DenseResult result;
  result.T_world_lidar = T_world_lidar_guess;
  result.num_source_points = static_cast<int>(source.size());
  if (map.empty() || source.empty()) {
    result.message = map.empty() ? "empty local map" : "no source points";
    return result;
  }

  Eigen::Matrix3d R = T_world_lidar_guess.rotation();
  Eigen::Vector3d t = T_world_lidar_guess.translation();
  const double max_scale_m = options.initial_kernel_scale_m > 0.0
                                 ? std::min(options.initial_kernel_scale_m,
                                            params.max_correspondence_distance_m / 3.0)
                                 : params.max_correspondence_distance_m / 3.0;
  // Each source point's last plane lookup, for the next iteration.
  std::vector<VoxelPlaneMap::PlaneLookup> lookups(source.size());
  for (int iteration = 0; iteration < params.max_iterations; ++iteration) {
    const double scale_m =
        std::max(params.min_kernel_scale_m, max_scale_m * std::pow(0.5, iteration));
    Linearisation l = linearise(source,
                                map,
                                lookups,
                                R,
                                t,
                                scale_m,
                                params.max_correspondence_distance_m,
                                params.degeneracy_min_support > 0.0);
    result.iterations = iteration + 1;
    result.num_correspondences = l.paired;
    result.rmse_m = l.inliers > 0 ? std::sqrt(l.sum_sq / l.inliers) : 0.0;
    if (l.paired < params.min_correspondences) {
      result.message = "dense: " + std::to_string(l.paired) +
                       " points paired with map planes < " +
                       std::to_string(params.min_correspondences);
      return result;
    }

    // Solve in H's eigenbasis, skipping (or anchoring) the degenerate directions.
    Eigen::Isometry3d T_now = Eigen::Isometry3d::Identity();
    T_now.linear() = R;
    T_now.translation() = t;
    Vector6d to_anchor = Vector6d::Zero();
    if (options.T_world_anchor) {
      to_anchor = l.system.tangent(T_now, *options.T_world_anchor);
      const bool within =
          to_anchor.tail<3>().norm() <= options.prior_within_m &&
          to_anchor.head<3>().norm() / kRotationLengthM * 180.0 / M_PI <=
              options.prior_within_deg;
      if (options.prior_ratio > 0.0 && within)
        l.system.setStepPrior(to_anchor, options.prior_ratio * l.system.sumWeights());
    }
    const PointToPlaneSystem::Step step = l.system.solveDegeneracyAware(
        params.degeneracy_min_ratio,
        options.T_world_anchor ? &to_anchor : nullptr,
        params.degeneracy_min_support,
        params.degeneracy_support_derivative);
    const Vector6d& dx = step.dx;
    result.degenerate_directions = step.degenerate_directions;
    result.weakest_ratio = step.weakest_ratio;
    result.least_support = step.least_support;
    result.information = step.information;
    if (!dx.allFinite()) {
      result.message = "dense: non-finite update";
      return result;
    }
    const Eigen::Vector3d omega = dx.head<3>() / kRotationLengthM;
    const double angle = omega.norm();
    if (angle > 1e-12)
      R = Eigen::AngleAxisd(angle, omega / angle).toRotationMatrix() * R;
    t += dx.tail<3>();
    R = Eigen::Quaterniond(R).normalized().toRotationMatrix();
    const bool annealed = scale_m <= params.min_kernel_scale_m;
    if (annealed && angle < params.convergence_rotation_rad &&
        dx.tail<3>().norm() < params.convergence_translation_m)
      break;
  }
  result.T_world_lidar.linear() = R;
  result.T_world_lidar.translation() = t;
  finish(result, T_world_lidar_guess, params);
  return result;
}

} // namespace odometry_detail
} // namespace rast
} // namespace pcl
