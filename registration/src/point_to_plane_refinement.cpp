/// \file point_to_plane_refinement.cpp
/// \brief Robust point-to-plane ICP (Gauss-Newton on SE(3), left perturbation) with a
/// kd-tree target prepared once. The only TU of the module with PCL's kd-tree.

#include <pcl/registration/point_to_plane_refinement.h>

#include <pcl/kdtree/kdtree_flann.h>

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <stdexcept>
#include <unordered_set>

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

/// Robust weight w(r) of a residual r for kernel scale s.
double
robustWeight(RobustKernel kernel, double r, double s)
{
  const double a = std::abs(r);
  switch (kernel) {
  case RobustKernel::kNone:
    return 1.0;
  case RobustKernel::kHuber: { // usual tuning constant k = 1.345 sigma
    const double k = 1.345 * s;
    return a <= k ? 1.0 : k / a;
  }
  case RobustKernel::kTukey: { // usual tuning constant c = 4.685 sigma
    const double c = 4.685 * s;
    if (a >= c)
      return 0.0;
    const double u = 1.0 - (r / c) * (r / c);
    return u * u;
  }
  case RobustKernel::kGemanMcClure: {
    const double u = s * s / (s * s + r * r);
    return u * u;
  }
  }
  return 1.0;
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
  // 21 bits per axis: +-2^20 voxels, i.e. +-52 km at 5 cm voxels.
  auto key = [voxel_size_m](const Eigen::Vector3d& p) {
    std::uint64_t k = 0;
    for (int a = 0; a < 3; ++a) {
      const auto cell = static_cast<std::int64_t>(std::floor(p[a] / voxel_size_m));
      k = (k << 21) | (static_cast<std::uint64_t>(cell + (1 << 20)) & 0x1FFFFF);
    }
    return k;
  };
  std::unordered_set<std::uint64_t> occupied;
  occupied.reserve(points.size());
  for (const auto& p : points)
    if (p.allFinite() && occupied.insert(key(p)).second)
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

struct PointToPlaneTarget::Index
{
  pcl::KdTreeFLANN<pcl::PointXYZ> tree;
};

PointToPlaneTarget::PointToPlaneTarget() = default;
PointToPlaneTarget::~PointToPlaneTarget() = default;
PointToPlaneTarget::PointToPlaneTarget(PointToPlaneTarget&&) noexcept = default;
PointToPlaneTarget&
PointToPlaneTarget::operator=(PointToPlaneTarget&&) noexcept = default;

void
PointToPlaneTarget::buildIndex()
{
  auto cloud = std::make_shared<pcl::PointCloud<pcl::PointXYZ>>();
  cloud->resize(points_.size());
  for (std::size_t i = 0; i < points_.size(); ++i)
    (*cloud)[i].getVector3fMap() = points_[i].cast<float>();
  index_ = std::make_unique<Index>();
  index_->tree.setSortedResults(false);
  index_->tree.setInputCloud(cloud);
}

void
PointToPlaneTarget::build(const PointVector& points, const PointToPlaneParams& params)
{
  checkParams(params, "PointToPlaneTarget::build");
  PointVector voxels = voxelDownsample(points, params.target_voxel_size_m);
  const int k = params.normal_neighbours;
  if (static_cast<int>(voxels.size()) < k)
    throw std::invalid_argument("PointToPlaneTarget::build: " + std::to_string(voxels.size()) +
                                " target points after voxelization, need at least "
                                "normal_neighbours = " + std::to_string(k));
  const std::size_t num_voxels = voxels.size();
  points_ = std::move(voxels);
  normals_.clear();
  buildIndex();

  // Plane of each point's k nearest neighbours: normal = eigenvector of the smallest
  // eigenvalue of their covariance; keep points whose neighbourhood is planar.
  PointVector planar_points, planar_normals;
  planar_points.reserve(points_.size());
  planar_normals.reserve(points_.size());
  pcl::Indices neighbours(k);
  std::vector<float> distances_sq(k);
  pcl::PointXYZ query;
  for (const auto& p : points_) {
    query.getVector3fMap() = p.cast<float>();
    if (index_->tree.nearestKSearch(query, k, neighbours, distances_sq) < 3)
      continue;
    Eigen::Vector3d mean = Eigen::Vector3d::Zero();
    for (const auto j : neighbours)
      mean += points_[j];
    mean /= static_cast<double>(neighbours.size());
    Eigen::Matrix3d covariance = Eigen::Matrix3d::Zero();
    for (const auto j : neighbours) {
      const Eigen::Vector3d d = points_[j] - mean;
      covariance += d * d.transpose();
    }
    const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(covariance);
    const Eigen::Vector3d lambda = eig.eigenvalues().cwiseMax(0.0); // ascending
    const double sum = lambda.sum();
    // Collinear neighbourhoods (one scan ring) have no defined normal: lambda_1 ~ 0.
    if (sum <= 0.0 || lambda(0) > params.max_surface_variation * sum ||
        lambda(1) < 1e-2 * lambda(2))
      continue;
    planar_points.push_back(p);
    planar_normals.push_back(eig.eigenvectors().col(0).normalized());
  }
  points_ = std::move(planar_points);
  normals_ = std::move(planar_normals);
  if (points_.empty())
    throw std::invalid_argument("PointToPlaneTarget::build: no planar target point among " +
                                std::to_string(num_voxels) + " voxels");
  buildIndex();
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
  buildIndex();
}

bool
PointToPlaneTarget::nearest(const Eigen::Vector3d& query,
                            double max_distance_m,
                            Eigen::Vector3d& point,
                            Eigen::Vector3d& normal) const
{
  if (!index_ || points_.empty())
    return false;
  pcl::PointXYZ q;
  q.getVector3fMap() = query.cast<float>();
  pcl::Indices index(1);
  std::vector<float> distance_sq(1);
  if (index_->tree.nearestKSearch(q, 1, index, distance_sq) < 1 ||
      distance_sq[0] > max_distance_m * max_distance_m)
    return false;
  point = points_[index[0]];
  normal = normals_[index[0]];
  return true;
}

PointToPlaneResult
refinePointToPlane(const PointVector& source,
                   const PointToPlaneTarget& target,
                   const Eigen::Isometry3d& T_target_source_guess,
                   const PointToPlaneParams& params)
{
  checkParams(params, "refinePointToPlane");
  if (target.empty())
    throw std::invalid_argument("refinePointToPlane: the target is empty (call build first)");

  PointToPlaneResult result;
  result.T_target_source = T_target_source_guess;
  result.num_source_points = static_cast<int>(source.size());
  const double max_scale_m = params.max_correspondence_distance_m / 3.0;

  Eigen::Isometry3d T = T_target_source_guess;
  std::vector<double> residuals, abs_residuals;
  std::vector<Eigen::Matrix<double, 6, 1>, Eigen::aligned_allocator<Eigen::Matrix<double, 6, 1>>>
      jacobians;
  residuals.reserve(source.size());
  jacobians.reserve(source.size());
  Eigen::Vector3d q, n;

  for (int iteration = 0; iteration < params.max_iterations; ++iteration) {
    // Data association: nearest planar target point of each transformed source point.
    residuals.clear();
    jacobians.clear();
    for (const auto& p : source) {
      const Eigen::Vector3d p_target = T * p;
      if (!target.nearest(p_target, params.max_correspondence_distance_m, q, n))
        continue;
      // r = n . (T p - q); for T <- Exp([omega, dt]) T: dr/domega = (T p) x n, dr/ddt = n.
      Eigen::Matrix<double, 6, 1> J;
      J.head<3>() = p_target.cross(n);
      J.tail<3>() = n;
      residuals.push_back(n.dot(p_target - q));
      jacobians.push_back(J);
    }
    result.iterations = iteration + 1;
    result.num_correspondences = static_cast<int>(residuals.size());
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
      abs_residuals.resize(residuals.size());
      std::transform(residuals.begin(), residuals.end(), abs_residuals.begin(),
                     [](double r) { return std::abs(r); });
      auto middle = abs_residuals.begin() + abs_residuals.size() / 2;
      std::nth_element(abs_residuals.begin(), middle, abs_residuals.end());
      // Graduated: start wide and halve each iteration, so that a dominant,
      // already-aligned ground plane (small median) cannot freeze the other axes.
      const double annealed_m = max_scale_m * std::pow(0.5, iteration);
      scale_m = std::clamp(std::max(1.4826 * *middle, annealed_m), params.min_kernel_scale_m,
                           std::max(max_scale_m, params.min_kernel_scale_m));
    }

    // Weighted normal equations H dx = -b.
    Eigen::Matrix<double, 6, 6> H = Eigen::Matrix<double, 6, 6>::Zero();
    Eigen::Matrix<double, 6, 1> b = Eigen::Matrix<double, 6, 1>::Zero();
    double sum_sq = 0.0;
    int num_inliers = 0;
    for (std::size_t i = 0; i < residuals.size(); ++i) {
      const double w = robustWeight(params.kernel, residuals[i], scale_m);
      H.noalias() += w * jacobians[i] * jacobians[i].transpose();
      b.noalias() += w * residuals[i] * jacobians[i];
      if (std::abs(residuals[i]) <= 3.0 * scale_m) {
        sum_sq += residuals[i] * residuals[i];
        ++num_inliers;
      }
    }
    result.rmse_m = num_inliers > 0 ? std::sqrt(sum_sq / num_inliers) : 0.0;
    const Eigen::LDLT<Eigen::Matrix<double, 6, 6>> ldlt(H);
    if (ldlt.info() != Eigen::Success) {
      result.message = "refinement failed: singular normal equations";
      return result;
    }
    const Eigen::Matrix<double, 6, 1> dx = ldlt.solve(-b);
    if (!dx.allFinite()) {
      result.message = "refinement failed: non-finite update (degenerate geometry)";
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
                   std::to_string(source.size()) + " points paired";
  return result;
}

PointToPlaneResult
refinePointToPlane(const pcl::PointCloud<pcl::PointXYZI>& source,
                   const PointToPlaneTarget& target,
                   const Eigen::Isometry3d& T_target_source_guess,
                   const PointToPlaneParams& params)
{
  checkParams(params, "refinePointToPlane");
  return refinePointToPlane(voxelDownsample(toPointVector(source), params.source_voxel_size_m),
                            target, T_target_source_guess, params);
}

} // namespace rast
} // namespace pcl
