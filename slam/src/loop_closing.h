#pragma once
/// \file loop_closing.h
/// \brief Internal to RastSlam: the information matrices of the pose graph's edges.
/// Not installed.

#include <Eigen/Core>
#include <cstddef>
#include <map>
#include <pcl/rast/rigid_pose.h>
#include <pcl/slam/rast_slam.h>
#include <pcl/slam/session.h>
#include <vector>

namespace pcl {
namespace rast {
namespace loop_closing_detail {

/// Odometry edge of a key-frame step \a T_prev_kf: sigma grows with its length, and
/// with a young local map (fewer than young_map_scans scans).
Eigen::Matrix<double, 6, 6>
odometryInformation(const Pose3d& T_prev_kf, int map_scans, const LoopClosingParams& p);

/// Loop edge of \a num_inliers feature inliers: sigma scaled by
/// sqrt(loop_reference_inliers / inliers).
Eigen::Matrix<double, 6, 6> loopInformation(int num_inliers, const LoopClosingParams& p);

/// The pose graph of the key-frames of \a map at \a poses (key-frame 0 fixed):
/// odometry edges, and the active \a loops among them. \a loop_of_edge (optional)
/// maps each loop edge's index to its index in \a loops.
PoseGraph keyFrameGraph(const PoseVector& poses,
                        const SlamMap& map,
                        const std::vector<LoopEdge>& loops,
                        const LoopClosingParams& params,
                        std::vector<std::size_t>* loop_of_edge);
/// The pose graph of all key-frames of \a map: odometry edges (tracking's relative
/// motion, refined by local BA), the active loop edges (robust loss), key-frame 0 fixed.
/// Loops still inconsistent after it (a false loop keeps a large residual) are
/// deactivated in the map, worst first, and the graph re-optimized from the same start
/// (up to 3 times). False when there is nothing to optimize or the solve failed.
/// \param[out] corrected the optimized pose of every key-frame
/// \param[out] loops the map's loop edges; \param[out] dropped the indices dropped
bool optimizeKeyFrameGraph(SlamMap& map,
                           const SlamParams& params,
                           std::map<KeyFrameId, Pose3d>& corrected,
                           std::vector<LoopEdge>& loops,
                           std::vector<std::size_t>& dropped);

} // namespace loop_closing_detail
} // namespace rast
} // namespace pcl
