/// \file loop_closing.cpp
/// \brief The loop-closing stage's parts outside the threads: LoopClosingParams, the
/// information of odometry and loop edges, the pose graph of all key-frames and the
/// global bundle adjustment.

#include "loop_closing.h"

#include <algorithm>
#include <cmath>
#include <string>
#include <vector>

namespace pcl {
namespace rast {
namespace loop_closing_detail {

namespace {

/// Diagonal information (translation, rotation) from standard deviations.
Eigen::Matrix<double, 6, 6>
diagonalInformation(double sigma_t_m, double sigma_r_rad)
{
  Eigen::Matrix<double, 6, 6> info = Eigen::Matrix<double, 6, 6>::Zero();
  info.diagonal().head<3>().setConstant(1.0 / (sigma_t_m * sigma_t_m));
  info.diagonal().tail<3>().setConstant(1.0 / (sigma_r_rad * sigma_r_rad));
  return info;
}

} // namespace

Eigen::Matrix<double, 6, 6>
odometryInformation(const Pose3d& T_prev_kf, int map_scans, const LoopClosingParams& p)
{
  const double d = T_prev_kf.translation().norm();
  double young = 1.0;
  if (p.young_map_scans > 1 && map_scans < p.young_map_scans) {
    const double maturity = std::clamp(static_cast<double>(map_scans - 1) /
                                           static_cast<double>(p.young_map_scans - 1),
                                       0.0, 1.0);
    young = p.young_map_sigma_scale + (1.0 - p.young_map_sigma_scale) * maturity;
  }
  return diagonalInformation(
      young * (p.odometry_sigma_t_base_m + p.odometry_sigma_t_per_m * d),
      young * (p.odometry_sigma_r_base_rad + p.odometry_sigma_r_per_m_rad * d));
}

Eigen::Matrix<double, 6, 6>
loopInformation(int num_inliers, const LoopClosingParams& p)
{
  const double scale =
      std::sqrt(static_cast<double>(p.loop_reference_inliers) / std::max(1, num_inliers));
  return diagonalInformation(p.loop_sigma_t_m * scale, p.loop_sigma_r_rad * scale);
}

PoseGraph
keyFrameGraph(const PoseVector& poses,
              const SlamMap& map,
              const std::vector<LoopEdge>& loops,
              const LoopClosingParams& params,
              std::vector<std::size_t>* loop_of_edge)
{
  const std::size_t n = poses.size();
  const std::vector<KeyFrame::Ptr> keyframes = map.keyFrames(); // at least the n posed
  PoseGraph graph;
  for (std::size_t id = 0; id < n; ++id)
    graph.addNode(static_cast<int>(id), poses[id], id == 0);
  for (std::size_t id = 1; id < n; ++id) {
    const auto kf_id = static_cast<KeyFrameId>(id);
    const Pose3d T = map.odometryEdge(kf_id);
    graph.addEdge(static_cast<int>(id - 1), static_cast<int>(id), T,
                  odometryInformation(T, keyframes[id]->odometry_map_scans, params),
                  PoseGraphEdgeType::kOdometry);
  }
  for (std::size_t k = 0; k < loops.size(); ++k) {
    if (!loops[k].active || loops[k].query >= n || loops[k].candidate >= n)
      continue;
    const std::size_t edge = graph.addEdge(
        static_cast<int>(loops[k].candidate), static_cast<int>(loops[k].query),
        loops[k].T_candidate_query, loopInformation(loops[k].num_inliers, params),
        PoseGraphEdgeType::kLoop);
    if (loop_of_edge) {
      loop_of_edge->resize(edge + 1, loops.size());
      (*loop_of_edge)[edge] = k;
    }
  }
  return graph;
}

bool
optimizeKeyFrameGraph(SlamMap& map,
                      const SlamParams& params,
                      std::map<KeyFrameId, Pose3d>& corrected,
                      std::vector<LoopEdge>& loops,
                      std::vector<std::size_t>& dropped)
{
  const PoseVector poses = map.keyFramePoses();
  if (poses.size() < 2)
    return false;
  loops = map.loopEdges();
  PoseGraph graph;
  for (int attempt = 0; attempt < 4; ++attempt) {
    std::vector<std::size_t> loop_of_edge; // edge index -> loop index
    graph = keyFrameGraph(poses, map, loops, params.loop_closing, &loop_of_edge);
    PoseGraphOptions options = params.pose_graph;
    options.gauge_node_id = 0;
    const PoseGraphSummary summary = optimizePoseGraph(graph, options);
    if (!summary.success)
      return false;
    const auto bad = findInconsistentEdges(graph, params.loop_closing.inconsistent_chi2,
                                           PoseGraphEdgeType::kLoop);
    if (bad.empty())
      break;
    // Drop the worst loop only: one false loop can make true ones look bad too.
    const std::size_t k = loop_of_edge.at(bad.front().edge_index);
    loops[k].active = false;
    map.deactivateLoopEdge(k);
    dropped.push_back(k);
  }
  for (const auto& [id, node] : graph.nodes())
    corrected[static_cast<KeyFrameId>(id)] = node.pose();
  return true;
}

} // namespace loop_closing_detail

PoseGraph
keyFrameGraph(const SlamMap& map,
              const std::vector<LoopEdge>& loops,
              const LoopClosingParams& params)
{
  return loop_closing_detail::keyFrameGraph(map.keyFramePoses(), map, loops, params, nullptr);
}

using loop_closing_detail::loopInformation;
using loop_closing_detail::odometryInformation;

bool
LoopClosingParams::isValid(std::string* why) const
{
  std::string reason;
  const auto positive = [](double v) { return v > 0.0 && std::isfinite(v); };
  const auto non_negative = [](double v) { return v >= 0.0 && std::isfinite(v); };
  if (!positive(odometry_sigma_t_base_m) || !non_negative(odometry_sigma_t_per_m))
    reason = "odometry translation sigmas must be > 0 (base) and >= 0 (per metre)";
  else if (!positive(odometry_sigma_r_base_rad) || !non_negative(odometry_sigma_r_per_m_rad))
    reason = "odometry rotation sigmas must be > 0 (base) and >= 0 (per metre)";
  else if (!positive(loop_sigma_t_m) || !positive(loop_sigma_r_rad))
    reason = "loop sigmas must be > 0, got " + std::to_string(loop_sigma_t_m) + ", " +
             std::to_string(loop_sigma_r_rad);
  else if (loop_reference_inliers < 1)
    reason = "loop_reference_inliers must be >= 1, got " +
             std::to_string(loop_reference_inliers);
  else if (!positive(inconsistent_chi2))
    reason = "inconsistent_chi2 must be > 0, got " + std::to_string(inconsistent_chi2);
  else if (cooldown_keyframes < 0)
    reason = "cooldown_keyframes must be >= 0, got " + std::to_string(cooldown_keyframes);
  else if (!positive(revisit_radius_m))
    reason = "revisit_radius_m must be > 0, got " + std::to_string(revisit_radius_m);
  else if (!(revisit_angle_deg > 0.0 && revisit_angle_deg <= 180.0))
    reason = "revisit_angle_deg must be in (0, 180], got " + std::to_string(revisit_angle_deg);
  else if (revisit_anchor_keyframes < 0)
    reason = "revisit_anchor_keyframes must be >= 0, got " +
             std::to_string(revisit_anchor_keyframes);
  else if (!(young_map_sigma_scale >= 1.0 && std::isfinite(young_map_sigma_scale)))
    reason = "young_map_sigma_scale must be >= 1, got " + std::to_string(young_map_sigma_scale);
  else if (young_map_scans < 1)
    reason = "young_map_scans must be >= 1, got " + std::to_string(young_map_scans);
  else if (global_ba_max_iterations < 1)
    reason = "global_ba_max_iterations must be >= 1, got " +
             std::to_string(global_ba_max_iterations);
  if (why && !reason.empty())
    *why = reason;
  return reason.empty();
}

BundleAdjustmentSummary
globalBundleAdjustment(std::map<KeyFrameId, Pose3d>& poses,
                       const std::vector<KeyFrame::Ptr>& keyframes,
                       const std::vector<MapPoint>& points,
                       const std::vector<LoopEdge>& loops,
                       const LoopClosingParams& loop_params,
                       const BundleAdjustmentParams& ba_params)
{
  BundleAdjustmentProblem problem;
  problem.poses = poses;
  if (!problem.poses.empty())
    problem.fixed.insert(problem.poses.begin()->first); // gauge: the first key-frame
  for (const MapPoint& mp : points) {
    int n = 0;
    for (const auto& o : mp.observations)
      n += problem.poses.count(o.keyframe) && o.keyframe < keyframes.size();
    if (n < 2)
      continue; // a point seen once does not constrain any pose
    problem.points[mp.id] = mp.p_world;
    for (const auto& o : mp.observations)
      if (problem.poses.count(o.keyframe) && o.keyframe < keyframes.size())
        problem.observations.push_back({o.keyframe, mp.id, o.p_keyframe.cast<double>()});
  }
  // Odometry edges keep key-frames without shared points connected; loop edges carry
  // the loop (no map point is associated across a loop).
  for (std::size_t id = 1; id < keyframes.size(); ++id) {
    if (!problem.poses.count(id) || !problem.poses.count(id - 1))
      continue;
    const Pose3d T = keyframes[id]->T_previous_keyframe;
    problem.pose_constraints.push_back(
        {static_cast<KeyFrameId>(id - 1), static_cast<KeyFrameId>(id), T,
         odometryInformation(T, keyframes[id]->odometry_map_scans, loop_params).cwiseSqrt()});
  }
  for (const LoopEdge& e : loops)
    if (e.active && problem.poses.count(e.candidate) && problem.poses.count(e.query))
      problem.pose_constraints.push_back(
          {e.candidate, e.query, e.T_candidate_query,
           loopInformation(e.num_inliers, loop_params).cwiseSqrt()});
  BundleAdjustmentSummary summary = bundleAdjust(problem, ba_params);
  if (summary.success)
    poses = problem.poses;
  return summary;
}

} // namespace rast
} // namespace pcl
