/// \file slam_map_cloud.cpp
/// \brief The merged map of SlamMap: voxel means (voxelDownsample), the compact
/// key-frame clouds, the tile-by-tile map builder and the streamed, atomic PCD writer.

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <functional>
#include <limits>
#include <pcl/io/pcd_io.h>
#include <pcl/rast/atomic_file.h>
#include <pcl/registration/voxel_hash_map.h>
#include <pcl/slam/session.h>
#include <pcl/slam/slam_map.h>
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

namespace {

/// One key-frame's cloud for the tile builder: its pose, the largest distance of a
/// point from its origin, and a way to visit its points (key-frame frame, intensity).
struct TileSource
{
  using PointVisitor = std::function<void(const Eigen::Vector3d&, float)>;
  Pose3d T_world_keyframe = Pose3d::Identity();
  double radius_m = 0.0;
  std::function<void(const PointVisitor&)> for_each_point;
};

/// The map of \a sources, voxelized with \a leaf_m one square world tile at a time.
void
forEachTile(const std::vector<TileSource>& sources,
            double leaf_m,
            const SlamMap::MapTileSink& sink)
{
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
  for (std::size_t k = 0; k < sources.size(); ++k) {
    const Eigen::Vector3d c = sources[k].T_world_keyframe.translation();
    const double r = sources[k].radius_m;
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
      const Eigen::Isometry3d& T = sources[k].T_world_keyframe;
      const std::pair<std::int64_t, std::int64_t> here = tile;
      sources[k].for_each_point([&](const Eigen::Vector3d& q, float intensity) {
        const Eigen::Vector3d p = T * q;
        if (tileOf(p.x()) != here.first || tileOf(p.y()) != here.second)
          return;
        samples.push_back({voxelKeyOf(p, inv_leaf),
                           static_cast<float>(p.x()),
                           static_cast<float>(p.y()),
                           static_cast<float>(p.z()),
                           intensity,
                           1});
      });
    }
    if (samples.empty())
      continue;
    out.clear();
    appendVoxelMeans(samples, out);
    sink(out);
  }
}

void
checkLeaf(const char* caller, double leaf_m)
{
  if (!(leaf_m > 0.0) || !std::isfinite(leaf_m))
    throw std::invalid_argument(std::string(caller) + ": leaf_m must be > 0, got " +
                                std::to_string(leaf_m));
}

} // namespace

void
SlamMap::forEachMapTile(double leaf_m, const MapTileSink& sink) const
{
  checkLeaf("SlamMap::forEachMapTile", leaf_m);
  const std::vector<KeyFrameEntry> entries = mapCloudEntries();
  const auto res = static_cast<float>(CompactCloud::kResolutionM);
  std::vector<TileSource> sources(entries.size());
  for (std::size_t k = 0; k < entries.size(); ++k) {
    const KeyFrameEntry& e = entries[k];
    sources[k].T_world_keyframe = e.T_world_keyframe;
    sources[k].radius_m = e.map_cloud_radius_m;
    sources[k].for_each_point = [this, &e, res](const TileSource::PointVisitor& visit) {
      for (const CompactCloud::Point& q : loadMapCloud(e).points)
        visit(Eigen::Vector3d(q.x * res, q.y * res, q.z * res), q.intensity * e.intensity_scale);
    };
  }
  forEachTile(sources, leaf_m, sink);
}

namespace {

/// A tile source of a key-frame cloud that \a cloud_of returns (read again for each tile
/// the cloud reaches when it is not kept in memory).
TileSource
sessionTileSource(const KeyFrame& kf,
                  const pcl::PointCloud<pcl::PointXYZI>& cloud,
                  std::function<pcl::PointCloud<pcl::PointXYZI>::ConstPtr()> cloud_of)
{
  TileSource source;
  source.T_world_keyframe = kf.T_world_keyframe;
  for (const auto& p : cloud.points)
    source.radius_m = std::max(source.radius_m, p.getVector3fMap().cast<double>().norm());
  source.for_each_point =
      [cloud_of = std::move(cloud_of)](const TileSource::PointVisitor& visit) {
        const pcl::PointCloud<pcl::PointXYZI>::ConstPtr cloud = cloud_of();
        for (const auto& p : cloud->points)
          visit(p.getVector3fMap().cast<double>(), p.intensity);
      };
  return source;
}

} // namespace

void
forEachSessionMapTile(const std::vector<KeyFrame::Ptr>& keyframes,
                      double leaf_m,
                      const SlamMap::MapTileSink& sink)
{
  checkLeaf("forEachSessionMapTile", leaf_m);
  std::vector<TileSource> sources;
  for (const KeyFrame::Ptr& kf : keyframes) {
    if (!kf || !kf->cloud || kf->cloud->empty())
      continue;
    const pcl::PointCloud<pcl::PointXYZI>::ConstPtr cloud = kf->cloud;
    sources.push_back(sessionTileSource(*kf, *cloud, [cloud] { return cloud; }));
  }
  forEachTile(sources, leaf_m, sink);
}

void
forEachSessionMapTile(const Session& session,
                      const std::vector<KeyFrame::Ptr>& keyframes,
                      double leaf_m,
                      const SlamMap::MapTileSink& sink)
{
  checkLeaf("forEachSessionMapTile", leaf_m);
  std::vector<TileSource> sources;
  for (const KeyFrame::Ptr& kf : keyframes) {
    if (!kf || !sessionHasCloud(session, kf->id))
      continue;
    // Held clouds come back at once; others are read here for the radius, then again
    // by each tile they reach.
    const pcl::PointCloud<pcl::PointXYZI>::ConstPtr cloud = sessionCloud(session, kf->id);
    if (!cloud || cloud->empty())
      continue;
    const KeyFrameId id = kf->id;
    sources.push_back(sessionTileSource(
        *kf, *cloud, [&session, id] { return sessionCloud(session, id); }));
  }
  forEachTile(sources, leaf_m, sink);
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
