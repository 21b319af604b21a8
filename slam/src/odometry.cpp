/// \file odometry.cpp
/// \brief Odometry::processFrame, step by step as in the paper's tracking figure:
/// ground removal -> raster -> ORB -> match the last key-frame -> RANSAC -> dense
/// refinement against the local map -> feature-consistency fallbacks -> key-frame.

#include "odometry_local_map.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <numeric>
#include <optional>
#include <pcl/common/io.h>
#include <pcl/registration/hamming_correspondence_estimation.h>
#include <pcl/registration/rigid_ransac.h>
#include <pcl/slam/odometry.h>
#include <stdexcept>
#include <vector>

namespace pcl {
namespace rast {

using odometry_detail::DenseOptions;
using odometry_detail::DenseResult;
using odometry_detail::denseSeparation;
using odometry_detail::Points3f;
using odometry_detail::VoxelPlaneMap;

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

using Clock = std::chrono::steady_clock;

double
msSince(Clock::time_point start)
{
  return std::chrono::duration<double, std::milli>(Clock::now() - start).count();
}

bool
finitePositive(double v)
{
  return std::isfinite(v) && v > 0.0;
}

double
angleDeg(const Pose3d& T)
{
  return Eigen::AngleAxisd(T.rotation()).angle() * 180.0 / M_PI;
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

/// The dense step's figures of the fit a frame's pose comes from.
void
keepDenseStats(const DenseResult& dense, OdometryFrameResult& result)
{
  result.dense_correspondences = dense.num_correspondences;
  result.dense_degenerate_directions = dense.degenerate_directions;
  result.dense_rmse_m = dense.rmse_m;
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

/// After this many frames without feature or dense tracking, a frame with features
/// becomes a key-frame anyway (re-anchoring, flagged), so that tracking recovers after
/// a featureless stretch instead of comparing forever against a stale key-frame.
constexpr int kReanchorAfterFrames = 3;

/// Dense ICP from the prior (no feature support) is accepted only when at least this
/// fraction of the source points pairs with map planes (well-tracked frames: 0.8-0.95).
constexpr double kMinFallbackPairedRatio = 0.6;
/// ... or fewer when the optimum is distinct: it pairs at least kDistinctPairsFactor
/// times as many points as any hypothesis that ended elsewhere. Little overlap with the
/// map is normal after a large motion against a single key-frame (cold start at 4 m per
/// scan: 33-60 % paired), while a wrong start settling on the ground plane is never
/// distinct: the ground pairs about as many points from anywhere.
constexpr double kDistinctPairsFactor = 1.25;
/// ... but never below this fraction.
constexpr double kMinDistinctPairedRatio = 0.2;
/// With a tracked velocity, dense ICP from the prior is kept over a hypothesis that
/// pairs at most 1 / this times as many points (moving cars pair too).
constexpr double kPriorPairsShare = 0.9;
/// ... or when the features back it (MotionHypothesisParams::guided_gate_m). The
/// raster's descriptors are too alike for global matching (the ratio test drops most
/// true pairs) but not under a given motion: at the start of KITTI 02 at 2 Hz (7.6 m per
/// scan) 58 features pair at the true motion, 10-15 at 1-2 m along the road, where dense
/// ICP pairs 395 vs 366 points.

/// The firing times of one scan's points: given (a time field), or from the azimuth,
/// then computed only for the points asked for (the non-ground points and the dense
/// step's source), and for the whole scan only when a key-frame or the map keeps it.
class PointTimes
{
public:
  /// Times from \a given (one per point of \a cloud).
  PointTimes(const pcl::PointCloud<pcl::PointXYZI>& cloud,
             const std::vector<float>& given)
      : cloud_(cloud), given_(&given)
  {}
  /// Times from the azimuth (azimuthTimes).
  PointTimes(const pcl::PointCloud<pcl::PointXYZI>& cloud,
             double period_s,
             const SweepParams& sweep)
      : cloud_(cloud), period_s_(period_s), sweep_(sweep)
  {}

  /// times[k] of point indices[k].
  std::vector<float> of(const pcl::Indices& indices) const
  {
    return given_ ? gather(*given_, indices)
                  : azimuthTimes(cloud_, indices, period_s_, sweep_);
  }
  /// One per point of the cloud.
  const std::vector<float>& all()
  {
    if (given_)
      return *given_;
    if (all_.empty())
      all_ = azimuthTimes(cloud_, period_s_, sweep_);
    return all_;
  }

private:
  static std::vector<float> gather(const std::vector<float>& times,
                                   const pcl::Indices& indices)
  {
    std::vector<float> out(indices.size());
    for (std::size_t k = 0; k < indices.size(); ++k)
      out[k] = times[static_cast<std::size_t>(indices[k])];
    return out;
  }

  const pcl::PointCloud<pcl::PointXYZI>& cloud_;
  const std::vector<float>* given_ = nullptr;
  double period_s_ = 0.0;
  SweepParams sweep_;
  std::vector<float> all_;
};

/// Whether \a a and \a b differ by more than \a metres or \a degrees.
bool
moved(const Pose3d& a, const Pose3d& b, double metres, double degrees)
{
  const Pose3d d = a.inverse() * b;
  return d.translation().norm() > metres || angleDeg(d) > degrees;
}

/// The motion from \a T_world_last with the features' planar part (x, y, yaw in the
/// last scan's frame, which top-down raster features measure well) and the prior's
/// height, roll and pitch (which max-height pixels of few inliers do not).
Pose3d
planarFromFeatures(const Pose3d& T_world_last,
                   const Pose3d& T_world_features,
                   const Pose3d& T_world_prior)
{
  const Pose3d d_f = T_world_last.inverse() * T_world_features;
  const Pose3d d_p = T_world_last.inverse() * T_world_prior;
  const double yaw_f = std::atan2(d_f.rotation()(1, 0), d_f.rotation()(0, 0));
  const double yaw_p = std::atan2(d_p.rotation()(1, 0), d_p.rotation()(0, 0));
  Pose3d d = d_p; // the prior, turned to the features' heading and moved to their x, y
  d.linear() =
      Eigen::AngleAxisd(yaw_f - yaw_p, Eigen::Vector3d::UnitZ()).toRotationMatrix() *
      d_p.rotation();
  d.translation().x() = d_f.translation().x();
  d.translation().y() = d_f.translation().y();
  return T_world_last * d;
}

/// Starts for the dense search when the features fail: the prior, the weak feature
/// estimates, and the prior's motion from \a T_world_last turned by +-k * yaw_step_deg
/// (up to max_yaw_deg) about the LiDAR z axis, its translation turned by half that
/// (a car's arc; negligible for slow handheld motion). Without a tracked velocity
/// (\a max_travel_m > 0: cold start, after a tracking loss) the prior is also shifted
/// along the LiDAR x axis (the direction of travel) by +-k * cold_start_step_m up to
/// \a max_travel_m. Nearest-to-prior first.
std::vector<Pose3d>
motionHypotheses(const Pose3d& T_world_prior,
                 const Pose3d& T_world_last,
                 const std::vector<Pose3d>& weak_estimates,
                 double max_travel_m,
                 const MotionHypothesisParams& params)
{
  std::vector<Pose3d> starts{T_world_prior};
  if (!params.enabled)
    return starts;
  starts.insert(starts.end(), weak_estimates.begin(), weak_estimates.end());
  const int shifts =
      static_cast<int>(std::ceil(max_travel_m / params.cold_start_step_m - 1e-9));
  for (int k = 1; k <= shifts; ++k)
    for (const int sign : {1, -1}) {
      Pose3d shifted = Pose3d::Identity();
      shifted.translation().x() = sign * k * params.cold_start_step_m;
      starts.push_back(T_world_prior * shifted);
    }
  const Pose3d delta = T_world_last.inverse() * T_world_prior;
  const int steps =
      static_cast<int>(std::floor(params.max_yaw_deg / params.yaw_step_deg + 1e-9));
  for (int k = 1; k <= steps; ++k)
    for (const int sign : {1, -1}) {
      const double yaw = sign * k * params.yaw_step_deg * M_PI / 180.0;
      Pose3d turned = Pose3d::Identity();
      turned.linear() = Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()) * delta.linear();
      turned.translation() =
          Eigen::AngleAxisd(yaw / 2.0, Eigen::Vector3d::UnitZ()) * delta.translation();
      starts.push_back(T_world_last * turned);
    }
  return starts;
}

/// Outcome of the dense search over motion hypotheses.
struct HypothesisSearch
{
  DenseResult dense;       ///< the standard refinement from the best coarse result
  int best_pairs = 0;      ///< pairs of the best coarse run
  int runner_up_pairs = 0; ///< most pairs of a coarse run that ended elsewhere
  Pose3d T_world_runner_up = Pose3d::Identity(); ///< where that run ended
};

/// Dense ICP from every start with a wider basin (coarse), then the standard refinement
/// from the coarse result that paired the most points (ties: lower RMS residual).
/// Also reports how well the best alternative did: a coarse run (converged or not)
/// that ended farther than max_correspondence_distance_m or yaw_step_deg / 2 from the
/// winner, so that the caller can tell a distinct optimum from an ambiguous one.
HypothesisSearch
bestDenseFromHypotheses(const Points3f& source,
                        const VoxelPlaneMap& map,
                        const std::vector<Pose3d>& starts,
                        const DenseTrackingParams& dense,
                        const MotionHypothesisParams& params)
{
  DenseTrackingParams coarse = dense;
  coarse.max_correspondence_distance_m = std::max(
      dense.max_correspondence_distance_m, params.coarse_correspondence_distance_m);
  coarse.max_correction_m =
      std::max(dense.max_correction_m, params.coarse_max_correction_m);
  coarse.max_correction_deg = std::max(dense.max_correction_deg, params.yaw_step_deg);
  std::vector<DenseResult> runs;
  runs.reserve(starts.size());
  int best = -1;
  for (const Pose3d& start : starts) {
    runs.push_back(registerToMap(source, map, start, coarse));
    const DenseResult& r = runs.back();
    if (!r.success || r.degenerate_directions > 0)
      continue;
    if (best < 0 || r.num_correspondences > runs[best].num_correspondences ||
        (r.num_correspondences == runs[best].num_correspondences &&
         r.rmse_m < runs[best].rmse_m))
      best = static_cast<int>(runs.size()) - 1;
  }
  HypothesisSearch search;
  if (best < 0) {
    search.dense.message = "no motion hypothesis converged";
    return search;
  }
  for (const DenseResult& r : runs) {
    const Pose3d diff = runs[best].T_world_lidar.inverse() * r.T_world_lidar;
    if ((diff.translation().norm() > dense.max_correspondence_distance_m ||
         angleDeg(diff) > params.yaw_step_deg / 2.0) &&
        r.num_correspondences > search.runner_up_pairs) {
      search.runner_up_pairs = r.num_correspondences;
      search.T_world_runner_up = r.T_world_lidar;
    }
  }
  search.best_pairs = runs[best].num_correspondences;
  search.dense = registerToMap(source, map, runs[best].T_world_lidar, dense);
  return search;
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
  else if (!(indistinct_residual_m >= 0.0 && std::isfinite(indistinct_residual_m)))
    reason = "indistinct_residual_m must be >= 0 and finite, got " +
             std::to_string(indistinct_residual_m);
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

struct Odometry::Impl
{
  explicit Impl(const OdometryParams& p) : params(p), ground(p.ground), map(p.dense)
  {
    orb.setParams(p.orb);
    orb.setRasterParams(p.raster);
  }

  OdometryParams params;
  SACGroundRemoval<pcl::PointXYZI> ground;
  OrbRasterFeatureEstimator<pcl::PointXYZI> orb;
  VoxelPlaneMap map;
  int map_scans = 0; ///< scans inserted into the map so far
  /// The scan that started the map, while it could not be motion-compensated yet (no
  /// motion before it): kept with its times until the next frame's motion is known.
  pcl::PointCloud<pcl::PointXYZI>::ConstPtr first_scan;
  std::vector<float> first_times;
  Pose3d T_world_first = Pose3d::Identity();
  double t_first = 0.0;

  // The key-frame tracked against. Only its immutable parts (features) are read:
  // its pose may be corrected by the back end, tracking keeps its own copy.
  KeyFrame::ConstPtr keyframe;
  Pose3d T_world_keyframe = Pose3d::Identity();
  KeyFrameId next_keyframe_id = 0;
  int frames_since_keyframe = 0;
  int frames_without_tracking = 0;
  // The previous frame's features and pose (when it was tracked): the second reference
  // when the key-frame is too far (large motion at a low frame rate).
  std::shared_ptr<const RasterFeatureSet> last_features;
  Pose3d T_world_last_features = Pose3d::Identity();

  // Motion state for the constant-velocity prior.
  int num_poses = 0;
  Pose3d T_world_last = Pose3d::Identity(), T_world_before = Pose3d::Identity();
  double t_last = 0.0, t_before = 0.0;
  bool have_index = false;
  std::size_t last_index = 0;
  // Whether the last two poses were both tracked (features or dense), i.e. whether the
  // constant-velocity prior is a measured motion; false at the cold start.
  bool last_tracked = false;
  bool velocity_tracked = false;

  Pose3d predict(double timestamp_s) const;
  /// Seconds since the last frame (timestamps scaled by deskew.seconds_per_timestamp).
  double frameInterval(double timestamp_s) const;
  void checkIndex(std::size_t frame_index);
  void commitPose(const OdometryFrameResult& result);
  OdometryFrameResult
  skip(double timestamp_s, std::size_t frame_index, const std::string& reason);
  OdometryFrameResult track(const pcl::PointCloud<pcl::PointXYZI>::ConstPtr& input,
                            const std::vector<float>& point_times,
                            OdometryFrameResult result);
  /// Step 5b of track: where the estimated motion differs from the previous frame's (a
  /// stop, a start, a turn), the dense step's source points are compensated with it and
  /// refined once more from the estimate. When that is kept, \a xi_sweep becomes the
  /// twist the scan is compensated with (key-frame, young map).
  void secondDeskewPass(const pcl::PointCloud<pcl::PointXYZI>& input,
                        const PointTimes& times,
                        const std::vector<int>& source_indices,
                        double dt,
                        const Pose3d& T_motion_prior,
                        OdometryFrameResult& result,
                        Twist& xi_sweep);
  /// The points \a indices of \a input compensated with \a xi (params.deskew.bins).
  pcl::PointCloud<pcl::PointXYZI>::Ptr
  deskewIndices(const pcl::PointCloud<pcl::PointXYZI>& input,
                const PointTimes& times,
                const pcl::Indices& indices,
                const Twist& xi) const;
  /// Step 5c of track: the scan that started the map was used as it was (no motion
  /// before it). Once the next frame's motion is known, the local map is rebuilt from
  /// that scan compensated with it (the key-frame's own stored cloud stays as it was).
  void rebuildMapFromFirstScan(OdometryFrameResult& result);
  /// The times to compensate \a input with (params.deskew): the given ones (processFrame
  /// passes only usable ones), times from the azimuth, or none.
  std::optional<PointTimes> sweepTimes(const pcl::PointCloud<pcl::PointXYZI>& input,
                                       const std::vector<float>& given,
                                       double frame_interval_s,
                                       std::string& source) const;
  KeyFrame::Ptr makeKeyFrame(const OdometryFrameResult& result,
                             RasterFeatureSet&& features,
                             const pcl::PointCloud<pcl::PointXYZI>& cloud);
  void insertIntoMap(const pcl::PointCloud<pcl::PointXYZI>& cloud,
                     const Pose3d& T_world_lidar);
};

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
Odometry::Impl::frameInterval(double timestamp_s) const
{
  const double dt = (timestamp_s - t_last) * params.deskew.seconds_per_timestamp;
  // Without usable timestamps assume 10 Hz; cap at 5 s.
  return std::isfinite(dt) && dt > 1e-6 ? std::min(dt, 5.0) : 0.1;
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
  last_tracked = tracked;
  if (result.keyframe) {
    frames_since_keyframe = 0;
    frames_without_tracking = 0;
  }
}

KeyFrame::Ptr
Odometry::Impl::makeKeyFrame(const OdometryFrameResult& result,
                             RasterFeatureSet&& features,
                             const pcl::PointCloud<pcl::PointXYZI>& cloud)
{
  auto kf = std::make_shared<KeyFrame>();
  kf->id = next_keyframe_id++;
  kf->frame_index = result.frame_index;
  kf->timestamp_s = result.timestamp_s;
  kf->T_world_keyframe = result.T_world_lidar;
  kf->T_previous_keyframe =
      keyframe ? composePoses(T_world_keyframe.inverse(), result.T_world_lidar)
               : Pose3d::Identity();
  kf->features = std::move(features);
  kf->map_point_ids.assign(kf->features.size(), kNoMapPoint);
  kf->odometry_map_scans = map_scans;

  // The voxelized scan the key-frame keeps (memory: keyframe_voxel_size_m) ...
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

  insertIntoMap(cloud, result.T_world_lidar);
  keyframe = kf;
  T_world_keyframe = result.T_world_lidar;
  return kf;
}

/// The scan into the local map, denser than a key-frame's cloud, so that a single scan
/// already gives every map voxel on a surface enough points for a plane (4 x 4 per
/// voxel face).
void
Odometry::Impl::insertIntoMap(const pcl::PointCloud<pcl::PointXYZI>& cloud,
                              const Pose3d& T_world_lidar)
{
  const odometry_detail::RangeFilter in_range(params.min_range_m, params.max_range_m);
  const Eigen::Isometry3f T = T_world_lidar.cast<float>();
  Points3f points_world;
  for (const int i : odometry_detail::voxelDownsampleIndices(
           cloud, params.dense.map_voxel_size_m / 4.0, in_range))
    points_world.push_back(T * cloud.points[i].getVector3fMap());
  map.insert(points_world, T.translation());
  ++map_scans;
}

OdometryFrameResult
Odometry::Impl::track(const pcl::PointCloud<pcl::PointXYZI>::ConstPtr& input_ptr,
                      const std::vector<float>& point_times,
                      OdometryFrameResult result)
{
  const auto& input = *input_ptr;
  const auto frame_start = Clock::now();
  const Pose3d T_world_prior = predict(result.timestamp_s);
  result.T_world_lidar = T_world_prior;
  result.reference_keyframe = keyframe ? keyframe->id : 0;

  // 0. Enough finite points within the range limits? (Ground removal and raster skip
  //    non-finite points themselves; the range limits apply to the dense steps.)
  const odometry_detail::RangeFilter in_range(params.min_range_m, params.max_range_m);
  const std::size_t num_usable = odometry_detail::countInRange(input, in_range);
  if (num_usable < 10) {
    result.status = TrackingStatus::kSkipped;
    result.degraded = true;
    result.message = "no usable points (" + std::to_string(num_usable) + " of " +
                     std::to_string(input.size()) +
                     " finite and in range): constant-velocity prediction";
    return result;
  }
  // 0b. Motion compensation (deskew.h) with the previous frame's motion. Every step
  //     below uses compensated points: the non-ground points (raster, features) and the
  //     dense step's source points right away, the whole scan only when a key-frame or
  //     the local map keeps it (keptCloud below).
  auto start = Clock::now();
  const double dt = frameInterval(result.timestamp_s);
  std::optional<PointTimes> times =
      sweepTimes(input, point_times, dt, result.deskew_times);
  const Pose3d T_motion_prior = T_world_last.inverse() * T_world_prior;
  std::optional<Twist> xi_sweep; // the motion the kept points are compensated with
  if (times && num_poses >= 2)
    xi_sweep = logSE3(T_motion_prior) / dt;
  result.timings.deskew_ms = msSince(start);

  // 1. Ground removal (paper sec. 4), optionally levelling the non-ground cloud. On the
  //    raw scan: the sweep's motion moves ground points along the ground plane, and
  //    only the plane is kept.
  start = Clock::now();
  ground.setInputCloud(input_ptr);
  pcl::Indices non_ground_indices;
  ground.filter(non_ground_indices);
  result.ground_found = ground.groundFound();
  result.timings.ground_ms = msSince(start);
  // The levelled frame, where the sensor is tilted (params.ground.level_cloud).
  const Eigen::Isometry3f T_level_lidar = ground.getLevellingTransform();
  const bool levelled = params.ground.level_cloud && result.ground_found &&
                        !T_level_lidar.isApprox(Eigen::Isometry3f::Identity());
  // The non-ground points, compensated (one copy of them either way), then levelled.
  start = Clock::now();
  pcl::PointCloud<pcl::PointXYZI>::Ptr non_ground;
  if (xi_sweep) {
    non_ground = deskewIndices(input, *times, non_ground_indices, *xi_sweep);
    result.timings.deskew_ms += msSince(start);
  } else {
    non_ground = std::make_shared<pcl::PointCloud<pcl::PointXYZI>>();
    pcl::copyPointCloud(input, non_ground_indices, *non_ground);
    result.timings.ground_ms += msSince(start);
  }
  if (levelled)
    for (auto& p : non_ground->points)
      p.getVector3fMap() = T_level_lidar.linear() * p.getVector3fMap();

  // 2-3. Raster of the non-ground points and ORB features (sec. 5-6).
  auto features = std::make_shared<RasterFeatureSet>();
  if (!non_ground->empty()) {
    orb.setInputCloud(non_ground);
    const OrbRasterFeatureResult orb_result = orb.compute(*features);
    result.timings.raster_ms = orb_result.raster_ms;
    result.timings.orb_ms = orb_result.detect_ms + orb_result.describe_ms;
    // Features of a levelled raster go back to the LiDAR frame.
    if (levelled) {
      const Eigen::Isometry3f T_lidar_level = T_level_lidar.inverse();
      for (auto& p : features->points)
        p.getVector3fMap() = T_lidar_level * p.getVector3fMap();
    }
  }
  result.num_features = static_cast<int>(features->size());

  // The first usable frame starts the map.
  if (!keyframe) {
    if (times) {
      first_scan = input_ptr;
      first_times = times->all();
      T_world_first = result.T_world_lidar;
      t_first = result.timestamp_s;
    }
    result.status = TrackingStatus::kFirstFrame;
    result.message = "first frame: key-frame 0";
    start = Clock::now();
    result.keyframe = makeKeyFrame(result, std::move(*features), input);
    result.reference_keyframe = result.keyframe->id;
    result.timings.keyframe_ms = msSince(start);
    result.timings.total_ms = msSince(frame_start);
    return result;
  }
  const Pose3d T_keyframe_prior = T_world_keyframe.inverse() * T_world_prior;

  // 4. Match the last key-frame's features (no spatial gate by default: large motion
  //    must track), rigid RANSAC, eq. 4 on the inliers (sec. 7.1-7.2).
  start = Clock::now();
  const RasterFeatureSet& kf_features = keyframe->features;
  auto fit = [&](const RasterFeatureSet& target, const pcl::Correspondences& matches) {
    return matches.size() >= 3
               ? estimateRigidRansac(
                     features->points, target.points, matches, params.registration.ransac)
               : RigidRansacResult();
  };
  auto inliersOf = [](const RigidRansacResult& fit) {
    return fit.success ? static_cast<int>(fit.inlier_indices.size()) : 0;
  };
  // One distance pass gives the ratio-tested matches and, for the re-match below, every
  // feature's nearest neighbour.
  pcl::Correspondences kf_matches, kf_nearest;
  if (features->size() >= 3 && kf_features.size() >= 3)
    kf_matches = matchHamming(*features,
                              kf_features,
                              params.registration.matching,
                              T_keyframe_prior,
                              &kf_nearest);
  result.num_matches = static_cast<int>(kf_matches.size());
  RigidRansacResult ransac = fit(kf_features, kf_matches);
  result.num_inliers = inliersOf(ransac);
  bool features_ok = result.num_inliers >= params.min_feature_inliers;
  Pose3d T_world_features = T_world_keyframe * ransac.T_target_source;
  // Estimates too weak for the consistency check are still hypotheses for the dense
  // search below (under large motion they are often right, with 5-14 inliers).
  std::vector<Pose3d> weak_estimates;
  auto keepWeak = [&](const RigidRansacResult& r, const Pose3d& T_world_reference) {
    if (static_cast<int>(r.inlier_indices.size()) >= params.turn_search.min_weak_inliers)
      weak_estimates.push_back(T_world_reference * r.T_target_source);
  };
  keepWeak(ransac, T_world_keyframe);
  std::string reference = "the key-frame";
  if (!features_ok && last_features && features->size() >= 3 &&
      last_features->size() >= 3) {
    // Too far from the key-frame: the previous frame is closer.
    const pcl::Correspondences matches =
        matchHamming(*features,
                     *last_features,
                     params.registration.matching,
                     T_world_last_features.inverse() * T_world_prior);
    const RigidRansacResult last = fit(*last_features, matches);
    keepWeak(last, T_world_last_features);
    if (inliersOf(last) >= params.min_feature_inliers) {
      features_ok = true;
      T_world_features = T_world_last_features * last.T_target_source;
      result.num_matches = static_cast<int>(matches.size());
      ransac = last;
      reference = "the previous frame";
      // num_inliers stays the count with the key-frame ("points in common").
    }
  }
  if (params.loose_rematch && inliersOf(ransac) < params.strong_feature_inliers) {
    // Weak: the key-frame's nearest-neighbour matches alone; RANSAC sorts them out.
    const RigidRansacResult nearest = fit(kf_features, kf_nearest);
    keepWeak(nearest, T_world_keyframe);
    if (inliersOf(nearest) > inliersOf(ransac) &&
        inliersOf(nearest) >= params.min_feature_inliers) {
      features_ok = true;
      T_world_features = T_world_keyframe * nearest.T_target_source;
      result.num_matches = static_cast<int>(kf_nearest.size());
      result.num_inliers = std::max(result.num_inliers, inliersOf(nearest));
      ransac = nearest;
      reference = "the key-frame (nearest-neighbour matches)";
    }
  }
  result.timings.match_ms = msSince(start);

  // 5. Dense refinement against the local map, from the feature estimate; the
  //    feature-consistency check falls back to dense ICP from the prior, then to the
  //    prior itself.
  start = Clock::now();
  // Subsample the voxel indices, then copy only the points kept.
  std::vector<int> source_indices;
  Points3f source;
  if (params.registration.refine || !features_ok) {
    source_indices = odometry_detail::strideSubsample(
        odometry_detail::voxelDownsampleIndices(
            input, params.dense.source_voxel_size_m, in_range),
        static_cast<std::size_t>(params.dense.max_source_points));
    if (xi_sweep) {
      const auto t0 = Clock::now();
      source = odometry_detail::toPoints(
          *deskewIndices(input, *times, source_indices, *xi_sweep));
      result.timings.deskew_ms += msSince(t0);
    } else {
      source = odometry_detail::toPoints(input, source_indices);
    }
  }
  if (features_ok) {
    const int inliers = static_cast<int>(ransac.inlier_indices.size());
    const Pose3d prior_diff = T_world_prior.inverse() * T_world_features;
    const bool near_prior = prior_diff.translation().norm() <= params.prior_gate_m &&
                            angleDeg(prior_diff) <= params.prior_gate_deg;
    result.status = TrackingStatus::kFeatures;
    result.T_world_lidar = T_world_features;
    result.message =
        "features: " + std::to_string(inliers) + " inliers with " + reference;
    if (params.registration.refine) {
      // Along the directions the scan does not constrain (a corridor's axis, an open
      // field's x, y and yaw) strong features set the pose; weak ones (a few posts of a
      // guard rail, a passing car) do not, the constant-velocity prior does.
      const bool strong = inliers >= params.strong_feature_inliers;
      const Pose3d& T_world_anchor = strong ? T_world_features : T_world_prior;
      const DenseOptions anchored{0.0, &T_world_anchor};
      DenseResult dense =
          registerToMap(source, map, T_world_features, params.dense, anchored);
      if (!strong) {
        // Weak features: their height, roll and pitch come from max-height pixels of few
        // inliers (a 16-beam scan: decimetres off; 2 Hz: up to ~2 deg of pitch), from
        // where the dense step can settle in a wrong minimum. A second dense fit starts
        // from the features' planar motion with the prior's height, roll and pitch (near
        // the prior, a level mount) or from the prior itself; the better paired one wins.
        const bool second_from_features = near_prior && !params.ground.level_cloud;
        const Pose3d T_second =
            second_from_features
                ? planarFromFeatures(T_world_last, T_world_features, T_world_prior)
                : T_world_prior;
        const DenseResult second =
            registerToMap(source, map, T_second, params.dense, anchored);
        // Far from a tracked prior, weak features are as likely aliased (guard-rail
        // posts every 2.7 m passed at 2.7 m a frame) as right: there the prior's fit
        // wins unless the features' pairs clearly more (kPriorPairsShare).
        const bool prior_nearly_as_good =
            !near_prior && velocity_tracked && second.success && dense.success &&
            second.num_correspondences >= kPriorPairsShare * dense.num_correspondences;
        if (second.success &&
            (!dense.success || second.num_correspondences > dense.num_correspondences ||
             prior_nearly_as_good)) {
          dense = second;
          if (!near_prior) {
            result.status = TrackingStatus::kDenseFallback;
            result.degraded = true;
            result.message =
                "weak features disagree with the prior: dense from the prior";
          } else {
            result.message += " (dense from their planar part fitted better)";
          }
        }
        // Cross-check: weak features must not drag the dense step along a direction the
        // scan hardly constrains. Dense from the prior as well; where the scan cannot
        // tell the two results apart, the prior's wins.
        if (dense.success && second_from_features) {
          const DenseResult from_prior =
              registerToMap(source, map, T_world_prior, params.dense, anchored);
          // 2 cm / 0.1 deg: below the range noise a choice changes nothing.
          if (from_prior.success &&
              moved(dense.T_world_lidar, from_prior.T_world_lidar, 0.02, 0.1) &&
              denseSeparation(from_prior, dense.T_world_lidar) <
                  params.indistinct_residual_m) {
            dense = from_prior;
            result.degraded = true;
            result.message +=
                " (the scan does not tell the weak features' slide from the "
                "prior: dense from the prior)";
          }
        }
      }
      keepDenseStats(dense, result);
      if (dense.success) {
        result.T_world_lidar = dense.T_world_lidar;
        result.refined = true;
        result.message += "; " + dense.message;
        // The other way round: dense ICP must not slide away from strong features
        // along a direction where the scan hardly sees a difference (the local map's
        // planes along a corridor, cars driving beside). There the features' planar
        // motion stands; height, roll and pitch stay dense ICP's.
        // A slide, not the centimetres dense ICP refines features by (their pixels).
        if (strong && moved(dense.T_world_lidar, T_world_features, 0.1, 0.5) &&
            denseSeparation(dense, T_world_features) < params.indistinct_residual_m) {
          result.T_world_lidar =
              planarFromFeatures(T_world_last, T_world_features, dense.T_world_lidar);
          result.message +=
              "; its slide from the features is indistinct: their planar motion kept";
        }
        if (dense.degenerate_directions > 0) {
          result.degraded = true;
          result.message += strong ? " (from the features)" : " (from the prior)";
        }
      } else {
        result.degraded = true;
        result.message +=
            "; refinement failed, feature estimate kept (" + dense.message + ")";
      }
    }
  } else {
    // Feature-consistency check failed. Large motion (a sharp turn at a low frame rate)
    // makes the constant-velocity prior wrong, so dense ICP is started from several
    // hypotheses: the prior, the weak feature estimates, the prior turned by +-yaw
    // steps and, without a tracked velocity (cold start), shifted along the direction
    // of travel; the best-paired result wins.
    const double max_travel_m = velocity_tracked
                                    ? 0.0
                                    : params.turn_search.cold_start_max_speed_mps *
                                          frameInterval(result.timestamp_s);
    const std::vector<Pose3d> starts = motionHypotheses(
        T_world_prior, T_world_last, weak_estimates, max_travel_m, params.turn_search);
    const HypothesisSearch search =
        bestDenseFromHypotheses(source, map, starts, params.dense, params.turn_search);
    DenseResult dense = search.dense;
    result.degraded = true;
    const std::string why = "feature-consistency check failed (" +
                            std::to_string(result.num_inliers) + " inliers < " +
                            std::to_string(params.min_feature_inliers) + ")";
    // Features pairing under a motion: each only against the key-frame's features
    // within the gate of where the motion puts it, nearest descriptor, no ratio test.
    const bool can_guide = params.turn_search.enabled &&
                           params.turn_search.guided_gate_m > 0.0 &&
                           features->size() >= 3 && kf_features.size() >= 3;
    auto guidedMatches = [&](const Pose3d& T_world_lidar, double gate_m) {
      HammingMatchParams gated = params.registration.matching;
      gated.ratio = 1.0;
      gated.mutual_check = false;
      gated.spatial_gate_radius_m = gate_m;
      return matchHamming(
          *features, kf_features, gated, T_world_keyframe.inverse() * T_world_lidar);
    };
    auto guidedPairs = [&](const Pose3d& T_world_lidar) {
      return static_cast<int>(
          guidedMatches(T_world_lidar, params.turn_search.guided_gate_m).size());
    };
    // Re-fit: dense ICP can settle a degree or two off in yaw where the scan is weak in
    // structure (a hillside's scan rings). The features matched under its result (a
    // wider gate) and RANSAC give x, y and yaw; dense ICP from there (height, roll and
    // pitch of the first result) wins when more features pair under it.
    std::string refit;
    int dense_guided_pairs = -1; // guidedPairs(dense.T_world_lidar) once known
    if (dense.success && can_guide && params.turn_search.guided_refit_gate_m > 0.0) {
      const pcl::Correspondences matches =
          guidedMatches(dense.T_world_lidar, params.turn_search.guided_refit_gate_m);
      const RigidRansacResult fit = matches.size() >= 3
                                        ? estimateRigidRansac(features->points,
                                                              kf_features.points,
                                                              matches,
                                                              params.registration.ransac)
                                        : RigidRansacResult();
      if (inliersOf(fit) >= params.min_feature_inliers) {
        const DenseResult again =
            registerToMap(source,
                          map,
                          planarFromFeatures(T_world_last,
                                             T_world_keyframe * fit.T_target_source,
                                             dense.T_world_lidar),
                          params.dense);
        const int before = guidedPairs(dense.T_world_lidar);
        const int after = again.success ? guidedPairs(again.T_world_lidar) : 0;
        dense_guided_pairs = std::max(before, after);
        if (after > before) {
          dense = again;
          refit = "; re-fitted from " + std::to_string(inliersOf(fit)) +
                  " features matched under it (" + std::to_string(before) + " -> " +
                  std::to_string(after) + " pairing)";
        }
      }
    }
    keepDenseStats(dense, result);
    // Dense ICP alone from a wrong start can settle on the ground plane with the wrong
    // yaw; accept it only when most of the scan pairs with the map, or when fewer do
    // but no other hypothesis comes close (a distinct optimum).
    const double paired_ratio = static_cast<double>(dense.num_correspondences) /
                                std::max(1, dense.num_source_points);
    // Distinct needs a rival that ended elsewhere: when every start agrees (or only the
    // prior was tried) the ratio test above is all there is.
    const bool distinct =
        search.runner_up_pairs > 0 &&
        search.best_pairs >= kDistinctPairsFactor * search.runner_up_pairs &&
        paired_ratio >= kMinDistinctPairedRatio;
    // ... or when the features back it against that rival.
    bool feature_backed = false;
    if (dense.success && search.runner_up_pairs > 0 && can_guide) {
      result.guided_pairs =
          dense_guided_pairs >= 0 ? dense_guided_pairs : guidedPairs(dense.T_world_lidar);
      const int rival = guidedPairs(search.T_world_runner_up);
      feature_backed =
          result.guided_pairs >= params.min_feature_inliers &&
          result.guided_pairs >= params.turn_search.guided_support_factor * rival;
    }
    const bool well_paired =
        paired_ratio >= kMinFallbackPairedRatio || distinct || feature_backed;
    // The prior, corrected only along the directions the scan constrains (e.g. the
    // ground's height, roll and pitch on an open field).
    const DenseOptions anchored{0.0, &T_world_prior};
    std::optional<DenseResult> from_prior;
    auto fromPrior = [&]() -> const DenseResult& {
      if (!from_prior)
        from_prior = registerToMap(source, map, T_world_prior, params.dense, anchored);
      return *from_prior;
    };
    if (dense.success && dense.degenerate_directions == 0 && well_paired) {
      result.status = TrackingStatus::kDenseFallback;
      result.T_world_lidar = dense.T_world_lidar;
      result.refined = true;
      result.message = why + ": dense ICP from " + std::to_string(starts.size()) +
                       " motion hypotheses; " + dense.message + refit;
      if (result.guided_pairs > 0)
        result.message += "; " + std::to_string(result.guided_pairs) +
                          " features pair under its motion";
      // With a tracked velocity the prior is rarely far off. A hypothesis that beat it
      // by a few pairs along a direction the scan hardly constrains (a tunnel's axis,
      // with weak features on passing cars whose points pair too) is not better than
      // the prior: where dense ICP from the prior pairs nearly as well, or the scan
      // cannot tell the two apart, the prior stands.
      if (velocity_tracked && fromPrior().success &&
          moved(dense.T_world_lidar, fromPrior().T_world_lidar, 0.02, 0.1)) {
        const DenseResult& prior_dense = fromPrior();
        const double prior_ratio = static_cast<double>(prior_dense.num_correspondences) /
                                   std::max(1, prior_dense.num_source_points);
        const bool nearly_as_well = prior_ratio >= kMinFallbackPairedRatio &&
                                    prior_dense.num_correspondences >=
                                        kPriorPairsShare * dense.num_correspondences;
        if (nearly_as_well || denseSeparation(prior_dense, dense.T_world_lidar) <
                                  params.indistinct_residual_m) {
          result.message += "; dense ICP from the prior pairs " +
                            std::to_string(prior_dense.num_correspondences) + " vs " +
                            std::to_string(dense.num_correspondences) +
                            ": the prior stands";
          result.T_world_lidar = prior_dense.T_world_lidar;
          keepDenseStats(prior_dense, result);
        }
      }
    } else {
      result.status = TrackingStatus::kConstantVelocity;
      if (fromPrior().success)
        result.T_world_lidar = fromPrior().T_world_lidar;
      result.message = why + ": constant-velocity prediction (" + dense.message + ")";
    }
  }
  result.timings.refine_ms = msSince(start);

  // 5b. Second pass of the motion compensation with the estimated motion; 5c. the local
  //     map rebuilt from the first scan, compensated, once its motion is known.
  if (xi_sweep && result.refined && !source_indices.empty())
    secondDeskewPass(
        input, *times, source_indices, dt, T_motion_prior, result, *xi_sweep);
  if (first_scan)
    rebuildMapFromFirstScan(result);
  // The whole compensated scan, made once and only when a key-frame or the map keeps it.
  pcl::PointCloud<pcl::PointXYZI>::ConstPtr kept_cloud;
  auto keptCloud = [&]() -> const pcl::PointCloud<pcl::PointXYZI>& {
    if (!kept_cloud) {
      const auto t0 = Clock::now();
      kept_cloud = xi_sweep
                       ? deskewCloud(input, times->all(), *xi_sweep, params.deskew.bins)
                       : input_ptr;
      result.timings.deskew_ms += msSince(t0);
    }
    return *kept_cloud;
  };

  // 6. Key-frame decision: the paper's rule (sec. 7.3) plus safety rules. The pose is
  //    final here; it is kept on SO(3) (single-precision steps add ~1e-7 each).
  start = Clock::now();
  if (!result.T_world_lidar.matrix().allFinite()) {
    // A degenerate solve must not reach the map and the pose graph: predict instead.
    result.T_world_lidar = T_world_prior;
    result.status = TrackingStatus::kConstantVelocity;
    result.degraded = true;
    result.message += "; non-finite estimate: constant-velocity prediction";
  }
  result.T_world_lidar = normalizedPose(result.T_world_lidar);
  result.T_keyframe_lidar =
      composePoses(T_world_keyframe.inverse(), result.T_world_lidar);
  const bool tracked =
      result.status == TrackingStatus::kFeatures ||
      (result.status == TrackingStatus::kDenseFallback && result.refined);
  const int frames_since = frames_since_keyframe + 1;
  const bool paper_rule = frames_since >= params.keyframe_min_frames &&
                          result.num_inliers <= params.keyframe_max_common_points;
  const bool far =
      result.T_keyframe_lidar.translation().norm() > params.keyframe_max_distance_m ||
      angleDeg(result.T_keyframe_lidar) > params.keyframe_max_rotation_deg;
  const bool useful = result.num_features >= params.keyframe_min_inliers;
  const bool weak = result.num_inliers < params.keyframe_min_inliers && useful;
  const bool reanchor = frames_without_tracking + 1 >= kReanchorAfterFrames && useful;
  if ((tracked && (paper_rule || far || weak)) || reanchor) {
    result.keyframe = makeKeyFrame(result, std::move(*features), keptCloud());
    result.reference_keyframe = result.keyframe->id;
    result.T_keyframe_lidar = Pose3d::Identity();
    if (!tracked) {
      result.degraded = true;
      result.message += "; re-anchored: new key-frame after a stretch without tracking";
    }
  }
  if (!result.keyframe && tracked && result.refined &&
      map_scans < params.dense.young_map_scans)
    insertIntoMap(keptCloud(), result.T_world_lidar);
  result.timings.keyframe_ms = msSince(start);
  if (tracked && !result.keyframe) {
    last_features = features;
    T_world_last_features = result.T_world_lidar;
  } else if (result.keyframe) {
    last_features.reset(); // the key-frame itself is now the closest reference
  }
  result.timings.total_ms = msSince(frame_start);
  return result;
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

const OdometryParams&
Odometry::params() const
{
  return impl_->params;
}

std::size_t
Odometry::numKeyFrames() const
{
  return impl_->next_keyframe_id;
}

std::size_t
Odometry::localMapSize() const
{
  return impl_->map.size();
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
  const auto start = Clock::now();
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
        map,
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
  result.timings.deskew_ms += msSince(start);
}

void
Odometry::Impl::rebuildMapFromFirstScan(OdometryFrameResult& result)
{
  const double dt_first =
      (result.timestamp_s - t_first) * params.deskew.seconds_per_timestamp;
  if (result.refined && map_scans == 1 && dt_first > 1e-6 && dt_first < 1.0) {
    const auto start = Clock::now();
    const Twist xi = logSE3(T_world_first.inverse() * result.T_world_lidar) / dt_first;
    map = VoxelPlaneMap(params.dense);
    map_scans = 0;
    insertIntoMap(*deskewCloud(*first_scan, first_times, xi, params.deskew.bins),
                  T_world_first);
    result.timings.deskew_ms += msSince(start);
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
  impl_->checkIndex(frame_index);
  const auto start = Clock::now();
  OdometryFrameResult result;
  result.frame_index = frame_index;
  result.timestamp_s = timestamp_s;
  if (!cloud)
    return impl_->skip(timestamp_s, frame_index, "null cloud");
  try {
    static const std::vector<float> kNoTimes;
    const bool times_usable =
        point_times_s.empty() || usableTimes(point_times_s, cloud->size());
    result = impl_->track(cloud, times_usable ? point_times_s : kNoTimes, result);
    if (!times_usable)
      result.message += "; " + std::to_string(point_times_s.size()) +
                        " point times for " + std::to_string(cloud->size()) +
                        " points, or not finite or beyond +-1 s: ignored";
  } catch (const std::exception& e) {
    // Bad data must not stop the odometry: report it and predict.
    result = OdometryFrameResult();
    result.frame_index = frame_index;
    result.timestamp_s = timestamp_s;
    result.status = TrackingStatus::kConstantVelocity;
    result.degraded = true;
    result.T_world_lidar = impl_->predict(timestamp_s);
    result.message =
        std::string("tracking failed: ") + e.what() + ": constant-velocity prediction";
  }
  if (!result.keyframe) {
    result.reference_keyframe = impl_->keyframe ? impl_->keyframe->id : 0;
    result.T_keyframe_lidar =
        composePoses(impl_->T_world_keyframe.inverse(), result.T_world_lidar);
  }
  result.timings.total_ms =
      std::chrono::duration<double, std::milli>(Clock::now() - start).count();
  impl_->commitPose(result);
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
