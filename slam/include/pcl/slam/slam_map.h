#pragma once
/// \file slam_map.h
/// \brief The SLAM map (the paper's key-frame database and local map): key-frames with
/// their corrected poses, map points, one record per input frame and the accepted loop
/// closures. One mutex guards everything, so the tracking, local-mapping and
/// loop-closing threads share it safely; every accessor returns copies.
/// \ingroup slam

#include <pcl/features/raster_feature_types.h>
#include <pcl/slam/blob_store.h>
#include <pcl/slam/keyframe.h>
#include <pcl/rast/rigid_pose.h>

#include <pcl/point_cloud.h>
#include <pcl/point_types.h>

#include <Eigen/Core>

#include <cstddef>
#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <utility>
#include <vector>

namespace pcl {
namespace rast {

/// \brief One observation of a map point: feature \a feature_index of key-frame
/// \a keyframe, with that feature's point (bundle adjustment reads it from here, so a
/// key-frame's features can be released while its observations live on).
struct MapPointObservation
{
  KeyFrameId keyframe = 0;
  int feature_index = 0;
  Eigen::Vector3f p_keyframe = Eigen::Vector3f::Zero(); ///< in the key-frame's LiDAR frame [m]
};

/// \brief A 3D landmark of the local map (the paper's map-point): world position,
/// ORB descriptor (of its first observation) and the key-frames that see it.
struct MapPoint
{
  MapPointId id = kNoMapPoint;
  Eigen::Vector3d p_world = Eigen::Vector3d::Zero(); ///< [m]
  OrbDescriptor descriptor{};
  /// The key-frame that created it: a correction of that key-frame's pose moves the point.
  KeyFrameId reference_keyframe = 0;
  std::vector<MapPointObservation> observations;
};

/// \brief FrameRecord::reference_keyframe of a frame before the first key-frame.
constexpr KeyFrameId kNoKeyFrame = static_cast<KeyFrameId>(-1);

/// \brief What happened to one input frame.
struct FrameRecord
{
  std::size_t frame_index = 0;
  double timestamp_s = 0.0;
  /// Tracked against this key-frame; kNoKeyFrame before the first key-frame (leading
  /// empty or unusable scans), and T_keyframe_lidar is then the frame's world pose.
  KeyFrameId reference_keyframe = 0;
  Pose3d T_keyframe_lidar = Pose3d::Identity();     ///< pose relative to it
  std::string status;                               ///< tracking status ("features", ...)
  bool skipped = false;                             ///< no usable scan
  std::string skipped_reason;                       ///< why (when skipped)
  std::string path;                                 ///< the scan file, when known
};

/// \brief An accepted loop closure: T_candidate_query measured between two key-frames.
struct LoopEdge
{
  KeyFrameId query = 0;     ///< the newer key-frame
  KeyFrameId candidate = 0; ///< the older key-frame it was matched to
  Pose3d T_candidate_query = Pose3d::Identity();
  int num_inliers = 0;
  bool active = true; ///< false once found inconsistent by the pose graph and dropped
};

/// \brief A key-frame cloud stored compactly for the merged map: coordinates in the
/// key-frame's LiDAR frame quantized to kResolutionM in int16 (+-327 m), intensity as
/// uint8 scaled by the cloud's maximum. 8 bytes per point instead of 32 (PointXYZI).
struct CompactCloud
{
  struct Point
  {
    std::int16_t x = 0, y = 0, z = 0;
    std::uint8_t intensity = 0;
  };
  static constexpr double kResolutionM = 0.01;
  std::vector<Point> points;
  float intensity_scale = 0.0f; ///< intensity = stored value * intensity_scale

  /// \brief Quantize \a cloud; non-finite points and points beyond the int16 range
  /// (327 m) are dropped.
  static CompactCloud fromCloud(const pcl::PointCloud<pcl::PointXYZI>& cloud);
  /// \brief The points as a PointXYZI cloud (key-frame frame).
  pcl::PointCloud<pcl::PointXYZI>::Ptr toCloud() const;
  std::size_t size() const { return points.size(); }
};

/// \brief Thread-safe store of the SLAM state (see file comment).
///
/// Corrections (local BA, pose graph) are written with applyKeyFramePoses(): key-frames
/// newer than the corrected ones (added by tracking while the optimizer ran) follow the
/// newest corrected key-frame, and map points move rigidly with their reference key-frame.
class SlamMap
{
public:
  using Ptr = std::shared_ptr<SlamMap>;
  using ConstPtr = std::shared_ptr<const SlamMap>;

