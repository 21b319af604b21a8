#pragma once
/// \file loop_detector.h
/// \brief Loop detection and verification (the paper's section 9, "Loop closure"):
/// candidates are the key-frames near the query's current estimate (the paper), plus
/// key-frames that look alike (beyond the paper: multi-index hashing of the ORB
/// descriptors, which survives a drift of tens of metres); each candidate is verified
/// by ORB matching with the ratio test, seeded rigid RANSAC, and checks made for
/// repetitive scenes (inlier count and ratio, spatial spread, a unique hypothesis, a
/// dense point-to-plane check, consistency with odometry). See doc/loop_closure.md.
/// \ingroup slam

#include <pcl/rast/rigid_pose.h>
#include <pcl/registration/point_to_plane_refinement.h>
#include <pcl/slam/blob_store.h>
#include <pcl/slam/keyframe.h>
#include <pcl/slam/keyframe_database.h>
#include <pcl/slam/loop_types.h>

#include <cstddef>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>

namespace pcl {
namespace rast {

/// \brief Loop search and verification: the verifier of the loop-closing thread, over
/// its KeyFrameDatabase (retrieval by distance and appearance).
///
/// \code
/// pcl::rast::LoopDetector detector(params);
/// for each new key-frame kf at its current estimate T_world_kf:
///   const pcl::rast::LoopDetection d = detector.detect(*kf, T_world_kf);
///   if (const auto* loop = d.best()) add edge (loop->candidate, loop->query,
///                                              loop->T_candidate_query);
///   detector.addKeyFrame(kf, T_world_kf);
/// after a pose-graph optimisation: detector.updatePose(id, T_world_kf) for every id,
/// or, once, detector.setPoseSource(...) to read the poses from their owner (the SLAM
/// reads them from its SlamMap: one owner of poses)
/// \endcode
/// Thread-safe: detect() and verify() may run concurrently with each other; addKeyFrame()
/// and updatePose() take an exclusive lock. Results depend only on the inputs (seeded).
class LoopDetector
{
public:
  using Ptr = std::shared_ptr<LoopDetector>;
  using ConstPtr = std::shared_ptr<const LoopDetector>;

  /// \param[in] params detection and verification settings
  /// \param[in] dense_store where the key-frames' dense-check targets are kept (null:
  /// in memory); a store spilled to disk keeps the database's memory small.
  /// \throws std::invalid_argument when !params.isValid() (message says why)
  explicit LoopDetector(const LoopDetectorParams& params = LoopDetectorParams(),
                        BlobStore::Ptr dense_store = nullptr);
  ~LoopDetector();

  const LoopDetectorParams& params() const { return params_; }

  /// \brief Search and verify loops for \a query (not yet in the database) at its
  /// current estimate \a T_world_query.
  LoopDetection detect(const KeyFrame& query, const Pose3d& T_world_query) const;

  /// \brief Add a key-frame to the database (after detect for it).
  /// \throws std::invalid_argument when null or its id is already in the database
  void addKeyFrame(const KeyFrame::ConstPtr& keyframe, const Pose3d& T_world_keyframe);

  /// \brief The database key-frame nearest to \a T_world_query among those a loop
  /// could be closed with (at least min_keyframe_gap key-frames and min_travel_gap_m
  /// back) that lie within \a radius_m and \a angle_deg (rotation angle) of it; none
  /// when the place is not in the database yet. Trusts the poses: ask after the map
  /// was anchored there by a loop.
  /// \throws std::invalid_argument when radius_m or angle_deg is not positive
  std::optional<KeyFrameId> coveringKeyFrame(const KeyFrame& query,
                                             const Pose3d& T_world_query,
                                             double radius_m,
                                             double angle_deg) const;

  /// \brief Pass over a key-frame that is not added (its place is covered, see
  /// coveringKeyFrame): later key-frames still count its step in the travelled
  /// distance that candidate eligibility uses.
  void skipKeyFrame(const KeyFrame& keyframe, const Pose3d& T_world_keyframe);

  /// \brief Key-frames passed over by skipKeyFrame.
  std::size_t numSkipped() const;

