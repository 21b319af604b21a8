#pragma once
/// \file keyframe_database.h
/// \brief The key-frames a loop can be closed with (the loop-closing thread's database):
/// their ORB descriptors in an appearance index (multi-index hashing), their dense-check
/// targets, the distance travelled up to each, and the retrieval of candidates for a
/// query by distance and by appearance. The verifier is LoopDetector. Poses are read
/// from their owner (SlamMap in the SLAM) through a PoseSource. See
/// doc/loop_closure.md.
/// \ingroup slam

#include <pcl/rast/rigid_pose.h>
#include <pcl/registration/point_to_plane_refinement.h>
#include <pcl/slam/blob_store.h>
#include <pcl/slam/keyframe.h>
#include <pcl/slam/loop_types.h>

#include <array>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <shared_mutex>
#include <unordered_map>
#include <utility>
#include <vector>

namespace pcl {
namespace rast {

/// \brief A candidate the database proposes for verification, with what the verifier
/// needs of it.
struct RetrievedKeyFrame
{
  LoopCandidate candidate;
  KeyFrame::ConstPtr keyframe;
  Pose3d T_world_keyframe = Pose3d::Identity(); ///< its current pose
  double travel_m = 0.0;                        ///< distance travelled up to it
  BlobStore::Handle dense_target;               ///< see KeyFrameDatabase::denseTarget
};

/// \brief Key-frame database for loop retrieval.
///
/// Key-frames are added after their own search (add) or passed over where their place is
/// already covered (skip). Poses come from a PoseSource when one is set (every query reads
/// one snapshot of them), otherwise from the poses given to add() and updatePose(s).
/// Thread-safe: queries may run concurrently; add, skip and updates take an exclusive lock.
class KeyFrameDatabase
{
public:
  using Ptr = std::shared_ptr<KeyFrameDatabase>;
  /// Every key-frame pose indexed by key-frame id, e.g. SlamMap::keyFramePoses.
  using PoseSource = std::function<PoseVector()>;
  /// A dense-check target point in the key-frame's LiDAR frame, quantized to 1 cm.
  using DensePoint = std::array<std::int16_t, 3>;
  /// The appearance index hashes descriptor substrings of this many bits ...
  static constexpr int kSubstringBits = 16;
  /// ... so a 256-bit descriptor has at most this many tables.
  static constexpr int kMaxHashTables = 256 / kSubstringBits;

  /// \param[in] params retrieval, eligibility and dense-target settings
  /// \param[in] dense_store where the dense-check targets are kept (null: in memory)
  /// \throws std::invalid_argument when !params.isValid() (message says why)
  explicit KeyFrameDatabase(const LoopDetectorParams& params,
                            BlobStore::Ptr dense_store = nullptr);
  ~KeyFrameDatabase();

  /// \brief Read poses from \a source from now on (null: the database's own).
  void
  setPoseSource(PoseSource source);

  /// \brief Add a key-frame at \a T_world_keyframe (its pose now).
  /// \throws std::invalid_argument when null, inconsistent or its id is already in
  void
  add(const KeyFrame::ConstPtr& keyframe, const Pose3d& T_world_keyframe);

  /// \brief Pass over a key-frame that is not added: later key-frames still count its
  /// step in the travelled distance that candidate eligibility uses.
  void
  skip(const KeyFrame& keyframe, const Pose3d& T_world_keyframe);

  /// \brief The database's own pose of a key-frame (without a PoseSource).
  /// \throws std::invalid_argument when \a id is unknown
  void
  updatePose(KeyFrameId id, const Pose3d& T_world_keyframe);
  /// \brief The database's own poses from poses indexed by id; ids beyond keep theirs.
  void
  updatePoses(const PoseVector& T_world_by_id);
  /// \brief The current pose of a key-frame in the database.
  /// \throws std::invalid_argument when \a id is unknown
  Pose3d
  pose(KeyFrameId id) const;

  std::size_t
  size() const;
  /// \brief Key-frames passed over by skip().
  std::size_t
  numSkipped() const;

  /// \brief Approximate heap bytes (key-frame features are owned by the key-frames).
  struct MemoryUsage
  {
    std::size_t dense_targets = 0;         ///< in memory
    std::size_t dense_targets_on_disk = 0; ///< spilled to disk
    std::size_t appearance_index = 0;    ///< the substring buckets
    std::size_t appearance_keys = 0;     ///< the bucket of each key (4 MB with 16 tables)
    std::size_t appearance_features = 0; ///< the indexed descriptors, packed for scoring
  };
  MemoryUsage
  memoryUsage() const;

  /// \brief The eligible key-frame nearest to \a T_world_query within \a radius_m and
  /// \a angle_deg of it (LoopDetector::coveringKeyFrame).
  std::optional<KeyFrameId>
  covering(const KeyFrame& query,
           const Pose3d& T_world_query,
           double radius_m,
           double angle_deg) const;

  /// \brief Appearance votes of every eligible key-frame, best first (normalised).
  std::vector<std::pair<KeyFrameId, int>>
  rankByAppearance(const KeyFrame& query, const Pose3d& T_world_query) const;