  /// \param[in] map_cloud_leaf_m each key-frame's cloud is kept for the merged map
  /// voxel-downsampled to this leaf (<= 0: all its points), quantized (CompactCloud).
  /// \param[in] cloud_store where those compact clouds are kept (null: in memory); a
  /// store spilled to disk keeps the map's memory from growing with the sequence.
  explicit SlamMap(double map_cloud_leaf_m = 0.0, BlobStore::Ptr cloud_store = nullptr);
  SlamMap(const SlamMap&) = delete;
  SlamMap& operator=(const SlamMap&) = delete;

  /// \brief Insert a key-frame from tracking. Its corrected pose is chained from the
  /// (corrected) pose of the previous key-frame by kf->T_previous_keyframe, so tracking
  /// may keep working in its own drifting odometry frame. The first key-frame takes
  /// kf->T_world_keyframe. \return the corrected pose.
  /// \throws std::invalid_argument on a null key-frame or an id that is not the next one.
  Pose3d addKeyFrame(const KeyFrame::Ptr& kf);

  /// \brief Record one input frame (in input order). \throws std::invalid_argument when
  /// it references an unknown key-frame (non-skipped frames only).
  void addFrame(const FrameRecord& record);

  std::size_t numKeyFrames() const;
  std::size_t numFrames() const;
  std::size_t numMapPoints() const;
  /// \brief Map points created so far (culled ones included).
  std::size_t numMapPointsCreated() const;

  /// \throws std::out_of_range on an unknown id.
  KeyFrame::Ptr keyFrame(KeyFrameId id) const;
  /// \throws std::out_of_range on an unknown id.
  Pose3d keyFramePose(KeyFrameId id) const;
  /// \brief Corrected poses of all key-frames, in id order.
  PoseVector keyFramePoses() const;
  /// \brief All key-frames, in id order.
  std::vector<KeyFrame::Ptr> keyFrames() const;
  /// \brief The compact copy of key-frame \a id's cloud kept for the merged map, as a
  /// cloud in the key-frame's LiDAR frame (empty when the key-frame had no cloud).
  /// \throws std::out_of_range on an unknown id.
  pcl::PointCloud<pcl::PointXYZI>::Ptr keyFrameCloud(KeyFrameId id) const;
  /// \brief Drop key-frame \a id's full-precision cloud (KeyFrame::cloud becomes null)
  /// once no stage needs it any more; the map keeps its compact copy. Callers that
  /// read KeyFrame::cloud of key-frames from keyFrames() must not run concurrently.
  /// \throws std::out_of_range on an unknown id.
  void releaseKeyFrameCloud(KeyFrameId id);
  /// \brief Drop key-frame \a id's features and map-point ids (both become empty),
  /// for key-frames no stage reads any more (outside the loop database, behind local
  /// mapping's window and tracking): map-point observations keep their own copy of the
  /// point. The same caveat as above applies.
  /// \throws std::out_of_range on an unknown id.
  void releaseKeyFrameFeatures(KeyFrameId id);
  /// \brief Approximate heap bytes held, by part (memory reports).
  struct MemoryUsage
  {
    std::size_t map_clouds = 0;      ///< compact key-frame clouds in memory
    std::size_t map_clouds_on_disk = 0; ///< compact key-frame clouds spilled to disk
    std::size_t keyframe_clouds = 0; ///< full-precision clouds not yet released
    std::size_t features = 0;        ///< key-frame features, descriptors, map-point ids
    std::size_t map_points = 0;      ///< live and archived map points
    std::size_t frames = 0;          ///< per-frame records
  };
  MemoryUsage memoryUsage() const;
  /// \brief The odometry-edge measurement T_previous_keyframe of key-frame \a id
  /// (tracking's value, refined by local BA when enabled).
  Pose3d odometryEdge(KeyFrameId id) const;
  /// \brief Replace odometry-edge measurements (local BA refines them).
  void setOdometryEdges(const std::map<KeyFrameId, Pose3d>& T_previous_keyframe);

