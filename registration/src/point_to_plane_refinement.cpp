/// \file point_to_plane_refinement.cpp
/// \brief Robust plane-to-plane / point-to-plane ICP (Gauss-Newton on SE(3), left
/// perturbation) against a PointToPlaneTarget (point_to_plane_target.cpp).

#include <pcl/registration/point_to_plane_refinement.h>
#include <pcl/registration/voxel_hash_map.h>

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
  else if (threads < 1 || threads > 2)
    reason = "threads must be 1 or 2, got " + std::to_string(threads);
  else if (!(degeneracy_min_ratio >= 0.0 && degeneracy_min_ratio < 1.0))
    reason = "degeneracy_min_ratio must be in [0, 1), got " +
             std::to_string(degeneracy_min_ratio);
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

using Vector6d = Eigen::Matrix<double, 6, 1>;

/// A source point paired with its nearest planar target point.
struct Pair
{
  Eigen::Vector3d p_target; // T p
  Eigen::Vector3d q, n_q;
  Eigen::Vector3d n_p; // R n_p (plane-to-plane)
  double r;            // n_q . (T p - q), metres
};

/// At most params.max_source_points of the source, evenly spread (scan order), with
/// their normals when given.
void
subsampleSource(const PointVector& source_all,
                const PointVector& source_normals_all,
                const PointToPlaneParams& params,
                PointVector& source,
                PointVector& source_normals)
{
  const bool with_normals = !source_normals_all.empty();
  const std::size_t n_all = source_all.size();
  const std::size_t n_max = params.max_source_points > 0
                                ? static_cast<std::size_t>(params.max_source_points)
                                : n_all;
  if (n_all <= n_max) {
    source = source_all;
    source_normals = source_normals_all;
    return;
  }
  source.reserve(n_max);
  for (std::size_t k = 0; k < n_max; ++k) {
    const std::size_t i = k * n_all / n_max;
    source.push_back(source_all[i]);
    if (with_normals)
      source_normals.push_back(source_normals_all[i]);
  }
}

/// Data association: the nearest planar target point of each transformed source point.
void
associate(const PointVector& source,
          const PointVector& source_normals,
          bool plane_to_plane,
          const PointToPlaneTarget& target,
          const Eigen::Isometry3d& T,
          double max_distance_m,
          std::vector<PointToPlaneTarget::CellLookup>& lookups,
          std::vector<Pair>& pairs)
{
  pairs.clear();
  lookups.resize(source.size());
  Eigen::Vector3d q, n;
  for (std::size_t i = 0; i < source.size(); ++i) {
    const Eigen::Vector3d p_target = T * source[i];
    if (!target.nearest(p_target, max_distance_m, q, n, lookups[i]))
      continue;
    Pair pair{p_target, q, n, Eigen::Vector3d::Zero(), n.dot(p_target - q)};
    if (plane_to_plane)
      pair.n_p = T.linear() * source_normals[i];
    pairs.push_back(pair);
  }
}

/// Kernel scale of an iteration: fixed, or a robust sigma (1.4826 MAD) of the current
/// residuals, graduated: it starts wide and halves each iteration, so that a dominant,
/// already-aligned ground plane (small median) cannot freeze the other axes.
double
kernelScale(const std::vector<Pair>& pairs,
            int iteration,
            const PointToPlaneParams& params,
            std::vector<double>& abs_residuals)
{
  if (params.kernel_scale_m > 0.0)
    return params.kernel_scale_m;
  const double max_scale_m = params.max_correspondence_distance_m / 3.0;
  abs_residuals.resize(pairs.size());
  std::transform(pairs.begin(), pairs.end(), abs_residuals.begin(),
                 [](const Pair& pair) { return std::abs(pair.r); });
  auto middle = abs_residuals.begin() + abs_residuals.size() / 2;
  std::nth_element(abs_residuals.begin(), middle, abs_residuals.end());
  const double annealed_m = max_scale_m * std::pow(0.5, iteration);
  return std::clamp(std::max(1.4826 * *middle, annealed_m), params.min_kernel_scale_m,
                    std::max(max_scale_m, params.min_kernel_scale_m));
}

/// The weighted normal equations of \a pairs; \a rmse_m over the pairs within 3 scales.
PointToPlaneSystem
normalEquations(const std::vector<Pair>& pairs,
                bool plane_to_plane,
                double scale_m,
                const PointToPlaneParams& params,
                double& rmse_m)
{
  const double eps = params.plane_covariance_epsilon;
  // Pivot at the target origin.
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
  rmse_m = num_inliers > 0 ? std::sqrt(sum_sq / num_inliers) : 0.0;
  return system;
}

