#include <pcl/slam/slam_map.h>
#include <pcl/rast/atomic_file.h>
#include <pcl/registration/voxel_hash_map.h>

#include <pcl/io/pcd_io.h>

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

namespace {

/// Side of the square world tiles buildMap voxelizes one at a time [m].
constexpr double kMapTileSizeM = 100.0;

/// A point ready for voxel averaging: its voxel key, position and intensity (24 bytes).
struct VoxelSample
{
  VoxelKey key;
  float x, y, z, intensity;
  std::uint32_t weight = 1; ///< points it stands for (a merged voxel mean)
};

/// Sort \a samples by voxel and merge each run of one key into its weighted mean, in
/// place (key order).
void
mergeVoxelSamples(std::vector<VoxelSample>& samples)
{
  std::sort(samples.begin(), samples.end(), [](const VoxelSample& a, const VoxelSample& b) {
    return a.key < b.key;
  });
  std::size_t kept = 0;
  for (std::size_t i = 0; i < samples.size();) {
    double sx = 0.0, sy = 0.0, sz = 0.0, si = 0.0, n = 0.0;
    std::size_t j = i;
    for (; j < samples.size() && samples[j].key == samples[i].key; ++j) {
      const double w = samples[j].weight;
      sx += w * samples[j].x;
      sy += w * samples[j].y;
      sz += w * samples[j].z;
      si += w * samples[j].intensity;
      n += w;
    }
    samples[kept++] = {samples[i].key, static_cast<float>(sx / n), static_cast<float>(sy / n),
                       static_cast<float>(sz / n), static_cast<float>(si / n),
                       static_cast<std::uint32_t>(n)};
    i = j;
  }
  samples.resize(kept);
}

/// Append one point per voxel of \a samples (centroid, mean intensity) to \a out, in
/// key order: deterministic, and no hash map of cells.
void
appendVoxelMeans(std::vector<VoxelSample>& samples, pcl::PointCloud<pcl::PointXYZI>& out)
{
  mergeVoxelSamples(samples);
  for (const VoxelSample& v : samples) {
    pcl::PointXYZI p;
    p.x = v.x;
    p.y = v.y;
    p.z = v.z;
    p.intensity = v.intensity;
    out.push_back(p);
  }
  out.width = static_cast<std::uint32_t>(out.size());
  out.height = 1;
  out.is_dense = true;
}

} // namespace

pcl::PointCloud<pcl::PointXYZI>::Ptr
voxelDownsample(const pcl::PointCloud<pcl::PointXYZI>& cloud, double leaf_m)
{
  if (!(leaf_m > 0.0) || !std::isfinite(leaf_m))
    throw std::invalid_argument("voxelDownsample: leaf_m must be > 0, got " +
                                std::to_string(leaf_m));
  const double inv_leaf = 1.0 / leaf_m;
  std::vector<VoxelSample> samples;
  samples.reserve(cloud.size());
  for (const auto& p : cloud.points)
    if (std::isfinite(p.x) && std::isfinite(p.y) && std::isfinite(p.z))
      samples.push_back({voxelKeyOf(p.getVector3fMap(), inv_leaf), p.x, p.y, p.z,
                         p.intensity, 1});
  auto out = std::make_shared<pcl::PointCloud<pcl::PointXYZI>>();
  appendVoxelMeans(samples, *out);
  return out;
}

CompactCloud
CompactCloud::fromCloud(const pcl::PointCloud<pcl::PointXYZI>& cloud)
{
  CompactCloud out;
  float max_intensity = 0.0f;
  for (const auto& p : cloud.points)
    if (std::isfinite(p.intensity))
      max_intensity = std::max(max_intensity, p.intensity);
  out.intensity_scale = max_intensity > 0.0f ? max_intensity / 255.0f : 0.0f;
  const double inv_res = 1.0 / kResolutionM;
  const auto quantize = [inv_res](float v, std::int16_t& q) {
    const double s = std::round(v * inv_res);
    if (!(std::abs(s) <= 32767.0)) // also rejects NaN
      return false;
    q = static_cast<std::int16_t>(s);
    return true;
  };
  out.points.reserve(cloud.size());
  for (const auto& p : cloud.points) {
    Point q;
    if (!quantize(p.x, q.x) || !quantize(p.y, q.y) || !quantize(p.z, q.z))
      continue;
    const float i = out.intensity_scale > 0.0f && std::isfinite(p.intensity)
                        ? std::max(0.0f, p.intensity) / out.intensity_scale
                        : 0.0f;
    q.intensity = static_cast<std::uint8_t>(std::min(255.0f, std::round(i)));
    out.points.push_back(q);
  }
  out.points.shrink_to_fit();
  return out;
}

