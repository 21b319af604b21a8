#pragma once
/// \file rast_slam.h
/// \brief The whole SLAM system of the paper for PCL users: tracking (Odometry),
/// local mapping (LocalMapping: map points, local BA, culling) and loop closing
/// (LoopDetector + pose graph) running as three stages that hand key-frames over through
/// queues, on three threads or, in deterministic mode, in sequence on the caller's.
/// \ingroup slam
///
/// \code
/// pcl::rast::RastSlam slam(pcl::rast::SlamParams{});
/// for (i, cloud, t) in scans: slam.addScan(cloud, t, i);
/// slam.finish();                             // drains the queues, joins the threads
/// pcl::rast::PoseVector poses = slam.framePoses();  // one per input frame, corrected
/// auto map = slam.buildMap(0.2);             // merged, voxelized, intensity kept
/// \endcode

#include <pcl/slam/local_mapping.h>
#include <pcl/slam/loop_detector.h>
#include <pcl/slam/odometry.h>
#include <pcl/slam/pose_graph.h>
#include <pcl/slam/slam_map.h>

#include <pcl/point_cloud.h>
#include <pcl/point_types.h>

#include <cstddef>
#include <functional>
#include <map>
#include <memory>
#include <string>
#include <vector>

namespace pcl {
namespace rast {

/// \brief Settings of the loop-closing stage beyond the detector and the optimizer.
struct LoopClosingParams
{
  bool enable = true; ///< detect loops at all (off: odometry + local mapping only)
  /// Odometry edges: translation sigma = base + per_m * |t| [m], rotation sigma =
  /// base + per_m * |t| [rad]: tracking's drift grows with the distance between
  /// key-frames.
  double odometry_sigma_t_base_m = 0.02;
  double odometry_sigma_t_per_m = 0.01;
  double odometry_sigma_r_base_rad = 0.001;
  double odometry_sigma_r_per_m_rad = 0.0005;
  /// ... times a factor for key-frames that tracking registered against a young local
  /// map of n < young_map_scans scans: young_map_sigma_scale for n <= 1, falling linearly
  /// to 1 at young_map_scans. The first frames of a drive are the chain's weakest
  /// links (a VLP-16 start rotates ~2 deg wrong over its first 10 frames, later frames
  /// ~0.02 deg each); with equal sigmas a loop back to the start spreads the correction
  /// over the whole loop instead of putting it there. 1: equal sigmas.
  double young_map_sigma_scale = 10.0;
  int young_map_scans = 10;
  /// Loop edges: sigma at reference_inliers inliers, scaled by sqrt(reference / inliers).
  double loop_sigma_t_m = 0.1;
  double loop_sigma_r_rad = 0.005;
  int loop_reference_inliers = 50;
  /// After optimizing, loop edges with chi2 above this are dropped and the graph is
  /// re-optimized (6 dof: 22.5 = 99.9 %).
  double inconsistent_chi2 = 22.5;
  /// After an accepted loop, the next this many key-frames are only added to the
  /// detector's database, not searched (as ORB-SLAM does): consecutive key-frames of a
  /// revisit find the same loop again, and each costs a dense check and a pose-graph
  /// optimisation. 0: search every key-frame.
  int cooldown_keyframes = 10;
  /// Threaded mode: when key-frames wait in the loop-closing queue, only the newest one
  /// is searched, the older ones are only added to the database (the stage keeps up with
  /// tracking instead of falling behind). Deterministic mode never waits.
  bool search_newest_only_when_backlogged = true;
  /// Revisit culling: a key-frame is not added to the loop database when an earlier
  /// database key-frame lies within revisit_radius_m and revisit_angle_deg of it and the
  /// map is anchored there, i.e. a loop was accepted at most revisit_anchor_keyframes
  /// key-frames ago (before that, poses may have drifted and closeness means little).
  /// Its place stays findable through the earlier key-frame, and its features are
  /// released once local mapping is done with it. The database, and the memory, then
  /// grow with the mapped area rather than with the time spent in it.
  bool cull_revisits = true;
  double revisit_radius_m = 3.0;
  double revisit_angle_deg = 30.0;
  int revisit_anchor_keyframes = 20;
  /// Run a global bundle adjustment (all key-frames, all map points, loop edges as
  /// pose constraints) after each pose-graph optimization: the paper's comparison.
  /// Keeps every map point (no culling from memory), so it is for measurements only.
  bool global_bundle_adjustment = false;
  int global_ba_max_iterations = 20;

