/// \file odometry.cpp
/// \brief The odometry's parameters, its public calls (processFrame, skipFrame) and the
/// state between frames: constant-velocity prediction, key-frames, the local map and the
/// motion compensation passes. The tracking steps are in odometry_tracking.cpp.

#include "odometry_impl.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <system_error>

namespace pcl {
namespace rast {

using namespace odometry_detail;

const char*
toString(TrackingStatus status)
{
  switch (status) {
  case TrackingStatus::kFirstFrame:
    return "first_frame";
  case TrackingStatus::kFeatures:
    return "features";
  case TrackingStatus::kDenseFallback:
    return "dense_fallback";
  case TrackingStatus::kConstantVelocity:
    return "constant_velocity";
  case TrackingStatus::kSkipped:
    return "skipped";
  }
  return "unknown";
}

namespace {

bool
finitePositive(double v)
{
  return std::isfinite(v) && v > 0.0;
}

/// Point times a scan can be compensated with: one per point, each finite and within a
/// second of the reference (a sweep).
bool
usableTimes(const std::vector<float>& times, std::size_t num_points)
{
  return !times.empty() && times.size() == num_points &&
         std::all_of(
             times.begin(), times.end(), [](float t) { return std::abs(t) <= 1.0f; });
}

/// The motion \a delta scaled by \a ratio (rotation angle and translation), for a
/// constant-velocity prediction over a different time step.
Pose3d
scaleMotion(const Pose3d& delta, double ratio)
{
  const Eigen::AngleAxisd aa(delta.rotation());
  Pose3d out = Pose3d::Identity();
  out.linear() = Eigen::AngleAxisd(aa.angle() * ratio, aa.axis()).toRotationMatrix();
  out.translation() = delta.translation() * ratio;
  return out;
}

} // namespace

bool
DenseTrackingParams::isValid(std::string* why) const
{
  std::string reason;
  if (!finitePositive(source_voxel_size_m))
    reason = "source_voxel_size_m must be > 0";
  else if (max_source_points < 10)
    reason = "max_source_points must be >= 10";
  else if (!finitePositive(map_voxel_size_m))
    reason = "map_voxel_size_m must be > 0";
  else if (map_max_points_per_voxel < 5)
    reason = "map_max_points_per_voxel must be >= 5 (a plane needs 5 points)";
  else if (!(map_nearer_ratio >= 0.0 && map_nearer_ratio <= 1.0))
    reason =
        "map_nearer_ratio must be in [0, 1], got " + std::to_string(map_nearer_ratio);
  else if (!finitePositive(map_radius_m))
    reason = "map_radius_m must be > 0";
  else if (!(max_surface_variation > 0.0 && max_surface_variation <= 1.0 / 3.0))
    reason = "max_surface_variation must be in (0, 1/3]";
  else if (!finitePositive(max_correspondence_distance_m))
    reason = "max_correspondence_distance_m must be > 0";
  else if (max_iterations < 1)
    reason = "max_iterations must be >= 1";
  else if (!finitePositive(min_kernel_scale_m))
    reason = "min_kernel_scale_m must be > 0";
  else if (!(convergence_translation_m >= 0.0) || !(convergence_rotation_rad >= 0.0))
    reason = "convergence thresholds must be >= 0";
  else if (!(degeneracy_min_ratio >= 0.0 && degeneracy_min_ratio < 1.0))
    reason = "degeneracy_min_ratio must be in [0, 1)";
  else if (!(degeneracy_min_support >= 0.0) || !std::isfinite(degeneracy_min_support))
    reason = "degeneracy_min_support must be finite and >= 0, got " +
             std::to_string(degeneracy_min_support);
  else if (!(degeneracy_support_derivative > 0.0 && degeneracy_support_derivative <= 1.0))
    reason = "degeneracy_support_derivative must be in (0, 1], got " +
             std::to_string(degeneracy_support_derivative);
  else if (min_correspondences < 6)
    reason = "min_correspondences must be >= 6";
  else if (!finitePositive(max_correction_m) || !finitePositive(max_correction_deg))
    reason = "max_correction_m and max_correction_deg must be > 0";
  else if (young_map_scans < 1)
    reason = "young_map_scans must be >= 1, got " + std::to_string(young_map_scans);
  if (why)
    *why = reason;
  return reason.empty();
}

bool
MotionHypothesisParams::isValid(std::string* why) const
{
  std::string reason;
  if (!(max_yaw_deg >= 0.0 && max_yaw_deg <= 180.0))
    reason = "max_yaw_deg must be in [0, 180]";
  else if (!finitePositive(yaw_step_deg))
    reason = "yaw_step_deg must be > 0";
  else if (min_weak_inliers < 3)
    reason = "min_weak_inliers must be >= 3";
  else if (!finitePositive(coarse_correspondence_distance_m) ||
           !finitePositive(coarse_max_correction_m))
    reason = "coarse_correspondence_distance_m and coarse_max_correction_m must be > 0";
  else if (!finitePositive(cold_start_step_m) || !(cold_start_max_speed_mps >= 0.0) ||
           !std::isfinite(cold_start_max_speed_mps))
    reason = "cold_start_step_m must be > 0 and cold_start_max_speed_mps >= 0";
  else if (!(guided_gate_m >= 0.0) || !std::isfinite(guided_gate_m))
    reason =
        "guided_gate_m must be finite and >= 0, got " + std::to_string(guided_gate_m);
  else if (!(guided_refit_gate_m >= 0.0) || !std::isfinite(guided_refit_gate_m))
    reason = "guided_refit_gate_m must be finite and >= 0, got " +
             std::to_string(guided_refit_gate_m);
  else if (!(guided_support_factor >= 1.0) || !std::isfinite(guided_support_factor))
    reason = "guided_support_factor must be finite and >= 1, got " +
             std::to_string(guided_support_factor);
  else if (threads < 1 || threads > 2)
    reason = "threads must be 1 or 2, got " + std::to_string(threads);
  if (why)
    *why = reason;
  return reason.empty();
}

bool
OdometryParams::isValid(std::string* why) const
{
  std::string reason, sub;
  if (!ground.isValid(&sub))
    reason = "ground." + sub;
  else if (!raster.isValid(&sub))
    reason = "raster." + sub;
  else if (!orb.isValid(&sub))
    reason = "orb." + sub;
  else if (!registration.isValid(&sub))
    reason = "registration." + sub;
  else if (!dense.isValid(&sub))
    reason = "dense." + sub;
  else if (!turn_search.isValid(&sub))
    reason = "turn_search." + sub;
  else if (!deskew.isValid(&sub))
    reason = "deskew." + sub;
  else if (!elevation_calibration.isValid(&sub))
    reason = "elevation_calibration." + sub;
  else if (keyframe_min_frames < 1)
    reason =
        "keyframe_min_frames must be >= 1, got " + std::to_string(keyframe_min_frames);
  else if (keyframe_max_common_points < 0)
    reason = "keyframe_max_common_points must be >= 0, got " +
             std::to_string(keyframe_max_common_points);
  else if (!(min_range_m >= 0.0) || !(max_range_m > min_range_m) ||
           !std::isfinite(max_range_m))
    reason = "need 0 <= min_range_m < max_range_m (finite), got " +
             std::to_string(min_range_m) + ", " + std::to_string(max_range_m);
  else if (min_feature_inliers < 3)
    reason =
        "min_feature_inliers must be >= 3, got " + std::to_string(min_feature_inliers);
  else if (strong_feature_inliers < min_feature_inliers)
    reason = "strong_feature_inliers must be >= min_feature_inliers";
  else if (!finitePositive(prior_gate_m) || !finitePositive(prior_gate_deg))
    reason = "prior_gate_m and prior_gate_deg must be > 0";
  else if (!(dense_prior_ratio >= 0.0 && dense_prior_ratio < 1.0))
    reason =
        "dense_prior_ratio must be in [0, 1), got " + std::to_string(dense_prior_ratio);
  else if (!(weak_feature_share >= 0.0 && weak_feature_share <= 1.0))
    reason =
        "weak_feature_share must be in [0, 1], got " + std::to_string(weak_feature_share);
  else if (failed_features_skip_frames < 0)
    reason = "failed_features_skip_frames must be >= 0, got " +
             std::to_string(failed_features_skip_frames);
  else if (!(prior_gate_accel_mps2 >= 0.0 && std::isfinite(prior_gate_accel_mps2)) ||
           !(prior_gate_angular_accel_dps2 >= 0.0 &&
             std::isfinite(prior_gate_angular_accel_dps2)))
    reason = "prior_gate_accel_mps2 and prior_gate_angular_accel_dps2 must be >= 0 and "
             "finite, got " +
             std::to_string(prior_gate_accel_mps2) + ", " +
             std::to_string(prior_gate_angular_accel_dps2);
  else if (!(prior_gate_vertical_accel_mps2 >= 0.0 &&
             std::isfinite(prior_gate_vertical_accel_mps2)))
    reason = "prior_gate_vertical_accel_mps2 must be >= 0 and finite, got " +
             std::to_string(prior_gate_vertical_accel_mps2);
  else if (!(indistinct_residual_m >= 0.0 && std::isfinite(indistinct_residual_m)))
    reason = "indistinct_residual_m must be >= 0 and finite, got " +
             std::to_string(indistinct_residual_m);
  else if (!(visibility_margin_m >= 0.0 && std::isfinite(visibility_margin_m)))
    reason = "visibility_margin_m must be >= 0 and finite, got " +
             std::to_string(visibility_margin_m);
  else if (!finitePositive(visibility_radius_m))
    reason = "visibility_radius_m must be > 0 and finite, got " +
             std::to_string(visibility_radius_m);
  else if (!finitePositive(keyframe_voxel_size_m))
    reason = "keyframe_voxel_size_m must be > 0";
  else if (keyframe_min_inliers < 0)
    reason = "keyframe_min_inliers must be >= 0";
  else if (!finitePositive(keyframe_max_distance_m) ||
           !finitePositive(keyframe_max_rotation_deg))
    reason = "keyframe_max_distance_m and keyframe_max_rotation_deg must be > 0";
  if (why)
    *why = reason;
  return reason.empty();
}

const char*
toString(DeskewMode mode)
{
  switch (mode) {
  case DeskewMode::kAuto:
    return "auto";
  case DeskewMode::kOn:
    return "on";
  case DeskewMode::kOff:
    return "off";
  }
  return "unknown";
}

bool
DeskewParams::isValid(std::string* why) const
{
  std::string reason, sub;
  if (!sweep.isValid(&sub))
    reason = "sweep." + sub;
  else if (!std::isfinite(sweep_period_s) || sweep_period_s > 1.0)
    reason = "sweep_period_s must be finite and <= 1 s (<= 0: the frame interval), got " +
             std::to_string(sweep_period_s);
  else if (!(seconds_per_timestamp > 0.0) || !std::isfinite(seconds_per_timestamp))
    reason = "seconds_per_timestamp must be > 0 and finite, got " +
             std::to_string(seconds_per_timestamp);
  else if (!(second_pass_translation_m >= 0.0) || !(second_pass_rotation_deg >= 0.0))
    reason = "second_pass_translation_m and second_pass_rotation_deg must be >= 0";
  else if (bins < 1 || bins > 65536)
    reason = "bins must be in [1, 65536], got " + std::to_string(bins);
  if (why)
    *why = reason;
  return reason.empty();
}

// ---------------------------------------------------------------------------

Pose3d
Odometry::Impl::predict(double timestamp_s) const
{
  if (num_poses == 0)
    return Pose3d::Identity();
  if (num_poses == 1)
    return T_world_last;
  // Constant velocity: repeat the last motion, scaled to this frame's time step.
  const double dt_prev = t_last - t_before, dt = timestamp_s - t_last;
  double ratio = 1.0;
  if (std::isfinite(dt_prev) && std::isfinite(dt) && dt_prev > 1e-6 && dt > 0.0)
    ratio = std::min(dt / dt_prev, 5.0);
  return composePoses(T_world_last,
                      scaleMotion(T_world_before.inverse() * T_world_last, ratio));
}

double
Odometry::Impl::interval(double t0, double t1) const
{
  const double dt = (t1 - t0) * params.deskew.seconds_per_timestamp;
  // Without usable timestamps assume 10 Hz; cap at 5 s.
  return std::isfinite(dt) && dt > 1e-6 ? std::min(dt, 5.0) : 0.1;
}

Odometry::Impl::SweepMotion
Odometry::Impl::sweepMotion(double timestamp_s) const
{
  SweepMotion m;
  m.dt = frameInterval(timestamp_s);
  m.T_motion = T_world_last.inverse() * predict(timestamp_s);
  if (num_poses >= 2)
    m.xi = logSE3(m.T_motion) / m.dt;
  return m;
}

void
Odometry::Impl::checkIndex(std::size_t frame_index)
{
  if (have_index && frame_index <= last_index)
    throw std::invalid_argument("Odometry: frame indices must increase, got " +
                                std::to_string(frame_index) + " after " +
                                std::to_string(last_index));
  have_index = true;
  last_index = frame_index;
}

void
Odometry::Impl::commitPose(const OdometryFrameResult& result)
{
  T_world_before = T_world_last;
  t_before = t_last;
  T_world_last = result.T_world_lidar; // normalized where it was made (step 6, predict)
  t_last = result.timestamp_s;
  ++num_poses;
  ++frames_since_keyframe;
  const bool tracked = result.status == TrackingStatus::kFeatures ||
                       result.status == TrackingStatus::kDenseFallback ||
                       result.status == TrackingStatus::kFirstFrame;
  frames_without_tracking = tracked ? 0 : frames_without_tracking + 1;
  velocity_tracked = tracked && last_tracked;
  velocity_age_frames = velocity_tracked          ? 0
                        : velocity_age_frames < 0 ? -1
                                                  : velocity_age_frames + 1;
  last_tracked = tracked;
  if (result.keyframe) {
    frames_since_keyframe = 0;
    frames_without_tracking = 0;
  }
}

KeyFrame::Ptr
Odometry::Impl::makeKeyFrame(const OdometryFrameResult& result,
                             const RasterFeatureSet& features,
                             const pcl::PointCloud<pcl::PointXYZI>::ConstPtr& cloud_ptr)
{
  const pcl::PointCloud<pcl::PointXYZI>& cloud = *cloud_ptr;
  auto kf = std::make_shared<KeyFrame>();
  kf->id = next_keyframe_id++;
  kf->frame_index = result.frame_index;
  kf->timestamp_s = result.timestamp_s;
  kf->T_world_keyframe = result.T_world_lidar;
  kf->T_previous_keyframe =
      keyframe ? composePoses(T_world_keyframe.inverse(), result.T_world_lidar)
               : Pose3d::Identity();
  kf->features = features; // a copy: the frame's result keeps its own
  kf->map_point_ids.assign(kf->features.size(), kNoMapPoint);
  kf->odometry_map_scans = map_scans;

  // The voxelized scan the key-frame keeps (memory: keyframe_voxel_size_m) ...
  if (params.keyframe_clouds) {
    const odometry_detail::RangeFilter in_range(params.min_range_m, params.max_range_m);
    const std::vector<int> kept = odometry_detail::voxelDownsampleIndices(
        cloud, params.keyframe_voxel_size_m, in_range);
    auto voxels = std::make_shared<pcl::PointCloud<pcl::PointXYZI>>();
    voxels->header = cloud.header;
    voxels->points.reserve(kept.size());
    for (const int i : kept)
      voxels->points.push_back(cloud.points[i]);
    voxels->width = static_cast<std::uint32_t>(voxels->points.size());
    voxels->height = 1;
    voxels->is_dense = true;
    kf->cloud = voxels;
  }

  insertIntoMap(cloud_ptr, result.T_world_lidar);
  keyframe = kf;
  T_world_keyframe = result.T_world_lidar;
  return kf;
}

/// The scan into the local map, denser than a key-frame's cloud, so that a single scan
/// already gives every map voxel on a surface enough points for a plane (4 x 4 per
/// voxel face).
void
Odometry::Impl::insertIntoMap(const pcl::PointCloud<pcl::PointXYZI>::ConstPtr& cloud,
                              const Pose3d& T_world_lidar)
{
  // One at a time, in order: the map is the same as inserted here.
  finishMapInsertion();
  ++map_scans;
  auto work = [this, cloud, T_world_lidar] { insertNow(*cloud, T_world_lidar); };
  try {
    if (!map_thread)
      map_thread = std::make_unique<slam_detail::TaskThread<void>>();
  } catch (const std::system_error&) {
    work(); // no thread to be had: here
    return;
  }
  map_insertion = map_thread->run(std::move(work));
}

void
Odometry::Impl::insertNow(const pcl::PointCloud<pcl::PointXYZI>& cloud,
                          const Pose3d& T_world_lidar)
{
  insertScan(cloud, T_world_lidar, local_map);
}

void
Odometry::Impl::insertScan(const pcl::PointCloud<pcl::PointXYZI>& cloud,
                           const Pose3d& T_world_lidar,
                           VoxelPlaneMap& map) const
{
  const odometry_detail::RangeFilter in_range(params.min_range_m, params.max_range_m);
  const Eigen::Isometry3f T = T_world_lidar.cast<float>();
  Points3f points_world;
  for (const int i : odometry_detail::voxelDownsampleIndices(
           cloud, params.dense.map_voxel_size_m / 4.0, in_range))
    points_world.push_back(T * cloud.points[i].getVector3fMap());
  map.insert(points_world, T.translation());
}

// ---------------------------------------------------------------------------

Odometry::Odometry(const OdometryParams& params)
{
  std::string why;
  if (!params.isValid(&why))
    throw std::invalid_argument("Odometry: invalid params: " + why);
  impl_ = std::make_unique<Impl>(params);
}

Odometry::~Odometry() = default;

ElevationCalibrationState
Odometry::elevationCalibration() const
{
  return impl_->elevation ? impl_->elevation->state() : ElevationCalibrationState();
}

const OdometryParams&
Odometry::params() const
{
  return impl_->params;
}

void
Odometry::setFeaturesWanted(bool wanted)
{
  impl_->features_wanted = wanted;
}

std::size_t
Odometry::numKeyFrames() const
{
  return impl_->next_keyframe_id;
}

std::size_t
Odometry::localMapSize() const
{
  return impl_->localMap().size();
}

pcl::PointCloud<pcl::PointXYZI>::Ptr
Odometry::Impl::deskewIndices(const pcl::PointCloud<pcl::PointXYZI>& input,
                              const PointTimes& times,
                              const pcl::Indices& indices,
                              const Twist& xi) const
{
  // One copy of the chosen points, compensated in place.
  auto subset = std::make_shared<pcl::PointCloud<pcl::PointXYZI>>(input, indices);
  deskewCloudInPlace(*subset, times.of(indices), xi, params.deskew.bins);
  return subset;
}

void
Odometry::Impl::secondDeskewPass(const pcl::PointCloud<pcl::PointXYZI>& input,
                                 const PointTimes& times,
                                 const std::vector<int>& source_indices,
                                 double dt,
                                 const Pose3d& T_motion_prior,
                                 OdometryFrameResult& result,
                                 Twist& xi_sweep)
{
  const pcl::StopWatch watch;
  const Pose3d T_motion = T_world_last.inverse() * result.T_world_lidar;
  if (moved(T_motion_prior,
            T_motion,
            params.deskew.second_pass_translation_m,
            params.deskew.second_pass_rotation_deg)) {
    const Pose3d change = T_motion_prior.inverse() * T_motion;
    const Twist xi = logSE3(T_motion) / dt;
    // The points moved by about the change of motion: the annealing starts at twice
    // that, not at the first pass's metre-scale kernel.
    const double start_scale_m =
        2.0 * std::max(change.translation().norm(), params.dense.min_kernel_scale_m);
    const DenseResult dense = registerToMap(
        odometry_detail::toPoints(*deskewIndices(input, times, source_indices, xi)),
        localMap(),
        result.T_world_lidar,
        params.dense,
        {start_scale_m, nullptr});
    // Kept when it pairs about as well as the first fit (a compensation that does not
    // fit the map is not the better one).
    if (dense.success &&
        dense.num_correspondences >= 0.95 * result.dense_correspondences) {
      xi_sweep = xi;
      keepDenseStats(dense, result);
      result.T_world_lidar = dense.T_world_lidar;
      result.deskew_second_pass = true;
    }
  }
  result.timings.deskew_ms += watch.getTime();
}

std::optional<double>
Odometry::Impl::sinceFirstScan(double timestamp_s) const
{
  const double dt = (timestamp_s - t_first) * params.deskew.seconds_per_timestamp;
  return dt > 1e-6 && dt < 1.0 ? std::optional<double>(dt) : std::nullopt;
}

void
Odometry::Impl::solveColdStartMotion(const Frame& frame,
                                     OdometryFrameResult& result) const
{
  const std::optional<double> since_first = sinceFirstScan(result.timestamp_s);
  if (!frame.times || frame.source_indices.empty() || !since_first)
    return;
  const double dt_first = *since_first;
  const pcl::StopWatch watch;
  Pose3d T = result.T_world_lidar;
  DenseResult dense;
  int rounds = 0;
  bool converged = false;
  while (!converged && rounds < kColdStartRounds) {
    ++rounds;
    const Twist xi = logSE3(T_world_first.inverse() * T) / dt_first;
    // The map rebuildMapFromFirstScan would build with this motion.
    VoxelPlaneMap map(params.dense);
    insertScan(*deskewCloud(*first_scan, first_times, xi, params.deskew.bins),
               T_world_first,
               map);
    dense = registerToMap(odometry_detail::toPoints(*deskewIndices(
                              frame.input, *frame.times, frame.source_indices, xi)),
                          map,
                          T,
                          params.dense);
    if (!dense.success)
      break;
    converged = (dense.T_world_lidar.translation() - T.translation()).norm() <
                kColdStartConvergedM;
    T = dense.T_world_lidar;
  }
  result.timings.deskew_ms += watch.getTime();
  const double speed_mps = (T_world_first.inverse() * T).translation().norm() / dt_first;
  if (!converged || !dense.success ||
      speed_mps > params.turn_search.cold_start_max_speed_mps)
    return;
  result.status = TrackingStatus::kDenseFallback;
  result.T_world_lidar = T;
  result.refined = true;
  keepDenseStats(dense, result);
  char text[192];
  std::snprintf(text,
                sizeof text,
                "; in its place, as a cold start, the motion solved with both scans "
                "compensated by it (%d round%s, %d/%d paired, %.1f m/s)",
                rounds,
                rounds == 1 ? "" : "s",
                dense.num_correspondences,
                dense.num_source_points,
                speed_mps);
  result.message += text;
}

void
Odometry::Impl::rebuildMapFromFirstScan(OdometryFrameResult& result)
{
  const std::optional<double> dt_first = sinceFirstScan(result.timestamp_s);
  if (result.refined && map_scans == 1 && dt_first) {
    const pcl::StopWatch watch;
    const Twist xi = logSE3(T_world_first.inverse() * result.T_world_lidar) / *dt_first;
    localMap() = VoxelPlaneMap(params.dense);
    map_scans = 0;
    insertIntoMap(deskewCloud(*first_scan, first_times, xi, params.deskew.bins),
                  T_world_first);
    result.timings.deskew_ms += watch.getTime();
  }
  first_scan.reset();
  first_times.clear();
}

std::optional<PointTimes>
Odometry::Impl::sweepTimes(const pcl::PointCloud<pcl::PointXYZI>& input,
                           const std::vector<float>& given,
                           double frame_interval_s,
                           std::string& source) const
{
  if (params.deskew.mode == DeskewMode::kOff)
    return std::nullopt;
  // processFrame passes usable times or none (and reports the unusable ones).
  if (!given.empty()) {
    source = "field";
    return PointTimes(input, given);
  }
  if (params.deskew.mode != DeskewMode::kOn)
    return std::nullopt;
  const double period = params.deskew.sweep_period_s > 0.0 ? params.deskew.sweep_period_s
                                                           : frame_interval_s;
  source = "azimuth";
  return PointTimes(input, period, params.deskew.sweep);
}

OdometryFrameResult
Odometry::processFrame(const pcl::PointCloud<pcl::PointXYZI>::ConstPtr& cloud,
                       double timestamp_s,
                       std::size_t frame_index)
{
  return processFrame(cloud, timestamp_s, frame_index, {});
}

OdometryFrameResult
Odometry::processFrame(const pcl::PointCloud<pcl::PointXYZI>::ConstPtr& cloud,
                       double timestamp_s,
                       std::size_t frame_index,
                       const std::vector<float>& point_times_s)
{
  return impl_->process(cloud, timestamp_s, frame_index, point_times_s, nullptr);
}

OdometryFrameResult
Odometry::processFrame(const pcl::PointCloud<pcl::PointXYZI>::ConstPtr& cloud,
                       double timestamp_s,
                       std::size_t frame_index,
                       const std::vector<float>& point_times_s,
                       const OdometryInput& next)
{
  if (next.frame_index <= frame_index)
    throw std::invalid_argument("Odometry: the look-ahead scan's frame index " +
                                std::to_string(next.frame_index) +
                                " is not after this frame's " +
                                std::to_string(frame_index));
  return impl_->process(cloud, timestamp_s, frame_index, point_times_s, &next);
}

Odometry::Impl::Prepared
Odometry::Impl::prepare(
    FrontEnd& front,
    const pcl::PointCloud<pcl::PointXYZI>::ConstPtr& input,
    const std::shared_ptr<const odometry_detail::ElevationTable>& elevation_table,
    const std::vector<float>& given_times,
    bool keep_times,
    double frame_interval_s,
    const SweepMotion* motion,
    OdometryFrameResult result,
    bool features) const
{
  pcl::PointCloud<pcl::PointXYZI>::ConstPtr corrected;
  if (elevation_table) {
    const pcl::StopWatch t0;
    corrected = odometry_detail::applyElevationTable(*elevation_table, *input);
    result.timings.elevation_ms = t0.getTime();
  }
  auto frame = std::make_unique<Frame>(input, corrected);
  frame->elevation_table = elevation_table;
  if (keep_times)
    frame->own_times = given_times;
  const std::vector<float>& point_times = keep_times ? frame->own_times : given_times;
  static const std::vector<float> kNoTimes;
  const bool times_usable =
      point_times.empty() || usableTimes(point_times, input->size());
  if (!times_usable)
    frame->times_message = std::to_string(point_times.size()) + " point times for " +
                           std::to_string(input->size()) +
                           " points, or not finite or beyond +-1 s: ignored";
  // 0. Enough finite points within the range limits? (Ground removal and raster skip
  //    non-finite points themselves; the range limits apply to the dense steps.)
  const odometry_detail::RangeFilter in_range(params.min_range_m, params.max_range_m);
  const std::size_t num_usable = odometry_detail::countInRange(frame->input, in_range);
  if (num_usable < 10) {
    frame->usable = false;
    result.status = TrackingStatus::kSkipped;
    result.degraded = true;
    result.message = "no usable points (" + std::to_string(num_usable) + " of " +
                     std::to_string(frame->input.size()) +
                     " finite and in range): constant-velocity prediction";
    return {std::move(frame), std::move(result)};
  }
  // 0b. The times of the motion compensation (deskew.h).
  const pcl::StopWatch watch;
  if (auto times = sweepTimes(frame->input,
                              times_usable ? point_times : kNoTimes,
                              frame_interval_s,
                              result.deskew_times))
    frame->times.emplace(std::move(*times)); // (PointTimes refers to the cloud)
  result.timings.deskew_ms = watch.getTime();

  removeGround(front, *frame, result); // 1
  // Without times there is nothing to compensate; features not wanted wait (process).
  if (features && (motion || !frame->times))
    finishPrepare(front, *frame, result, motion);
  return {std::move(frame), std::move(result)};
}

void
Odometry::Impl::finishPrepare(FrontEnd& front,
                              Frame& frame,
                              OdometryFrameResult& result,
                              const SweepMotion* motion) const
{
  applySweepMotion(frame, result, motion);
  extractFeatures(front, frame, result); // 2-3
  frame.extracted = true;
}

void
Odometry::Impl::applySweepMotion(Frame& frame,
                                 OdometryFrameResult& result,
                                 const SweepMotion* motion)
{
  // 0c. The compensation's motion: the previous frame's. Every step below uses
  //     compensated points: the non-ground points (raster, features) and the dense
  //     step's source points right away, the whole scan only when a key-frame or the
  //     local map keeps it (keptCloud).
  if (frame.times && motion && motion->xi) {
    frame.xi_sweep = motion->xi;
    frame.T_motion_deskew = motion->T_motion;
  }
  result.deskew_applied = frame.xi_sweep.has_value();
}

void
Odometry::Impl::ensureFeatures(Frame& frame, OdometryFrameResult& result) const
{
  if (!frame.extracted && frame.deferred_front) {
    extractFeatures(*frame.deferred_front, frame, result); // 2-3
    frame.extracted = true;
  } else if (result.features_skipped && frame.features) { // made ahead, then left unused
    result.features = frame.features;
    result.num_features = static_cast<int>(frame.features->size());
  }
  result.features_skipped = false;
}

std::future<void>
Odometry::Impl::onSearchThread(std::function<void()> work) const
{
  try {
    if (!search_thread)
      search_thread = std::make_unique<slam_detail::TaskThread<void>>();
  } catch (const std::system_error&) {
    return {}; // no thread to be had: the caller does the work itself
  }
  return search_thread->run(std::move(work));
}

void
Odometry::Impl::launchAhead(const OdometryInput& next, double timestamp_s)
{
  // Started before this frame is tracked: what needs its motion (the compensation of a
  // scan with times, and the raster and ORB of the compensated points) waits.
  const double next_interval = interval(timestamp_s, next.timestamp_s);
  OdometryFrameResult next_result;
  next_result.frame_index = next.frame_index;
  next_result.timestamp_s = next.timestamp_s;
  next_result.extracted_ahead = true;
  if (!ahead_thread)
    ahead_thread = std::make_unique<slam_detail::TaskThread<Prepared>>();
  Ahead a;
  a.cloud = next.cloud.get();
  a.frame_index = next.frame_index;
  a.timestamp_s = next.timestamp_s;
  a.after_s = timestamp_s;
  // The features of a scan without times are made here, unless this frame's are not
  // wanted: then likely neither are the next one's (made in its call if they are).
  a.job = ahead_thread->run([this,
                             input = next.cloud,
                             table = elevation ? elevation->table() : nullptr,
                             times = next.point_times_s,
                             next_interval,
                             next_result = std::move(next_result),
                             features = features_wanted] {
    return prepare(front_end_ahead,
                   input,
                   table,
                   times,
                   true,
                   next_interval,
                   nullptr,
                   next_result,
                   features);
  });
  ahead.emplace(std::move(a));
}

OdometryFrameResult
Odometry::Impl::process(const pcl::PointCloud<pcl::PointXYZI>::ConstPtr& cloud,
                        double timestamp_s,
                        std::size_t frame_index,
                        const std::vector<float>& point_times,
                        const OdometryInput* next)
{
  checkIndex(frame_index);
  const pcl::StopWatch watch;
  OdometryFrameResult result;
  result.frame_index = frame_index;
  result.timestamp_s = timestamp_s;
  // The look-ahead of the call before: this scan's steps 0-3 when it was this scan.
  // Waited for before the next one starts: the two share front_end_ahead.
  std::optional<Ahead> mine = std::exchange(ahead, std::nullopt);
  if (mine)
    mine->job.wait();
  if (mine && (mine->cloud != cloud.get() || mine->frame_index != frame_index ||
               mine->timestamp_s != timestamp_s || mine->after_s != t_last))
    mine.reset(); // another scan came, or a frame was skipped in between: dropped
  if (next && next->cloud) {
    try {
      launchAhead(*next, timestamp_s);
    } catch (const std::exception&) {
      ahead.reset(); // no thread to be had: the next frame goes without
    }
  }
  if (!cloud)
    return skip(timestamp_s, frame_index, "null cloud");
  try {
    const SweepMotion motion = sweepMotion(timestamp_s);
    std::optional<Prepared> taken;
    if (mine)
      taken = mine->job.get();
    if (taken && taken->frame->own_times != point_times)
      taken.reset(); // prepared for other point times (a caller's mistake): again
    const std::shared_ptr<const odometry_detail::ElevationTable> elevation_table =
        elevation ? elevation->table() : nullptr;
    if (taken && taken->frame->elevation_table != elevation_table)
      taken.reset(); // the calibration was updated since (once a window): again
    // Without features wanted, steps 2-3 wait for a frame the dense step alone does
    // not track (and for a key-frame). Only with a key-frame and a tracked velocity to
    // predict from, and after the cold start's first scan has found its motion.
    const bool defer = !features_wanted && keyframe && velocity_tracked && !first_scan &&
                       params.registration.refine;
    Prepared prepared = taken ? std::move(*taken)
                              : prepare(front_end,
                                        cloud,
                                        elevation_table,
                                        point_times,
                                        false,
                                        motion.dt,
                                        &motion,
                                        result,
                                        !defer);
    if (prepared.frame->usable) {
      // (Features a scan without times had made ahead are left unused the same way:
      // the poses do not depend on the look-ahead.)
      if (defer) {
        if (!prepared.frame->extracted)
          applySweepMotion(*prepared.frame, prepared.result, &motion);
        prepared.frame->deferred_front = &front_end;
      } else if (!prepared.frame->extracted) {
        finishPrepare(front_end, *prepared.frame, prepared.result, &motion);
      }
      // The dense step's source points, here on the caller's thread: about as much
      // work is left to it as to the look-ahead's.
      const pcl::StopWatch source_watch;
      selectDenseSource(*prepared.frame);
      makeDenseSource(*prepared.frame, prepared.result);
      prepared.result.timings.refine_ms = source_watch.getTime();
    }
    result = track(*prepared.frame, std::move(prepared.result));
    if (!prepared.frame->times_message.empty())
      result.message += "; " + prepared.frame->times_message;
  } catch (const std::exception& e) {
    // Bad data must not stop the odometry: report it and predict.
    result = OdometryFrameResult();
    result.frame_index = frame_index;
    result.timestamp_s = timestamp_s;
    result.status = TrackingStatus::kConstantVelocity;
    result.degraded = true;
    result.T_world_lidar = predict(timestamp_s);
    result.message =
        std::string("tracking failed: ") + e.what() + ": constant-velocity prediction";
  }
  if (!result.keyframe) {
    result.reference_keyframe = keyframe ? keyframe->id : 0;
    result.T_keyframe_lidar =
        composePoses(T_world_keyframe.inverse(), result.T_world_lidar);
  }
  result.timings.total_ms = watch.getTime();
  commitPose(result);
  return result;
}

OdometryFrameResult
Odometry::skipFrame(double timestamp_s,
                    std::size_t frame_index,
                    const std::string& reason)
{
  impl_->checkIndex(frame_index);
  return impl_->skip(timestamp_s, frame_index, reason);
}

OdometryFrameResult
Odometry::Impl::skip(double timestamp_s,
                     std::size_t frame_index,
                     const std::string& reason)
{
  OdometryFrameResult result;
  result.frame_index = frame_index;
  result.timestamp_s = timestamp_s;
  result.status = TrackingStatus::kSkipped;
  result.degraded = true;
  result.T_world_lidar = predict(timestamp_s);
  result.reference_keyframe = keyframe ? keyframe->id : 0;
  result.T_keyframe_lidar =
      composePoses(T_world_keyframe.inverse(), result.T_world_lidar);
  result.message = reason + ": constant-velocity prediction";
  commitPose(result);
  return result;
}

} // namespace rast
} // namespace pcl