/// Failure when little overlap is left or the correction ran away; else the summary.
void
checkResult(PointToPlaneResult& result,
            const Eigen::Isometry3d& T_target_source_guess,
            std::size_t num_source,
            bool plane_to_plane,
            const PointToPlaneParams& params)
{
  const Eigen::Isometry3d& T = result.T_target_source;
  const Eigen::Isometry3d correction = T_target_source_guess.inverse() * T;
  const double correction_m = correction.translation().norm();
  const double correction_rad = Eigen::AngleAxisd(correction.rotation()).angle();
  const double overlap =
      num_source == 0 ? 0.0
                     : static_cast<double>(result.num_correspondences) / num_source;
  if (overlap < params.min_overlap_ratio) {
    result.message = "refinement diverged: only " + std::to_string(overlap * 100.0) +
                     " % of the source points paired (< min_overlap_ratio)";
    return;
  }
  if (correction_m > params.max_correction_m || correction_rad > params.max_correction_rad) {
    result.message = "refinement diverged: moved " + std::to_string(correction_m) + " m / " +
                     std::to_string(correction_rad * 180.0 / M_PI) +
                     " deg from the initial guess (> max_correction)";
    return;
  }
  result.success = true;
  result.message = std::string(result.converged ? "converged" : "stopped at max_iterations") +
                   " after " + std::to_string(result.iterations) + " iterations, " +
                   std::to_string(result.num_correspondences) + "/" +
                   std::to_string(num_source) + " points paired" +
                   (plane_to_plane ? " (plane-to-plane)" : " (point-to-plane)");
}

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
  PointVector source, source_normals;
  subsampleSource(source_all, source_normals_all, params, source, source_normals);
  const bool plane_to_plane =
      !source_normals_all.empty() && params.cost == RefinementCost::kPlaneToPlane;

  PointToPlaneResult result;
  result.T_target_source = T_target_source_guess;
  result.num_source_points = static_cast<int>(source.size());
  Eigen::Isometry3d T = T_target_source_guess;
  std::vector<Pair> pairs;
  pairs.reserve(source.size());
  // Each source point's cells, kept between iterations (the same pairs, fewer look-ups).
  std::vector<PointToPlaneTarget::CellLookup> lookups;
  std::vector<double> abs_residuals;
  for (int iteration = 0; iteration < params.max_iterations; ++iteration) {
    associate(source,
              source_normals,
              plane_to_plane,
              target,
              T,
              params.max_correspondence_distance_m,
              lookups,
              pairs);
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
    const double scale_m = kernelScale(pairs, iteration, params, abs_residuals);
    const PointToPlaneSystem system =
        normalEquations(pairs, plane_to_plane, scale_m, params, result.rmse_m);
    Vector6d dx;
    if (params.degeneracy_min_ratio > 0.0) {
      const PointToPlaneSystem::Step step =
          system.solveDegeneracyAware(params.degeneracy_min_ratio);
      result.degenerate_directions = step.degenerate_directions;
      result.weakest_ratio = step.weakest_ratio;
      dx = step.dx;
    }
    if (params.degeneracy_min_ratio <= 0.0 || result.degenerate_directions == 0) {
      // Every direction constrained: the plain step, as without the option.
      if (!system.solve(dx)) {
        result.message = "refinement failed: singular normal equations or non-finite "
                         "update (degenerate geometry)";
        return result;
      }
    } else if (!dx.allFinite()) {
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
  checkResult(result, T_target_source_guess, source.size(), plane_to_plane, params);
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
  source.build(toPointVector(cloud),
               source_params,
               static_cast<std::size_t>(std::max(params.max_source_points, 0)),
               PointToPlaneTarget::Times());
  return source;
}

PointToPlaneTarget
prepareSource(const pcl::PointCloud<pcl::PointXYZI>& cloud,
              const std::vector<float>& times_s,
              const PointToPlaneParams& params,
              std::vector<float>& prepared_times_s)
{
  if (times_s.size() != cloud.size())
    throw std::invalid_argument("prepareSource: " + std::to_string(times_s.size()) +
                                " times for " + std::to_string(cloud.size()) + " points");
  // The finite points and their times, as toPointVector() keeps them.
  PointVector points;
  std::vector<float> times;
  points.reserve(cloud.size());
  times.reserve(cloud.size());
  for (std::size_t i = 0; i < cloud.size(); ++i) {
    const auto& p = cloud.points[i];
    if (std::isfinite(p.x) && std::isfinite(p.y) && std::isfinite(p.z)) {
      points.emplace_back(p.x, p.y, p.z);
      times.push_back(times_s[i]);
    }
  }
  PointToPlaneParams source_params = params;
  source_params.target_voxel_size_m = params.source_voxel_size_m;
  PointToPlaneTarget::Times with_times;
  with_times.in = &times;
  with_times.out = &prepared_times_s;
  PointToPlaneTarget source;
  source.build(points,
               source_params,
               static_cast<std::size_t>(std::max(params.max_source_points, 0)),
               with_times);
  return source;
}

PointToPlaneResult
refinePointToPlane(const PointVector& source,
                   const PointVector& source_normals,
                   const PointToPlaneTarget& target,
                   const Eigen::Isometry3d& T_target_source_guess,
                   const PointToPlaneParams& params)
{
  checkParams(params, "refinePointToPlane");
  if (source_normals.size() != source.size())
    throw std::invalid_argument(
        "refinePointToPlane: " + std::to_string(source_normals.size()) + " normals for " +
        std::to_string(source.size()) + " points");
  return refine(source, source_normals, target, T_target_source_guess, params);
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
