/// \file slam_map.cpp
/// \brief SlamMap: key-frames and their poses (their one owner), frames, map points,
/// loop edges and the corrections applied to them. The merged map cloud is in
/// slam_map_cloud.cpp.

#include <pcl/slam/slam_map.h>

#include <algorithm>
#include <array>
#include <limits>
#include <cmath>
#include <cstdio>
#include <set>
#include <stdexcept>
#include <unistd.h>

namespace pcl {
namespace rast {

SlamMap::SlamMap(double map_cloud_leaf_m, BlobStore::Ptr cloud_store)
  : map_cloud_leaf_m_(map_cloud_leaf_m)
  , cloud_store_(cloud_store ? std::move(cloud_store) : std::make_shared<BlobStore>())
{}

CompactCloud
SlamMap::loadMapCloud(const KeyFrameEntry& entry) const
{
  CompactCloud cloud;
  cloud.points = cloud_store_->getVector<CompactCloud::Point>(entry.map_cloud);
  cloud.intensity_scale = entry.intensity_scale;
  return cloud;
}

Pose3d
SlamMap::addKeyFrame(const KeyFrame::Ptr& kf)
{
  if (!kf)
    throw std::invalid_argument("SlamMap::addKeyFrame: null key-frame");
  CompactCloud map_cloud;
  if (kf->cloud)
    map_cloud = CompactCloud::fromCloud(
        map_cloud_leaf_m_ > 0.0 ? *voxelDownsample(*kf->cloud, map_cloud_leaf_m_) : *kf->cloud);
  float radius_m = 0.0f;
  for (const CompactCloud::Point& q : map_cloud.points)
    radius_m = std::max(radius_m, std::sqrt(float(q.x) * q.x + float(q.y) * q.y + float(q.z) * q.z));
  radius_m *= static_cast<float>(CompactCloud::kResolutionM);
  const BlobStore::Handle stored = cloud_store_->putVector(map_cloud.points);
  std::lock_guard<std::mutex> lock(mutex_);
  if (kf->id != keyframes_.size())
    throw std::invalid_argument("SlamMap::addKeyFrame: expected id " +
                                std::to_string(keyframes_.size()) + ", got " +
                                std::to_string(kf->id));
  KeyFrameEntry entry;
  entry.kf = kf;
  // Poses are kept on SO(3): thousands of composed steps must not drift off it.
  entry.T_previous_keyframe = normalizedPose(kf->T_previous_keyframe);
  entry.T_world_keyframe =
      keyframes_.empty() ? normalizedPose(kf->T_world_keyframe)
                         : composePoses(keyframes_.back().T_world_keyframe, entry.T_previous_keyframe);
  entry.map_cloud = stored;
  entry.intensity_scale = map_cloud.intensity_scale;
  entry.map_cloud_radius_m = radius_m;
  keyframes_.push_back(std::move(entry));
  kf->map_point_ids.assign(kf->features.size(), kNoMapPoint);
  return entry.T_world_keyframe;
}

void
SlamMap::addFrame(const FrameRecord& record)
{
  std::lock_guard<std::mutex> lock(mutex_);
  if (!record.skipped && record.reference_keyframe != kNoKeyFrame &&
      record.reference_keyframe >= keyframes_.size())
    throw std::invalid_argument("SlamMap::addFrame: frame " +
                                std::to_string(record.frame_index) +
                                " references unknown key-frame " +
                                std::to_string(record.reference_keyframe));
  frames_.push_back(record);
  frames_.back().T_keyframe_lidar = normalizedPose(record.T_keyframe_lidar);
}

std::size_t
SlamMap::numKeyFrames() const
{
  std::lock_guard<std::mutex> lock(mutex_);
  return keyframes_.size();
}
std::size_t
SlamMap::numFrames() const
{
  std::lock_guard<std::mutex> lock(mutex_);
  return frames_.size();
}
std::size_t
SlamMap::numMapPoints() const
{
  std::lock_guard<std::mutex> lock(mutex_);
  return map_points_.size();
}
std::size_t
SlamMap::numMapPointsCreated() const
{
  std::lock_guard<std::mutex> lock(mutex_);
  return static_cast<std::size_t>(next_map_point_id_);
}

KeyFrame::Ptr
SlamMap::keyFrame(KeyFrameId id) const
{
  std::lock_guard<std::mutex> lock(mutex_);
  return keyframes_.at(id).kf;
}

Pose3d
SlamMap::keyFramePose(KeyFrameId id) const
{
  std::lock_guard<std::mutex> lock(mutex_);
  return keyframes_.at(id).T_world_keyframe;
}

PoseVector
SlamMap::keyFramePoses() const
{
  std::lock_guard<std::mutex> lock(mutex_);
  PoseVector out;
  out.reserve(keyframes_.size());
  for (const auto& e : keyframes_)
    out.push_back(e.T_world_keyframe);
  return out;
}

pcl::PointCloud<pcl::PointXYZI>::Ptr
SlamMap::keyFrameCloud(KeyFrameId id) const
{
  KeyFrameEntry entry;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    entry = keyframes_.at(id);
  }
  return loadMapCloud(entry).toCloud();
}

void
SlamMap::releaseKeyFrameCloud(KeyFrameId id)
{
  std::lock_guard<std::mutex> lock(mutex_);
  keyframes_.at(id).kf->cloud.reset();
}

void
SlamMap::releaseKeyFrameFeatures(KeyFrameId id)
{
  std::lock_guard<std::mutex> lock(mutex_);
  KeyFrame& kf = *keyframes_.at(id).kf;
  kf.features = RasterFeatureSet();
  kf.map_point_ids = std::vector<MapPointId>();
}

SlamMap::MemoryUsage
SlamMap::memoryUsage() const
{
  MemoryUsage m;
  std::lock_guard<std::mutex> lock(mutex_);
  for (const auto& e : keyframes_) {
    (cloud_store_->spilled() ? m.map_clouds_on_disk : m.map_clouds) += e.map_cloud.bytes;
    if (e.kf->cloud)
      m.keyframe_clouds += e.kf->cloud->points.capacity() * sizeof(pcl::PointXYZI);
    m.features += e.kf->features.points.points.capacity() * sizeof(RasterFeaturePoint) +
                  e.kf->features.descriptors.capacity() * sizeof(OrbDescriptor) +
                  e.kf->map_point_ids.capacity() * sizeof(MapPointId);
  }
  // std::map node: the value plus about four pointers of tree bookkeeping.
  const auto pointBytes = [](const MapPoint& p) {
    return sizeof(MapPoint) + 32 + p.observations.capacity() * sizeof(MapPointObservation);
  };
  for (const auto& [id, p] : map_points_)
    m.map_points += pointBytes(p);
  for (const auto& [id, p] : archive_)
    m.map_points += pointBytes(p);
  for (const auto& f : frames_)
    m.frames += sizeof(FrameRecord) + f.status.capacity() + f.skipped_reason.capacity() +
                f.path.capacity();
  return m;
}

std::vector<KeyFrame::Ptr>
SlamMap::keyFrames() const
{
  std::lock_guard<std::mutex> lock(mutex_);
  std::vector<KeyFrame::Ptr> out;
  out.reserve(keyframes_.size());
  for (const auto& e : keyframes_)
    out.push_back(e.kf);
  return out;
}

Pose3d
SlamMap::odometryEdge(KeyFrameId id) const
{
  std::lock_guard<std::mutex> lock(mutex_);
  return keyframes_.at(id).T_previous_keyframe;
}

void
SlamMap::setOdometryEdges(const std::map<KeyFrameId, Pose3d>& T_previous_keyframe)
{
  std::lock_guard<std::mutex> lock(mutex_);
  for (const auto& [id, T] : T_previous_keyframe)
    if (id < keyframes_.size() && id > 0)
      keyframes_[id].T_previous_keyframe = normalizedPose(T);
}

void
SlamMap::applyPosesLocked(const std::map<KeyFrameId, Pose3d>& poses, bool propagate_to_newer)
{
  if (poses.empty())
    return;
  // Correction of each moved key-frame: T_new * T_old^-1 (world frame), for the points.
  std::map<KeyFrameId, Pose3d> delta;
  for (const auto& [id, T_new] : poses) {
    if (id >= keyframes_.size())
      continue;
    const Pose3d T_rigid = normalizedPose(T_new);
    delta[id] = composePoses(T_rigid, keyframes_[id].T_world_keyframe.inverse());
    keyframes_[id].T_world_keyframe = T_rigid;
  }
  if (delta.empty())
    return;
  if (propagate_to_newer) {
    const auto& [last_id, last_delta] = *delta.rbegin();
    for (std::size_t id = last_id + 1; id < keyframes_.size(); ++id) {
      keyframes_[id].T_world_keyframe = composePoses(last_delta, keyframes_[id].T_world_keyframe);
      delta[static_cast<KeyFrameId>(id)] = last_delta;
    }
  }
  for (auto* points : {&map_points_, &archive_})
    for (auto& [pid, mp] : *points) {
      const auto it = delta.find(mp.reference_keyframe);
      if (it != delta.end())
        mp.p_world = it->second * mp.p_world;
    }
}

void
SlamMap::setKeepCulledMapPoints(bool keep)
{
  std::lock_guard<std::mutex> lock(mutex_);
  keep_culled_ = keep;
}

std::vector<MapPoint>
SlamMap::allMapPoints() const
{
  std::lock_guard<std::mutex> lock(mutex_);
  std::vector<MapPoint> out;
  out.reserve(map_points_.size() + archive_.size());
  for (const auto& [id, mp] : archive_)
    out.push_back(mp);
  for (const auto& [id, mp] : map_points_)
    out.push_back(mp);
  return out;
}

void
SlamMap::applyKeyFramePoses(const std::map<KeyFrameId, Pose3d>& poses, bool propagate_to_newer)
{
  std::lock_guard<std::mutex> lock(mutex_);
  applyPosesLocked(poses, propagate_to_newer);
}

std::uint64_t
SlamMap::correctionEpoch() const
{
  std::lock_guard<std::mutex> lock(mutex_);
  return epoch_;
}

void
SlamMap::applyLoopCorrection(const std::map<KeyFrameId, Pose3d>& poses)
{
  std::lock_guard<std::mutex> lock(mutex_);
  applyPosesLocked(poses, true);
  ++epoch_;
}

bool
SlamMap::applyBundleAdjustment(std::uint64_t epoch,
                               const std::map<KeyFrameId, Pose3d>& poses,
                               const std::map<MapPointId, Eigen::Vector3d>& points_world)
{
  std::lock_guard<std::mutex> lock(mutex_);
  if (epoch != epoch_)
    return false;
  // Points first (absolute optimized positions), then poses: optimized points must not
  // be moved again by their reference key-frame's correction.
  std::map<MapPointId, Eigen::Vector3d> kept;
  for (const auto& [pid, p] : points_world)
    if (map_points_.count(pid))
      kept[pid] = p;
  applyPosesLocked(poses, true);
  for (const auto& [pid, p] : kept)
    map_points_[pid].p_world = p;
  return true;
}

MapPointId
SlamMap::createMapPoint(KeyFrameId keyframe,
                        int feature_index,
                        const Eigen::Vector3d& p_world,
                        const OrbDescriptor& descriptor)
{
  std::lock_guard<std::mutex> lock(mutex_);
  const MapPointObservation observation = observationLocked(keyframe, feature_index);
  MapPoint mp;
  mp.id = next_map_point_id_++;
  mp.p_world = p_world;
  mp.descriptor = descriptor;
  mp.reference_keyframe = keyframe;
  mp.observations.push_back(observation);
  auto& ids = keyframes_[keyframe].kf->map_point_ids;
  if (static_cast<std::size_t>(feature_index) < ids.size())
    ids[feature_index] = mp.id;
  map_points_.emplace(mp.id, std::move(mp));
  return next_map_point_id_ - 1;
}

void
SlamMap::addObservation(MapPointId id, KeyFrameId keyframe, int feature_index)
{
  std::lock_guard<std::mutex> lock(mutex_);
  const MapPointObservation observation = observationLocked(keyframe, feature_index);
  auto it = map_points_.find(id);
  if (it == map_points_.end())
    return;
  it->second.observations.push_back(observation);
  auto& ids = keyframes_[keyframe].kf->map_point_ids;
  if (static_cast<std::size_t>(feature_index) < ids.size())
    ids[feature_index] = id;
}

MapPointObservation
SlamMap::observationLocked(KeyFrameId keyframe, int feature_index) const
{
  if (keyframe >= keyframes_.size())
    throw std::invalid_argument("SlamMap: unknown key-frame " + std::to_string(keyframe));
  const RasterFeatureSet& features = keyframes_[keyframe].kf->features;
  if (feature_index < 0 || static_cast<std::size_t>(feature_index) >= features.size())
    throw std::invalid_argument("SlamMap: key-frame " + std::to_string(keyframe) +
                                " has no feature " + std::to_string(feature_index) + " (" +
                                std::to_string(features.size()) + " features)");
  return {keyframe, feature_index, features.points[feature_index].getVector3fMap()};
}

std::vector<MapPoint>
SlamMap::mapPoints() const
{
  std::lock_guard<std::mutex> lock(mutex_);
  std::vector<MapPoint> out;
  out.reserve(map_points_.size());
  for (const auto& [id, mp] : map_points_)
    out.push_back(mp);
  return out;
}

std::vector<MapPoint>
SlamMap::mapPointsSeenBy(const std::vector<KeyFrameId>& keyframes) const
{
  const std::set<KeyFrameId> window(keyframes.begin(), keyframes.end());
  std::lock_guard<std::mutex> lock(mutex_);
  std::vector<MapPoint> out;
  for (const auto& [id, mp] : map_points_)
    for (const auto& obs : mp.observations)
      if (window.count(obs.keyframe)) {
        out.push_back(mp);
        break;
      }
  return out;
}

std::size_t
SlamMap::cullMapPoints(const std::vector<KeyFrameId>& keyframes)
{
  const std::set<KeyFrameId> window(keyframes.begin(), keyframes.end());
  std::lock_guard<std::mutex> lock(mutex_);
  std::size_t removed = 0;
  for (auto it = map_points_.begin(); it != map_points_.end();) {
    const bool seen = std::any_of(it->second.observations.begin(),
                                  it->second.observations.end(),
                                  [&](const MapPointObservation& o) {
                                    return window.count(o.keyframe) != 0;
                                  });
    if (seen) {
      ++it;
      continue;
    }
    if (keep_culled_)
      archive_.emplace(it->first, std::move(it->second));
    it = map_points_.erase(it);
    ++removed;
  }
  return removed;
}

std::size_t
SlamMap::cullWeakMapPoints(KeyFrameId before_keyframe, std::size_t min_observations)
{
  std::lock_guard<std::mutex> lock(mutex_);
  std::size_t removed = 0;
  for (auto it = map_points_.begin(); it != map_points_.end();) {
    KeyFrameId newest = 0;
    for (const auto& o : it->second.observations)
      newest = std::max(newest, o.keyframe);
    if (it->second.observations.size() < min_observations && newest < before_keyframe) {
      for (const auto& o : it->second.observations) {
        auto& ids = keyframes_[o.keyframe].kf->map_point_ids;
        if (static_cast<std::size_t>(o.feature_index) < ids.size())
          ids[o.feature_index] = kNoMapPoint;
      }
      it = map_points_.erase(it);
      ++removed;
    }
    else {
      ++it;
    }
  }
  return removed;
}

void
SlamMap::addLoopEdge(const LoopEdge& edge)
{
  std::lock_guard<std::mutex> lock(mutex_);
  loop_edges_.push_back(edge);
  loop_edges_.back().T_candidate_query = normalizedPose(edge.T_candidate_query);
}

void
SlamMap::deactivateLoopEdge(std::size_t index)
{
  std::lock_guard<std::mutex> lock(mutex_);
  loop_edges_.at(index).active = false;
}

std::vector<LoopEdge>
SlamMap::loopEdges() const
{
  std::lock_guard<std::mutex> lock(mutex_);
  return loop_edges_;
}

std::vector<FrameRecord>
SlamMap::frames() const
{
  std::lock_guard<std::mutex> lock(mutex_);
  return frames_;
}

PoseVector
SlamMap::framePoses() const
{
  std::lock_guard<std::mutex> lock(mutex_);
  PoseVector out;
  out.reserve(frames_.size());
  for (const auto& f : frames_) {
    if (f.reference_keyframe < keyframes_.size())
      out.push_back(composePoses(keyframes_[f.reference_keyframe].T_world_keyframe, f.T_keyframe_lidar));
    else
      out.push_back(f.T_keyframe_lidar);
  }
  return out;
}

} // namespace rast
} // namespace pcl
