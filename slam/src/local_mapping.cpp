#include <pcl/slam/local_mapping.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <set>
#include <stdexcept>
#include <unordered_map>

namespace pcl {
namespace rast {

namespace {

/// Features of a key-frame hashed on a 2D grid (x, y in its LiDAR frame).
class FeatureGrid
{
public:
  FeatureGrid(const RasterFeatureSet& features, double cell_m) : inv_cell_(1.0 / cell_m)
  {
    for (std::size_t i = 0; i < features.size(); ++i) {
      const auto& p = features.points[i];
      if (std::isfinite(p.x) && std::isfinite(p.y) && std::isfinite(p.z))
        cells_[key(cellOf(p.x), cellOf(p.y))].push_back(static_cast<int>(i));
    }
  }

  template <typename F>
  void forNeighbours(const Eigen::Vector3d& p, F&& f) const
  {
    const long cx = cellOf(p.x()), cy = cellOf(p.y());
    for (long dx = -1; dx <= 1; ++dx)
      for (long dy = -1; dy <= 1; ++dy) {
        const auto it = cells_.find(key(cx + dx, cy + dy));
        if (it != cells_.end())
          for (int i : it->second)
            f(i);
      }
  }

private:
  long cellOf(double v) const { return static_cast<long>(std::floor(v * inv_cell_)); }
  /// x in the high, y in the low 32 bits; shifted as unsigned (a negative x shifted
  /// as signed is undefined behaviour, UBSan's finding in issue 12).
  static unsigned long long key(long x, long y)
  {
    return (static_cast<unsigned long long>(x) << 32) ^
           (static_cast<unsigned long long>(y) & 0xffffffffULL);
  }
  double inv_cell_;
  std::unordered_map<unsigned long long, std::vector<int>> cells_;
};

} // namespace

bool
LocalMappingParams::isValid(std::string* why) const
{
  std::string reason, ba_why;
  if (window_size < 2)
    reason = "window_size must be >= 2, got " + std::to_string(window_size);
  else if (max_border_keyframes < 0)
    reason = "max_border_keyframes must be >= 0, got " + std::to_string(max_border_keyframes);
  else if (!(match_radius_m > 0.0) || !std::isfinite(match_radius_m))
    reason = "match_radius_m must be > 0, got " + std::to_string(match_radius_m);
  else if (max_hamming_distance < 0 || max_hamming_distance > 256)
    reason = "max_hamming_distance must be in [0, 256], got " +
             std::to_string(max_hamming_distance);
  else if (!bundle_adjustment.isValid(&ba_why))
    reason = "bundle_adjustment: " + ba_why;
  if (why && !reason.empty())
    *why = reason;
  return reason.empty();
}

LocalMapping::LocalMapping(const LocalMappingParams& params, SlamMap::Ptr map)
  : params_(params), map_(std::move(map))
{
  std::string why;
  if (!params_.isValid(&why))
    throw std::invalid_argument("LocalMapping: invalid params: " + why);
  if (!map_)
    throw std::invalid_argument("LocalMapping: null map");
}

LocalMappingResult
LocalMapping::processKeyFrame(const KeyFrame::Ptr& kf)
{
  if (!kf)
    throw std::invalid_argument("LocalMapping::processKeyFrame: null key-frame");
  if (kf->id >= map_->numKeyFrames())
    throw std::invalid_argument("LocalMapping::processKeyFrame: key-frame " +
                                std::to_string(kf->id) + " is not in the map");
  const auto start = std::chrono::steady_clock::now();
  LocalMappingResult result;
  result.keyframe = kf->id;

  associate(kf, result);
  const std::vector<KeyFrameId> window = windowOf(kf->id);
  if (params_.enable_bundle_adjustment && window.size() >= 2)
    adjustWindow(window, result);

  // 5. Map-point culling (paper 8.1): points seen by none of the window's key-frames go.
  result.num_culled = static_cast<int>(map_->cullMapPoints(window));
  result.num_map_points = static_cast<int>(map_->numMapPoints());
  result.total_ms =
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
  return result;
}

void
LocalMapping::associate(const KeyFrame::Ptr& kf, LocalMappingResult& result)
{
  // 1. Associate the key-frame's features with the local map (paper 8.1): each map point
  // is predicted into the key-frame by its pose; candidates are the features within
  // match_radius_m, the best Hamming distance wins; a feature keeps its best point.
  const Pose3d T_world_kf = map_->keyFramePose(kf->id);
  const Pose3d T_kf_world = T_world_kf.inverse();
  const RasterFeatureSet& features = kf->features;
  const std::vector<MapPoint> local_map = map_->mapPoints();
  const FeatureGrid grid(features, params_.match_radius_m);
  const double radius_sq = params_.match_radius_m * params_.match_radius_m;
  std::vector<int> best_distance(features.size(), params_.max_hamming_distance + 1);
  std::vector<MapPointId> best_point(features.size(), kNoMapPoint);
  for (const MapPoint& mp : local_map) {
    const Eigen::Vector3d p_kf = T_kf_world * mp.p_world;
    int best = params_.max_hamming_distance + 1, best_i = -1;
    grid.forNeighbours(p_kf, [&](int i) {
      const Eigen::Vector3d o = features.points[i].getVector3fMap().cast<double>();
      if ((o - p_kf).squaredNorm() > radius_sq)
        return;
      const int d = hammingDistance(mp.descriptor, features.descriptors[i]);
      if (d < best) {
        best = d;
        best_i = i;
      }
    });
    if (best_i >= 0 && best < best_distance[best_i]) {
      best_distance[best_i] = best;
      best_point[best_i] = mp.id;
    }
  }
  // 2. Matched features observe their map point; the others create new map points.
  for (std::size_t i = 0; i < features.size(); ++i) {
    const auto& p = features.points[i];
    if (!std::isfinite(p.x) || !std::isfinite(p.y) || !std::isfinite(p.z))
      continue;
    if (best_point[i] != kNoMapPoint) {
      map_->addObservation(best_point[i], kf->id, static_cast<int>(i));
      ++result.num_matched;
    }
    else {
      map_->createMapPoint(kf->id, static_cast<int>(i),
                           T_world_kf * p.getVector3fMap().cast<double>(),
                           features.descriptors[i]);
      ++result.num_created;
    }
  }
}

std::vector<KeyFrameId>
LocalMapping::windowOf(KeyFrameId newest) const
{
  // The newest n key-frames (key-frame culling: older ones leave it).
  std::vector<KeyFrameId> window;
  const KeyFrameId first =
      newest + 1 >= static_cast<KeyFrameId>(params_.window_size) ? newest + 1 - params_.window_size : 0;
  for (KeyFrameId id = first; id <= newest; ++id)
    window.push_back(id);
  return window;
}

void
LocalMapping::adjustWindow(const std::vector<KeyFrameId>& window, LocalMappingResult& result)
{
  // Local bundle adjustment over the window and the map points it sees.
  const std::uint64_t epoch = map_->correctionEpoch();
  const std::vector<MapPoint> points = map_->mapPointsSeenBy(window);
  const std::set<KeyFrameId> in_window(window.begin(), window.end());
  BundleAdjustmentProblem problem;
  for (KeyFrameId id : window)
    problem.poses[id] = map_->keyFramePose(id);
  // Border: older key-frames that see the window's points, newest first, held constant.
  std::set<KeyFrameId, std::greater<KeyFrameId>> border_candidates;
  for (const MapPoint& mp : points)
    for (const auto& o : mp.observations)
      if (!in_window.count(o.keyframe))
        border_candidates.insert(o.keyframe);
  std::set<KeyFrameId> border;
  for (KeyFrameId id : border_candidates) {
    if (static_cast<int>(border.size()) >= params_.max_border_keyframes)
      break;
    border.insert(id);
    problem.poses[id] = map_->keyFramePose(id);
  }
  // Gauge: the border key-frames are held constant: they were optimized before and
  // anchor the window to the rest of the map; the error only depends on relative poses,
  // so without an anchor the window could drift freely. Without a border (the start of
  // the sequence) the oldest window key-frame is held constant instead; key-frame 0
  // (the world frame's origin) is never moved.
  problem.fixed = border;
  if (problem.fixed.empty() || in_window.count(0))
    problem.fixed.insert(window.front());
  for (const MapPoint& mp : points) {
    problem.points[mp.id] = mp.p_world;
    for (const auto& o : mp.observations)
      if (problem.poses.count(o.keyframe))
        problem.observations.push_back({o.keyframe, mp.id, o.p_keyframe.cast<double>()});
  }
  result.ba = bundleAdjust(problem, params_.bundle_adjustment);
  result.ba_run = true;
  if (result.ba.success) {
    std::map<KeyFrameId, Pose3d> moved;
    for (KeyFrameId id : window)
      if (!problem.fixed.count(id))
        moved[id] = problem.poses[id];
    result.ba_applied = map_->applyBundleAdjustment(epoch, moved, problem.points);
    if (result.ba_applied) {
      // The refined relative poses become the odometry edges of the pose graph.
      std::map<KeyFrameId, Pose3d> edges;
      for (std::size_t k = 1; k < window.size(); ++k)
        edges[window[k]] = problem.poses[window[k - 1]].inverse() * problem.poses[window[k]];
      map_->setOdometryEdges(edges);
    }
  }
}

} // namespace rast
} // namespace pcl
