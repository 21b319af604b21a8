/// \file rast_slam.cpp
/// \brief RastSlam: tracking, local mapping and loop closing as three threads (or in
/// sequence), with the queues between them; loop_closing.cpp holds the edge information
/// and the global bundle adjustment.

#include "loop_closing.h"
#include "stage_util.h"
#include "work_queue.h"

#include <pcl/slam/rast_slam.h>

#include <algorithm>
#include <cmath>
#include <condition_variable>
#include <deque>
#include <exception>
#include <mutex>
#include <optional>
#include <stdexcept>
#include <thread>
#include <time.h>

namespace pcl {
namespace rast {

namespace {

using loop_closing_detail::optimizeKeyFrameGraph;
using slam_detail::WorkQueue;


/// CPU time of the calling thread [ms].
double
threadCpuMs()
{
  timespec ts{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return ts.tv_sec * 1e3 + ts.tv_nsec * 1e-6;
}

StageTiming
timingOf(std::vector<double> samples)
{
  StageTiming t;
  t.count = samples.size();
  if (samples.empty())
    return t;
  for (double s : samples) {
    t.total_ms += s;
    t.max_ms = std::max(t.max_ms, s);
  }
  t.mean_ms = t.total_ms / samples.size();
  const std::size_t mid = samples.size() / 2;
  std::nth_element(samples.begin(), samples.begin() + mid, samples.end());
  t.median_ms = samples[mid];
  if (samples.size() % 2 == 0) {
    const double lower = *std::max_element(samples.begin(), samples.begin() + mid);
    t.median_ms = 0.5 * (t.median_ms + lower);
  }
  return t;
}

} // namespace

bool
SlamParams::isValid(std::string* why) const
{
  std::string sub, reason;
  if (!odometry.isValid(&sub))
    reason = "odometry: " + sub;
  else if (!local_mapping.isValid(&sub))
    reason = "local_mapping: " + sub;
  else if (!loop_detector.isValid(&sub))
    reason = "loop_detector: " + sub;
  else if (!pose_graph.isValid(&sub))
    reason = "pose_graph: " + sub;
  else if (!loop_closing.isValid(&sub))
    reason = "loop_closing: " + sub;
  else if (!std::isfinite(map_cloud_leaf_m))
    reason = "map_cloud_leaf_m must be finite";
  if (why && !reason.empty())
    *why = reason;
  return reason.empty();
}

struct RastSlam::Impl
{
  const SlamParams& params;
  SlamMap::Ptr map;
  Odometry odometry;
  LocalMapping local_mapping;
  LoopDetector detector;

  // Threads and the queues between the stages.
  WorkQueue<KeyFrame::Ptr> mapping_queue, loop_queue;
  std::thread mapping_thread, loop_thread;
  bool finished = false;
  std::mutex error_mutex;
  std::exception_ptr error;
  bool error_reported = false;

  // Statistics (own mutex: written by all stages).
  mutable std::mutex stats_mutex;
  std::vector<double> tracking_ms, mapping_ms, detection_ms, pose_graph_ms, global_ba_ms;
  std::vector<double> retrieval_ms, verification_ms;
  std::map<std::string, double> cpu_ms; ///< per stage, the threads' CPU time
  std::size_t searches_skipped = 0;
  int keyframes_since_loop = -1; ///< loop-closing thread only; -1: no loop yet
  /// Loop-closing thread only: key-frames outside the loop database whose features are
  /// still held (see releaseFinishedFeatures), oldest first.
  std::deque<KeyFrameId> features_to_release;
  std::map<std::string, std::size_t> status_counts;
  std::size_t without_features = 0; ///< frames tracked without their features
  std::size_t skipped = 0, accepted = 0, rejected = 0, inconsistent = 0, candidates = 0;
  std::vector<LoopRecord> loop_records;
  RastSlam::KeyFrameObserver observer; ///< set before the first scan, then read only

