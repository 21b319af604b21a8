/// \file loop_verifier.cpp
/// \brief LoopDetector's verification of one (query, candidate) pair, in named steps:
/// ratio-test matching and seeded RANSAC (firstEstimate), guided matching
/// (guidedEstimate), inlier spread, a unique hypothesis, consistency with odometry,
/// self-similarity, the dense point-to-plane check and the final refinement.

#include "stage_util.h"

#include <pcl/slam/loop_detector.h>

#include <Eigen/Eigenvalues>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <set>
#include <stdexcept>
#include <utility>

namespace pcl {
namespace rast {

namespace {

using slam_detail::kDegPerRad;
using slam_detail::rotationDeg;

std::string
format(const char* fmt, double a, double b = 0.0, double c = 0.0, double d = 0.0)
{
  char buffer[256];
  std::snprintf(buffer, sizeof(buffer), fmt, a, b, c, d);
  return buffer;
}

/// Cells occupied by the inliers' x-y positions and their smaller principal std.
void
inlierSpread(const pcl::PointCloud<RasterFeaturePoint>& points,
             const pcl::Correspondences& matches,
             const std::vector<int>& inliers,
             double cell_size_m,
             int& cells,
             double& spread_m)
{
  std::set<std::pair<long, long>> occupied;
  Eigen::Vector2d mean = Eigen::Vector2d::Zero();
  for (const int k : inliers) {
    const auto& p = points[matches[k].index_query];
    occupied.emplace(static_cast<long>(std::floor(p.x / cell_size_m)),
                     static_cast<long>(std::floor(p.y / cell_size_m)));
    mean += Eigen::Vector2d(p.x, p.y);
  }
  cells = static_cast<int>(occupied.size());
  spread_m = 0.0;
  if (inliers.size() < 2)
    return;
  mean /= static_cast<double>(inliers.size());
  Eigen::Matrix2d cov = Eigen::Matrix2d::Zero();
  for (const int k : inliers) {
    const auto& p = points[matches[k].index_query];
    const Eigen::Vector2d d = Eigen::Vector2d(p.x, p.y) - mean;
    cov += d * d.transpose();
  }
  cov /= static_cast<double>(inliers.size());
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d> eig(cov);
  spread_m = std::sqrt(std::max(0.0, eig.eigenvalues()(0)));
}

/// The best rigid motion mapping a feature set onto itself elsewhere (each feature
/// paired with its nearest descriptor more than \a min_shift_m away): in a street of
/// equal blocks, the block period. Returns its inlier count and shift length.
int
selfSimilarity(const RasterFeatureSet& f,
               const RigidRansacParams& ransac_params,
               int max_hamming,
               double min_shift_m,
               double& shift_m)
{
  shift_m = 0.0;
  const std::size_t n = f.size();
  pcl::Correspondences pairs;
  const float min_sq = static_cast<float>(min_shift_m * min_shift_m);
  constexpr int kPerFeature = 3;         // a repeated feature has copies on both sides
  std::vector<std::pair<int, int>> best; // (distance, j)
  for (std::size_t i = 0; i < n; ++i) {
    best.clear();
    const Eigen::Vector3f pi = f.points[i].getVector3fMap();
    for (std::size_t j = 0; j < n; ++j) {
      if ((f.points[j].getVector3fMap() - pi).squaredNorm() < min_sq)
        continue;
      const int d = hammingDistance(f.descriptors[i], f.descriptors[j]);
      if (d <= max_hamming)
        best.emplace_back(d, static_cast<int>(j));
    }
    const auto keep = std::min<std::size_t>(kPerFeature, best.size());
    std::partial_sort(best.begin(), best.begin() + keep, best.end());
    for (std::size_t k = 0; k < keep; ++k)
      pairs.emplace_back(
          static_cast<int>(i), best[k].second, static_cast<float>(best[k].first));
  }
  if (static_cast<int>(pairs.size()) < ransac_params.min_inliers)
    return 0;
  const RigidRansacResult r =
      estimateRigidRansac(f.points, f.points, pairs, ransac_params);
  if (!r.success || r.T_target_source.translation().norm() < min_shift_m)
    return 0;
  shift_m = r.T_target_source.translation().norm();
  return static_cast<int>(r.inlier_indices.size());
}

/// Steps 1-3 of a verification: the matches and the first RANSAC estimate.
struct FirstEstimate
{
  pcl::Correspondences matches;
  RigidRansacResult ransac;
  RigidRansacParams ransac_params; ///< params_.ransac with min_initial_inliers
};

/// Step 4: the guided matches and their RANSAC.
struct GuidedEstimate
{
  pcl::Correspondences matches;
  RigidRansacResult ransac;
};

/// The nearest-descriptor matches whose ORB rotation lies in the best window of three
/// rotation bins, then RANSAC (LoopDetectorParams::rotation_filtered_matching).
/// Returns why the pair is rejected (after \a failure of the ratio test), or nothing.
std::string
rotationFilteredEstimate(const LoopDetectorParams& params,
                         const KeyFrame& query,
                         const KeyFrame& candidate,
                         LoopVerification& v,
                         FirstEstimate& first,
                         const std::string& failure)
{
  HammingMatchParams nearest = params.matching;
  nearest.ratio = 1.0;
  nearest.mutual_check = false;
  const pcl::Correspondences all = matchHamming(query.features, candidate.features, nearest);
  const double bin_deg = params.rotation_bin_deg > 0.0 ? params.rotation_bin_deg : 10.0;
  const int bins = std::max(3, static_cast<int>(std::lround(360.0 / bin_deg)));
  std::vector<int> bin_of(all.size()), histogram(bins, 0);
  for (std::size_t k = 0; k < all.size(); ++k) {
    bin_of[k] = slam_detail::rotationBin(
        candidate.features.points[all[k].index_match].angle_deg -
            query.features.points[all[k].index_query].angle_deg,
        bins);
    ++histogram[bin_of[k]];
  }
  const int best = slam_detail::bestRotationWindow(histogram.data(), bins).first;
  pcl::Correspondences kept;
  for (std::size_t k = 0; k < all.size(); ++k) {
    const int off = (bin_of[k] - best + bins) % bins;
    if (off == 0 || off == 1 || off == bins - 1)
      kept.push_back(all[k]);
  }
  RigidRansacResult ransac =
      static_cast<int>(kept.size()) >= params.min_initial_inliers
          ? estimateRigidRansac(
                query.features.points, candidate.features.points, kept, first.ransac_params)
          : RigidRansacResult();
  const double ratio =
      kept.empty() ? 0.0 : static_cast<double>(ransac.inlier_indices.size()) / kept.size();
  if (!ransac.success)
    return failure + "; rotation-filtered: " + std::to_string(ransac.inlier_indices.size()) +
           " RANSAC inliers of " + std::to_string(kept.size()) + " matches";
  first.matches = std::move(kept);
  first.ransac = std::move(ransac);
  v.num_matches = static_cast<int>(first.matches.size());
  v.num_initial_inliers = static_cast<int>(first.ransac.inlier_indices.size());
  v.inlier_ratio = ratio;
  v.T_candidate_query = first.ransac.T_target_source;
  return {};
}

/// Steps 1-3: ORB matches with the ratio test (paper), seeded RANSAC on them (paper),
/// and the inlier ratio: in a repetitive scene many matches agree with no single
/// motion. When that fails, the same under the odometry guess (distance candidates):
/// the gate, not the ratio test, keeps the matches apart; RANSAC sorts out the nearest
/// descriptors. Returns why the pair is rejected, or nothing.
std::string
firstEstimate(const LoopDetectorParams& params,
              const KeyFrame& query,
              const KeyFrame& candidate,
              const Pose3d& T_candidate_query_guess,
              const GuessTolerance& tolerance,
              LoopVerification& v,
              FirstEstimate& first)
{
  pcl::Correspondences& matches = first.matches;
  RigidRansacResult& ransac = first.ransac;
  matches = matchHamming(query.features, candidate.features, params.matching);
  v.num_matches = static_cast<int>(matches.size());
  first.ransac_params = params.ransac;
  first.ransac_params.min_inliers = params.min_initial_inliers;
  std::string failure;
  if (v.num_matches < params.min_initial_inliers) {
    failure = "too few matches: " + std::to_string(v.num_matches) + " < " +
              std::to_string(params.min_initial_inliers);
  }
  else {
    ransac = estimateRigidRansac(
        query.features.points, candidate.features.points, matches, first.ransac_params);
    v.num_initial_inliers = static_cast<int>(ransac.inlier_indices.size());
    v.inlier_ratio = static_cast<double>(v.num_initial_inliers) / v.num_matches;
    v.T_candidate_query = ransac.T_target_source;
    if (!ransac.success)
      failure = "RANSAC: " + ransac.message;
    else if (v.inlier_ratio < params.min_inlier_ratio)
      failure = format("inlier ratio %.2f < %.2f", v.inlier_ratio, params.min_inlier_ratio);
  }
  if (failure.empty())
    return {};
  const double gate = std::min(tolerance.translation_m, params.guess_gate_max_m);
  if (!(gate > 0.0)) {
    if (!params.rotation_filtered_matching)
      return failure;
    return rotationFilteredEstimate(params, query, candidate, v, first, failure);
  }
  HammingMatchParams gated = params.matching;
  gated.ratio = 1.0;
  gated.mutual_check = false;
  gated.spatial_gate_radius_m = gate;
  matches = matchHamming(query.features, candidate.features, gated, T_candidate_query_guess);
  ransac = matches.size() >= 3 ? estimateRigidRansac(query.features.points,
                                                      candidate.features.points,
                                                      matches,
                                                      first.ransac_params)
                               : RigidRansacResult();
  if (!ransac.success)
    return failure + "; under the odometry guess: " +
           std::to_string(ransac.inlier_indices.size()) + " RANSAC inliers of " +
           std::to_string(matches.size()) + " matches";
  v.from_guess = true;
  v.num_matches = static_cast<int>(matches.size());
  v.num_initial_inliers = static_cast<int>(ransac.inlier_indices.size());
  v.inlier_ratio = static_cast<double>(v.num_initial_inliers) / v.num_matches;
  v.T_candidate_query = ransac.T_target_source;
  return {};
}

/// Step 4: guided matching from the first estimate (the ratio test over the whole scan
/// drops most true matches between distant viewpoints), then RANSAC again with the
/// paper's minimum number of inliers.
std::string
guidedEstimate(const LoopDetectorParams& params,
               const KeyFrame& query,
               const KeyFrame& candidate,
               const FirstEstimate& first,
               LoopVerification& v,
               GuidedEstimate& guided)
{
  HammingMatchParams guided_params = params.matching;
  guided_params.ratio = std::max(guided_params.ratio, 0.9);
  guided_params.spatial_gate_radius_m = params.guided_radius_m;
  if (v.from_guess) {
    // Descriptors that failed the ratio test globally fail it within the gate too.
    guided_params.ratio = 1.0;
    guided_params.mutual_check = false;
  }
  guided.matches = matchHamming(
      query.features, candidate.features, guided_params, first.ransac.T_target_source);
  v.num_guided_matches = static_cast<int>(guided.matches.size());
  RigidRansacParams final_params = params.ransac;
  const int needed = v.from_guess ? params.min_guess_inliers : params.min_inliers;
  final_params.min_inliers = needed;
  guided.ransac = static_cast<int>(guided.matches.size()) >= needed
                      ? estimateRigidRansac(query.features.points,
                                            candidate.features.points,
                                            guided.matches,
                                            final_params)
                      : RigidRansacResult();
  v.num_inliers = static_cast<int>(guided.ransac.inlier_indices.size());
  v.inlier_rmse_m = guided.ransac.inlier_rmse_m;
  if (!guided.ransac.success || v.num_inliers < needed)
    return "guided matching: " + std::to_string(v.num_inliers) + " inliers of " +
           std::to_string(v.num_guided_matches) + " matches < " + std::to_string(needed);
  v.T_candidate_query = guided.ransac.T_target_source;
  return {};
}

/// Step 5: spatial spread of the inliers: not all on one object.
std::string
checkSpread(const LoopDetectorParams& params,
            const KeyFrame& query,
            const GuidedEstimate& guided,
            LoopVerification& v)
{
  inlierSpread(query.features.points,
               guided.matches,
               guided.ransac.inlier_indices,
               params.spread_cell_size_m,
               v.inlier_cells,
               v.inlier_spread_m);
  if (v.inlier_cells < params.min_inlier_cells)
    return "inliers in " + std::to_string(v.inlier_cells) + " cells < " +
           std::to_string(params.min_inlier_cells);
  if (v.inlier_spread_m < params.min_inlier_spread_m)
    return format(
        "inlier spread %.2f m < %.2f m", v.inlier_spread_m, params.min_inlier_spread_m);
  return {};
}

/// Step 6: uniqueness: a second, different motion explaining many outliers of the
/// first RANSAC means the scene repeats (a row of equal buildings): maybe the wrong copy.
std::string
checkUniqueness(const LoopDetectorParams& params,
                const KeyFrame& query,
                const KeyFrame& candidate,
                const FirstEstimate& first,
                LoopVerification& v)
{
  if (!(params.max_second_model_ratio < 1.0))
    return {};
  const int needed = std::max(
      params.min_initial_inliers,
      static_cast<int>(std::ceil(params.max_second_model_ratio * v.num_initial_inliers)));
  pcl::Correspondences rest;
  std::size_t k = 0;
  const auto& inliers = first.ransac.inlier_indices;
  for (std::size_t m = 0; m < first.matches.size(); ++m) {
    if (k < inliers.size() && inliers[k] == static_cast<int>(m)) {
      ++k;
      continue;
    }
    rest.push_back(first.matches[m]);
  }
  if (static_cast<int>(rest.size()) < needed)
    return {};
  RigidRansacParams second_params = first.ransac_params;
  second_params.min_inliers = needed;
  const RigidRansacResult second = estimateRigidRansac(
      query.features.points, candidate.features.points, rest, second_params);
  const Pose3d delta = first.ransac.T_target_source.inverse() * second.T_target_source;
  if (second.success && (delta.translation().norm() > 2.0 || rotationDeg(delta) > 10.0)) {
    v.second_model_inliers = static_cast<int>(second.inlier_indices.size());
    return "ambiguous: a second motion has " + std::to_string(v.second_model_inliers) +
           " inliers vs " + std::to_string(v.num_initial_inliers);
  }
  return {};
}

/// Step 7: consistency with the odometry estimate (distance candidates).
std::string
checkOdometry(const Pose3d& T_candidate_query_guess,
              const GuessTolerance& tolerance,
              const LoopVerification& v)
{
  const Pose3d deviation = T_candidate_query_guess.inverse() * v.T_candidate_query;
  const double dev_m = deviation.translation().norm();
  const double dev_deg = rotationDeg(deviation);
  if ((tolerance.translation_m >= 0.0 && dev_m > tolerance.translation_m) ||
      (tolerance.rotation_deg >= 0.0 && dev_deg > tolerance.rotation_deg))
    return format("inconsistent with odometry: %.2f m / %.1f deg away (allowed "
                  "%.2f m / %.1f deg)",
                  dev_m,
                  dev_deg,
                  tolerance.translation_m,
                  tolerance.rotation_deg);
  return {};
}

/// Step 8: self-similarity: if query or candidate matches itself under a shift (a
/// street of equal blocks), the loop could be any copy; only a tight odometry guess
/// decides.
std::string
checkSelfSimilarity(const LoopDetectorParams& params,
                    const KeyFrame& query,
                    const KeyFrame& candidate,
                    const GuessTolerance& tolerance,
                    LoopVerification& v)
{
  if (!(params.max_self_similarity_ratio < 1.0))
    return {};
  RigidRansacParams self_params = params.ransac;
  self_params.min_inliers = std::max(
      params.min_initial_inliers,
      static_cast<int>(std::ceil(params.max_self_similarity_ratio * v.num_inliers)));
  for (const KeyFrame* kf : {&candidate, &query}) {
    double shift_m = 0.0;
    const int n =
        selfSimilarity(kf->features, self_params, params.retrieval_max_hamming, 3.0, shift_m);
    if (n > v.self_similar_inliers) {
      v.self_similar_inliers = n;
      v.self_similar_shift_m = shift_m;
    }
  }
  if (v.self_similar_inliers > 0 &&
      !(tolerance.translation_m >= 0.0 &&
        tolerance.translation_m < 0.5 * v.self_similar_shift_m))
    return format("repetitive scene: a %.1f m self-shift has %.0f inliers (loop %.0f) "
                  "and no odometry guess tighter than half of it",
                  v.self_similar_shift_m,
                  v.self_similar_inliers,
                  v.num_inliers);
  return {};
}

} // namespace

void
LoopDetector::refineAccepted(const KeyFrame& query,
                             const PointToPlaneTarget& target,
                             LoopVerification& v) const
{
  if (!params_.final_refinement || !query.cloud)
    return;
  PointToPlaneResult r;
  try {
    r = refinePointToPlane(*query.cloud, target, v.T_candidate_query, params_.final_refine);
  } catch (const std::invalid_argument&) {
    return;
  }
  if (!r.success)
    return;
  const Pose3d delta = v.T_candidate_query.inverse() * r.T_target_source;
  const double change_m = delta.translation().norm();
  const double change_deg = rotationDeg(delta);
  if (change_m > params_.final_max_change_m || change_deg > params_.final_max_change_deg)
    return;
  v.T_candidate_query = r.T_target_source;
  v.refined = true;
  v.refinement_change_m = change_m;
  v.refinement_change_deg = change_deg;
}

// ---------------------------------------------------------------- verification

LoopVerification
LoopDetector::verify(const KeyFrame& query,
                     const KeyFrame& candidate,
                     const Pose3d& T_candidate_query_guess) const
{
  GuessTolerance tolerance;
  tolerance.translation_m = params_.max_odometry_deviation_m;
  tolerance.rotation_deg = params_.max_odometry_deviation_deg;
  return verify(query, candidate, T_candidate_query_guess, tolerance);
}

LoopVerification
LoopDetector::verify(const KeyFrame& query,
                     const KeyFrame& candidate,
                     const Pose3d& T_candidate_query_guess,
                     const GuessTolerance& tolerance) const
{
  return verifyPair(query, candidate, T_candidate_query_guess, tolerance, nullptr);
}

LoopVerification
LoopDetector::verify(const KeyFrame& query,
                     const KeyFrame& candidate,
                     const Pose3d& T_candidate_query_guess,
                     const GuessTolerance& tolerance,
                     const PointVector& dense_target) const
{
  return verifyPair(
      query, candidate, T_candidate_query_guess, tolerance, nullptr, &dense_target);
}

LoopVerification
LoopDetector::verifyPair(const KeyFrame& query,
                         const KeyFrame& candidate,
                         const Pose3d& T_candidate_query_guess,
                         const GuessTolerance& tolerance,
                         const RetrievedKeyFrame* retrieved,
                         const PointVector* dense_target) const
{
  const pcl::StopWatch t0;
  LoopVerification v;
  v.query = query.id;
  v.candidate = candidate.id;
  auto reject = [&](const std::string& why) {
    v.accepted = false;
    v.reason = why;
    v.verify_ms = t0.getTime();
    return v;
  };
  if (static_cast<int>(query.features.size()) < params_.min_inliers ||
      static_cast<int>(candidate.features.size()) < params_.min_inliers)
    return reject("too few features: " + std::to_string(query.features.size()) + " / " +
                  std::to_string(candidate.features.size()));

  // Each step either passes or says why the pair is rejected.
  FirstEstimate first;
  GuidedEstimate guided;
  std::string why = firstEstimate(params_, query, candidate, T_candidate_query_guess,
                                  tolerance, v, first);
  if (why.empty())
    why = guidedEstimate(params_, query, candidate, first, v, guided);
  if (why.empty())
    why = checkSpread(params_, query, guided, v);
  if (why.empty())
    why = checkUniqueness(params_, query, candidate, first, v);
  if (why.empty())
    why = checkOdometry(T_candidate_query_guess, tolerance, v);
  if (why.empty())
    why = checkSelfSimilarity(params_, query, candidate, tolerance, v);
  if (why.empty() && params_.dense_check)
    why = denseCheck(query,
                     candidate,
                     retrieved,
                     dense_target,
                     tolerance.min_dense_overlap >= 0.0 ? tolerance.min_dense_overlap
                                                        : params_.min_dense_overlap,
                     v);
  if (!why.empty())
    return reject(why);

  v.accepted = true;
  v.verify_ms = t0.getTime();
  v.reason =
      v.dense_undecided
          ? format("accepted: %.0f inliers (ratio %.2f), too little structure for the "
                   "dense check",
                   v.num_inliers,
                   v.inlier_ratio)
          : format("accepted: %.0f inliers (ratio %.2f), dense overlap %.2f, rmse %.3f m",
                   v.num_inliers,
                   v.inlier_ratio,
                   v.dense_overlap,
                   v.dense_rmse_m);
  return v;
}

std::string
LoopDetector::denseCheck(const KeyFrame& query,
                         const KeyFrame& candidate,
                         const RetrievedKeyFrame* retrieved,
                         const PointVector* dense_target,
                         double min_overlap,
                         LoopVerification& v) const
{
  // 9. Dense check: point-to-plane refinement of the query's planar points on the
  // candidate's, then the share of query structure (walls, not ground) that fits.
  // The candidate's target as the database keeps it (empty when it had no cloud at
  // insertion), else made from its cloud. A candidate given without its retrieval
  // (verify(); a session key-frame whose cloud stays in its file) is looked up. A
  // target given by the caller replaces both.
  PointVector looked_up;
  if (!dense_target)
    looked_up =
        retrieved ? database_.denseTarget(*retrieved) : database_.denseTarget(candidate);
  const PointVector& stored = dense_target ? *dense_target : looked_up;
  if (!query.cloud || (!candidate.cloud && stored.empty()))
    return "dense check: a key-frame has no cloud";
  const PointToPlaneParams& dp = params_.dense;
  PointToPlaneTarget target, query_planes;
  PointToPlaneParams query_params = dp;
  query_params.target_voxel_size_m = dp.source_voxel_size_m;
  try {
    target.build(!stored.empty() ? stored
                                 : KeyFrameDatabase::decodeDense(
                                       KeyFrameDatabase::makeDenseTarget(*candidate.cloud, params_)),
                 dp);
    query_planes.build(
        KeyFrameDatabase::croppedCloud(
            *query.cloud, query_params.target_voxel_size_m, params_.dense_crop_radius_m),
        query_params);
  } catch (const std::invalid_argument& e) {
    return std::string("dense check: ") + e.what();
  }
  if (target.empty() || query_planes.empty())
    return "dense check: no planar points";
  const PointToPlaneResult refined =
      refinePointToPlane(query_planes.points(), target, v.T_candidate_query, dp);
  if (!refined.success)
    return "dense check: " + refined.message;
  const Pose3d& T = refined.T_target_source;
  int structure = 0, paired = 0;
  double sum_sq = 0.0;
  const double cos_normal = std::cos(30.0 / kDegPerRad);
  for (std::size_t i = 0; i < query_planes.size(); ++i) {
    const Eigen::Vector3d& n = query_planes.normals()[i];
    if (std::abs(n.z()) > 0.7) // ground, roofs: agree under any planar motion
      continue;
    ++structure;
    const Eigen::Vector3d p = T * query_planes.points()[i];
    const Eigen::Vector3d n_t = T.linear() * n;
    Eigen::Vector3d q, n_q;
    if (!target.nearest(p, 2.0 * params_.dense_inlier_distance_m, q, n_q))
      continue;
    const double r = n_q.dot(p - q);
    if (std::abs(n_q.dot(n_t)) < cos_normal || std::abs(r) > params_.dense_inlier_distance_m)
      continue;
    ++paired;
    sum_sq += r * r;
  }
  v.dense_overlap = structure > 0 ? static_cast<double>(paired) / structure : 0.0;
  v.dense_rmse_m = paired > 0 ? std::sqrt(sum_sq / paired) : 0.0;
  if (structure < params_.min_dense_structure) {
    v.dense_undecided = true;
    v.T_candidate_query = T;
    return {};
  }
  if (structure == 0 || v.dense_overlap < min_overlap) {
    if (structure == 0 || params_.tentative_dense_overlap < 0.0 ||
        v.dense_overlap < params_.tentative_dense_overlap)
      return format("dense overlap %.2f < %.2f (%.0f structure points)",
                    v.dense_overlap,
                    min_overlap,
                    structure);
    v.dense_short = true;
  }
  if (v.dense_rmse_m > params_.max_dense_rmse_m)
    return format("dense rmse %.3f m > %.3f m", v.dense_rmse_m, params_.max_dense_rmse_m);
  v.T_candidate_query = T;
  refineAccepted(query, target, v);
  return {};
}

} // namespace rast
} // namespace pcl
