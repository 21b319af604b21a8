/// \file rigid_ransac.cpp
/// \brief RANSAC with a rigid model: 3-point samples, cheap pre-rejection (degenerate
/// triangles, pairwise distances not preserved), adaptive iteration count, MSAC score,
/// and an iterated least-squares re-estimate on the inliers.

#include <pcl/registration/rigid_ransac.h>
#include <pcl/registration/umeyama_estimation.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <random>
#include <stdexcept>

namespace pcl {
namespace rast {

bool
RigidRansacParams::isValid(std::string* why) const
{
  std::string reason;
  if (!(inlier_threshold_m > 0.0) || !std::isfinite(inlier_threshold_m))
    reason = "inlier_threshold_m must be finite and > 0, got " +
             std::to_string(inlier_threshold_m);
  else if (!(confidence > 0.0 && confidence < 1.0))
    reason = "confidence must be in (0, 1), got " + std::to_string(confidence);
  else if (max_iterations < 1)
    reason = "max_iterations must be >= 1, got " + std::to_string(max_iterations);
  else if (min_inliers < 3)
    reason = "min_inliers must be >= 3, got " + std::to_string(min_inliers);
  else if (!(min_sample_extent_m >= 0.0) || !std::isfinite(min_sample_extent_m))
    reason = "min_sample_extent_m must be finite and >= 0, got " +
             std::to_string(min_sample_extent_m);
  if (why)
    *why = reason;
  return reason.empty();
}

namespace {

/// Coincident or near-collinear triangle: a side or the smallest altitude is short.
bool
isDegenerateTriangle(const Eigen::Vector3d& a,
                     const Eigen::Vector3d& b,
                     const Eigen::Vector3d& c,
                     double min_extent_m)
{
  const double ab = (b - a).norm(), bc = (c - b).norm(), ca = (a - c).norm();
  const double longest = std::max({ab, bc, ca});
  if (std::min({ab, bc, ca}) < min_extent_m || longest <= 0.0)
    return true;
  const double twice_area = (b - a).cross(c - a).norm();
  return twice_area / longest < std::max(min_extent_m, 1e-9 * longest);
}

/// Inliers of T and their MSAC score sum(min(e^2, threshold^2)).
double
scoreModel(const Eigen::Matrix3Xd& source,
           const Eigen::Matrix3Xd& target,
           const Eigen::Isometry3d& T,
           double threshold_m,
           std::vector<int>* inliers)
{
  const double threshold_sq = threshold_m * threshold_m;
  const Eigen::Matrix3d R = T.linear();
  const Eigen::Vector3d t = T.translation();
  double score = 0.0;
  if (inliers)
    inliers->clear();
  for (Eigen::Index i = 0; i < source.cols(); ++i) {
    const double e_sq = (target.col(i) - R * source.col(i) - t).squaredNorm();
    if (e_sq < threshold_sq) {
      score += e_sq;
      if (inliers)
        inliers->push_back(static_cast<int>(i));
    }
    else
      score += threshold_sq;
  }
  return score;
}

Eigen::Matrix3Xd
gather(const Eigen::Matrix3Xd& points, const std::vector<int>& indices)
{
  Eigen::Matrix3Xd out(3, indices.size());
  for (std::size_t k = 0; k < indices.size(); ++k)
    out.col(k) = points.col(indices[k]);
  return out;
}

/// Number of samples needed so that one is all-inlier with the given confidence.
int
requiredIterations(double inlier_ratio, double confidence, int max_iterations)
{
  const double w3 = inlier_ratio * inlier_ratio * inlier_ratio;
  if (w3 >= 1.0)
    return 1;
  if (w3 <= 0.0)
    return max_iterations;
  const double n = std::log(1.0 - confidence) / std::log(1.0 - w3);
  return static_cast<int>(std::min<double>(std::ceil(n), max_iterations));
}

/// Three distinct correspondences drawn from \a rng, or false when a rigid motion
/// cannot map them: a degenerate triangle on either side, or a mutual distance that
/// changes by more than \a distance_tolerance_m (at least one is an outlier).
bool
drawSample(const Eigen::Matrix3Xd& source,
           const Eigen::Matrix3Xd& target,
           std::uniform_int_distribution<int>& pick,
           std::mt19937& rng,
           double min_extent_m,
           double distance_tolerance_m,
           Eigen::Matrix3Xd& sample_source,
           Eigen::Matrix3Xd& sample_target)
{
  int idx[3];
  idx[0] = pick(rng);
  do
    idx[1] = pick(rng);
  while (idx[1] == idx[0]);
  do
    idx[2] = pick(rng);
  while (idx[2] == idx[0] || idx[2] == idx[1]);
  for (int k = 0; k < 3; ++k) {
    sample_source.col(k) = source.col(idx[k]);
    sample_target.col(k) = target.col(idx[k]);
  }
  if (isDegenerateTriangle(sample_source.col(0), sample_source.col(1),
                           sample_source.col(2), min_extent_m) ||
      isDegenerateTriangle(sample_target.col(0), sample_target.col(1),
                           sample_target.col(2), min_extent_m))
    return false;
  for (int a = 0; a < 3; ++a) {
    const int b = (a + 1) % 3;
    const double d_source = (sample_source.col(a) - sample_source.col(b)).norm();
    const double d_target = (sample_target.col(a) - sample_target.col(b)).norm();
    if (std::abs(d_source - d_target) > distance_tolerance_m)
      return false;
  }
  return true;
}

/// Re-estimate \a T on all its inliers until the inlier set stops changing (or would
/// shrink); \a inliers ends as the final consensus.
Eigen::Isometry3d
reestimateOnInliers(const Eigen::Matrix3Xd& source,
                    const Eigen::Matrix3Xd& target,
                    Eigen::Isometry3d T,
                    double inlier_threshold_m,
                    std::vector<int>& inliers)
{
  scoreModel(source, target, T, inlier_threshold_m, &inliers);
  for (int round = 0; round < 10 && inliers.size() >= 3; ++round) {
    const Eigen::Matrix3Xd inlier_source = gather(source, inliers);
    const RigidTransformEstimate estimate =
        estimateRigidTransform(inlier_source, gather(target, inliers));
    std::vector<int> new_inliers;
    scoreModel(source, target, estimate.T_target_source, inlier_threshold_m, &new_inliers);
    if (new_inliers.size() < inliers.size())
      break; // keep the larger consensus
    T = estimate.T_target_source;
    const bool same = new_inliers == inliers;
    inliers.swap(new_inliers);
    if (same)
      break;
  }
  return T;
}

/// The final checks: enough inliers, not collinear; the summary otherwise.
void
checkConsensus(const Eigen::Matrix3Xd& inlier_source,
               int num_correspondences,
               const RigidRansacParams& params,
               RigidRansacResult& result)
{
  const std::size_t num_inliers = result.inlier_indices.size();
  if (static_cast<int>(num_inliers) < params.min_inliers) {
    result.message = "RANSAC failed: best model has " + std::to_string(num_inliers) +
                     " inliers < min_inliers " + std::to_string(params.min_inliers);
    return;
  }
  const double extent_m = secondaryExtent(inlier_source);
  if (extent_m < params.min_sample_extent_m) {
    result.degenerate = true;
    result.message = "RANSAC failed: inliers are nearly collinear (secondary extent " +
                     std::to_string(extent_m) + " m < " +
                     std::to_string(params.min_sample_extent_m) + " m)";
    return;
  }
  result.success = true;
  result.message = std::to_string(num_inliers) + "/" + std::to_string(num_correspondences) +
                   " inliers after " + std::to_string(result.iterations) + " samples";
}

} // namespace

RigidRansacResult
estimateRigidRansac(const Eigen::Matrix3Xd& source,
                    const Eigen::Matrix3Xd& target,
                    const RigidRansacParams& params)
{
  std::string why;
  if (!params.isValid(&why))
    throw std::invalid_argument("estimateRigidRansac: invalid params: " + why);
  if (source.cols() != target.cols())
    throw std::invalid_argument("estimateRigidRansac: " + std::to_string(source.cols()) +
                                " source points but " + std::to_string(target.cols()) +
                                " target points");
  RigidRansacResult result;
  const auto n = static_cast<int>(source.cols());
  if (n < params.min_inliers || n < 3) {
    result.message = "too few correspondences: " + std::to_string(n) + " < min_inliers " +
                     std::to_string(params.min_inliers);
    return result;
  }

  // Hypotheses from seeded 3-point samples, pre-rejected when a rigid motion cannot
  // map them; the best score wins, and the iteration count adapts to its inliers.
  std::mt19937 rng(params.seed);
  std::uniform_int_distribution<int> pick(0, n - 1);
  double best_score = std::numeric_limits<double>::infinity();
  Eigen::Isometry3d best_T = Eigen::Isometry3d::Identity();
  int best_inlier_count = 0;
  int needed = params.max_iterations;
  std::vector<int> inliers;
  Eigen::Matrix3Xd sample_source(3, 3), sample_target(3, 3);
  while (result.iterations < needed) {
    ++result.iterations;
    if (!drawSample(source, target, pick, rng, params.min_sample_extent_m,
                    2.0 * params.inlier_threshold_m, sample_source, sample_target)) {
      ++result.degenerate_samples;
      continue;
    }
    const Eigen::Isometry3d T = estimateRigidTransform(sample_source, sample_target).T_target_source;
    const double score = scoreModel(source, target, T, params.inlier_threshold_m, &inliers);
    if (score < best_score) {
      best_score = score;
      best_T = T;
      best_inlier_count = static_cast<int>(inliers.size());
      needed = std::max(result.iterations,
                        requiredIterations(static_cast<double>(best_inlier_count) / n,
                                           params.confidence, params.max_iterations));
    }
  }
  if (best_inlier_count == 0) {
    result.degenerate = result.degenerate_samples == result.iterations;
    result.message = result.degenerate
                         ? "RANSAC failed: all " + std::to_string(result.iterations) +
                               " samples were degenerate (coincident/collinear points or "
                               "distances not preserved)"
                         : "RANSAC failed: no model with inliers";
    return result;
  }

  const Eigen::Isometry3d T =
      reestimateOnInliers(source, target, best_T, params.inlier_threshold_m, inliers);
  result.T_target_source = T;
  result.inlier_indices = inliers;
  const Eigen::Matrix3Xd inlier_source = gather(source, inliers);
  const Eigen::Matrix3Xd residuals =
      gather(target, inliers) - ((T.linear() * inlier_source).colwise() + T.translation());
  result.inlier_rmse_m =
      inliers.empty() ? 0.0 : std::sqrt(residuals.colwise().squaredNorm().mean());
  checkConsensus(inlier_source, n, params, result);
  return result;
}

RigidRansacResult
estimateRigidRansac(const pcl::PointCloud<RasterFeaturePoint>& source,
                    const pcl::PointCloud<RasterFeaturePoint>& target,
                    const pcl::Correspondences& correspondences,
                    const RigidRansacParams& params)
{
  const auto n = static_cast<Eigen::Index>(correspondences.size());
  Eigen::Matrix3Xd source_points(3, n), target_points(3, n);
  for (Eigen::Index i = 0; i < n; ++i) {
    const pcl::Correspondence& c = correspondences[i];
    if (c.index_query < 0 || static_cast<std::size_t>(c.index_query) >= source.size() ||
        c.index_match < 0 || static_cast<std::size_t>(c.index_match) >= target.size())
      throw std::invalid_argument("estimateRigidRansac: correspondence " + std::to_string(i) +
                                  " (" + std::to_string(c.index_query) + " -> " +
                                  std::to_string(c.index_match) + ") is out of range");
    source_points.col(i) = source[c.index_query].getVector3fMap().cast<double>();
    target_points.col(i) = target[c.index_match].getVector3fMap().cast<double>();
  }
  return estimateRigidRansac(source_points, target_points, params);
}

RigidRansacRejector::RigidRansacRejector(const RigidRansacParams& params) { setParams(params); }

void
RigidRansacRejector::setParams(const RigidRansacParams& params)
{
  std::string why;
  if (!params.isValid(&why))
    throw std::invalid_argument("RigidRansacRejector::setParams: " + why);
  params_ = params;
}

RigidRansacResult
RigidRansacRejector::getRemainingCorrespondences(const pcl::Correspondences& original,
                                                 pcl::Correspondences& remaining) const
{
  if (!source_ || !target_)
    throw std::invalid_argument(
        std::string("RigidRansacRejector::getRemainingCorrespondences: no input ") +
        (source_ ? "target" : "source") + " cloud");
  RigidRansacResult result = estimateRigidRansac(*source_, *target_, original, params_);
  remaining.clear();
  if (result.success)
    for (const int i : result.inlier_indices)
      remaining.push_back(original[i]);
  return result;
}

} // namespace rast
} // namespace pcl