  bool isValid(std::string* why = nullptr) const;
};

/// \brief All settings of RastSlam; the defaults suit a car-mounted HDL-64 at 10 Hz.
struct SlamParams
{
  OdometryParams odometry;
  LocalMappingParams local_mapping;
  LoopDetectorParams loop_detector;
  PoseGraphOptions pose_graph;
  LoopClosingParams loop_closing;
  /// true: tracking, local mapping and loop closing run in sequence on the caller's
  /// thread (same input, same output). false: local mapping and loop closing run on
  /// their own threads, tracking on the caller's.
  bool deterministic = false;
  /// Each key-frame's cloud is kept for the merged map at this voxel size [m]
  /// (<= 0: tracking's voxelized cloud is shared, no copy). A leaf coarser than
  /// tracking's key-frame voxel bounds the memory of long sequences.
  double map_cloud_leaf_m = 0.0;
  /// false: a key-frame's full-precision cloud (KeyFrame::cloud) is released once loop
  /// closing has prepared what it needs from it; the map keeps a compact copy
  /// (SlamMap::keyFrameCloud, 8 bytes a point) for buildMap. true: kept (memory grows
  /// by ~32 bytes a point per key-frame).
  bool keep_keyframe_clouds = false;
  /// Non-empty: the compact key-frame clouds of the map and the loop detector's dense
  /// targets (about 120 kB per key-frame) are spilled to an anonymous file in this
  /// folder, which vanishes with the process. Memory then no longer grows with them.
  /// Empty: kept in memory.
  std::string spill_directory;
  /// true: tracking makes a scan's raster features only where it needs them
  /// (Odometry::setFeaturesWanted(false)): a frame whose dense step tracks it alone from
  /// the constant-velocity prior, with the checks of that path, skips them; key-frames
  /// and every other frame have them.
  bool features_on_demand = false;

  bool isValid(std::string* why = nullptr) const;
};

/// \brief Wall-time statistics of one stage [ms].
struct StageTiming
{
  std::size_t count = 0;
  double mean_ms = 0.0;
  double median_ms = 0.0;
  double max_ms = 0.0;
  double total_ms = 0.0;
  double cpu_total_ms = 0.0; ///< CPU time of the stage's thread (0: not measured)
};

/// \brief Counts and timings of a run.
struct SlamStatistics
{
  std::size_t frames = 0;          ///< input frames (skipped included)
  std::size_t skipped_frames = 0;  ///< frames without a usable scan
  /// Frames tracked without making their features (SlamParams::features_on_demand).
  std::size_t frames_without_features = 0;
  std::size_t keyframes = 0;
  std::size_t map_points = 0;         ///< live (local map) map points
  std::size_t map_points_created = 0; ///< ever created
  std::size_t loops_accepted = 0;     ///< verified loops (edges added)
  std::size_t loops_rejected = 0;     ///< verifications that failed
  std::size_t loops_inconsistent = 0; ///< accepted, later dropped by the pose graph
  std::size_t loop_candidates = 0;    ///< candidates proposed
  std::size_t pose_graph_runs = 0;
  /// Key-frames added to the loop database without a search (cooldown after a loop,
  /// or a backlog in threaded mode).
  std::size_t loop_searches_skipped = 0;
  /// Key-frames in the loop database, and those left out by revisit culling.
  std::size_t loop_database_keyframes = 0;
  std::size_t loop_database_revisits_culled = 0;
  /// Approximate heap bytes by part: "map_clouds", "keyframe_clouds", "features",
  /// "map_points", "frames" (the map) and "loop_dense_targets",
  /// "loop_appearance_index", "loop_appearance_keys", "loop_appearance_features" (the
  /// loop database); "map_clouds_on_disk" and
  /// "loop_dense_targets_on_disk" count what was spilled (SlamParams::spill_directory).
  std::map<std::string, std::size_t> memory_bytes;
  std::map<std::string, std::size_t> tracking_status; ///< frames per tracking status
  /// Per stage: "tracking" (per frame), "local_mapping" (per key-frame),
  /// "loop_detection" (per searched key-frame, with its "loop_retrieval" and
  /// "loop_verification" parts), "pose_graph" (per optimization), "global_ba" (per run).
  std::map<std::string, StageTiming> timing;
};

/// \brief One verification of the loop-closing stage, for reports.
struct LoopRecord
{
  LoopVerification verification;
  LoopCandidateSource source = LoopCandidateSource::kDistance;
  bool dropped_inconsistent = false;
};

/// \brief The three stages a key-frame passes through.
enum class SlamStage
{
  kTracking,     ///< made by tracking (caller's thread)
  kLocalMapping, ///< local mapping is done with it
  kLoopClosing   ///< loop closing is done with it (searched, maybe closed a loop)
};

/// \brief "tracking", "local_mapping" or "loop_closing".
const char*
toString(SlamStage stage);

/// \brief The SLAM system (see the file comment).
class RastSlam
{
public:
  using Ptr = std::shared_ptr<RastSlam>;
  /// \brief Called with each key-frame once a stage is done with it, on that stage's
  /// thread (see setKeyFrameObserver).
  using KeyFrameObserver = std::function<void(SlamStage, const KeyFrame&)>;