pcl::PointCloud<pcl::PointXYZI>::Ptr
CompactCloud::toCloud() const
{
  auto out = std::make_shared<pcl::PointCloud<pcl::PointXYZI>>();
  out->points.reserve(points.size());
  const auto res = static_cast<float>(kResolutionM);
  for (const Point& q : points) {
    pcl::PointXYZI p;
    p.x = q.x * res;
    p.y = q.y * res;
    p.z = q.z * res;
    p.intensity = q.intensity * intensity_scale;
    out->points.push_back(p);
  }
  out->width = static_cast<std::uint32_t>(out->points.size());
  out->height = 1;
  out->is_dense = true;
  return out;
}

void
savePcdAtomically(const std::string& path, const pcl::PointCloud<pcl::PointXYZI>& cloud)
{
  const std::string tmp = path + ".tmp." + std::to_string(::getpid());
  pcl::PCDWriter writer;
  int rc = -1;
  try {
    if (cloud.empty()) {
      // PCL refuses to write an empty cloud in binary; an empty ASCII PCD is valid.
      rc = writer.writeASCII(tmp, cloud);
    }
    else {
      rc = writer.writeBinary(tmp, cloud);
    }
  } catch (const std::exception& e) {
    std::remove(tmp.c_str());
    throw std::runtime_error(path + ": cannot write PCD: " + e.what());
  }
  if (rc != 0) {
    std::remove(tmp.c_str());
    throw std::runtime_error(path + ": cannot write PCD");
  }
  if (std::rename(tmp.c_str(), path.c_str()) != 0) {
    std::remove(tmp.c_str());
    throw std::runtime_error(path + ": cannot rename the temporary PCD into place");
  }
}

namespace {

/// The folder of \a path ("." when it has none), for the spill file.
std::string
folderOf(const std::string& path)
{
  const std::size_t slash = path.find_last_of('/');
  if (slash == std::string::npos)
    return ".";
  return slash == 0 ? "/" : path.substr(0, slash);
}

} // namespace

PcdStreamWriter::PcdStreamWriter(const std::string& path) : path_(path), body_(folderOf(path))
{}

void
PcdStreamWriter::append(const pcl::PointCloud<pcl::PointXYZI>& points)
{
  if (committed_)
    throw std::logic_error("PcdStreamWriter::append after commit (" + path_ + ")");
  if (points.empty())
    return;
  // PCD binary data: the fields x y z intensity of each point, packed (16 bytes).
  std::vector<std::array<float, 4>> packed;
  packed.reserve(points.size());
  for (const auto& p : points.points)
    packed.push_back({p.x, p.y, p.z, p.intensity});
  chunks_.push_back(body_.putVector(packed));
  num_points_ += points.size();
}

void
PcdStreamWriter::commit()
{
  if (committed_)
    throw std::logic_error("PcdStreamWriter::commit called twice (" + path_ + ")");
  committed_ = true;
  if (num_points_ == 0) {
    savePcdAtomically(path_, pcl::PointCloud<pcl::PointXYZI>());
    return;
  }
  if (num_points_ > static_cast<std::size_t>(std::numeric_limits<int>::max()))
    throw std::runtime_error(path_ + ": " + std::to_string(num_points_) +
                             " points are more than a PCD file can hold");
  const std::string header =
      pcl::PCDWriter::generateHeader(pcl::PointCloud<pcl::PointXYZI>(),
                                     static_cast<int>(num_points_)) +
      "DATA binary\n";
  writeFileAtomically(path_, [&](std::FILE* file) {
    bool ok = std::fwrite(header.data(), 1, header.size(), file) == header.size();
    std::vector<char> buffer;
    for (std::size_t c = 0; ok && c < chunks_.size(); ++c) {
      buffer.resize(chunks_[c].bytes);
      body_.get(chunks_[c], buffer.data()); // throws on a read error
      ok = std::fwrite(buffer.data(), 1, buffer.size(), file) == buffer.size();
    }
    return ok;
  });
}

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

std::vector<SlamMap::KeyFrameEntry>
SlamMap::mapCloudEntries() const
{
  std::lock_guard<std::mutex> lock(mutex_);
  std::vector<KeyFrameEntry> entries;
  entries.reserve(keyframes_.size());
  for (const auto& e : keyframes_) {
    entries.push_back(e);
    entries.back().kf.reset(); // only pose, handle and radius are needed
  }
  return entries;
}