  Impl(const SlamParams& p, SlamMap::Ptr m, BlobStore::Ptr store)
    : params(p)
    , map(std::move(m))
    , odometry(p.odometry)
    , local_mapping(p.local_mapping, map)
    , detector(p.loop_detector, std::move(store))
  {
    if (p.features_on_demand)
      odometry.setFeaturesWanted(false);
    if (p.loop_closing.global_bundle_adjustment)
      map->setKeepCulledMapPoints(true);
    // The map owns the key-frame poses; the loop database reads them there.
    detector.setPoseSource([map = map] { return map->keyFramePoses(); });
    if (!p.deterministic) {
      mapping_thread = std::thread([this] { runMapping(); });
      loop_thread = std::thread([this] { runLoopClosing(); });
    }
  }

  void recordError(std::exception_ptr e)
  {
    {
      std::lock_guard<std::mutex> lock(error_mutex);
      if (!error)
        error = e;
    }
    // Unblock everyone: the pipeline stops after an error.
    mapping_queue.close();
    loop_queue.close();
  }

  void rethrowError()
  {
    std::lock_guard<std::mutex> lock(error_mutex);
    if (error && !error_reported) {
      error_reported = true;
      std::rethrow_exception(error);
    }
  }

  bool failed()
  {
    std::lock_guard<std::mutex> lock(error_mutex);
    return static_cast<bool>(error);
  }

  void runMapping()
  {
    try {
      KeyFrame::Ptr kf;
      while (mapping_queue.pop(kf)) {
        mapKeyFrame(kf);
        loop_queue.push(kf);
      }
    } catch (...) {
      recordError(std::current_exception());
    }
    loop_queue.close();
  }

  void runLoopClosing()
  {
    try {
      KeyFrame::Ptr kf;
      while (loop_queue.pop(kf))
        closeLoops(kf, params.loop_closing.search_newest_only_when_backlogged &&
                           loop_queue.size() > 0);
    } catch (...) {
      recordError(std::current_exception());
    }
  }

  /// Map points feed the bundle adjustments only (local and global, both off by
  /// default): without one, local mapping would build them for nothing (doc/slam.md).
  bool mapPointsUsed() const
  {
    return params.local_mapping.enable_bundle_adjustment ||
           params.loop_closing.global_bundle_adjustment;
  }

  void mapKeyFrame(const KeyFrame::Ptr& kf)
  {
    if (!mapPointsUsed()) {
      notify(SlamStage::kLocalMapping, *kf);
      return;
    }
    const double cpu0 = threadCpuMs();
    const LocalMappingResult r = local_mapping.processKeyFrame(kf);
    {
      std::lock_guard<std::mutex> lock(stats_mutex);
      mapping_ms.push_back(r.total_ms);
      cpu_ms["local_mapping"] += threadCpuMs() - cpu0;
    }
    notify(SlamStage::kLocalMapping, *kf);
  }

  void notify(SlamStage stage, const KeyFrame& kf) const
  {
    if (observer)
      observer(stage, kf);
  }

  /// The loop-closing stage for one key-frame (after local mapping): search, verify,
  /// and on an accepted loop optimize the pose graph of all key-frames. With \a backlog
  /// (newer key-frames wait) or during the cooldown after a loop the key-frame only
  /// joins the database. Its full cloud is released afterwards unless kept.
  void closeLoops(const KeyFrame::Ptr& kf, bool backlog = false)
  {
    const bool in_database = params.loop_closing.enable && searchAndClose(kf, backlog);
    if (!params.keep_keyframe_clouds)
      map->releaseKeyFrameCloud(kf->id); // the detector keeps its dense target
    if (!in_database && !params.loop_closing.global_bundle_adjustment)
      features_to_release.push_back(kf->id);
    releaseFinishedFeatures(kf->id);
    notify(SlamStage::kLoopClosing, *kf);
  }