  /// \throws std::invalid_argument when \a params are invalid (the message says why).
  explicit RastSlam(const SlamParams& params = SlamParams());
  /// Finishes (joins the threads); errors of the workers are swallowed here, call
  /// finish() to see them.
  ~RastSlam();
  RastSlam(const RastSlam&) = delete;
  RastSlam& operator=(const RastSlam&) = delete;

  /// \brief Track one scan (LiDAR frame) and hand a new key-frame to the back end.
  /// Frame indices must increase. \a path is only recorded (for reports).
  /// \throws std::logic_error after finish(); rethrows an exception of a worker thread.
  OdometryFrameResult addScan(const pcl::PointCloud<pcl::PointXYZI>::ConstPtr& cloud,
                              double timestamp_s,
                              std::size_t frame_index,
                              const std::string& path = "");

  /// \brief addScan with the points' times relative to the frame time [s], one per
  /// point (ScanFrame::point_times_s), for motion compensation (OdometryParams::deskew).
  OdometryFrameResult addScan(const pcl::PointCloud<pcl::PointXYZI>::ConstPtr& cloud,
                              double timestamp_s,
                              std::size_t frame_index,
                              const std::vector<float>& point_times_s,
                              const std::string& path = "");

  /// \brief addScan while \a next, the scan the next addScan will get, is prepared on a
  /// second thread (Odometry::processFrame with a look-ahead scan: the same poses).
  /// \throws std::invalid_argument when next.frame_index is not after \a frame_index
  OdometryFrameResult addScan(const pcl::PointCloud<pcl::PointXYZI>::ConstPtr& cloud,
                              double timestamp_s,
                              std::size_t frame_index,
                              const std::vector<float>& point_times_s,
                              const OdometryInput& next,
                              const std::string& path = "");

  /// \brief Account for a frame without a usable scan (constant-velocity pose).
  OdometryFrameResult addSkippedScan(std::size_t frame_index,
                                     double timestamp_s,
                                     const std::string& reason,
                                     const std::string& path = "");

  /// \brief Process everything queued, stop the worker threads. Idempotent.
  /// \throws the first exception a worker thread raised (once). The results so far
  /// (framePoses, keyFramePoses, map, statistics) stay readable after it: an error
  /// ends the run, it does not discard it.
  void finish();

  /// \brief Watch key-frames pass the stages (progress, viewers, fault injection in
  /// tests). Set it before the first addScan. The observer runs on the stage's
  /// thread: it must be thread-safe and quick. An exception it throws ends the run as
  /// an error of that stage would (addScan or finish rethrows it).
  void setKeyFrameObserver(KeyFrameObserver observer);

  /// \brief Corrected pose of every input frame so far (LiDAR frame in the world frame
  /// of the first scan), in input order.
  PoseVector framePoses() const;

  /// \brief The tracking's estimate of the beams' elevation errors
  /// (OdometryParams::elevation_calibration).
  ElevationCalibrationState elevationCalibration() const;
  /// \brief Frame records (status, reference key-frame, skipped reason), input order.
  std::vector<FrameRecord> frames() const;
  /// \brief Corrected key-frame poses, by id.
  PoseVector keyFramePoses() const;
  /// \brief The key-frames, by id. Their clouds are released after loop closing
  /// (SlamParams::keep_keyframe_clouds), and the features of those left out of the loop
  /// database once local mapping is done with them (LoopClosingParams::cull_revisits).
  std::vector<KeyFrame::Ptr> keyFrames() const;
  /// \brief Merged map of all key-frame clouds at their corrected poses.
  pcl::PointCloud<pcl::PointXYZI>::Ptr buildMap(double leaf_m) const;
  /// \brief Loop edges accepted (inactive ones were dropped as inconsistent).
  std::vector<LoopEdge> loops() const;
  /// \brief Every loop verification made (accepted and rejected).
  std::vector<LoopRecord> loopRecords() const;
  SlamStatistics statistics() const;
  const SlamParams& params() const { return params_; }
  /// \brief The shared map (read access for viewers; thread-safe).
  SlamMap::ConstPtr map() const { return map_; }

private:
  struct Impl;
  SlamParams params_;
  SlamMap::Ptr map_;
  std::unique_ptr<Impl> impl_;
};

/// \brief Global bundle adjustment of all key-frames and the given map points plus
/// the loop edges as pose constraints (the paper's comparison to the pose graph);
/// key-frame 0 is held constant. \return the optimized poses (by id) in \a poses.
BundleAdjustmentSummary globalBundleAdjustment(std::map<KeyFrameId, Pose3d>& poses,
                                               const std::vector<KeyFrame::Ptr>& keyframes,
                                               const std::vector<MapPoint>& points,
                                               const std::vector<LoopEdge>& loops,
                                               const LoopClosingParams& loop_params,
                                               const BundleAdjustmentParams& ba_params);

} // namespace rast
} // namespace pcl