void
SlamMap::forEachMapTile(double leaf_m, const MapTileSink& sink) const
{
  if (!(leaf_m > 0.0) || !std::isfinite(leaf_m))
    throw std::invalid_argument("SlamMap::forEachMapTile: leaf_m must be > 0, got " +
                                std::to_string(leaf_m));
  const std::vector<KeyFrameEntry> entries = mapCloudEntries();
  const auto res = static_cast<float>(CompactCloud::kResolutionM);
  // Square tiles of whole voxels in the world's x-y plane, each voxelized on its own:
  // a voxel lies in exactly one tile, so the tiles together equal one global grid.
  const double inv_leaf = 1.0 / leaf_m;
  const auto voxels_per_tile =
      std::max<std::int64_t>(1, static_cast<std::int64_t>(std::ceil(kMapTileSizeM * inv_leaf)));
  const auto tileOf = [&](double v) {
    const auto voxel = static_cast<std::int64_t>(std::floor(v * inv_leaf));
    return voxel >= 0 ? voxel / voxels_per_tile : -((-voxel - 1) / voxels_per_tile) - 1;
  };
  // The tiles each key-frame's points can reach (its position +- its cloud's radius).
  std::map<std::pair<std::int64_t, std::int64_t>, std::vector<std::size_t>> tiles;
  for (std::size_t k = 0; k < entries.size(); ++k) {
    const Eigen::Vector3d c = entries[k].T_world_keyframe.translation();
    const double r = entries[k].map_cloud_radius_m;
    for (auto tx = tileOf(c.x() - r); tx <= tileOf(c.x() + r); ++tx)
      for (auto ty = tileOf(c.y() - r); ty <= tileOf(c.y() + r); ++ty)
        tiles[{tx, ty}].push_back(k);
  }
  // Per tile: every point as (voxel key, position, intensity), sorted by key, each run
  // of one key reduced to its centroid: 32 bytes a point, a few MB per tile. Where the
  // drive passed many times, the samples are merged whenever they have doubled since
  // the last merge, so a tile's memory follows its voxels, not its visits.
  constexpr std::size_t kMinSamplesBeforeMerge = 1 << 20;
  std::vector<VoxelSample> samples;
  pcl::PointCloud<pcl::PointXYZI> out;
  for (const auto& [tile, members] : tiles) {
    samples.clear();
    std::size_t merge_at = kMinSamplesBeforeMerge;
    for (const std::size_t k : members) {
      if (samples.size() >= merge_at) {
        mergeVoxelSamples(samples);
        merge_at = std::max(kMinSamplesBeforeMerge, 2 * samples.size());
      }
      const KeyFrameEntry& e = entries[k];
      const Eigen::Isometry3d& T = e.T_world_keyframe;
      for (const CompactCloud::Point& q : loadMapCloud(e).points) {
        const Eigen::Vector3d p = T * Eigen::Vector3d(q.x * res, q.y * res, q.z * res);
        if (tileOf(p.x()) != tile.first || tileOf(p.y()) != tile.second)
          continue;
        samples.push_back({voxelKeyOf(p, inv_leaf),
                           static_cast<float>(p.x()),
                           static_cast<float>(p.y()),
                           static_cast<float>(p.z()),
                           q.intensity * e.intensity_scale,
                           1});
      }
    }
    if (samples.empty())
      continue;
    out.clear();
    appendVoxelMeans(samples, out);
    sink(out);
  }
}

pcl::PointCloud<pcl::PointXYZI>::Ptr
SlamMap::buildMap(double leaf_m) const
{
  auto out = std::make_shared<pcl::PointCloud<pcl::PointXYZI>>();
  if (leaf_m > 0.0) {
    forEachMapTile(leaf_m, [&](const pcl::PointCloud<pcl::PointXYZI>& tile) { *out += tile; });
  }
  else {
    const auto res = static_cast<float>(CompactCloud::kResolutionM);
    for (const auto& e : mapCloudEntries()) {
      const Eigen::Isometry3f T = e.T_world_keyframe.cast<float>();
      for (const CompactCloud::Point& q : loadMapCloud(e).points) {
        pcl::PointXYZI p;
        p.getVector3fMap() = T * Eigen::Vector3f(q.x * res, q.y * res, q.z * res);
        p.intensity = q.intensity * e.intensity_scale;
        out->push_back(p);
      }
    }
  }
  out->width = static_cast<std::uint32_t>(out->size());
  out->height = 1;
  out->is_dense = true;
  return out;
}

} // namespace rast
} // namespace pcl