  /// Key-frames outside the loop database hold their features only for tracking and
  /// local mapping (bundle adjustment reads the observations' own copies): once well
  /// behind the newest key-frame loop closing has, which local mapping is done with,
  /// nothing reads them again, and they are released (~28 kB a key-frame).
  void releaseFinishedFeatures(KeyFrameId newest)
  {
    const auto margin = static_cast<KeyFrameId>(2 * params.local_mapping.window_size + 2);
    while (!features_to_release.empty() && features_to_release.front() + margin <= newest) {
      map->releaseKeyFrameFeatures(features_to_release.front());
      features_to_release.pop_front();
    }
  }

  /// Add the key-frame to the loop database, unless its place is in it already and the
  /// map is anchored there by a recent loop (revisit culling): then the database grows
  /// with the mapped area, not with the time spent in it. Returns whether it was added.
  bool admit(const KeyFrame::Ptr& kf)
  {
    const LoopClosingParams& lc = params.loop_closing;
    const Pose3d T_world_kf = map->keyFramePose(kf->id);
    const bool anchored =
        keyframes_since_loop >= 0 && keyframes_since_loop <= lc.revisit_anchor_keyframes;
    if (lc.cull_revisits && anchored &&
        detector.coveringKeyFrame(*kf, T_world_kf, lc.revisit_radius_m, lc.revisit_angle_deg)) {
      detector.skipKeyFrame(*kf, T_world_kf);
      return false;
    }
    detector.addKeyFrame(kf, T_world_kf);
    return true;
  }

  /// Returns whether the key-frame joined the loop database.
  bool searchAndClose(const KeyFrame::Ptr& kf, bool backlog)
  {
    const Pose3d T_world_kf = map->keyFramePose(kf->id);
    const int cooldown = params.loop_closing.cooldown_keyframes;
    const bool cooling = keyframes_since_loop >= 0 && keyframes_since_loop < cooldown;
    if (keyframes_since_loop >= 0)
      ++keyframes_since_loop;
    const double cpu0 = threadCpuMs();
    if (backlog || cooling) {
      const bool added = admit(kf);
      std::lock_guard<std::mutex> lock(stats_mutex);
      ++searches_skipped;
      cpu_ms["loop_detection"] += threadCpuMs() - cpu0;
      return added;
    }
    const pcl::StopWatch watch;
    const LoopDetection detection = detector.detect(*kf, T_world_kf);
    const double detect_ms = watch.getTime();
    const LoopVerification* best = detection.best();
    {
      std::lock_guard<std::mutex> lock(stats_mutex);
      detection_ms.push_back(detect_ms);
      retrieval_ms.push_back(detection.retrieval_ms);
      verification_ms.push_back(detection.verify_ms);
      cpu_ms["loop_detection"] += threadCpuMs() - cpu0;
      candidates += detection.candidates.size();
      accepted += best ? 1 : 0;
      rejected += static_cast<std::size_t>(detection.num_rejected);
      for (std::size_t k = 0; k < detection.verifications.size(); ++k) {
        LoopRecord rec;
        rec.verification = detection.verifications[k];
        if (k < detection.candidates.size())
          rec.source = detection.candidates[k].source;
        loop_records.push_back(rec);
      }
    }
    if (!best)
      return admit(kf);
    keyframes_since_loop = 0;
    LoopEdge edge;
    edge.query = best->query;
    edge.candidate = best->candidate;
    edge.T_candidate_query = best->T_candidate_query;
    edge.num_inliers = best->num_inliers;
    map->addLoopEdge(edge);
    const double cpu1 = threadCpuMs();
    optimizeGraph();
    {
      std::lock_guard<std::mutex> lock(stats_mutex);
      cpu_ms["pose_graph"] += threadCpuMs() - cpu1;
    }
    return admit(kf); // at its corrected pose
  }

