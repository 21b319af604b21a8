#pragma once
/// \file session_merge.h
/// \brief Multi-session mapping (issue 13): a new drive joined to a prior session by
/// inter-session loops and optimized with the prior's pose graph.
///
/// Every key-frame of the new drive that has features is placed on the prior map with
/// no prior pose (SessionLocalizer: appearance retrieval, feature and dense
/// verification). Each placement proposes where the drive's frame lies in the map's
/// world; the largest set of placements that agree anchors the drive. Those become
/// inter-session loop edges, and one pose graph holds the prior's edges, the drive's
/// own odometry and loop edges and the inter-session loops (prior key-frame 0 fixed).
/// A drive with too few agreeing placements never met the map: it stays a separate
/// component of the merged session, in its own frame, and the result says so.
/// \ingroup slam

#include <pcl/slam/loop_types.h>
#include <pcl/slam/pose_graph.h>
#include <pcl/slam/rast_slam.h>
#include <pcl/slam/session.h>

#include <string>
#include <vector>

namespace pcl {
namespace rast {

class SessionLocalizer;

/// \brief Settings of mergeSessions.
struct SessionMergeParams
{
  /// Placements that must agree on the drive's frame before it is joined (>= 1). Two
  /// by default: one verified placement can still be a look-alike place.
  int min_anchor_loops = 2;
  /// Two placements agree when the frame one implies puts the other's key-frame within
  /// this distance of where it was placed [m] ...
  double agreement_m = 2.0;
  /// ... plus this fraction of the distance between the two key-frames along the drive
  /// (the drive's own odometry drifts between them) ...
  double agreement_per_m = 0.02;
  /// ... and within this rotation [rad].
  double agreement_rad = 3.0 * 3.14159265358979323846 / 180.0;
  /// Try every n-th key-frame of the drive (>= 1; 1: all with features).
  int keyframe_stride = 1;
  /// Threads placing key-frames (>= 1); SessionLocalizer::place is thread-safe.
  int num_threads = 2;
  /// Information of the edges (odometry_sigma..., loop sigmas) and the chi2 beyond
  /// which an inter-session loop is dropped after the optimization.
  LoopClosingParams loop_closing;
  PoseGraphOptions pose_graph;
  /// \brief Whether all values are usable; on failure \a why (if not null) says which.
  bool isValid(std::string* why = nullptr) const;
};

/// \brief One inter-session loop: a drive key-frame placed on a prior key-frame.
struct InterSessionLoop
{
  KeyFrameId prior_keyframe = 0;
  KeyFrameId drive_keyframe = 0;  ///< id in the drive session (not the merged one)
  Pose3d T_prior_drive = Pose3d::Identity(); ///< drive key-frame in the prior's frame
  int num_inliers = 0;
  bool agrees = false;  ///< in the set that anchored the drive
  bool dropped = false; ///< inconsistent after the optimization
};

/// \brief Outcome of mergeSessions.
struct SessionMergeResult
{
  /// The prior's key-frames (ids kept), then the drive's (ids + drive_first_keyframe),
  /// with the optimized poses; the prior's loops and drives, then the drive's, and the
  /// inter-session loops (query: drive key-frame, candidate: prior key-frame).
  Session merged;
  /// The drive was joined to the prior map (component 0). Otherwise it is a separate
  /// component in the merged session and its poses are in its own frame.
  bool connected = false;
  int component = 0; ///< the drive's component in the merged session
  KeyFrameId drive_first_keyframe = 0;
  /// Where the drive's frame lies in the prior's world, from the anchoring placements
  /// (before the optimization); identity when not connected.
  Pose3d T_prior_drive = Pose3d::Identity();
  /// Optimized pose of each drive key-frame in the merged world (drive id order).
  PoseVector drive_keyframe_poses;
  std::vector<InterSessionLoop> loops; ///< every verified placement
  int keyframes_tried = 0;  ///< drive key-frames placed (those with features)
  int loops_agreeing = 0;   ///< placements in the anchoring set
  int loops_used = 0;       ///< inter-session loop edges left after the optimization
  PoseGraphSummary optimization; ///< of the joint graph (when connected)
  double time_ms = 0.0;
  std::string message; ///< what joined the drive, or why nothing did
};

/// \brief Join \a drive to the map of \a prior (a SessionLocalizer on the prior
/// session) as described in the file comment.
/// \throws std::invalid_argument on invalid params or a drive without key-frames.
SessionMergeResult
mergeSessions(const SessionLocalizer& prior,
              const Session& drive,
              const SessionMergeParams& params = SessionMergeParams());

} // namespace rast
} // namespace pcl