  /// \brief Overwrite key-frame poses (see the class comment for what follows them).
  /// \param[in] poses new T_world_keyframe per key-frame id
  /// \param[in] propagate_to_newer key-frames with ids above the largest corrected one
  /// are moved by its correction (they were chained from its old pose)
  void applyKeyFramePoses(const std::map<KeyFrameId, Pose3d>& poses, bool propagate_to_newer);

  /// \brief Bumped by every loop correction; a local BA started before it must not
  /// write its (stale) result back.
  std::uint64_t correctionEpoch() const;
  /// \brief Like applyKeyFramePoses, then bumps the epoch.
  void applyLoopCorrection(const std::map<KeyFrameId, Pose3d>& poses);
  /// \brief applyKeyFramePoses plus map point positions, only when the epoch is still
  /// \a epoch. \return false (nothing written) when a loop correction happened meanwhile.
  bool applyBundleAdjustment(std::uint64_t epoch,
                             const std::map<KeyFrameId, Pose3d>& poses,
                             const std::map<MapPointId, Eigen::Vector3d>& points_world);

  // ---- map points (local mapping) ----
  /// \brief Create a map point seen by feature \a feature_index of \a keyframe.
  /// \throws std::invalid_argument when the map has no such key-frame or feature
  MapPointId createMapPoint(KeyFrameId keyframe,
                            int feature_index,
                            const Eigen::Vector3d& p_world,
                            const OrbDescriptor& descriptor);
  /// \brief Add an observation to an existing map point (ignored when it was culled).
  /// \throws std::invalid_argument when the map has no such key-frame or feature
  void addObservation(MapPointId id, KeyFrameId keyframe, int feature_index);
  /// \brief Snapshot of all live map points.
  std::vector<MapPoint> mapPoints() const;
  /// \brief Snapshot of the live map points seen by any of \a keyframes.
  std::vector<MapPoint> mapPointsSeenBy(const std::vector<KeyFrameId>& keyframes) const;
  /// \brief Remove map points seen by none of \a keyframes (paper 8.1); observations by
  /// other key-frames are dropped with them. \return the number removed.
  std::size_t cullMapPoints(const std::vector<KeyFrameId>& keyframes);
  /// \brief Remove map points with fewer than \a min_observations observations whose
  /// newest observation is older than \a before_keyframe (spurious points).
  std::size_t cullWeakMapPoints(KeyFrameId before_keyframe, std::size_t min_observations);

  /// \brief Keep culled map points in an archive (for global BA) instead of freeing them.
  void setKeepCulledMapPoints(bool keep);
  /// \brief Live and archived map points.
  std::vector<MapPoint> allMapPoints() const;

  // ---- loops ----
  void addLoopEdge(const LoopEdge& edge);
  /// \brief Mark the loop edge with index \a index inactive.
  void deactivateLoopEdge(std::size_t index);
  std::vector<LoopEdge> loopEdges() const;

  // ---- results ----
  /// \brief Records of all frames, in input order.
  std::vector<FrameRecord> frames() const;
  /// \brief Corrected pose of every recorded frame: T_world_kf * T_kf_lidar. Skipped
  /// frames carry the constant-velocity pose tracking gave them.
  PoseVector framePoses() const;

  /// \brief Merge all key-frame clouds into the world frame by their corrected poses,
  /// voxel-downsampled with \a leaf_m (<= 0: no downsampling); intensity kept.
  /// The voxel grid is filled one square tile of the world at a time, so building
  /// needs little memory beyond the result. Tracking and the other stages go on
  /// meanwhile (the poses are copied first).
  pcl::PointCloud<pcl::PointXYZI>::Ptr buildMap(double leaf_m) const;