  /// \brief After an optimisation: the corrected pose of a key-frame in the database.
  /// \throws std::invalid_argument when \a id is unknown
  void updatePose(KeyFrameId id, const Pose3d& T_world_keyframe);

  /// \brief Verify one pair, checking the result against \a T_candidate_query_guess
  /// with the base tolerances (max_odometry_deviation_m / _deg): the guess is an
  /// odometry estimate. Use the overload with GuessTolerance{} for no guess.
  LoopVerification verify(const KeyFrame& query,
                          const KeyFrame& candidate,
                          const Pose3d& T_candidate_query_guess) const;

  /// \brief Verify one pair with an explicit tolerance on the guess.
  LoopVerification verify(const KeyFrame& query,
                          const KeyFrame& candidate,
                          const Pose3d& T_candidate_query_guess,
                          const GuessTolerance& tolerance) const;

  /// \brief verify() with the dense check on \a dense_target (points in the
  /// candidate's LiDAR frame) instead of the target the database keeps for the
  /// candidate: for a candidate that stands for several key-frames, say
  /// (SessionLocalizerParams::neighbourhood_keyframes).
  LoopVerification verify(const KeyFrame& query,
                          const KeyFrame& candidate,
                          const Pose3d& T_candidate_query_guess,
                          const GuessTolerance& tolerance,
                          const PointVector& dense_target) const;

  /// \brief Appearance scores (votes) of every eligible (not recent) database
  /// key-frame for \a query at \a T_world_query: key-frame ids with their scores,
  /// best first (normalised ranking), no minimum applied. Empty with retrieval kNone.
  /// For evaluation and tools.
  std::vector<std::pair<KeyFrameId, int>>
  rankByAppearance(const KeyFrame& query, const Pose3d& T_world_query) const;

  /// \brief Update the poses of all key-frames in the database (and of the last one
  /// skipped) from poses indexed by key-frame id; ids beyond the vector keep theirs.
  void updatePoses(const PoseVector& T_world_by_id);

  /// \brief Number of key-frames in the database.
  std::size_t size() const;

  /// \brief Approximate heap bytes of the database (memory reports): the dense-check
  /// targets and the appearance index (key-frame features are owned by the key-frames).
  using MemoryUsage = KeyFrameDatabase::MemoryUsage;
  MemoryUsage memoryUsage() const;

  /// \brief Read key-frame poses from \a source (e.g. SlamMap::keyFramePoses) from now
  /// on instead of the ones given to addKeyFrame and updatePose(s).
  void setPoseSource(KeyFrameDatabase::PoseSource source);

  /// \brief The key-frame database searched.
  const KeyFrameDatabase& database() const { return database_; }

  /// \brief The current pose of a database key-frame.
  /// \throws std::invalid_argument when \a id is unknown
  Pose3d pose(KeyFrameId id) const;

private:
  /// verify() with the candidate's retrieval given (nullptr: looked up), or its dense
  /// target itself (\a dense_target not null).
  LoopVerification verifyPair(const KeyFrame& query,
                              const KeyFrame& candidate,
                              const Pose3d& T_candidate_query_guess,
                              const GuessTolerance& tolerance,
                              const RetrievedKeyFrame* retrieved,
                              const PointVector* dense_target = nullptr) const;
  /// Step 9 of verifyPair: the point-to-plane check on the candidate's dense target;
  /// returns why the pair is rejected, or nothing.
  std::string denseCheck(const KeyFrame& query,
                         const KeyFrame& candidate,
                         const RetrievedKeyFrame* retrieved,
                         const PointVector* dense_target,
                         double min_overlap,
                         LoopVerification& v) const;
  /// The final refinement of an accepted \a v on the candidate's dense \a target.
  void refineAccepted(const KeyFrame& query, const PointToPlaneTarget& target,
                      LoopVerification& v) const;
  /// Step 4 of detect: verify the retrieved candidates, most promising first.
  void verifyCandidates(const KeyFrame& query,
                        const Pose3d& T_world_query,
                        double query_travel_m,
                        const std::vector<RetrievedKeyFrame>& retrieved,
                        LoopDetection& out) const;

  LoopDetectorParams params_;
  KeyFrameDatabase database_;
};

} // namespace rast
} // namespace pcl