  /// Pose-graph optimisation over all key-frames (optimizeKeyFrameGraph), the optional
  /// global bundle adjustment, the correction applied to the map, and the statistics.
  void optimizeGraph()
  {
    const pcl::StopWatch watch;
    std::map<KeyFrameId, Pose3d> corrected;
    std::vector<LoopEdge> loops;
    std::vector<std::size_t> dropped;
    if (!optimizeKeyFrameGraph(*map, params, corrected, loops, dropped))
      return; // keep the old poses; the loop edge stays for the next attempt
    if (params.loop_closing.global_bundle_adjustment) {
      const pcl::StopWatch ba_watch;
      BundleAdjustmentParams ba = params.local_mapping.bundle_adjustment;
      ba.max_iterations = params.loop_closing.global_ba_max_iterations;
      globalBundleAdjustment(corrected, map->keyFrames(), map->allMapPoints(),
                             map->loopEdges(), params.loop_closing, ba);
      std::lock_guard<std::mutex> lock(stats_mutex);
      global_ba_ms.push_back(ba_watch.getTime());
    }
    map->applyLoopCorrection(corrected); // the detector reads the corrected poses
    std::lock_guard<std::mutex> lock(stats_mutex);
    pose_graph_ms.push_back(watch.getTime());
    inconsistent += dropped.size();
    for (std::size_t k : dropped) {
      const LoopEdge& e = loops[k];
      for (auto& rec : loop_records)
        if (rec.verification.accepted && rec.verification.query == e.query &&
            rec.verification.candidate == e.candidate)
          rec.dropped_inconsistent = true;
    }
  }

  /// Tracking output -> the map, and a new key-frame to the next stage.
  /// RastSlam::addScan (\a next: the look-ahead scan, or null).
  OdometryFrameResult add(const pcl::PointCloud<pcl::PointXYZI>::ConstPtr& cloud,
                          double timestamp_s,
                          std::size_t frame_index,
                          const std::vector<float>& point_times_s,
                          const OdometryInput* next,
                          const std::string& path);
  void handleTracking(const OdometryFrameResult& r, const std::string& path, bool is_skipped,
                      const std::string& reason)
  {
    if (r.keyframe)
      map->addKeyFrame(r.keyframe);
    FrameRecord rec;
    rec.frame_index = r.frame_index;
    rec.timestamp_s = r.timestamp_s;
    rec.reference_keyframe = r.reference_keyframe;
    rec.T_keyframe_lidar = r.T_keyframe_lidar;
    rec.status = toString(r.status);
    rec.skipped = is_skipped;
    rec.skipped_reason = reason;
    rec.path = path;
    if (map->numKeyFrames() == 0) {
      // No key-frame yet (leading empty or unusable scans): tracking's own pose, for
      // good. The first usable scan starts the map, whatever came before it.
      rec.T_keyframe_lidar = r.T_world_lidar;
      rec.reference_keyframe = kNoKeyFrame;
    }
    map->addFrame(rec);
    {
      std::lock_guard<std::mutex> lock(stats_mutex);
      tracking_ms.push_back(r.timings.total_ms);
      ++status_counts[rec.status];
      skipped += is_skipped ? 1 : 0;
      without_features += r.features_skipped ? 1 : 0;
    }
    if (!r.keyframe)
      return;
    // An error of a stage run here (the tracking observer; every stage in deterministic
    // mode) ends the run as a worker's does: recorded, so that later calls and finish()
    // report it, and thrown to the caller now.
    try {
      notify(SlamStage::kTracking, *r.keyframe);
      if (params.deterministic) {
        mapKeyFrame(r.keyframe);
        closeLoops(r.keyframe);
      }
    } catch (...) {
      recordError(std::current_exception());
      throw;
    }
    if (!params.deterministic)
      mapping_queue.push(r.keyframe);
  }

