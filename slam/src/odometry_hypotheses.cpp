/// \file odometry_hypotheses.cpp
/// \brief Step 5 of tracking when the features fail the consistency check: dense ICP
/// from several motion hypotheses (the prior, weak feature estimates, turns, shifts at a
/// cold start), the winner re-fitted from features matched under its motion, and the
/// acceptance rules that keep a wrong start from settling on the ground plane
/// (doc/odometry.md).

#include "odometry_impl.h"

#include <algorithm>
#include <cmath>
#include <pcl/registration/hamming_matching.h>

namespace pcl {
namespace rast {

using namespace odometry_detail;

namespace {

/// Starts for the dense search when the features fail: the prior, the weak feature
/// estimates, and the prior's motion from \a T_world_last turned by +-k * yaw_step_deg
/// (up to max_yaw_deg) about the LiDAR z axis, its translation turned by half that
/// (a car's arc; negligible for slow handheld motion). Without a tracked velocity
/// (\a max_travel_m > 0: cold start, after a tracking loss) the prior is also shifted
/// along the LiDAR x axis (the direction of travel) by +-k * cold_start_step_m up to
/// \a max_travel_m. Nearest-to-prior first.
std::vector<Pose3d>
motionHypotheses(const Pose3d& T_world_prior,
                 const Pose3d& T_world_last,
                 const std::vector<Pose3d>& weak_estimates,
                 double max_travel_m,
                 const MotionHypothesisParams& params)
{
  std::vector<Pose3d> starts{T_world_prior};
  if (!params.enabled)
    return starts;
  starts.insert(starts.end(), weak_estimates.begin(), weak_estimates.end());
  const int shifts =
      static_cast<int>(std::ceil(max_travel_m / params.cold_start_step_m - 1e-9));
  for (int k = 1; k <= shifts; ++k)
    for (const int sign : {1, -1}) {
      Pose3d shifted = Pose3d::Identity();
      shifted.translation().x() = sign * k * params.cold_start_step_m;
      starts.push_back(T_world_prior * shifted);
    }
  const Pose3d delta = T_world_last.inverse() * T_world_prior;
  const int steps =
      static_cast<int>(std::floor(params.max_yaw_deg / params.yaw_step_deg + 1e-9));
  for (int k = 1; k <= steps; ++k)
    for (const int sign : {1, -1}) {
      const double yaw = sign * k * params.yaw_step_deg * M_PI / 180.0;
      Pose3d turned = Pose3d::Identity();
      turned.linear() = Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()) * delta.linear();
      turned.translation() =
          Eigen::AngleAxisd(yaw / 2.0, Eigen::Vector3d::UnitZ()) * delta.translation();
      starts.push_back(T_world_last * turned);
    }
  return starts;
}

/// Runs \a work elsewhere and returns its future, or an invalid one when it cannot.
using Spawn = std::function<std::future<void>(std::function<void()>)>;

/// Outcome of the dense search over motion hypotheses.
struct HypothesisSearch
{
  DenseResult dense;       ///< the standard refinement from the best coarse result
  int best_pairs = 0;      ///< pairs of the best coarse run
  int runner_up_pairs = 0; ///< most pairs of a coarse run that ended elsewhere
  Pose3d T_world_runner_up = Pose3d::Identity(); ///< where that run ended
};

/// Dense ICP from every start with a wider basin (coarse), then the standard refinement
/// from the coarse result that paired the most points (ties: lower RMS residual).
/// Also reports how well the best alternative did: a coarse run (converged or not)
/// that ended farther than max_correspondence_distance_m or yaw_step_deg / 2 from the
/// winner, so that the caller can tell a distinct optimum from an ambiguous one.
/// \a spawn runs every other coarse run elsewhere (see below), or is empty.
HypothesisSearch
bestDenseFromHypotheses(const Points3f& source,
                        const VoxelPlaneMap& map,
                        const std::vector<Pose3d>& starts,
                        const DenseTrackingParams& dense,
                        const MotionHypothesisParams& params,
                        const Spawn& spawn)
{
  DenseTrackingParams coarse = dense;
  coarse.max_correspondence_distance_m = std::max(
      dense.max_correspondence_distance_m, params.coarse_correspondence_distance_m);
  coarse.max_correction_m =
      std::max(dense.max_correction_m, params.coarse_max_correction_m);
  coarse.max_correction_deg = std::max(dense.max_correction_deg, params.yaw_step_deg);
  // The coarse runs are independent (the map and the source are only read): every
  // other one on the search thread when there is one, the rest here, and the best is
  // chosen in the starts' order as if they had run one after the other.
  std::vector<DenseResult> runs(starts.size());
  const auto coarseRuns = [&](std::size_t first, std::size_t stride) {
    for (std::size_t k = first; k < starts.size(); k += stride)
      runs[k] = registerToMap(source, map, starts[k], coarse);
  };
  std::future<void> odd;
  if (spawn && starts.size() > 1)
    odd = spawn([&] { coarseRuns(1, 2); });
  {
    // Waits for the other thread even when a run here throws: it uses runs and source.
    struct Joined
    {
      std::future<void>& f;
      ~Joined()
      {
        if (f.valid())
          f.wait();
      }
    } joined{odd};
    coarseRuns(0, odd.valid() ? 2 : 1);
    if (odd.valid())
      odd.get(); // its exception, if any, here
  }
  int best = -1;
  for (std::size_t k = 0; k < runs.size(); ++k) {
    const DenseResult& r = runs[k];
    if (!r.success || r.degenerate_directions > 0)
      continue;
    if (best < 0 || r.num_correspondences > runs[best].num_correspondences ||
        (r.num_correspondences == runs[best].num_correspondences &&
         r.rmse_m < runs[best].rmse_m))
      best = static_cast<int>(k);
  }
  HypothesisSearch search;
  if (best < 0) {
    search.dense.message = "no motion hypothesis converged";
    return search;
  }
  for (const DenseResult& r : runs) {
    const Pose3d diff = runs[best].T_world_lidar.inverse() * r.T_world_lidar;
    if ((diff.translation().norm() > dense.max_correspondence_distance_m ||
         angleDeg(diff) > params.yaw_step_deg / 2.0) &&
        r.num_correspondences > search.runner_up_pairs) {
      search.runner_up_pairs = r.num_correspondences;
      search.T_world_runner_up = r.T_world_lidar;
    }
  }
  search.best_pairs = runs[best].num_correspondences;
  search.dense = registerToMap(source, map, runs[best].T_world_lidar, dense);
  return search;
}

} // namespace

pcl::Correspondences
Odometry::Impl::guidedMatches(const Frame& frame,
                              const Pose3d& T_world_lidar,
                              double gate_m) const
{
  HammingMatchParams gated = params.registration.matching;
  gated.ratio = 1.0;
  gated.mutual_check = false;
  gated.spatial_gate_radius_m = gate_m;
  return matchHamming(*frame.features,
                      keyframe->features,
                      gated,
                      T_world_keyframe.inverse() * T_world_lidar);
}

int
Odometry::Impl::guidedPairs(const Frame& frame, const Pose3d& T_world_lidar) const
{
  return static_cast<int>(
      guidedMatches(frame, T_world_lidar, params.turn_search.guided_gate_m).size());
}

bool
Odometry::Impl::canGuide(const Frame& frame) const
{
  return params.turn_search.enabled && params.turn_search.guided_gate_m > 0.0 &&
         frame.features->size() >= 3 && keyframe->features.size() >= 3;
}

std::string
Odometry::Impl::refitFromGuidedFeatures(const Frame& frame,
                                        DenseResult& dense,
                                        int& dense_guided_pairs) const
{
  // Re-fit: dense ICP can settle a degree or two off in yaw where the scan is weak in
  // structure (a hillside's scan rings). The features matched under its result (a
  // wider gate) and RANSAC give x, y and yaw; dense ICP from there (height, roll and
  // pitch of the first result) wins when more features pair under it.
  if (!dense.success || !canGuide(frame) ||
      !(params.turn_search.guided_refit_gate_m > 0.0))
    return {};
  const pcl::Correspondences matches =
      guidedMatches(frame, dense.T_world_lidar, params.turn_search.guided_refit_gate_m);
  const RigidRansacResult fit = fitFeatures(frame, keyframe->features, matches);
  if (inliersOf(fit) < params.min_feature_inliers)
    return {};
  const DenseResult again = registerToMap(
      frame.source,
      localMap(),
      planarFromFeatures(
          T_world_last, T_world_keyframe * fit.T_target_source, dense.T_world_lidar),
      params.dense);
  const int before = guidedPairs(frame, dense.T_world_lidar);
  const int after = again.success ? guidedPairs(frame, again.T_world_lidar) : 0;
  dense_guided_pairs = std::max(before, after);
  if (after <= before)
    return {};
  dense = again;
  return "; re-fitted from " + std::to_string(inliersOf(fit)) +
         " features matched under it (" + std::to_string(before) + " -> " +
         std::to_string(after) + " pairing)";
}

void
Odometry::Impl::searchHypotheses(const Frame& frame,
                                 const FeatureTrack& track,
                                 OdometryFrameResult& result) const
{
  // Feature-consistency check failed. Large motion (a sharp turn at a low frame rate)
  // makes the constant-velocity prior wrong, so dense ICP is started from several
  // hypotheses: the prior, the weak feature estimates, the prior turned by +-yaw steps
  // and, without a tracked velocity (cold start), shifted along the direction of
  // travel; the best-paired result wins.
  const double max_travel_m = velocity_tracked
                                  ? 0.0
                                  : params.turn_search.cold_start_max_speed_mps *
                                        frameInterval(result.timestamp_s);
  const std::vector<Pose3d> starts = motionHypotheses(frame.T_world_prior,
                                                      T_world_last,
                                                      track.weak_estimates,
                                                      max_travel_m,
                                                      params.turn_search);
  Spawn spawn;
  if (params.turn_search.threads > 1)
    spawn = [this](std::function<void()> work) {
      return onSearchThread(std::move(work));
    };
  const HypothesisSearch search = bestDenseFromHypotheses(
      frame.source, localMap(), starts, params.dense, params.turn_search, spawn);
  DenseResult dense = search.dense;
  result.degraded = true;
  const std::string why = "feature-consistency check failed (" +
                          std::to_string(result.num_inliers) + " inliers < " +
                          std::to_string(params.min_feature_inliers) + ")";
  int dense_guided_pairs = -1; // guidedPairs(dense.T_world_lidar) once known
  const std::string refit = refitFromGuidedFeatures(frame, dense, dense_guided_pairs);
  keepDenseStats(dense, result);
  // Dense ICP alone from a wrong start can settle on the ground plane with the wrong
  // yaw; accept it only when most of the scan pairs with the map, or when fewer do but
  // no other hypothesis comes close (a distinct optimum).
  const double paired_ratio = static_cast<double>(dense.num_correspondences) /
                              std::max(1, dense.num_source_points);
  // Distinct needs a rival that ended elsewhere: when every start agrees (or only the
  // prior was tried) the ratio test above is all there is.
  const bool distinct =
      search.runner_up_pairs > 0 &&
      search.best_pairs >= kDistinctPairsFactor * search.runner_up_pairs &&
      paired_ratio >= kMinDistinctPairedRatio;
  // ... or when the features back it against that rival.
  bool feature_backed = false;
  if (dense.success && search.runner_up_pairs > 0 && canGuide(frame)) {
    result.guided_pairs = dense_guided_pairs >= 0
                              ? dense_guided_pairs
                              : guidedPairs(frame, dense.T_world_lidar);
    const int rival = guidedPairs(frame, search.T_world_runner_up);
    feature_backed =
        result.guided_pairs >= params.min_feature_inliers &&
        result.guided_pairs >= params.turn_search.guided_support_factor * rival;
  }
  const bool well_paired =
      paired_ratio >= kMinFallbackPairedRatio || distinct || feature_backed;
  // The prior, corrected only along the directions the scan constrains (e.g. the
  // ground's height, roll and pitch on an open field), computed once when needed.
  std::optional<DenseResult> from_prior;
  auto fromPrior = [&]() -> const DenseResult& {
    if (!from_prior)
      from_prior = registerToMap(frame.source,
                                 localMap(),
                                 frame.T_world_prior,
                                 params.dense,
                                 priorAnchored(frame));
    return *from_prior;
  };
  // With a tracked velocity at a rate where a vehicle cannot deviate far from it, a
  // result beyond that (a tunnel's walls moving with the sensor: "no motion" at 26 m/s)
  // is not a motion but a wrong optimum: the prior, corrected where the scan
  // constrains it, stands.
  // (Only when the prior's own fit pairs most of the scan: a scan that pairs with
  // nothing, a corrupt one, falls back to constant velocity as before.)
  const bool implausible =
      dense.success && priorGate(frame).dynamics && !nearPrior(frame, dense.T_world_lidar) &&
      fromPrior().success &&
      fromPrior().num_correspondences >=
          kMinFallbackPairedRatio * std::max(1, fromPrior().num_source_points);
  if (implausible) {
    result.status = TrackingStatus::kDenseFallback;
    result.T_world_lidar = fromPrior().T_world_lidar;
    result.refined = true;
    keepDenseStats(fromPrior(), result);
    result.message = why + ": the best of " + std::to_string(starts.size()) +
                     " motion hypotheses is beyond what the vehicle can do in a frame "
                     "interval; dense ICP from the prior stands (" +
                     fromPrior().message + ")";
    return;
  }
  if (!(dense.success && dense.degenerate_directions == 0 && well_paired)) {
    result.status = TrackingStatus::kConstantVelocity;
    if (fromPrior().success)
      result.T_world_lidar = fromPrior().T_world_lidar;
    result.message = why + ": constant-velocity prediction (" + dense.message + ")";
    return;
  }
  result.status = TrackingStatus::kDenseFallback;
  result.T_world_lidar = dense.T_world_lidar;
  result.refined = true;
  result.message = why + ": dense ICP from " + std::to_string(starts.size()) +
                   " motion hypotheses; " + dense.message + refit;
  if (result.guided_pairs > 0)
    result.message +=
        "; " + std::to_string(result.guided_pairs) + " features pair under its motion";
  if (velocity_tracked && fromPrior().success)
    keepPriorWhereIndistinct(dense, fromPrior(), result);
}

void
Odometry::Impl::keepPriorWhereIndistinct(const DenseResult& dense,
                                         const DenseResult& prior_dense,
                                         OdometryFrameResult& result) const
{
  // With a tracked velocity the prior is rarely far off. A hypothesis that beat it by a
  // few pairs along a direction the scan hardly constrains (a tunnel's axis, with weak
  // features on passing cars whose points pair too) is not better than the prior: where
  // dense ICP from the prior pairs nearly as well, or the scan cannot tell the two
  // apart, the prior stands.
  if (!moved(dense.T_world_lidar, prior_dense.T_world_lidar, 0.02, 0.1))
    return;
  const double prior_ratio = static_cast<double>(prior_dense.num_correspondences) /
                             std::max(1, prior_dense.num_source_points);
  const bool nearly_as_well =
      prior_ratio >= kMinFallbackPairedRatio &&
      prior_dense.num_correspondences >= kPriorPairsShare * dense.num_correspondences;
  if (nearly_as_well ||
      denseSeparation(prior_dense, dense.T_world_lidar) < params.indistinct_residual_m) {
    result.message += "; dense ICP from the prior pairs " +
                      std::to_string(prior_dense.num_correspondences) + " vs " +
                      std::to_string(dense.num_correspondences) + ": the prior stands";
    result.T_world_lidar = prior_dense.T_world_lidar;
    keepDenseStats(prior_dense, result);
  }
}

} // namespace rast
} // namespace pcl
