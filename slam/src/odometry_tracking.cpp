/// \file odometry_tracking.cpp
/// \brief Odometry::Impl::track, the paper's tracking figure in named steps:
/// motion compensation -> ground removal, raster and ORB (extractFeatures) -> match the
/// key-frame and RANSAC (trackFeatures) -> dense refinement against the local map from
/// the feature estimate (trackDense) or, when the features fail, from several motion
/// hypotheses (searchHypotheses, odometry_hypotheses.cpp) -> key-frame decision
/// (decideKeyFrame).

#include "odometry_impl.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <pcl/common/io.h>
#include <pcl/registration/hamming_matching.h>
#include <utility>

namespace pcl {
namespace rast {

using namespace odometry_detail;

/// The motion from \a T_world_last with the features' planar part (x, y, yaw in the
/// last scan's frame, which top-down raster features measure well) and the prior's
/// height, roll and pitch (which max-height pixels of few inliers do not).
Pose3d
odometry_detail::planarFromFeatures(const Pose3d& T_world_last,
                                    const Pose3d& T_world_features,
                                    const Pose3d& T_world_prior)
{
  const Pose3d d_f = T_world_last.inverse() * T_world_features;
  const Pose3d d_p = T_world_last.inverse() * T_world_prior;
  const double yaw_f = std::atan2(d_f.rotation()(1, 0), d_f.rotation()(0, 0));
  const double yaw_p = std::atan2(d_p.rotation()(1, 0), d_p.rotation()(0, 0));
  Pose3d d = d_p; // the prior, turned to the features' heading and moved to their x, y
  d.linear() =
      Eigen::AngleAxisd(yaw_f - yaw_p, Eigen::Vector3d::UnitZ()).toRotationMatrix() *
      d_p.rotation();
  d.translation().x() = d_f.translation().x();
  d.translation().y() = d_f.translation().y();
  return T_world_last * d;
}

OdometryFrameResult
Odometry::Impl::track(Frame& frame, OdometryFrameResult result)
{
  frame.prior_overruled_before = std::exchange(prior_overruled_features, false);
  frame.T_world_prior = predict(result.timestamp_s);
  result.T_world_lidar = frame.T_world_prior;
  result.reference_keyframe = keyframe ? keyframe->id : 0;
  if (!frame.usable) // step 0 (prepare): status and message say why
    return result;
  frame.dt = frameInterval(result.timestamp_s);
  const pcl::PointCloud<pcl::PointXYZI>::ConstPtr& input_ptr = frame.input_ptr;
  pcl::StopWatch watch;

  // The first usable frame starts the map.
  if (!keyframe) {
    if (frame.times) {
      first_scan = input_ptr;
      first_times = frame.times->all();
      T_world_first = result.T_world_lidar;
      t_first = result.timestamp_s;
    }
    result.status = TrackingStatus::kFirstFrame;
    result.message = "first frame: key-frame 0";
    watch.reset();
    result.keyframe = makeKeyFrame(result, *frame.features, frame.input_ptr);
    keyframe_image = std::move(frame.image);
    result.reference_keyframe = result.keyframe->id;
    result.timings.keyframe_ms = watch.getTime();
    result.timings.total_ms = frame.watch.getTime();
    return result;
  }

  // 4-5 without features (none wanted): the dense step from the prior, where it alone
  // tracks the frame. (No visibility test: its image comes with the features.)
  bool dense_only = false;
  if (frame.deferred_front) {
    watch.reset();
    localMap().hideSeenThrough(nullptr, frame.T_world_prior.cast<float>(), 0.0f, 0.0f);
    dense_only = trackDenseOnly(frame, result);
    result.timings.refine_ms += watch.getTime();
  }
  FeatureTrack feature_track;
  if (dense_only) {
    if (frames_since_failed_features >= 0)
      ++frames_since_failed_features;
  } else {
    ensureFeatures(frame, result);
    feature_track = trackFeatures(frame, result); // 4
    frames_since_failed_features = feature_track.ok ? -1 : 0;
    // 4b. What moved out of the map's voxels, as this scan sees it from the prior, does
    //     not pair this frame (moving objects; dropMovedIn drops what moved in).
    frame.check_visibility = useVisibility(frame);
    const pcl::StopWatch hide_watch;
    result.hidden_map_voxels =
        localMap().hideSeenThrough(frame.check_visibility ? &frame.image : nullptr,
                                   frame.T_world_prior.cast<float>(),
                                   static_cast<float>(params.visibility_radius_m),
                                   static_cast<float>(params.visibility_margin_m));
    result.timings.visibility_ms += hide_watch.getTime();

    // 5. Dense refinement against the local map, from the feature estimate; the
    //    feature-consistency check falls back to dense ICP from the prior, then to the
    //    prior itself.
    watch.reset();
    if (params.registration.refine || !feature_track.ok)
      dropMovedIn(frame, result);
    if (feature_track.ok)
      prior_overruled_features = trackDense(frame, feature_track, result);
    else
      searchHypotheses(frame, feature_track, result);
    result.timings.refine_ms += watch.getTime(); // (+ the source points, prepare)
  }

  // 5b. Second pass of the motion compensation with the estimated motion.
  if (frame.xi_sweep && result.refined && !frame.source_indices.empty())
    secondDeskewPass(frame.input,
                     *frame.times,
                     frame.source_indices,
                     frame.dt,
                     frame.T_motion_deskew,
                     result,
                     *frame.xi_sweep);
  // 5c. Not from strong features: a height beyond the vehicle's vertical motion is a
  //     slide (checked after the second pass, which refines without the prior).
  if (!feature_track.ok ||
      inliersOf(feature_track.ransac) < params.strong_feature_inliers)
    keepPriorHeight(frame, result);
  // 5d. A cold start that measured no motion: solved with both scans compensated.
  if (first_scan && !result.refined)
    solveColdStartMotion(frame, result);
  // 5e. The local map rebuilt from the first scan, compensated, once its motion is
  //     known.
  if (first_scan)
    rebuildMapFromFirstScan(result);

  decideKeyFrame(frame, result); // 6
  result.timings.total_ms = frame.watch.getTime();
  return result;
}

void
Odometry::Impl::removeGround(FrontEnd& front,
                             Frame& frame,
                             OdometryFrameResult& result) const
{
  // 1. Ground removal (paper sec. 4). On the raw scan: the sweep's motion moves ground
  //    points along the ground plane, and only the plane is kept.
  const pcl::StopWatch watch;
  SACGroundRemoval<pcl::PointXYZI>& ground = front.ground;
  ground.setInputCloud(frame.input_ptr);
  ground.filter(frame.non_ground_indices);
  result.ground_found = ground.groundFound();
  frame.T_level_lidar = ground.getLevellingTransform();
  if (result.ground_found)
    frame.ground_plane = ground.getGroundPlane();
  result.timings.ground_ms = watch.getTime();
}

void
Odometry::Impl::extractFeatures(FrontEnd& front,
                                Frame& frame,
                                OdometryFrameResult& result) const
{
  OrbRasterFeatureEstimator<pcl::PointXYZI>& orb = front.orb;
  const pcl::Indices& non_ground_indices = frame.non_ground_indices;
  pcl::StopWatch watch;
  // The levelled frame, where the sensor is tilted (params.ground.level_cloud).
  const Eigen::Isometry3f& T_level_lidar = frame.T_level_lidar;
  const bool levelled = params.ground.level_cloud && result.ground_found &&
                        !T_level_lidar.isApprox(Eigen::Isometry3f::Identity());
  // The non-ground points, compensated (one copy of them either way), then levelled.
  watch.reset();
  pcl::PointCloud<pcl::PointXYZI>::Ptr non_ground;
  if (frame.xi_sweep) {
    non_ground =
        deskewIndices(frame.input, *frame.times, non_ground_indices, *frame.xi_sweep);
    result.timings.deskew_ms += watch.getTime();
  } else {
    non_ground = std::make_shared<pcl::PointCloud<pcl::PointXYZI>>();
    pcl::copyPointCloud(frame.input, non_ground_indices, *non_ground);
    result.timings.ground_ms += watch.getTime();
  }
  if (params.visibility_margin_m > 0.0) { // before levelling: in the LiDAR frame
    const pcl::StopWatch w;
    frame.image = VisibilityImage(*non_ground);
    // The image holds no ground, so where a ray met the ground it cannot tell: the
    // moving-in test leaves points near the ground alone (frame.ground_plane, its
    // normal up; zero without a ground).
    result.timings.visibility_ms = w.getTime(); // + hiding the map's voxels (track)
  }
  if (levelled)
    for (auto& p : non_ground->points)
      p.getVector3fMap() = T_level_lidar.linear() * p.getVector3fMap();

  // 2-3. Raster of the non-ground points and ORB features (sec. 5-6).
  frame.features = std::make_shared<RasterFeatureSet>();
  if (!non_ground->empty()) {
    orb.setInputCloud(non_ground);
    const OrbRasterFeatureResult orb_result = orb.compute(*frame.features);
    result.timings.raster_ms = orb_result.raster_ms;
    result.timings.orb_ms = orb_result.detect_ms + orb_result.describe_ms;
    // Features of a levelled raster go back to the LiDAR frame.
    if (levelled) {
      const Eigen::Isometry3f T_lidar_level = T_level_lidar.inverse();
      for (auto& p : frame.features->points)
        p.getVector3fMap() = T_lidar_level * p.getVector3fMap();
    }
  }
  result.num_features = static_cast<int>(frame.features->size());
  result.features = frame.features;
}

RigidRansacResult
Odometry::Impl::fitFeatures(const Frame& frame,
                            const RasterFeatureSet& target,
                            const pcl::Correspondences& matches) const
{
  return matches.size() >= 3 ? estimateRigidRansac(frame.features->points,
                                                   target.points,
                                                   matches,
                                                   params.registration.ransac)
                             : RigidRansacResult();
}

Odometry::Impl::FeatureTrack
Odometry::Impl::trackFeatures(const Frame& frame, OdometryFrameResult& result) const
{
  // 4. Match the last key-frame's features (no spatial gate by default: large motion
  //    must track), rigid RANSAC, eq. 4 on the inliers (sec. 7.1-7.2).
  const pcl::StopWatch watch;
  const RasterFeatureSet& features = *frame.features;
  const RasterFeatureSet& kf_features = keyframe->features;
  const Pose3d T_keyframe_prior = T_world_keyframe.inverse() * frame.T_world_prior;
  FeatureTrack track;
  // One distance pass gives the ratio-tested matches and, for the re-match below, every
  // feature's nearest neighbour.
  pcl::Correspondences kf_matches, kf_nearest;
  if (features.size() >= 3 && kf_features.size() >= 3)
    kf_matches = matchHamming(features,
                              kf_features,
                              params.registration.matching,
                              T_keyframe_prior,
                              &kf_nearest);
  result.num_matches = static_cast<int>(kf_matches.size());
  track.ransac = fitFeatures(frame, kf_features, kf_matches);
  result.num_inliers = inliersOf(track.ransac);
  track.ok = result.num_inliers >= params.min_feature_inliers;
  track.T_world_features = T_world_keyframe * track.ransac.T_target_source;
  // Estimates too weak for the consistency check are still hypotheses for the dense
  // search (under large motion they are often right, with 5-14 inliers).
  auto keepWeak = [&](const RigidRansacResult& r, const Pose3d& T_world_reference) {
    if (static_cast<int>(r.inlier_indices.size()) >= params.turn_search.min_weak_inliers)
      track.weak_estimates.push_back(T_world_reference * r.T_target_source);
  };
  keepWeak(track.ransac, T_world_keyframe);
  if (!track.ok && last_features && features.size() >= 3 && last_features->size() >= 3) {
    // Too far from the key-frame: the previous frame is closer.
    const pcl::Correspondences matches =
        matchHamming(features,
                     *last_features,
                     params.registration.matching,
                     T_world_last_features.inverse() * frame.T_world_prior);
    const RigidRansacResult last = fitFeatures(frame, *last_features, matches);
    keepWeak(last, T_world_last_features);
    if (inliersOf(last) >= params.min_feature_inliers) {
      track.ok = true;
      track.T_world_features = T_world_last_features * last.T_target_source;
      result.num_matches = static_cast<int>(matches.size());
      track.ransac = last;
      track.reference = "the previous frame";
      // num_inliers stays the count with the key-frame ("points in common").
    }
  }
  if (params.loose_rematch && inliersOf(track.ransac) < params.strong_feature_inliers) {
    // Weak: the key-frame's nearest-neighbour matches alone; RANSAC sorts them out.
    const RigidRansacResult nearest = fitFeatures(frame, kf_features, kf_nearest);
    keepWeak(nearest, T_world_keyframe);
    if (inliersOf(nearest) > inliersOf(track.ransac) &&
        inliersOf(nearest) >= params.min_feature_inliers) {
      track.ok = true;
      track.T_world_features = T_world_keyframe * nearest.T_target_source;
      result.num_matches = static_cast<int>(kf_nearest.size());
      result.num_inliers = std::max(result.num_inliers, inliersOf(nearest));
      track.ransac = nearest;
      track.reference = "the key-frame (nearest-neighbour matches)";
    }
  }
  result.timings.match_ms = watch.getTime();
  return track;
}

void
Odometry::Impl::selectDenseSource(Frame& frame) const
{
  // Subsample the voxel indices (the points are copied by makeDenseSource).
  const RangeFilter in_range(params.min_range_m, params.max_range_m);
  frame.source_indices = strideSubsample(
      voxelDownsampleIndices(frame.input, params.dense.source_voxel_size_m, in_range),
      static_cast<std::size_t>(params.dense.max_source_points));
}

void
Odometry::Impl::makeDenseSource(Frame& frame, OdometryFrameResult& result) const
{
  if (frame.xi_sweep) {
    const pcl::StopWatch t0;
    frame.source = toPoints(
        *deskewIndices(frame.input, *frame.times, frame.source_indices, *frame.xi_sweep));
    result.timings.deskew_ms += t0.getTime();
  } else {
    frame.source = toPoints(frame.input, frame.source_indices);
  }
}

void
Odometry::Impl::dropMovedIn(Frame& frame, OdometryFrameResult& result) const
{
  if (frame.check_visibility && !keyframe_image.empty()) {
    // The points that moved in: the key-frame's scan saw past where the prior puts them
    // (only above the ground: without a ground plane, none).
    const auto margin = static_cast<float>(params.visibility_margin_m);
    const Eigen::Isometry3f T_keyframe_lidar =
        (T_world_keyframe.inverse() * frame.T_world_prior).cast<float>();
    std::size_t kept = 0;
    for (std::size_t k = 0; k < frame.source.size(); ++k)
      if (frame.ground_plane.head<3>().dot(frame.source[k]) + frame.ground_plane.w() <
              kMinHeightAboveGroundM ||
          !keyframe_image.seenPast(T_keyframe_lidar * frame.source[k], margin)) {
        frame.source[kept] = frame.source[k];
        frame.source_indices[kept] = frame.source_indices[k];
        ++kept;
      }
    result.dropped_moving_points = static_cast<int>(frame.source.size() - kept);
    frame.source.resize(kept);
    frame.source_indices.resize(kept);
  }
}

bool
Odometry::Impl::trackDense(const Frame& frame,
                           const FeatureTrack& track,
                           OdometryFrameResult& result) const
{
  const int inliers = static_cast<int>(track.ransac.inlier_indices.size());
  result.status = TrackingStatus::kFeatures;
  result.T_world_lidar = track.T_world_features;
  result.message =
      "features: " + std::to_string(inliers) + " inliers with " + track.reference;
  if (!params.registration.refine)
    return false;
  // Along the directions the scan does not constrain (a corridor's axis, an open field's
  // x, y and yaw) strong features set the pose; weak ones (a few posts of a guard rail,
  // a passing car) do not alone: the constant-velocity prior does, moved part of the
  // way to them where they are near it (weak_feature_share). Before any velocity was
  // measured (a run's second frame) the prior is no motion at all, which says nothing
  // about a moving vehicle: the features set those directions, weak or not. (A VLP-16
  // starting at 10 m/s in a street measured 0.03 m a frame from there on.)
  bool strong = inliers >= params.strong_feature_inliers || velocity_age_frames < 0;
  Pose3d T_world_weak_anchor;
  const DenseOptions weak_anchored = weakAnchored(frame, track, T_world_weak_anchor);
  const DenseOptions anchored =
      strong ? DenseOptions{0.0, &track.T_world_features} : weak_anchored;
  DenseResult dense = registerToMap(
      frame.source, localMap(), track.T_world_features, params.dense, anchored);
  if (strong && velocity_tracked && dense.success && dense.degenerate_directions > 0 &&
      !nearPrior(frame, track.T_world_features)) {
    // Strong features far from a tracked prior, and the scan cannot confirm them along
    // some direction: nothing tells a large motion there from keypoints that move with
    // the sensor (a tunnel's walls, sampled the same way in every scan, give "no motion"
    // with dozens of inliers). The prior keeps that direction. (Without a tracked
    // velocity the prior is no motion at all, and the features stand.)
    strong = false;
    dense = registerToMap(frame.source,
                          localMap(),
                          track.T_world_features,
                          params.dense,
                          priorAnchored(frame));
    result.degraded = true;
    result.message +=
        "; far from the prior along a direction the scan does not constrain";
  }
  bool prior_won = false;
  if (strong && params.check_strong_features && !frame.prior_overruled_before &&
      velocity_tracked && dense.success && priorGate(frame).dynamics &&
      !nearPrior(frame, dense.T_world_lidar)) {
    // Strong features, refined, beyond what the vehicle can deviate from its tracked
    // velocity in one frame: periodic structure (a guard rail's posts every few metres)
    // aliases dozens of keypoints by part of a period, and the dense step stays in that
    // minimum. The prior's fit wins when it ends elsewhere and the scan cannot tell
    // the two apart: nearly as many pairs, an RMS residual within indistinct_residual_m
    // (a real manoeuvre the prior missed leaves the prior's fit clearly worse). Never two
    // frames running: a prior that won once may itself be the stale one (on a highway
    // the next frames' velocity would come from it), so the next features stand.
    const DenseResult from_prior = registerToMap(frame.source,
                                                 localMap(),
                                                 frame.T_world_prior,
                                                 params.dense,
                                                 priorAnchored(frame));
    if (from_prior.success &&
        from_prior.num_correspondences >= kPriorPairsShare * dense.num_correspondences &&
        moved(dense.T_world_lidar, from_prior.T_world_lidar, 0.02, 0.1) &&
        from_prior.rmse_m < dense.rmse_m + params.indistinct_residual_m) {
      strong = false;
      prior_won = true;
      dense = from_prior;
      result.degraded = true;
      result.message +=
          "; beyond the vehicle's motion from the prior, which the scan fits "
          "as well: dense from the prior";
    }
  }
  if (!strong && !prior_won)
    checkWeakFeatures(frame, track, weak_anchored, dense, result);
  keepDenseStats(dense, result);
  if (!dense.success) {
    result.degraded = true;
    result.message +=
        "; refinement failed, feature estimate kept (" + dense.message + ")";
    return false;
  }
  result.T_world_lidar = dense.T_world_lidar;
  result.refined = true;
  result.message += "; " + dense.message;
  // The other way round: dense ICP must not slide away from strong features along a
  // direction where the scan hardly sees a difference (the local map's planes along a
  // corridor, cars driving beside). There the features' planar motion stands; height,
  // roll and pitch stay dense ICP's. A slide, not the centimetres dense ICP refines
  // features by (their pixels).
  if (strong && moved(dense.T_world_lidar, track.T_world_features, 0.1, 0.5) &&
      denseSeparation(dense, track.T_world_features) < params.indistinct_residual_m) {
    result.T_world_lidar =
        planarFromFeatures(T_world_last, track.T_world_features, dense.T_world_lidar);
    result.message +=
        "; its slide from the features is indistinct: their planar motion kept";
  }
  if (dense.degenerate_directions > 0) {
    result.degraded = true;
    result.message += strong ? " (from the features)" : " (from the prior)";
  }
  return prior_won;
}

bool
Odometry::Impl::trackDenseOnly(const Frame& frame, OdometryFrameResult& result) const
{
  // Only where a vehicle cannot deviate far from its tracked velocity within the frame
  // interval. There a dense step from the prediction that pairs most of the scan,
  // constrains every direction and ends near the prediction is what the features'
  // estimate would have been refined to; anything else (a turn the prior missed, a
  // corridor, a scan that pairs poorly) goes the usual way, with its features.
  const PriorGate gate = priorGate(frame);
  if (!gate.dynamics)
    return false;
  const DenseResult dense = registerToMap(
      frame.source, localMap(), frame.T_world_prior, params.dense, priorAnchored(frame));
  const double paired_ratio = static_cast<double>(dense.num_correspondences) /
                              std::max(1, dense.num_source_points);
  // Soon after features failed here, a direction the scan leaves weak keeps the prior,
  // as the failed features' hypothesis search would keep it
  // (failed_features_skip_frames).
  const bool weak =
      dense.degenerate_directions > 0 || dense.weakest_ratio < kDenseOnlyMinWeakestRatio;
  const bool features_failed_lately =
      frames_since_failed_features >= 0 &&
      frames_since_failed_features < params.failed_features_skip_frames;
  if (!dense.success || (weak && !features_failed_lately) ||
      dense.iterations >= params.dense.max_iterations ||
      paired_ratio < kMinFallbackPairedRatio ||
      !withinGate(frame, dense.T_world_lidar, gate))
    return false;
  result.status = TrackingStatus::kDenseFallback;
  result.T_world_lidar = dense.T_world_lidar;
  result.refined = true;
  result.features_skipped = true;
  result.features.reset(); // (a scan without times may have had them made ahead)
  result.num_features = 0;
  keepDenseStats(dense, result);
  result.message =
      "dense from the prior, no features made (none wanted); " + dense.message;
  if (weak) {
    result.degraded = true;
    const int ago = frames_since_failed_features + 1;
    result.message += "; weakly constrained, kept near the prior: the features failed " +
                      std::to_string(ago) + (ago == 1 ? " frame" : " frames") + " before";
  }
  return true;
}

Odometry::Impl::PriorGate
Odometry::Impl::priorGate(const Frame& frame) const
{
  // Shrunk to what a vehicle can deviate from its velocity only when there is one: a
  // prior without a tracked velocity is a guess (no motion at the start). A velocity
  // measured k frames ago (carried by constant-velocity frames since) may have changed
  // over k more intervals: the gate is a * dt * (dt + k dt), up to the fixed one.
  PriorGate gate{params.prior_gate_m, params.prior_gate_deg, false};
  if (velocity_age_frames < 0)
    return gate;
  const double dt2 = velocityAgeDt2(frame);
  if (params.prior_gate_accel_mps2 > 0.0 &&
      params.prior_gate_accel_mps2 * dt2 < gate.metres) {
    gate.metres = params.prior_gate_accel_mps2 * dt2;
    gate.dynamics = true;
  }
  if (params.prior_gate_angular_accel_dps2 > 0.0 &&
      params.prior_gate_angular_accel_dps2 * dt2 < gate.degrees) {
    gate.degrees = params.prior_gate_angular_accel_dps2 * dt2;
    gate.dynamics = true;
  }
  return gate;
}

void
Odometry::Impl::keepPriorHeight(const Frame& frame, OdometryFrameResult& result) const
{
  // Top-down features say nothing about the height, and where the scan holds it only
  // weakly (steep ground, few planes) the dense step can slide up or down by
  // decimetres; after constant-velocity frames nothing else says where the height
  // went. Only then: with a velocity measured the frame before, the scan's height
  // stands (a prior held against it would carry its own climb on, frame after frame,
  // where the road's grade changes: doc/odometry.md).
  if (velocity_age_frames < 1 || !(params.prior_gate_vertical_accel_mps2 > 0.0))
    return;
  const double gate = params.prior_gate_vertical_accel_mps2 * velocityAgeDt2(frame);
  const double dz =
      (frame.T_world_prior.inverse() * result.T_world_lidar).translation().z();
  if (std::abs(dz) <= gate)
    return;
  result.T_world_lidar =
      planarFromFeatures(T_world_last, result.T_world_lidar, frame.T_world_prior);
  result.degraded = true;
  char text[160];
  std::snprintf(text,
                sizeof(text),
                "; %+.2f m in height from a stale prior, beyond a vehicle's vertical "
                "motion (%.2f m): the prior's height, roll and pitch kept",
                dz,
                gate);
  result.message += text;
}

bool
Odometry::Impl::withinGate(const Frame& frame,
                           const Pose3d& T_world_lidar,
                           const PriorGate& gate)
{
  const Pose3d diff = frame.T_world_prior.inverse() * T_world_lidar;
  return diff.translation().norm() <= gate.metres && angleDeg(diff) <= gate.degrees;
}

DenseOptions
Odometry::Impl::weakAnchored(const Frame& frame,
                             const FeatureTrack& track,
                             Pose3d& T_world_anchor) const
{
  DenseOptions options = priorAnchored(frame);
  if (!(params.weak_feature_share > 0.0) || !velocity_tracked ||
      params.ground.level_cloud || !nearPrior(frame, track.T_world_features))
    return options;
  // The prior alone holds the speed on an open road, where the scan does not
  // constrain it; the share moves it toward the features' x, y and yaw (the prior's
  // height, roll and pitch: doc/odometry.md), interpolated as poses. A steady
  // acceleration then lags by a dt^2 (1 - share) / share, and an aliased match
  // pulls by the share of its error.
  T_world_anchor = interpolatePose(
      frame.T_world_prior,
      planarFromFeatures(T_world_last, track.T_world_features, frame.T_world_prior),
      params.weak_feature_share);
  options.T_world_anchor = &T_world_anchor;
  return options;
}

void
Odometry::Impl::checkWeakFeatures(const Frame& frame,
                                  const FeatureTrack& track,
                                  const DenseOptions& anchored,
                                  DenseResult& dense,
                                  OdometryFrameResult& result) const
{
  // Weak features: their height, roll and pitch come from max-height pixels of few
  // inliers (a 16-beam scan: decimetres off; 2 Hz: up to ~2 deg of pitch), from where
  // the dense step can settle in a wrong minimum. A second dense fit starts from the
  // features' planar motion with the prior's height, roll and pitch (near the prior, a
  // level mount) or from the prior itself; the better paired one wins.
  const Pose3d& T_world_prior = frame.T_world_prior;
  const bool near_prior = nearPrior(frame, track.T_world_features);
  const bool second_from_features = near_prior && !params.ground.level_cloud;
  const Pose3d T_second =
      second_from_features
          ? planarFromFeatures(T_world_last, track.T_world_features, T_world_prior)
          : T_world_prior;
  const DenseResult second =
      registerToMap(frame.source, localMap(), T_second, params.dense, anchored);
  // Far from a tracked prior, weak features are as likely aliased (guard-rail posts
  // every 2.7 m passed at 2.7 m a frame) as right: there the prior's fit wins unless the
  // features' pairs clearly more (kPriorPairsShare).
  const bool prior_nearly_as_good =
      !near_prior && velocity_tracked && second.success && dense.success &&
      second.num_correspondences >= kPriorPairsShare * dense.num_correspondences;
  if (second.success &&
      (!dense.success || second.num_correspondences > dense.num_correspondences ||
       prior_nearly_as_good)) {
    dense = second;
    const PriorGate fixed{params.prior_gate_m, params.prior_gate_deg, false};
    if (!near_prior && withinGate(frame, track.T_world_features, fixed)) {
      // Beyond the vehicle's dynamics but within the fixed gates: the decimetres weak
      // features are off by (their pixels), resolved by the prior's fit; not a failure.
      result.message += "; beyond the vehicle's motion from the prior: dense from the prior";
    } else if (!near_prior) {
      result.status = TrackingStatus::kDenseFallback;
      result.degraded = true;
      result.message = "weak features disagree with the prior: dense from the prior";
    } else {
      result.message += " (dense from their planar part fitted better)";
    }
  }
  // Cross-check: weak features must not drag the dense step along a direction the scan
  // hardly constrains. Dense from the prior as well; where the scan cannot tell the two
  // results apart, the prior's wins.
  if (!dense.success || !second_from_features)
    return;
  const DenseResult from_prior =
      registerToMap(frame.source, localMap(), T_world_prior, params.dense, anchored);
  // 2 cm / 0.1 deg: below the range noise a choice changes nothing.
  if (from_prior.success &&
      moved(dense.T_world_lidar, from_prior.T_world_lidar, 0.02, 0.1) &&
      denseSeparation(from_prior, dense.T_world_lidar) < params.indistinct_residual_m) {
    dense = from_prior;
    result.degraded = true;
    result.message += " (the scan does not tell the weak features' slide from the "
                      "prior: dense from the prior)";
  }
}

const pcl::PointCloud<pcl::PointXYZI>&
Odometry::Impl::keptCloud(Frame& frame, OdometryFrameResult& result) const
{
  // The whole compensated scan, made once and only when a key-frame or the map keeps it.
  if (!frame.kept_cloud) {
    const pcl::StopWatch t0;
    frame.kept_cloud =
        frame.xi_sweep
            ? deskewCloud(
                  frame.input, frame.times->all(), *frame.xi_sweep, params.deskew.bins)
            : frame.input_ptr;
    result.timings.deskew_ms += t0.getTime();
  }
  return *frame.kept_cloud;
}

void
Odometry::Impl::decideKeyFrame(Frame& frame, OdometryFrameResult& result)
{
  // 6. Key-frame decision: the paper's rule (sec. 7.3) plus safety rules. The pose is
  //    final here; it is kept on SO(3) (single-precision steps add ~1e-7 each).
  const pcl::StopWatch watch;
  if (!result.T_world_lidar.matrix().allFinite()) {
    // A degenerate solve must not reach the map and the pose graph: predict instead.
    result.T_world_lidar = frame.T_world_prior;
    result.status = TrackingStatus::kConstantVelocity;
    result.degraded = true;
    result.message += "; non-finite estimate: constant-velocity prediction";
  }
  result.T_world_lidar = normalizedPose(result.T_world_lidar);
  result.T_keyframe_lidar =
      composePoses(T_world_keyframe.inverse(), result.T_world_lidar);
  const bool tracked =
      result.status == TrackingStatus::kFeatures ||
      (result.status == TrackingStatus::kDenseFallback && result.refined);
  if (elevation && tracked && result.refined && !result.degraded &&
      !frame.source.empty()) {
    // The residuals against the map the frame was just aligned to (before it is added),
    // of frames whose pose the scan fixes well: where a direction was kept at the
    // prior or a fallback set the pose, the residuals hold that pose's error too.
    const pcl::StopWatch t0;
    elevation->observe(*frame.raw_ptr,
                       frame.source_indices,
                       frame.source,
                       result.T_world_lidar.cast<float>(),
                       localMap());
    result.timings.elevation_ms += t0.getTime();
  }
  const int frames_since = frames_since_keyframe + 1;
  // A frame tracked without features has no inliers to count: the paper's rule waits
  // twice as long there (kDenseOnlyKeyframeFactor).
  const int min_frames = params.keyframe_min_frames *
                         (result.features_skipped ? kDenseOnlyKeyframeFactor : 1);
  const bool paper_rule = frames_since >= min_frames &&
                          result.num_inliers <= params.keyframe_max_common_points;
  const bool far =
      result.T_keyframe_lidar.translation().norm() > params.keyframe_max_distance_m ||
      angleDeg(result.T_keyframe_lidar) > params.keyframe_max_rotation_deg;
  const bool useful = result.num_features >= params.keyframe_min_inliers;
  const bool weak = result.num_inliers < params.keyframe_min_inliers && useful;
  const bool reanchor = frames_without_tracking + 1 >= kReanchorAfterFrames && useful;
  if ((tracked && (paper_rule || far || weak)) || reanchor) {
    ensureFeatures(frame, result); // a frame tracked without them: a key-frame has them
    result.keyframe = makeKeyFrame(result, *frame.features, keptCloudPtr(frame, result));
    keyframe_image = std::move(frame.image);
    result.reference_keyframe = result.keyframe->id;
    result.T_keyframe_lidar = Pose3d::Identity();
    if (!tracked) {
      result.degraded = true;
      result.message += "; re-anchored: new key-frame after a stretch without tracking";
    }
  }
  if (!result.keyframe && tracked && result.refined &&
      map_scans < params.dense.young_map_scans)
    insertIntoMap(keptCloudPtr(frame, result), result.T_world_lidar);
  result.timings.keyframe_ms = watch.getTime();
  if (tracked && !result.keyframe) {
    last_features = frame.features;
    T_world_last_features = result.T_world_lidar;
  } else if (result.keyframe) {
    last_features.reset(); // the key-frame itself is now the closest reference
  }
}

} // namespace rast
} // namespace pcl