  /// \brief Called with the voxelized points of one world tile (world frame).
  using MapTileSink = std::function<void(const pcl::PointCloud<pcl::PointXYZI>& tile)>;
  /// \brief buildMap(leaf_m) without holding the whole map: \a sink receives it one
  /// square tile of the world at a time (in a fixed order); together the tiles are
  /// exactly buildMap's points. For writing huge maps (see PcdStreamWriter).
  /// \throws std::invalid_argument unless leaf_m > 0.
  void forEachMapTile(double leaf_m, const MapTileSink& sink) const;

private:
  struct KeyFrameEntry
  {
    KeyFrame::Ptr kf;
    Pose3d T_world_keyframe = Pose3d::Identity();
    Pose3d T_previous_keyframe = Pose3d::Identity(); ///< odometry edge measurement
    /// The compact cloud for buildMap: CompactCloud::points in cloud_store_.
    BlobStore::Handle map_cloud;
    float intensity_scale = 0.0f; ///< CompactCloud::intensity_scale
    float map_cloud_radius_m = 0.0f; ///< largest distance of a point from the sensor
  };
  CompactCloud loadMapCloud(const KeyFrameEntry& entry) const;
  std::vector<KeyFrameEntry> mapCloudEntries() const; ///< copies, without key-frames
  void applyPosesLocked(const std::map<KeyFrameId, Pose3d>& poses, bool propagate_to_newer);

  double map_cloud_leaf_m_ = 0.0;
  BlobStore::Ptr cloud_store_;
  /// Observation of feature \a feature_index of \a keyframe (caller holds mutex_).
  MapPointObservation observationLocked(KeyFrameId keyframe, int feature_index) const;
  mutable std::mutex mutex_;
  std::vector<KeyFrameEntry> keyframes_; // index == id
  std::map<MapPointId, MapPoint> map_points_;
  bool keep_culled_ = false;
  std::map<MapPointId, MapPoint> archive_;
  MapPointId next_map_point_id_ = 0;
  std::vector<FrameRecord> frames_;
  std::vector<LoopEdge> loop_edges_;
  std::uint64_t epoch_ = 0;
};

/// \brief Voxel-grid downsampling (centroid of xyz and intensity per voxel) on 64-bit
/// voxel keys, so the extent of the cloud does not matter (PCL's VoxelGrid overflows its
/// index on large maps with small leaves). Output in voxel-key order (deterministic).
pcl::PointCloud<pcl::PointXYZI>::Ptr voxelDownsample(const pcl::PointCloud<pcl::PointXYZI>& cloud,
                                                     double leaf_m);

/// \brief Write \a cloud as binary PCD atomically (temporary file, then rename).
/// \throws std::runtime_error naming the file on failure.
void savePcdAtomically(const std::string& path, const pcl::PointCloud<pcl::PointXYZI>& cloud);

/// \brief A binary PCD (x y z intensity) written piece by piece without holding the
/// whole cloud, atomically: appended points go to an anonymous spill file in the
/// target's folder; commit() writes the header with the final count and the points to
/// a temporary file and renames it into place. Nothing appears at the path before
/// commit(), and nothing at all when the writer is destroyed without it.
///
/// \code
/// pcl::rast::PcdStreamWriter pcd("map.pcd");
/// slam_map.forEachMapTile(0.2, [&](const auto& tile) { pcd.append(tile); });
/// pcd.commit();
/// \endcode
class PcdStreamWriter
{
public:
  /// \throws std::runtime_error naming the folder when no spill file can be made there.
  explicit PcdStreamWriter(const std::string& path);
  PcdStreamWriter(const PcdStreamWriter&) = delete;
  PcdStreamWriter& operator=(const PcdStreamWriter&) = delete;

  /// \brief Append \a points (non-finite ones included, as PCL would write them).
  /// \throws std::logic_error after commit(); std::runtime_error on a write error.
  void append(const pcl::PointCloud<pcl::PointXYZI>& points);
  /// \brief Points appended so far.
  std::size_t size() const { return num_points_; }
  /// \brief Write the file. \throws std::runtime_error naming the file on failure
  /// (then nothing is left at the path or beside it); std::logic_error when called twice.
  void commit();

private:
  std::string path_;
  BlobStore body_;
  std::vector<BlobStore::Handle> chunks_;
  std::size_t num_points_ = 0;
  bool committed_ = false;
};

} // namespace rast
} // namespace pcl
