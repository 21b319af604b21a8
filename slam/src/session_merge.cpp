/// \file session_merge.cpp
/// \brief mergeSessions: a new drive anchored on a prior session by inter-session
/// loops and optimized with its pose graph (session_merge.h).

#include "loop_closing.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdio>
#include <memory>
#include <pcl/common/time.h>
#include <pcl/slam/session_localizer.h>
#include <pcl/slam/session_merge.h>
#include <stdexcept>
#include <thread>

namespace pcl {
namespace rast {

bool
SessionMergeParams::isValid(std::string* why) const
{
  const auto fail = [why](const std::string& message) {
    if (why)
      *why = message;
    return false;
  };
  std::string sub;
  if (min_anchor_loops < 1)
    return fail("min_anchor_loops must be >= 1, got " + std::to_string(min_anchor_loops));
  if (!(agreement_m > 0.0) || !std::isfinite(agreement_m))
    return fail("agreement_m must be > 0, got " + std::to_string(agreement_m));
  if (!(agreement_per_m >= 0.0) || !std::isfinite(agreement_per_m))
    return fail("agreement_per_m must be >= 0, got " + std::to_string(agreement_per_m));
  if (!(agreement_rad > 0.0) || !std::isfinite(agreement_rad))
    return fail("agreement_rad must be > 0, got " + std::to_string(agreement_rad));
  if (keyframe_stride < 1)
    return fail("keyframe_stride must be >= 1, got " + std::to_string(keyframe_stride));
  if (num_threads < 1)
    return fail("num_threads must be >= 1, got " + std::to_string(num_threads));
  if (!loop_closing.isValid(&sub))
    return fail("loop_closing: " + sub);
  if (!pose_graph.isValid(&sub))
    return fail("pose_graph: " + sub);
  return true;
}

namespace {

/// A verified placement of drive key-frame \a drive_keyframe: the frame of the drive in
/// the prior's world it implies.
struct Anchor
{
  std::size_t loop = 0; ///< index into the result's loops
  Pose3d T_prior_driveworld = Pose3d::Identity();
};

double
rotationAngle(const Eigen::Matrix3d& R)
{
  return Eigen::AngleAxisd(R).angle();
}

/// Place the drive key-frames \a ids on the prior map, \a num_threads at a time.
std::vector<Placement>
placeAll(const SessionLocalizer& prior,
         const Session& drive,
         const std::vector<KeyFrameId>& ids,
         int num_threads)
{
  std::vector<Placement> placements(ids.size());
  // Appearance alone: most of a drive's key-frames try, and the merge's anchors want
  // several placements that agree, not every one a placement could find.
  PlacementOptions options;
  options.polar_candidates = false;
  std::atomic<std::size_t> next{0};
  const auto work = [&] {
    for (std::size_t i = next++; i < ids.size(); i = next++) {
      const KeyFrame& kf = *drive.keyframes[ids[i]];
      if (kf.cloud) {
        placements[i] = prior.place(kf, nullptr, options);
        continue;
      }
      // A cloud read when it is needed (Session::cloud_source, cloud_files).
      KeyFrame query;
      query.features = kf.features;
      query.cloud = sessionCloud(drive, kf.id);
      if (!query.cloud || query.cloud->empty()) {
        placements[i].message = "key-frame " + std::to_string(kf.id) + " has no cloud";
        continue;
      }
      placements[i] = prior.place(query, nullptr, options);
    }
  };
  std::vector<std::thread> threads;
  const int extra = std::min<int>(num_threads, static_cast<int>(ids.size())) - 1;
  for (int t = 0; t < extra; ++t)
    threads.emplace_back(work);
  work();
  for (auto& thread : threads)
    thread.join();
  return placements;
}

} // namespace

SessionMergeResult
mergeSessions(const SessionLocalizer& prior,
              const Session& drive,
              const SessionMergeParams& params)
{
  std::string why;
  if (!params.isValid(&why))
    throw std::invalid_argument("mergeSessions: invalid parameters: " + why);
  if (drive.keyframes.empty())
    throw std::invalid_argument("mergeSessions: the drive has no key-frames");
  for (std::size_t i = 0; i < drive.keyframes.size(); ++i)
    if (!drive.keyframes[i] || drive.keyframes[i]->id != i)
      throw std::invalid_argument("mergeSessions: drive key-frame " + std::to_string(i) +
                                  " is missing or has another id");
  const pcl::StopWatch watch;
  const Session& old = prior.session();
  SessionMergeResult result;
  const auto offset = static_cast<KeyFrameId>(old.keyframes.size());
  result.drive_first_keyframe = offset;

  // ---- inter-session loops: each drive key-frame with features placed on the map ----
  std::vector<KeyFrameId> ids;
  for (std::size_t i = 0; i < drive.keyframes.size(); i += params.keyframe_stride)
    if (!drive.keyframes[i]->features.empty() &&
        sessionHasCloud(drive, static_cast<KeyFrameId>(i)))
      ids.push_back(static_cast<KeyFrameId>(i));
  result.keyframes_tried = static_cast<int>(ids.size());
  const std::vector<Placement> placements = placeAll(prior, drive, ids, params.num_threads);
  std::vector<Anchor> anchors;
  for (std::size_t i = 0; i < ids.size(); ++i) {
    const Placement& p = placements[i];
    if (!p.success)
      continue;
    InterSessionLoop loop;
    loop.prior_keyframe = p.keyframe;
    loop.drive_keyframe = ids[i];
    loop.T_prior_drive = p.T_world_lidar;
    loop.num_inliers = p.num_inliers;
    anchors.push_back(
        {result.loops.size(),
         normalizedPose(p.T_world_lidar * drive.keyframes[ids[i]]->T_world_keyframe.inverse())});
    result.loops.push_back(loop);
  }

  // ---- the largest set of placements that agree on where the drive lies ----
  const auto agreeing = [&](const Anchor& hypothesis) {
    std::vector<std::size_t> members;
    const InterSessionLoop& h = result.loops[hypothesis.loop];
    const Eigen::Vector3d h_position =
        drive.keyframes[h.drive_keyframe]->T_world_keyframe.translation();
    for (std::size_t a = 0; a < anchors.size(); ++a) {
      const InterSessionLoop& l = result.loops[anchors[a].loop];
      const Pose3d& T_drive = drive.keyframes[l.drive_keyframe]->T_world_keyframe;
      const Pose3d predicted = hypothesis.T_prior_driveworld * T_drive;
      const double along = (T_drive.translation() - h_position).norm();
      const double dt = (predicted.translation() - l.T_prior_drive.translation()).norm();
      const double dr =
          rotationAngle(predicted.rotation().transpose() * l.T_prior_drive.rotation());
      if (dt <= params.agreement_m + params.agreement_per_m * along &&
          dr <= params.agreement_rad)
        members.push_back(a);
    }
    return members;
  };
  std::vector<std::size_t> best;
  std::size_t best_hypothesis = 0;
  for (std::size_t a = 0; a < anchors.size(); ++a) {
    std::vector<std::size_t> members = agreeing(anchors[a]);
    if (members.size() > best.size()) {
      best = std::move(members);
      best_hypothesis = a;
    }
  }
  result.loops_agreeing = static_cast<int>(best.size());
  result.connected = static_cast<int>(best.size()) >= params.min_anchor_loops;
  for (const std::size_t a : best)
    result.loops[anchors[a].loop].agrees = result.connected;
  const Pose3d T_prior_driveworld =
      result.connected ? anchors[best_hypothesis].T_prior_driveworld : Pose3d::Identity();
  result.T_prior_drive = T_prior_driveworld;

  // ---- the merged session ----
  Session& merged = result.merged;
  merged.version = kSessionFormatVersion;
  merged.info = old.info;
  merged.info.num_frames = old.info.num_frames + drive.info.num_frames;
  int components = 1;
  for (const SessionDrive& d : old.drives)
    components = std::max(components, d.component + 1);
  merged.drives = sessionDrives(old);
  result.component = result.connected ? 0 : components;
  {
    std::size_t first = offset;
    for (SessionDrive d : sessionDrives(drive)) {
      d.first_keyframe = static_cast<KeyFrameId>(first);
      first += d.num_keyframes;
      // A drive session's own separate parts stay separate, after the prior's.
      d.component = d.component == 0 ? result.component : components + d.component;
      merged.drives.push_back(d);
    }
  }
  for (const KeyFrame::Ptr& kf : old.keyframes)
    merged.keyframes.push_back(std::make_shared<KeyFrame>(*kf));
  merged.cloud_files = old.cloud_files; // clouds of a prior loaded without them
  // Clouds neither held nor in a file: the prior's source below the drive's ids, the
  // drive's (its files or its source) from them on. The drive's lookup is kept by the
  // merged session: the drive may be gone when the clouds are read.
  if (old.cloud_source || !drive.cloud_files.empty() || drive.cloud_source) {
    auto drive_clouds = std::make_shared<Session>();
    drive_clouds->keyframes = drive.keyframes;
    drive_clouds->cloud_files = drive.cloud_files;
    drive_clouds->cloud_source = drive.cloud_source;
    merged.cloud_source =
        [old_source = old.cloud_source, drive_clouds, offset](
            KeyFrameId id) -> pcl::PointCloud<pcl::PointXYZI>::ConstPtr {
      if (id < offset)
        return old_source ? old_source(id) : nullptr;
      return sessionCloud(*drive_clouds, id - offset);
    };
  }
  for (const KeyFrame::Ptr& kf : drive.keyframes) {
    auto copy = std::make_shared<KeyFrame>(*kf);
    copy->id = kf->id + offset;
    copy->T_world_keyframe = normalizedPose(T_prior_driveworld * kf->T_world_keyframe);
    merged.keyframes.push_back(std::move(copy));
  }
  merged.loops = old.loops;
  for (LoopEdge loop : drive.loops) {
    loop.query += offset;
    loop.candidate += offset;
    merged.loops.push_back(loop);
  }

  // The joint graph: the prior's edges, the drive's, and the agreeing loops.
  PoseGraph& graph = merged.graph;
  for (const KeyFrame::Ptr& kf : merged.keyframes)
    graph.addNode(static_cast<int>(kf->id), kf->T_world_keyframe, kf->id == 0);
  for (const PoseGraphEdge& e : old.graph.edges())
    graph.addEdge(e);
  for (PoseGraphEdge e : drive.graph.edges()) {
    e.from += static_cast<int>(offset);
    e.to += static_cast<int>(offset);
    graph.addEdge(e);
  }
  std::vector<std::pair<std::size_t, std::size_t>> loop_edges; // (graph edge, loop)
  if (result.connected) {
    for (const std::size_t a : best) {
      const InterSessionLoop& l = result.loops[anchors[a].loop];
      const Pose3d T_prior_kf = old.keyframes.at(l.prior_keyframe)->T_world_keyframe;
      const Pose3d T_kf_drive = normalizedPose(T_prior_kf.inverse() * l.T_prior_drive);
      loop_edges.emplace_back(
          graph.addEdge(static_cast<int>(l.prior_keyframe),
                        static_cast<int>(l.drive_keyframe + offset), T_kf_drive,
                        loop_closing_detail::loopInformation(l.num_inliers, params.loop_closing),
                        PoseGraphEdgeType::kLoop),
          anchors[a].loop);
    }
    PoseGraphOptions options = params.pose_graph;
    options.gauge_node_id = 0;
    // A false inter-session loop keeps a large residual: drop the worst, re-optimize
    // from the same start (a few times at most).
    const PoseGraph start = graph;
    for (int round = 0; round < 4; ++round) {
      result.optimization = optimizePoseGraph(graph, options);
      if (!result.optimization.success)
        break;
      std::size_t worst = loop_edges.size();
      double worst_chi2 = params.loop_closing.inconsistent_chi2;
      for (std::size_t k = 0; k < loop_edges.size(); ++k) {
        const double chi2 = edgeChi2(graph, graph.edges()[loop_edges[k].first]);
        if (chi2 > worst_chi2) {
          worst_chi2 = chi2;
          worst = k;
        }
      }
      if (worst == loop_edges.size() ||
          static_cast<int>(loop_edges.size()) <= params.min_anchor_loops)
        break;
      result.loops[loop_edges[worst].second].dropped = true;
      const std::size_t edge_index = loop_edges[worst].first;
      loop_edges.erase(loop_edges.begin() + static_cast<std::ptrdiff_t>(worst));
      graph.removeEdge(edge_index); // later edges shift down by one
      for (auto& [edge, loop] : loop_edges)
        if (edge > edge_index)
          --edge;
      for (const auto& [id, node] : start.nodes())
        graph.setNodePose(id, node.pose());
    }
    if (!result.optimization.success) {
      // Keep the anchored start: still a usable merge, reported.
      for (const auto& [id, node] : start.nodes())
        graph.setNodePose(id, node.pose());
      result.message = "pose graph failed (" + result.optimization.message + "); ";
    }
    for (const auto& [edge, loop] : loop_edges) {
      const InterSessionLoop& l = result.loops[loop];
      LoopEdge e;
      e.query = l.drive_keyframe + offset;
      e.candidate = l.prior_keyframe;
      e.T_candidate_query = graph.edges()[edge].measurement();
      e.num_inliers = l.num_inliers;
      e.active = true;
      merged.loops.push_back(e);
    }
    result.loops_used = static_cast<int>(loop_edges.size());
    for (const KeyFrame::Ptr& kf : merged.keyframes)
      kf->T_world_keyframe = graph.node(static_cast<int>(kf->id)).pose();
  }
  else {
    // A separate component: its first key-frame holds its own gauge.
    graph.setNodeFixed(static_cast<int>(offset), true);
  }
  for (std::size_t i = 0; i < drive.keyframes.size(); ++i)
    result.drive_keyframe_poses.push_back(merged.keyframes[offset + i]->T_world_keyframe);

  char text[256];
  if (result.connected)
    std::snprintf(text, sizeof text,
                  "joined: %d of %d drive key-frames placed on the map, %d agree, %d "
                  "inter-session loops in the graph",
                  static_cast<int>(result.loops.size()), result.keyframes_tried,
                  result.loops_agreeing, result.loops_used);
  else
    std::snprintf(text, sizeof text,
                  "not joined (a separate component %d): %d of %d drive key-frames placed "
                  "on the map, at most %d agree, %d needed",
                  result.component, static_cast<int>(result.loops.size()),
                  result.keyframes_tried, result.loops_agreeing, params.min_anchor_loops);
  result.message += text;
  result.time_ms = watch.getTime();
  return result;
}

} // namespace rast
} // namespace pcl
