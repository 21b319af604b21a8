/// \file odometry_local_map.cpp
/// \brief The dense half of the odometry: voxel downsampling, the voxel-plane local map
/// and the point-to-plane Gauss-Newton against it (see odometry_local_map.h).

#include "odometry_local_map.h"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <limits>
#include <memory>

namespace pcl {
namespace rast {
namespace odometry_detail {

namespace {

/// Voxel coordinates packed in 21 bits per axis (+-2^20 voxels; wraps beyond, which
/// only merges far-apart voxels of a >1000 km map).
inline std::uint64_t
packKey(std::int64_t x, std::int64_t y, std::int64_t z)
{
  constexpr std::int64_t kOffset = 1 << 20;
  constexpr std::uint64_t kMask = 0x1FFFFF;
  return ((static_cast<std::uint64_t>(x + kOffset) & kMask) << 42) |
         ((static_cast<std::uint64_t>(y + kOffset) & kMask) << 21) |
         (static_cast<std::uint64_t>(z + kOffset) & kMask);
}

inline std::uint64_t
hashKey(std::uint64_t k)
{
  k ^= k >> 33;
  k *= 0xff51afd7ed558ccdULL;
  k ^= k >> 33;
  return k;
}

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
  const std::size_t n = cloud.size();
  // Linear probing with load factor <= 0.5, grown on demand (sized by the voxels,
  // not the points, so the table stays in cache); 0 marks an empty slot (packKey is
  // never 0 within +-2^20 voxels, and the range crop keeps points far inside that).
  std::vector<std::uint64_t> table(1 << 14, 0);
  std::size_t mask = table.size() - 1;
  auto insert = [&](std::uint64_t k) {
    std::size_t slot = hashKey(k) & mask;
    while (table[slot] != 0 && table[slot] != k)
      slot = (slot + 1) & mask;
    if (table[slot] == k)
      return false;
    table[slot] = k;
    return true;
  };
  // floor() via truncation of a positive biased value: several times cheaper.
  constexpr double kBias = 1 << 20;
  const double inv = 1.0 / voxel_size_m;
  auto cell = [&](float v) {
    return static_cast<std::int64_t>(v * inv + kBias) - static_cast<std::int64_t>(kBias);
  };
  out.reserve(n / 8);
  // Consecutive scan points often share a voxel: skip the probe for a repeated key
  // (already in the table). 0 is never a key, so the first point always probes.
  std::uint64_t last_key = 0;
  for (std::size_t i = 0; i < n; ++i) {
    const auto& p = cloud.points[i];
    if (!filter(p))
      continue;
    const std::uint64_t k = packKey(cell(p.x), cell(p.y), cell(p.z));
    if (k == last_key)
      continue;
    last_key = k;
    if (!insert(k))
      continue;
    out.push_back(static_cast<int>(i));
    if (2 * out.size() > table.size()) { // grow and rehash
      std::vector<std::uint64_t> old(table.size() * 2, 0);
      old.swap(table);
      mask = table.size() - 1;
      for (const std::uint64_t k : old)
        if (k != 0)
          insert(k);
    }
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

std::uint64_t
VoxelPlaneMap::key(std::int64_t x, std::int64_t y, std::int64_t z)
{
  return packKey(x, y, z);
}

std::uint64_t
VoxelPlaneMap::key(const Eigen::Vector3f& p) const
{
  return packKey(static_cast<std::int64_t>(std::floor(p.x() * inv_voxel_size_)),
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
  std::vector<Voxel*> touched;
  for (const auto& p : points_world) {
    Voxel& voxel = voxels_[key(p)];
    if (voxel.points.size() >= max_points)
      continue;
    if (voxel.points.empty())
      voxel.points.reserve(max_points);
    voxel.points.push_back(p);
    touched.push_back(&voxel);
  }
  std::sort(touched.begin(), touched.end());
  touched.erase(std::unique(touched.begin(), touched.end()), touched.end());
  for (Voxel* voxel : touched)
    fitPlane(*voxel);

  // Keep the map local: drop voxels far from the newest key-frame.
  const float radius_sq = static_cast<float>(params_.map_radius_m * params_.map_radius_m);
  for (auto it = voxels_.begin(); it != voxels_.end();) {
    if ((it->second.points.front() - center).squaredNorm() > radius_sq)
      it = voxels_.erase(it);
    else
      ++it;
  }
}

bool
VoxelPlaneMap::plane(const Eigen::Vector3f& query,
                     Eigen::Vector3f& centroid,
                     Eigen::Vector3f& normal) const
{
  const auto x = static_cast<std::int64_t>(std::floor(query.x() * inv_voxel_size_));
  const auto y = static_cast<std::int64_t>(std::floor(query.y() * inv_voxel_size_));
  const auto z = static_cast<std::int64_t>(std::floor(query.z() * inv_voxel_size_));
  auto it = voxels_.find(key(x, y, z));
  if (it != voxels_.end() && it->second.planar) {
    centroid = it->second.centroid;
    normal = it->second.normal;
    return true;
  }
  // The point may sit just off its surface's voxel: try the face neighbours.
  static const int kFaces[6][3] = {
      {1, 0, 0}, {-1, 0, 0}, {0, 1, 0}, {0, -1, 0}, {0, 0, 1}, {0, 0, -1}};
  float best_sq = std::numeric_limits<float>::max();
  for (const auto& f : kFaces) {
    it = voxels_.find(key(x + f[0], y + f[1], z + f[2]));
    if (it == voxels_.end() || !it->second.planar)
      continue;
    const float d_sq = (it->second.centroid - query).squaredNorm();
    if (d_sq < best_sq) {
      best_sq = d_sq;
      centroid = it->second.centroid;
      normal = it->second.normal;
    }
  }
  return best_sq < std::numeric_limits<float>::max();
}

// ---------------------------------------------------------------------------
// Point-to-plane Gauss-Newton

Eigen::Matrix<double, 6, 1>
denseTangent(const Eigen::Isometry3d& from, const Eigen::Isometry3d& to)
{
  const Eigen::AngleAxisd aa(to.rotation() * from.rotation().transpose());
  Eigen::Matrix<double, 6, 1> delta;
  delta.head<3>() = aa.angle() * aa.axis() * kRotationLengthM;
  delta.tail<3>() = to.translation() - from.translation();
  return delta;
}

double
denseSeparation(const DenseResult& dense, const Eigen::Isometry3d& other)
{
  const Eigen::Matrix<double, 6, 1> delta = denseTangent(dense.T_world_lidar, other);
  return std::sqrt(std::max(0.0, delta.dot(dense.information * delta)));
}

DenseResult
registerToMap(const Points3f& source,
              const VoxelPlaneMap& map,
              const Eigen::Isometry3d& T_world_lidar_guess,
              const DenseTrackingParams& params,
              const DenseOptions& options)
{
  using Vector6d = Eigen::Matrix<double, 6, 1>;
  using Matrix6d = Eigen::Matrix<double, 6, 6>;
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
  Eigen::Vector3f c, n;
  for (int iteration = 0; iteration < params.max_iterations; ++iteration) {
    const double scale_m =
        std::max(params.min_kernel_scale_m, max_scale_m * std::pow(0.5, iteration));
    const double scale_sq = scale_m * scale_m;
    const Eigen::Matrix3f R_f = R.cast<float>();
    const Eigen::Vector3f t_f = t.cast<float>();

    // Linearise r = n . (q - c), q = R p + t; perturbation about the sensor position:
    // R <- Exp(omega) R, t <- t + dt, so dr/domega = (q - t) x n, dr/ddt = n.
    Matrix6d H = Matrix6d::Zero();
    Vector6d g = Vector6d::Zero();
    double sum_w = 0.0, sum_sq = 0.0;
    int paired = 0, inliers = 0;
    for (const auto& p : source) {
      const Eigen::Vector3f q = R_f * p + t_f;
      if (!map.plane(q, c, n))
        continue;
      const double r = n.dot(q - c);
      if (std::abs(r) > params.max_correspondence_distance_m)
        continue;
      ++paired;
      const double u = scale_sq / (scale_sq + r * r); // Geman-McClure: w = u^2
      const double w = u * u;
      Vector6d J;
      J.head<3>() = (q - t_f).cast<double>().cross(n.cast<double>()) / kRotationLengthM;
      J.tail<3>() = n.cast<double>();
      H.noalias() += w * J * J.transpose();
      g.noalias() += w * r * J;
      sum_w += w;
      if (std::abs(r) <= 3.0 * scale_m) {
        sum_sq += r * r;
        ++inliers;
      }
    }
    result.iterations = iteration + 1;
    result.num_correspondences = paired;
    result.rmse_m = inliers > 0 ? std::sqrt(sum_sq / inliers) : 0.0;
    if (paired < params.min_correspondences) {
      result.message = "dense: " + std::to_string(paired) +
                       " points paired with map planes < " +
                       std::to_string(params.min_correspondences);
      return result;
    }

    // Solve H dx = -g in H's eigenbasis, skipping the degenerate directions.
    const Eigen::SelfAdjointEigenSolver<Matrix6d> eig(H);
    const double threshold = params.degeneracy_min_ratio * sum_w;
    Vector6d dx = Vector6d::Zero();
    int degenerate = 0;
    for (int k = 0; k < 6; ++k) {
      const double lambda = eig.eigenvalues()(k);
      if (!(lambda > threshold)) {
        ++degenerate;
        continue;
      }
      const Vector6d v = eig.eigenvectors().col(k);
      dx -= v * (v.dot(g) / lambda);
    }
    if (degenerate > 0 && options.T_world_anchor) {
      // The degenerate directions move to the anchor's value.
      Eigen::Isometry3d T_now = Eigen::Isometry3d::Identity();
      T_now.linear() = R;
      T_now.translation() = t;
      const Vector6d to_anchor = denseTangent(T_now, *options.T_world_anchor);
      for (int k = 0; k < 6; ++k)
        if (!(eig.eigenvalues()(k) > threshold)) {
          const Vector6d v = eig.eigenvectors().col(k);
          dx += v * v.dot(to_anchor);
        }
    }
    result.degenerate_directions = degenerate;
    result.weakest_ratio = sum_w > 0.0 ? eig.eigenvalues()(0) / sum_w : 0.0;
    result.information = sum_w > 0.0 ? Matrix6d(H / sum_w) : Matrix6d::Zero();
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
  const Eigen::Isometry3d correction =
      T_world_lidar_guess.inverse() * result.T_world_lidar;
  const double correction_m = correction.translation().norm();
  const double correction_deg =
      Eigen::AngleAxisd(correction.rotation()).angle() * 180.0 / M_PI;
  if (correction_m > params.max_correction_m ||
      correction_deg > params.max_correction_deg) {
    result.message = "dense: diverged, moved " + std::to_string(correction_m) + " m / " +
                     std::to_string(correction_deg) + " deg from its start";
    return result;
  }
  result.success = true;
  result.message = "dense: " + std::to_string(result.iterations) + " iterations, " +
                   std::to_string(result.num_correspondences) + "/" +
                   std::to_string(result.num_source_points) + " paired, rmse " +
                   std::to_string(result.rmse_m) + " m" + ", weakest direction " +
                   std::to_string(result.weakest_ratio) + " of the weight" +
                   (result.degenerate_directions > 0
                        ? ", " + std::to_string(result.degenerate_directions) +
                              " degenerate direction(s) kept at the guess"
                        : std::string());
  return result;
}

} // namespace odometry_detail
} // namespace rast
} // namespace pcl