  void finish()
  {
    if (!finished) {
      finished = true;
      mapping_queue.close();
      if (mapping_thread.joinable())
        mapping_thread.join();
      loop_queue.close();
      if (loop_thread.joinable())
        loop_thread.join();
    }
    rethrowError();
  }
};

RastSlam::RastSlam(const SlamParams& params) : params_(params)
{
  std::string why;
  if (!params_.isValid(&why))
    throw std::invalid_argument("RastSlam: invalid params: " + why);
  // One store for the bulky write-once data of both the map and the loop database.
  const auto store = std::make_shared<BlobStore>(params_.spill_directory);
  map_ = std::make_shared<SlamMap>(params_.map_cloud_leaf_m, store);
  impl_ = std::make_unique<Impl>(params_, map_, store);
}

RastSlam::~RastSlam()
{
  try {
    impl_->finish();
  } catch (...) {
    // finish() reports worker errors; a destructor must not throw.
  }
}

OdometryFrameResult
RastSlam::addScan(const pcl::PointCloud<pcl::PointXYZI>::ConstPtr& cloud,
                  double timestamp_s,
                  std::size_t frame_index,
                  const std::string& path)
{
  return addScan(cloud, timestamp_s, frame_index, {}, path);
}

OdometryFrameResult
RastSlam::addScan(const pcl::PointCloud<pcl::PointXYZI>::ConstPtr& cloud,
                  double timestamp_s,
                  std::size_t frame_index,
                  const std::vector<float>& point_times_s,
                  const std::string& path)
{
  return impl_->add(cloud, timestamp_s, frame_index, point_times_s, nullptr, path);
}

OdometryFrameResult
RastSlam::addScan(const pcl::PointCloud<pcl::PointXYZI>::ConstPtr& cloud,
                  double timestamp_s,
                  std::size_t frame_index,
                  const std::vector<float>& point_times_s,
                  const OdometryInput& next,
                  const std::string& path)
{
  return impl_->add(cloud, timestamp_s, frame_index, point_times_s, &next, path);
}

OdometryFrameResult
RastSlam::Impl::add(const pcl::PointCloud<pcl::PointXYZI>::ConstPtr& cloud,
                    double timestamp_s,
                    std::size_t frame_index,
                    const std::vector<float>& point_times_s,
                    const OdometryInput* next,
                    const std::string& path)
{
  if (finished)
    throw std::logic_error("RastSlam::addScan: called after finish()");
  if (failed())
    finish(); // joins and rethrows the worker's exception
  const double cpu0 = threadCpuMs();
  OdometryFrameResult r =
      next ? odometry.processFrame(cloud, timestamp_s, frame_index, point_times_s, *next)
           : odometry.processFrame(cloud, timestamp_s, frame_index, point_times_s);
  {
    std::lock_guard<std::mutex> lock(stats_mutex);
    cpu_ms["tracking"] += threadCpuMs() - cpu0;
  }
  handleTracking(r, path, false, "");
  return r;
}

OdometryFrameResult
RastSlam::addSkippedScan(std::size_t frame_index,
                         double timestamp_s,
                         const std::string& reason,
                         const std::string& path)
{
  if (impl_->finished)
    throw std::logic_error("RastSlam::addSkippedScan: called after finish()");
  if (impl_->failed())
    impl_->finish();
  OdometryFrameResult r = impl_->odometry.skipFrame(timestamp_s, frame_index, reason);
  r.keyframe.reset(); // a skipped frame is never a key-frame
  impl_->handleTracking(r, path, true, reason);
  return r;
}

void
RastSlam::finish()
{
  impl_->finish();
}

void
RastSlam::setKeyFrameObserver(KeyFrameObserver observer)
{
  // The worker threads read it unguarded: set only before they can see a key-frame.
  if (map_->numFrames() > 0 || impl_->finished)
    throw std::logic_error("RastSlam::setKeyFrameObserver: set it before the first addScan");
  impl_->observer = std::move(observer);
}

const char*
toString(SlamStage stage)
{
  switch (stage) {
  case SlamStage::kTracking:
    return "tracking";
  case SlamStage::kLocalMapping:
    return "local_mapping";
  case SlamStage::kLoopClosing:
    return "loop_closing";
  }
  return "unknown";
}

ElevationCalibrationState
RastSlam::elevationCalibration() const
{
  return impl_->odometry.elevationCalibration();
}

PoseVector
RastSlam::framePoses() const
{
  return map_->framePoses();
}
std::vector<FrameRecord>
RastSlam::frames() const
{
  return map_->frames();
}
PoseVector
RastSlam::keyFramePoses() const
{
  return map_->keyFramePoses();
}
std::vector<KeyFrame::Ptr>
RastSlam::keyFrames() const
{
  return map_->keyFrames();
}
pcl::PointCloud<pcl::PointXYZI>::Ptr
RastSlam::buildMap(double leaf_m) const
{
  return map_->buildMap(leaf_m);
}
std::vector<LoopEdge>
RastSlam::loops() const
{
  return map_->loopEdges();
}
std::vector<LoopRecord>
RastSlam::loopRecords() const
{
  std::lock_guard<std::mutex> lock(impl_->stats_mutex);
  return impl_->loop_records;
}

SlamStatistics
RastSlam::statistics() const
{
  SlamStatistics s;
  s.frames = map_->numFrames();
  s.keyframes = map_->numKeyFrames();
  s.map_points = map_->numMapPoints();
  s.map_points_created = map_->numMapPointsCreated();
  const SlamMap::MemoryUsage map_memory = map_->memoryUsage();
  s.memory_bytes["map_clouds"] = map_memory.map_clouds;
  s.memory_bytes["map_clouds_on_disk"] = map_memory.map_clouds_on_disk;
  s.memory_bytes["keyframe_clouds"] = map_memory.keyframe_clouds;
  s.memory_bytes["features"] = map_memory.features;
  s.memory_bytes["map_points"] = map_memory.map_points;
  s.memory_bytes["frames"] = map_memory.frames;
  const LoopDetector::MemoryUsage loop_memory = impl_->detector.memoryUsage();
  s.memory_bytes["loop_dense_targets"] = loop_memory.dense_targets;
  s.memory_bytes["loop_dense_targets_on_disk"] = loop_memory.dense_targets_on_disk;
  s.memory_bytes["loop_appearance_index"] = loop_memory.appearance_index;
  s.memory_bytes["loop_appearance_keys"] = loop_memory.appearance_keys;
  s.memory_bytes["loop_appearance_features"] = loop_memory.appearance_features;
  std::lock_guard<std::mutex> lock(impl_->stats_mutex);
  s.skipped_frames = impl_->skipped;
  s.frames_without_features = impl_->without_features;
  s.loops_accepted = impl_->accepted;
  s.loops_rejected = impl_->rejected;
  s.loops_inconsistent = impl_->inconsistent;
  s.loop_candidates = impl_->candidates;
  s.pose_graph_runs = impl_->pose_graph_ms.size();
  s.tracking_status = impl_->status_counts;
  s.timing["tracking"] = timingOf(impl_->tracking_ms);
  s.timing["local_mapping"] = timingOf(impl_->mapping_ms);
  s.timing["loop_detection"] = timingOf(impl_->detection_ms);
  s.timing["pose_graph"] = timingOf(impl_->pose_graph_ms);
  s.timing["global_ba"] = timingOf(impl_->global_ba_ms);
  s.timing["loop_retrieval"] = timingOf(impl_->retrieval_ms);
  s.timing["loop_verification"] = timingOf(impl_->verification_ms);
  for (const auto& [stage, ms] : impl_->cpu_ms)
    s.timing[stage].cpu_total_ms = ms;
  s.loop_searches_skipped = impl_->searches_skipped;
  s.loop_database_keyframes = impl_->detector.size();
  s.loop_database_revisits_culled = impl_->detector.numSkipped();
  return s;
}

} // namespace rast
} // namespace pcl