  /// \brief The candidates of \a query at \a T_world_query, most promising first: the
  /// key-frames near it (the paper), then the top ones by appearance (beyond it); both
  /// only among eligible key-frames (min_keyframe_gap and min_travel_gap_m back).
  /// \param[out] query_travel_m the distance travelled up to the query
  std::vector<RetrievedKeyFrame>
  retrieve(const KeyFrame& query, const Pose3d& T_world_query, double& query_travel_m) const;

  /// \brief The dense-check target of a retrieved key-frame, in its LiDAR frame (empty
  /// without dense_check or a cloud).
  PointVector
  denseTarget(const RetrievedKeyFrame& retrieved) const;

  /// \brief The dense-check target stored for \a keyframe (empty unless that very
  /// key-frame object was added with a cloud).
  PointVector
  denseTarget(const KeyFrame& keyframe) const;

  /// \brief The dense-check target a key-frame's cloud gives (voxelized at
  /// dense.target_voxel_size_m, cropped to dense_crop_radius_m, quantized).
  static std::vector<DensePoint>
  makeDenseTarget(const pcl::PointCloud<pcl::PointXYZI>& cloud,
                  const LoopDetectorParams& params);
  static PointVector
  decodeDense(const std::vector<DensePoint>& points);
  /// \brief \a cloud voxelized at \a voxel_m and cropped to \a radius_m around the
  /// sensor (x-y): the points a dense check uses.
  static PointVector
  croppedCloud(const pcl::PointCloud<pcl::PointXYZI>& cloud, double voxel_m, double radius_m);

private:
  struct Entry
  {
    KeyFrame::ConstPtr keyframe;
    /// The key-frame's cloud as the dense check's target needs it, prepared once at
    /// insertion: the key-frame's own cloud may be released afterwards.
    BlobStore::Handle dense_target;
    Pose3d T_world_keyframe = Pose3d::Identity(); ///< own pose (no PoseSource)
    double travel_m = 0.0;           ///< distance travelled up to this key-frame
  };
  /// The newest key-frame seen (added or skipped): the end of the travelled path.
  struct Tail
  {
    KeyFrameId id = 0;
    Pose3d T_world_keyframe = Pose3d::Identity();
    double travel_m = 0.0;
  };
  /// Global indices of the features sharing one substring; a bucket that outgrew
  /// max_bucket_size is only marked (retrieval skips it whatever the database size):
  /// its list is emptied, and a bucket is never empty otherwise.
  struct Bucket
  {
    std::vector<std::uint32_t> features;
    bool saturated() const { return features.empty(); }
  };

  /// The poses of one query: the source's snapshot, or empty (the entries' own).
  PoseVector
  snapshot() const;
  const Pose3d&
  poseOf(KeyFrameId id, const Pose3d& own, const PoseVector& snapshot) const;
  double
  travelTo(const KeyFrame& query, const Pose3d& T_world_query, const PoseVector& snapshot) const;
  /// Make \a keyframe the newest seen; returns its travelled distance.
  double
  advanceTail(const KeyFrame& keyframe, const Pose3d& T_world_keyframe);
  std::vector<char>
  eligibleSlots(const KeyFrame& query, double query_travel_m) const;
  void
  index(const KeyFrame& keyframe, std::uint32_t slot);
  /// Appearance score of every slot; only slots with eligible[slot] are scored.
  void
  scoreAppearance(const KeyFrame& query,
                  const std::vector<char>& eligible,
                  std::vector<double>& votes) const;

  LoopDetectorParams params_;
  BlobStore::Ptr dense_store_;
  PoseSource pose_source_;
  mutable std::shared_mutex mutex_;
  std::vector<Entry> entries_;
  std::optional<Tail> tail_;
  std::size_t skipped_ = 0;
  std::unordered_map<KeyFrameId, std::size_t> slot_of_;
  /// An indexed feature as scoring reads it, by global feature index, in two arrays
  /// rather than a walk through their key-frame's vectors (the retrieval's hot loop).
  /// A bucket's candidate costs one cache line: its descriptor, 32-byte aligned. Its
  /// slot and angle are read only for the few within retrieval_max_hamming bits.
  struct alignas(32) IndexedDescriptor
  {
    OrbDescriptor bits;
  };
  struct IndexedFeature
  {
    float angle_deg = 0.0f;
    std::uint32_t slot = 0;
  };
  std::vector<IndexedDescriptor> descriptors_; ///< by global feature index
  std::vector<IndexedFeature> features_;       ///< by global feature index
  /// The buckets in order of creation, and the one of each key (table << 16 |
  /// substring) plus one, 0 where none: a look-up is one array read. The array takes
  /// 4 bytes per possible key (4 MB for 16 tables) from the first feature indexed;
  /// the hash map it replaced took some 70 bytes per bucket, and a session of 1000
  /// key-frames fills most keys.
  std::vector<Bucket> buckets_;
  std::vector<std::uint32_t> bucket_of_key_;
  const Bucket* bucketOf(std::uint32_t key) const;
};

} // namespace rast
} // namespace pcl
