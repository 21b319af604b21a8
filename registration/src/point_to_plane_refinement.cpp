/// \file point_to_plane_refinement.cpp
/// \brief Robust plane-to-plane / point-to-plane ICP (Gauss-Newton on SE(3), left
/// perturbation) against a target indexed once in a voxel hash map (no kd-tree).

#include <pcl/registration/point_to_plane_refinement.h>
#include <pcl/registration/voxel_hash_map.h>

#include <Eigen/Eigenvalues>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <stdexcept>

namespace pcl {
namespace rast {

bool
PointToPlaneParams::isValid(std::string* why) const
{
  auto finite_non_negative = [](double v) { return std::isfinite(v) && v >= 0.0; };
  auto finite_positive = [](double v) { return std::isfinite(v) && v > 0.0; };
  std::string reason;
  if (!finite_non_negative(source_voxel_size_m))
    reason = "source_voxel_size_m must be finite and >= 0, got " +
             std::to_string(source_voxel_size_m);
  else if (!finite_non_negative(target_voxel_size_m))
    reason = "target_voxel_size_m must be finite and >= 0, got " +
             std::to_string(target_voxel_size_m);
  else if (normal_neighbours < 3)
    reason = "normal_neighbours must be >= 3, got " + std::to_string(normal_neighbours);
  else if (!(max_surface_variation >= 0.0 && max_surface_variation <= 1.0 / 3.0))
    reason = "max_surface_variation must be in [0, 1/3], got " +
             std::to_string(max_surface_variation);
  else if (!finite_positive(max_correspondence_distance_m))
    reason = "max_correspondence_distance_m must be finite and > 0, got " +
             std::to_string(max_correspondence_distance_m);
  else if (!finite_non_negative(kernel_scale_m))
    reason = "kernel_scale_m must be finite and >= 0, got " + std::to_string(kernel_scale_m);
  else if (!finite_positive(min_kernel_scale_m))
    reason = "min_kernel_scale_m must be finite and > 0, got " +
             std::to_string(min_kernel_scale_m);
  else if (!(plane_covariance_epsilon > 0.0 && plane_covariance_epsilon <= 1.0))
    reason = "plane_covariance_epsilon must be in (0, 1], got " +
             std::to_string(plane_covariance_epsilon);
  else if (max_source_points < 0)
    reason = "max_source_points must be >= 0, got " + std::to_string(max_source_points);
  else if (max_iterations < 1)
    reason = "max_iterations must be >= 1, got " + std::to_string(max_iterations);
  else if (!finite_non_negative(convergence_translation_m))
    reason = "convergence_translation_m must be finite and >= 0, got " +
             std::to_string(convergence_translation_m);
  else if (!finite_non_negative(convergence_rotation_rad))
    reason = "convergence_rotation_rad must be finite and >= 0, got " +
             std::to_string(convergence_rotation_rad);
  else if (min_correspondences < 6)
    reason = "min_correspondences must be >= 6, got " + std::to_string(min_correspondences);
  else if (!(min_overlap_ratio > 0.0 && min_overlap_ratio <= 1.0))
    reason = "min_overlap_ratio must be in (0, 1], got " + std::to_string(min_overlap_ratio);
  else if (!finite_positive(max_correction_m))
    reason = "max_correction_m must be finite and > 0, got " + std::to_string(max_correction_m);
  else if (!finite_positive(max_correction_rad))
    reason = "max_correction_rad must be finite and > 0, got " +
             std::to_string(max_correction_rad);
  if (why)
    *why = reason;
  return reason.empty();
}

namespace {

void
checkParams(const PointToPlaneParams& params, const char* function)
{
  std::string why;
  if (!params.isValid(&why))
    throw std::invalid_argument(std::string(function) + ": invalid params: " + why);
}

/// Rotation of a small rotation vector (Rodrigues).
Eigen::Matrix3d
expRotation(const Eigen::Vector3d& omega)
{
  const double angle = omega.norm();
  if (angle < 1e-12)
    return Eigen::Matrix3d::Identity();
  return Eigen::AngleAxisd(angle, omega / angle).toRotationMatrix();
}

} // namespace

PointVector
voxelDownsample(const PointVector& points, double voxel_size_m)
{
  PointVector out;
  out.reserve(points.size());
  if (!(voxel_size_m > 0.0)) {
    for (const auto& p : points)
      if (p.allFinite())
        out.push_back(p);
    return out;
  }
  VoxelOccupancy occupancy(voxel_size_m, points.size() / 8);
  for (const auto& p : points)
    if (p.allFinite() && occupancy.insert(p))
      out.push_back(p);
  return out;
}

PointVector
toPointVector(const pcl::PointCloud<pcl::PointXYZI>& cloud)
{
  PointVector out;
  out.reserve(cloud.size());
  for (const auto& p : cloud.points)
    if (std::isfinite(p.x) && std::isfinite(p.y) && std::isfinite(p.z))
      out.emplace_back(p.x, p.y, p.z);
  return out;
}

namespace {

Eigen::Array3i
cellOf(const Eigen::Vector3d& p, double inverse_cell_m)
{
  return (p * inverse_cell_m).array().floor().cast<int>();
}

VoxelKey
keyOf(const Eigen::Array3i& cell)
{
  return packVoxelKey(cell.x(), cell.y(), cell.z());
}

/// Raw-point statistics of one voxel: count, sum and sum of outer products.
struct VoxelStats
{
  int count = 0;
  Eigen::Vector3d sum = Eigen::Vector3d::Zero();
  Eigen::Matrix3d sum_outer = Eigen::Matrix3d::Zero();
  Eigen::Array3i cell;
};

} // namespace

/// Voxel hash map over the planar points (KISS-ICP style): cell -> [begin, end) into a
/// cell-sorted index list; nearest neighbours are searched in the 27 cells around.
struct PointToPlaneTarget::Index
{
  double cell_m = 1.0;
  double inverse_cell_m = 1.0;
  VoxelHashMap cells;                     // cell -> slot in ranges
  std::vector<std::pair<int, int>> ranges; // [begin, end) in order
  std::vector<int> order;                  // point indices sorted by cell
  // Point coordinates in `order`, float for a compact, cache-friendly scan.
  std::vector<Eigen::Vector3f, Eigen::aligned_allocator<Eigen::Vector3f>> ordered_points;
};

PointToPlaneTarget::PointToPlaneTarget() = default;
PointToPlaneTarget::~PointToPlaneTarget() = default;
PointToPlaneTarget::PointToPlaneTarget(PointToPlaneTarget&&) noexcept = default;
PointToPlaneTarget&
PointToPlaneTarget::operator=(PointToPlaneTarget&&) noexcept = default;

void
PointToPlaneTarget::buildIndex(double cell_size_m)
{
  auto index = std::make_unique<Index>();
  index->cell_m = cell_size_m;
  index->inverse_cell_m = 1.0 / cell_size_m;
  const std::size_t n = points_.size();
  std::vector<VoxelKey> keys(n);
  for (std::size_t i = 0; i < n; ++i) {
    const Eigen::Array3i c = cellOf(points_[i], index->inverse_cell_m);
    keys[i] = keyOf(c);
  }
  index->order.resize(n);
  for (std::size_t i = 0; i < n; ++i)
    index->order[i] = static_cast<int>(i);
  std::sort(index->order.begin(), index->order.end(),
            [&keys](int a, int b) { return keys[a] < keys[b]; });
  index->cells.reset(n);
  index->ordered_points.resize(n);
  for (std::size_t k = 0; k < n; ++k) {
    const int i = index->order[k];
    index->ordered_points[k] = points_[i].cast<float>();
    if (k == 0 || keys[i] != keys[index->order[k - 1]]) {
      index->cells.insert(keys[i], static_cast<int>(index->ranges.size()));
      index->ranges.emplace_back(static_cast<int>(k), static_cast<int>(k));
    }
    index->ranges.back().second = static_cast<int>(k) + 1;
  }
  index_ = std::move(index);
}

void
PointToPlaneTarget::build(const PointVector& points, const PointToPlaneParams& params)
{
  build(points, params, 0);
}

void
PointToPlaneTarget::build(const PointVector& points,
                          const PointToPlaneParams& params,
                          std::size_t max_planes)
{
  checkParams(params, "PointToPlaneTarget::build");
  // 1. Voxel statistics of the raw points in one pass (no per-point neighbour search).
  const double voxel_m = params.target_voxel_size_m > 0.0 ? params.target_voxel_size_m : 0.3;
  const double inverse_voxel_m = 1.0 / voxel_m;
  VoxelHashMap voxel_of_cell;
  voxel_of_cell.reset(points.size() / 32);
  std::vector<VoxelStats> voxels;
  voxels.reserve(points.size() / 4 + 16);
  for (const auto& p : points) {
    if (!p.allFinite())
      continue;
    const Eigen::Array3i c = cellOf(p, inverse_voxel_m);
    const auto [v, inserted] =
        voxel_of_cell.insert(keyOf(c), static_cast<int>(voxels.size()));
    if (inserted) {
      voxels.emplace_back();
      voxels.back().cell = c;
    }
    VoxelStats& s = voxels[v];
    ++s.count;
    s.sum += p;
    s.sum_outer.noalias() += p * p.transpose();
  }
  const int k = params.normal_neighbours;
  if (static_cast<int>(voxels.size()) < 3)
    throw std::invalid_argument("PointToPlaneTarget::build: " + std::to_string(voxels.size()) +
                                " occupied voxels, need at least 3");

  // 2. Plane of each voxel: fitted to the raw points of its 3x3x3 voxel block (a
  // neighbourhood of ~1.5 voxels radius); normal = eigenvector of the smallest
  // eigenvalue of their covariance; keep voxels whose neighbourhood is planar.
  // A source needs at most max_planes planes: fit them on evenly spread voxels only.
  const std::size_t stride =
      max_planes > 0 ? std::max<std::size_t>(1, voxels.size() / (2 * max_planes)) : 1;
  PointVector planar_points, planar_normals;
  planar_points.reserve(voxels.size() / stride + 1);
  planar_normals.reserve(voxels.size() / stride + 1);
  for (std::size_t v = 0; v < voxels.size(); v += stride) {
    const VoxelStats& voxel = voxels[v];
    int count = 0;
    Eigen::Vector3d sum = Eigen::Vector3d::Zero();
    Eigen::Matrix3d sum_outer = Eigen::Matrix3d::Zero();
    // 3x3x3 block; 5x5x5 where that holds too few points (sparse, far surfaces).
    for (int radius = 1; radius <= 2 && count < k; ++radius) {
      count = 0;
      sum.setZero();
      sum_outer.setZero();
      for (int dx = -radius; dx <= radius; ++dx)
        for (int dy = -radius; dy <= radius; ++dy)
          for (int dz = -radius; dz <= radius; ++dz) {
            const int j = voxel_of_cell.find(
                packVoxelKey(voxel.cell.x() + dx, voxel.cell.y() + dy, voxel.cell.z() + dz));
            if (j < 0)
              continue;
            count += voxels[j].count;
            sum += voxels[j].sum;
            sum_outer += voxels[j].sum_outer;
          }
    }
    if (count < k)
      continue;
    // E[p p^T] - mean mean^T: in double, cancellation costs ~1e-12 m^2 at 100 m range.
    const Eigen::Vector3d mean = sum / count;
    const Eigen::Matrix3d covariance = sum_outer / count - mean * mean.transpose();
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig;
    eig.computeDirect(covariance); // closed form: ~10x faster than the iterative solver
    const Eigen::Vector3d lambda = eig.eigenvalues().cwiseMax(0.0); // ascending
    const double lambda_sum = lambda.sum();
    // Collinear neighbourhoods (one scan ring) have no defined normal: lambda_1 ~ 0.
    if (lambda_sum <= 0.0 || lambda(0) > params.max_surface_variation * lambda_sum ||
        lambda(1) < 1e-2 * lambda(2))
      continue;
    planar_points.push_back(voxel.sum / voxel.count);
    planar_normals.push_back(eig.eigenvectors().col(0).normalized());
  }
  if (planar_points.empty())
    throw std::invalid_argument("PointToPlaneTarget::build: no planar target point among " +
                                std::to_string(voxels.size()) + " voxels");
  points_ = std::move(planar_points);
  normals_ = std::move(planar_normals);
  buildIndex(std::max(voxel_m, 0.5 * params.max_correspondence_distance_m));
}

void
PointToPlaneTarget::build(const pcl::PointCloud<pcl::PointXYZI>& cloud,
                          const PointToPlaneParams& params)
{
  build(toPointVector(cloud), params);
}

void
PointToPlaneTarget::build(const pcl::PointCloud<pcl::PointNormal>& cloud_with_normals)
{
  PointVector points, normals;
  for (const auto& p : cloud_with_normals.points) {
    const Eigen::Vector3d point(p.x, p.y, p.z);
    const Eigen::Vector3d normal(p.normal_x, p.normal_y, p.normal_z);
    if (!point.allFinite() || !normal.allFinite() || normal.norm() < 1e-6)
      continue;
    points.push_back(point);
    normals.push_back(normal.normalized());
  }
  if (points.empty())
    throw std::invalid_argument("PointToPlaneTarget::build: none of the " +
                                std::to_string(cloud_with_normals.size()) +
                                " points has a finite, non-zero normal");
  points_ = std::move(points);
  normals_ = std::move(normals);
  buildIndex(0.5); // the default max_correspondence_distance_m / 2
}

bool
PointToPlaneTarget::nearest(const Eigen::Vector3d& query,
                            double max_distance_m,
                            Eigen::Vector3d& point,
                            Eigen::Vector3d& normal) const
{
  if (!index_ || points_.empty())
    return false;
  const Index& index = *index_;
  const Eigen::Vector3f q = query.cast<float>();
  const Eigen::Array3f scaled = q.array() * static_cast<float>(index.inverse_cell_m);
  const Eigen::Array3f floor = scaled.floor();
  const Eigen::Array3i cell = floor.cast<int>();
  // Squared distances to the lower and upper faces of the query's cell, per axis.
  const float cell_m = static_cast<float>(index.cell_m);
  const Eigen::Array3f to_lower = (scaled - floor) * cell_m;
  const Eigen::Array3f to_upper = cell_m - to_lower;
  float best_sq = static_cast<float>(max_distance_m * max_distance_m);
  int best = -1;
  // Own cell first, then the 26 neighbours, skipping any farther than the best so far.
  static constexpr int kOffsets[3] = {0, -1, 1};
  for (const int dx : kOffsets) {
    const float gx = dx < 0 ? to_lower.x() * to_lower.x() : dx > 0 ? to_upper.x() * to_upper.x() : 0.f;
    if (gx >= best_sq)
      continue;
    for (const int dy : kOffsets) {
      const float gy = gx + (dy < 0 ? to_lower.y() * to_lower.y()
                                    : dy > 0 ? to_upper.y() * to_upper.y() : 0.f);
      if (gy >= best_sq)
        continue;
      for (const int dz : kOffsets) {
        const float gz = gy + (dz < 0 ? to_lower.z() * to_lower.z()
                                      : dz > 0 ? to_upper.z() * to_upper.z() : 0.f);
        if (gz >= best_sq)
          continue;
        const int slot = index.cells.find(packVoxelKey(cell.x() + dx, cell.y() + dy, cell.z() + dz));
        if (slot < 0)
          continue;
        const auto [begin, end] = index.ranges[slot];
        for (int k = begin; k < end; ++k) {
          const float d_sq = (index.ordered_points[k] - q).squaredNorm();
          if (d_sq < best_sq) {
            best_sq = d_sq;
            best = k;
          }
        }
      }
    }
  }
  if (best < 0)
    return false;
  point = points_[index.order[best]];
  normal = normals_[index.order[best]];
  return true;
}

namespace {

using Vector6d = Eigen::Matrix<double, 6, 1>;

/// Gauss-Newton on SE(3) (left perturbation T <- Exp([omega, dt]) T) for both costs.
/// source_normals empty: point-to-plane whatever params.cost says.
PointToPlaneResult
refine(const PointVector& source_all,
       const PointVector& source_normals_all,
       const PointToPlaneTarget& target,
       const Eigen::Isometry3d& T_target_source_guess,
       const PointToPlaneParams& params)
{
  if (target.empty())
    throw std::invalid_argument("refinePointToPlane: the target is empty (call build first)");

  // Evenly spread subset of the source (scan order), at most max_source_points.
  PointVector source, source_normals;
  const bool with_normals = !source_normals_all.empty();
  const std::size_t n_all = source_all.size();
  const std::size_t n_max = params.max_source_points > 0
                                ? static_cast<std::size_t>(params.max_source_points)
                                : n_all;
  if (n_all > n_max) {
    source.reserve(n_max);
    for (std::size_t k = 0; k < n_max; ++k) {
      const std::size_t i = k * n_all / n_max;
      source.push_back(source_all[i]);
      if (with_normals)
        source_normals.push_back(source_normals_all[i]);
    }
  } else {
    source = source_all;
    source_normals = source_normals_all;
  }
  const bool plane_to_plane = with_normals && params.cost == RefinementCost::kPlaneToPlane;
  const double eps = params.plane_covariance_epsilon;

  PointToPlaneResult result;
  result.T_target_source = T_target_source_guess;
  result.num_source_points = static_cast<int>(source.size());
  const double max_scale_m = params.max_correspondence_distance_m / 3.0;

  Eigen::Isometry3d T = T_target_source_guess;
  struct Pair
  {
    Eigen::Vector3d p_target; // T p
    Eigen::Vector3d q, n_q;
    Eigen::Vector3d n_p; // R n_p (plane-to-plane)
    double r;            // n_q . (T p - q), metres
  };
  std::vector<Pair> pairs;
  pairs.reserve(source.size());
  std::vector<double> abs_residuals;
  Eigen::Vector3d q, n;

  for (int iteration = 0; iteration < params.max_iterations; ++iteration) {
    // Data association: nearest planar target point of each transformed source point.
    pairs.clear();
    for (std::size_t i = 0; i < source.size(); ++i) {
      const Eigen::Vector3d p_target = T * source[i];
      if (!target.nearest(p_target, params.max_correspondence_distance_m, q, n))
        continue;
      Pair pair{p_target, q, n, Eigen::Vector3d::Zero(), n.dot(p_target - q)};
      if (plane_to_plane)
        pair.n_p = T.linear() * source_normals[i];
      pairs.push_back(pair);
    }
    result.iterations = iteration + 1;
    result.num_correspondences = static_cast<int>(pairs.size());
    if (result.num_correspondences < params.min_correspondences) {
      result.message = "refinement failed: " + std::to_string(result.num_correspondences) +
                       " source points within " +
                       std::to_string(params.max_correspondence_distance_m) +
                       " m of the target < min_correspondences " +
                       std::to_string(params.min_correspondences);
      return result;
    }

    // Kernel scale: fixed, or a robust sigma (1.4826 MAD) of the current residuals.
    double scale_m = params.kernel_scale_m;
    if (scale_m <= 0.0) {
      abs_residuals.resize(pairs.size());
      std::transform(pairs.begin(), pairs.end(), abs_residuals.begin(),
                     [](const Pair& pair) { return std::abs(pair.r); });
      auto middle = abs_residuals.begin() + abs_residuals.size() / 2;
      std::nth_element(abs_residuals.begin(), middle, abs_residuals.end());
      // Graduated: start wide and halve each iteration, so that a dominant,
      // already-aligned ground plane (small median) cannot freeze the other axes.
      const double annealed_m = max_scale_m * std::pow(0.5, iteration);
      scale_m = std::clamp(std::max(1.4826 * *middle, annealed_m), params.min_kernel_scale_m,
                           std::max(max_scale_m, params.min_kernel_scale_m));
    }

    // Weighted normal equations H dx = -g, pivot at the target origin.
    PointToPlaneSystem system;
    double sum_sq = 0.0;
    int num_inliers = 0;
    for (const Pair& pair : pairs) {
      const double w = robustWeight(params.kernel, pair.r, scale_m);
      if (std::abs(pair.r) <= 3.0 * scale_m) {
        sum_sq += pair.r * pair.r;
        ++num_inliers;
      }
      if (w <= 0.0)
        continue;
      if (!plane_to_plane) {
        system.addPointToPlane(pair.p_target, pair.n_q, pair.r, w);
        continue;
      }
      // e = T p - q with information (C_q + R C_p R^T)^-1, C = I - (1 - eps) n n^T
      // (Segal et al. 2009, plane-to-plane); scaled by eps so that a point-to-plane pair
      // (n_p = n_q) weighs ~ 1 / 2 along the normal, as the point-to-plane cost's 1.
      const Eigen::Matrix3d C = 2.0 * Eigen::Matrix3d::Identity() -
                                (1.0 - eps) * (pair.n_q * pair.n_q.transpose() +
                                               pair.n_p * pair.n_p.transpose());
      system.addPlaneToPlane(pair.p_target, eps * C.inverse(), pair.p_target - pair.q, w);
    }
    result.rmse_m = num_inliers > 0 ? std::sqrt(sum_sq / num_inliers) : 0.0;
    Vector6d dx;
    if (!system.solve(dx)) {
      result.message = "refinement failed: singular normal equations or non-finite update "
                       "(degenerate geometry)";
      return result;
    }
    Eigen::Isometry3d update = Eigen::Isometry3d::Identity();
    update.linear() = expRotation(dx.head<3>());
    update.translation() = dx.tail<3>();
    T = update * T;
    T.linear() = Eigen::Quaterniond(T.rotation()).normalized().toRotationMatrix();
    if (dx.head<3>().norm() < params.convergence_rotation_rad &&
        dx.tail<3>().norm() < params.convergence_translation_m) {
      result.converged = true;
      break;
    }
  }

  result.T_target_source = T;
  // Divergence guards: little overlap left, or a run-away correction.
  const Eigen::Isometry3d correction = T_target_source_guess.inverse() * T;
  const double correction_m = correction.translation().norm();
  const double correction_rad = Eigen::AngleAxisd(correction.rotation()).angle();
  const double overlap =
      source.empty() ? 0.0
                     : static_cast<double>(result.num_correspondences) / source.size();
  if (overlap < params.min_overlap_ratio) {
    result.message = "refinement diverged: only " + std::to_string(overlap * 100.0) +
                     " % of the source points paired (< min_overlap_ratio)";
    return result;
  }
  if (correction_m > params.max_correction_m || correction_rad > params.max_correction_rad) {
    result.message = "refinement diverged: moved " + std::to_string(correction_m) + " m / " +
                     std::to_string(correction_rad * 180.0 / M_PI) +
                     " deg from the initial guess (> max_correction)";
    return result;
  }
  result.success = true;
  result.message = std::string(result.converged ? "converged" : "stopped at max_iterations") +
                   " after " + std::to_string(result.iterations) + " iterations, " +
                   std::to_string(result.num_correspondences) + "/" +
                   std::to_string(source.size()) + " points paired" +
                   (plane_to_plane ? " (plane-to-plane)" : " (point-to-plane)");
  return result;
}

} // namespace

PointToPlaneResult
refinePointToPlane(const PointVector& source,
                   const PointToPlaneTarget& target,
                   const Eigen::Isometry3d& T_target_source_guess,
                   const PointToPlaneParams& params)
{
  checkParams(params, "refinePointToPlane");
  return refine(source, PointVector(), target, T_target_source_guess, params);
}

PointToPlaneResult
refinePointToPlane(const PointToPlaneTarget& source,
                   const PointToPlaneTarget& target,
                   const Eigen::Isometry3d& T_target_source_guess,
                   const PointToPlaneParams& params)
{
  checkParams(params, "refinePointToPlane");
  return refine(source.points(), source.normals(), target, T_target_source_guess, params);
}

PointToPlaneTarget
prepareSource(const pcl::PointCloud<pcl::PointXYZI>& cloud, const PointToPlaneParams& params)
{
  PointToPlaneParams source_params = params;
  source_params.target_voxel_size_m = params.source_voxel_size_m;
  PointToPlaneTarget source;
  source.build(toPointVector(cloud), source_params,
               static_cast<std::size_t>(std::max(params.max_source_points, 0)));
  return source;
}

PointToPlaneResult
refinePointToPlane(const pcl::PointCloud<pcl::PointXYZI>& source,
                   const PointToPlaneTarget& target,
                   const Eigen::Isometry3d& T_target_source_guess,
                   const PointToPlaneParams& params)
{
  checkParams(params, "refinePointToPlane");
  PointToPlaneTarget prepared;
  try {
    prepared = prepareSource(source, params);
  } catch (const std::invalid_argument&) {
    // No planar source point: refine the voxelized points (point-to-plane).
    return refinePointToPlane(voxelDownsample(toPointVector(source), params.source_voxel_size_m),
                              target, T_target_source_guess, params);
  }
  return refinePointToPlane(prepared, target, T_target_source_guess, params);
}

} // namespace rast
} // namespace pcl
