/// \file map_localization.cpp
/// \brief MapLocalization: a run of scans localized on a session's map: tracked by
/// the odometry, aligned to the map's key-frames, placed anew by SessionLocalizer when
/// lost or kidnapped (session_localizer.h, doc/session.md).

#include "fast_math.h"
#include "stage_util.h"
#include "work_queue.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <deque>
#include <functional>
#include <future>
#include <limits>
#include <map>
#include <optional>
#include <pcl/common/time.h>
#include <pcl/slam/deskew.h>
#include <pcl/slam/session_localizer.h>
#include <stdexcept>
#include <system_error>

namespace pcl {
namespace rast {

const char*
toString(LocalizationStatus status)
{
  switch (status) {
  case LocalizationStatus::kLocalized:
    return "localized";
  case LocalizationStatus::kTrackingOnly:
    return "tracking_only";
  case LocalizationStatus::kLost:
    return "lost";
  }
  return "unknown";
}

void
applySensorPreset(SensorPreset preset, MapLocalizationParams& params)
{
  switch (preset) {
  case SensorPreset::kVlp16:
    // Planes of 3 x 3 x 3 voxels of 1 m hold several rings; of 0.3 m, often one or
    // none. 0.6 and 2 m localized 334 and 335 of the 338 frames that 1 m localized
    // (simulated 05 world, seed 101, predicted by the map's velocity).
    params.alignment.target_voxel_size_m = 1.0;
    // Those planes leave a street's axis unconstrained on many frames (weakest
    // direction 0.1 % of the weight, against 2-8 % for an HDL-64 at 0.3 m on most
    // streets): the pose keeps the prediction there, and the odometry, run on every
    // frame, carries the motion along it. From the map's velocity the pose stopped
    // within a few frames (tuning seed 42: 0.03-0.15 m a frame at 1.07 m/frame).
    params.alignment.degeneracy_min_ratio = 0.002;
    // Converged at a millimetre and 0.1 mrad, as the odometry's dense step, instead of
    // 0.1 mm: 7.3 instead of 10.5 iterations a frame, 5-9 % more frames a second on the
    // map, the same poses to the millimetre on four simulated worlds. An HDL-64's
    // alignment lost 2 of 615 mapped-road frames with it (doc/session.md, "Session 54").
    params.alignment.convergence_translation_m = 1e-3;
    params.alignment.convergence_rotation_rad = 1e-4;
    params.track_on_map = false;
    break;
  case SensorPreset::kHdl64:
  case SensorPreset::kOs1_64:
  case SensorPreset::kOs0_128:
    break;
  }
}

bool
MapLocalizationParams::isValid(std::string* why) const
{
  const auto fail = [why](const std::string& message) {
    if (why)
      *why = message;
    return false;
  };
  std::string sub;
  if (!(map_radius_m > 0.0))
    return fail("map_radius_m must be > 0, got " + std::to_string(map_radius_m));
  if (!(prior_radius_m >= 0.0) || !(prior_radius_per_m >= 0.0) ||
      !(prior_max_radius_m >= prior_radius_m))
    return fail(
        "prior_radius_m and prior_radius_per_m must be >= 0 and prior_max_radius_m "
        ">= prior_radius_m, got " +
        std::to_string(prior_radius_m) + ", " + std::to_string(prior_radius_per_m) +
        " and " + std::to_string(prior_max_radius_m));
  if (!(lost_prior_min_dense_overlap <= 1.0))
    return fail("lost_prior_min_dense_overlap must be at most 1, got " +
                std::to_string(lost_prior_min_dense_overlap));
  if (!(reuse_target_m >= 0.0))
    return fail("reuse_target_m must be >= 0, got " + std::to_string(reuse_target_m));
  if (!(merged_keyframes_within_m >= 0.0))
    return fail("merged_keyframes_within_m must be >= 0, got " +
                std::to_string(merged_keyframes_within_m));
  if (!(tracked_together_min_overlap_ratio > 0.0 &&
        tracked_together_min_overlap_ratio <= 1.0))
    return fail("tracked_together_min_overlap_ratio must be in (0, 1], got " +
                std::to_string(tracked_together_min_overlap_ratio));
  if (map_keyframes < 1)
    return fail("map_keyframes must be >= 1, got " + std::to_string(map_keyframes));
  if (!alignment.isValid(&sub))
    return fail("alignment: " + sub);
  if (!(max_rmse_m > 0.0))
    return fail("max_rmse_m must be > 0, got " + std::to_string(max_rmse_m));
  if (!(max_rmse_ratio == 0.0 || max_rmse_ratio >= 1.0) || !(rmse_ratio_floor_m >= 0.0))
    return fail("max_rmse_ratio must be 0 or >= 1 and rmse_ratio_floor_m >= 0, got " +
                std::to_string(max_rmse_ratio) + " and " +
                std::to_string(rmse_ratio_floor_m));
  if (!(jump_m > 0.0))
    return fail("jump_m must be > 0, got " + std::to_string(jump_m));
  if (max_tracking_only_frames < 0)
    return fail("max_tracking_only_frames must be >= 0, got " +
                std::to_string(max_tracking_only_frames));
  if (max_realign_frames < 1)
    return fail("max_realign_frames must be >= 1, got " +
                std::to_string(max_realign_frames));
  if (tentative_window_frames < 0)
    return fail("tentative_window_frames must be >= 0, got " +
                std::to_string(tentative_window_frames));
  if (!(agree_m > 0.0) || !(agree_deg > 0.0))
    return fail("agree_m and agree_deg must be > 0, got " + std::to_string(agree_m) +
                " and " + std::to_string(agree_deg));
  if (placement_backoff_after < 0 || placement_every < 1)
    return fail("placement_backoff_after must be >= 0 and placement_every >= 1, got " +
                std::to_string(placement_backoff_after) + " and " +
                std::to_string(placement_every));
  if (first_attempts < 0 || first_attempts_neighbourhood_keyframes < 0)
    return fail("first_attempts and first_attempts_neighbourhood_keyframes must be >= 0, "
                "got " +
                std::to_string(first_attempts) + " and " +
                std::to_string(first_attempts_neighbourhood_keyframes));
  if (background_placement_lag < 0 ||
      (tentative_window_frames > 0 && background_placement_lag > tentative_window_frames))
    return fail(
        "background_placement_lag must be >= 0 and at most tentative_window_frames, "
        "got " +
        std::to_string(background_placement_lag) + " (tentative_window_frames " +
        std::to_string(tentative_window_frames) + ")");
  if (!(far_radius_m >= 0.0) || !(far_drift_ratio >= 0.0) ||
      !std::isfinite(far_radius_m) || !std::isfinite(far_drift_ratio))
    return fail("far_radius_m and far_drift_ratio must be finite and >= 0, got " +
                std::to_string(far_radius_m) + " and " + std::to_string(far_drift_ratio));
  if (far_placement_every < 1 || far_placement_lag < 0 ||
      (tentative_window_frames > 0 && far_placement_lag > tentative_window_frames))
    return fail("far_placement_every must be >= 1 and far_placement_lag >= 0 and at most "
                "tentative_window_frames, got " +
                std::to_string(far_placement_every) + " and " +
                std::to_string(far_placement_lag) + " (tentative_window_frames " +
                std::to_string(tentative_window_frames) + ")");
  if (backtrack_frames < 0)
    return fail("backtrack_frames must be >= 0, got " + std::to_string(backtrack_frames));
  if (!(leaving_map_corridor_m >= 0.0) || !std::isfinite(leaving_map_corridor_m))
    return fail("leaving_map_corridor_m must be finite and >= 0, got " +
                std::to_string(leaving_map_corridor_m));
  return true;
}

namespace {

/// " (far from the map: ...)" for a prediction \a far_m from its nearest key-frame.
std::string
farNote(const std::optional<double>& far_m)
{
  if (!far_m)
    return {};
  char text[64];
  std::snprintf(text, sizeof text, " (far from the map: %.0f m)", *far_m);
  return text;
}

/// A placement of \a query (a scan, or a key-frame with its features) with the prior
/// when there is one.
template <typename Query>
Placement
placeWithPrior(const SessionLocalizer& localizer,
               const Query& query,
               const std::optional<PlacementPrior>& prior,
               const PlacementOptions& options)
{
  return localizer.place(query, prior ? &*prior : nullptr, options);
}

} // namespace

struct MapLocalization::Impl
{
  Impl(const SessionLocalizer& l, const OdometryParams& o, const MapLocalizationParams& p)
      : localizer(l), odometry_params(trackingOnly(o)), params(p),
        odometry(std::make_unique<Odometry>(odometry_params))
  {}

  /// The odometry tracks only: no map is made of its key-frames.
  static OdometryParams trackingOnly(OdometryParams o)
  {
    o.keyframe_clouds = false;
    return o;
  }

  /// MapLocalization::addScan (\a next: the look-ahead scan, or null): localize(),
  /// then the frames before a placement backwards (backtrack()).
  LocalizationFrame add(const pcl::PointCloud<pcl::PointXYZI>::ConstPtr& raw_scan,
                        double timestamp_s,
                        std::size_t frame_index,
                        const std::vector<float>& point_times_s,
                        const OdometryInput* next);
  /// A frame's interval from the one before [s] and the motion it was compensated with.
  struct FrameMotion
  {
    double dt = 0.0;
    Pose3d step = Pose3d::Identity();
    /// The odometry ran on the frame and tracked its step from the one before (by
    /// features or the dense step, not predicted only).
    bool odometry_tracked = false;
  };
  /// This frame alone: aligned to the map, placed, or carried on by the odometry.
  LocalizationFrame localize(const pcl::PointCloud<pcl::PointXYZI>::ConstPtr& raw_scan,
                             double timestamp_s,
                             std::size_t frame_index,
                             const std::vector<float>& point_times_s,
                             const OdometryInput* next,
                             FrameMotion& motion);

  /// An alignment to the map that confirmed a pose.
  struct Alignment
  {
    Pose3d T_world_lidar = Pose3d::Identity();
    KeyFrameId keyframe = 0;
    int correspondences = 0;
    double rmse_m = 0.0;
    /// What the scan was aligned to, for the frame's message: "key-frame 7", or
    /// "key-frames 7/8/12 together".
    std::string target;
    /// Directions the scan did not constrain, kept at the prediction
    /// (PointToPlaneParams::degeneracy_min_ratio).
    int degenerate_directions = 0;
    bool together = false; ///< to several key-frames' clouds together (alignToMerged())
    double overlap = 0.0;  ///< the share of the source points paired
  };

  /// A scan prepared for the map alignment: its voxel planes (prepareSource()) from
  /// the raw scan, with the time of each when the scan is motion-compensated, which then
  /// moves these few points rather than the whole scan. So a scan can be prepared before
  /// the motion of the frame before it is known: on the source thread, while that frame
  /// is aligned (look-ahead).
  struct Source
  {
    PointVector points, normals;
    std::vector<float> times; ///< per point; empty when the scan is not compensated
    std::string error;        ///< why there are no points
  };
  /// The look-ahead's source being prepared, and the scan it is for.
  struct AheadSource
  {
    const pcl::PointCloud<pcl::PointXYZI>* cloud = nullptr;
    std::size_t frame_index = 0;
    double after_s = 0.0; ///< prepared with the interval from the frame at this time
    std::future<Source> job;
  };

  const SessionLocalizer& localizer;
  OdometryParams odometry_params;
  MapLocalizationParams params;
  std::unique_ptr<Odometry> odometry;
  /// The odometry missed frames (it rested while the map tracked, or the input
  /// jumped): its local map is stale, it starts afresh before its next frame.
  bool odometry_stale = false;
  bool started = false;
  std::optional<Pose3d> T_world_previous; ///< the last frame's pose on the map
  std::optional<double> last_timestamp_s; ///< of the last scan
  Pose3d T_odom_previous = Pose3d::Identity();
  bool have_odom_previous = false;
  /// The scan a jump was found on: the odometry restarted for the next frame tracks it
  /// first, so that the next frame's step is measured (not the identity of a first
  /// frame, which a direction the map alignment keeps at the prediction would hold).
  struct JumpScan
  {
    pcl::PointCloud<pcl::PointXYZI>::ConstPtr scan;
    double timestamp_s = 0.0;
    std::size_t frame_index = 0;
    std::vector<float> point_times_s;
    std::size_t frame = 0; ///< its frame count
  };
  std::optional<JumpScan> jump_scan;
  int tracking_only = 0;
  /// The motion per second between the last two frames, when the map confirmed both.
  std::optional<Twist> map_velocity;
  bool previous_confirmed = false; ///< the map confirmed the last frame
  /// ... by the clouds of the nearest key-frames together (alignTracked())
  bool previous_together = false;
  std::size_t frames = 0;          ///< scans and skipped scans so far
  int odometry_run = 0;            ///< counts the odometry's (re)starts
  /// The last placement (tentative or full) with the odometry's pose of its scan, for a
  /// later tentative placement to agree with.
  struct Recent
  {
    Pose3d T_world_lidar = Pose3d::Identity();
    Pose3d T_odom_lidar = Pose3d::Identity();
    int odometry_run = 0;
    std::size_t frame = 0;
    bool tentative = false; ///< not taken (yet): it waits for a scan that agrees
  };
  std::optional<Recent> recent_placement;
  std::deque<double> recent_rmse; ///< of the last confirmed alignments, since a placement
  int failed_placements = 0;      ///< placement attempts in a row that placed nothing
  std::size_t last_attempt_frame = 0; ///< the frame (count) of the last attempt
  /// The back-off found this frame's prediction far from the map (far_now) and the
  /// previous frame's (far_before, read before this frame's is known).
  bool far_now = false, far_before = false;
  double travelled_m = 0.0; ///< by the predictions since the map last confirmed a pose

  /// Where this frame's prediction may be on the map (MapLocalizationParams::
  /// prior_radius_m); none without a prediction or once it is too uncertain.
  std::optional<PlacementPrior>
  placementPrior(const std::optional<Pose3d>& predicted) const
  {
    if (!predicted || params.prior_radius_m <= 0.0)
      return std::nullopt;
    const double radius = params.prior_radius_m + params.prior_radius_per_m * travelled_m;
    if (radius > params.prior_max_radius_m)
      return std::nullopt;
    PlacementPrior prior;
    prior.T_world_lidar = *predicted;
    prior.radius_m = radius;
    if (tracking_only >= params.max_tracking_only_frames) // lost: entering the map, maybe
      prior.min_dense_overlap = params.lost_prior_min_dense_overlap;
    return prior;
  }

  /// Whether the last placement (tentative or full) is at most tentative_window_frames
  /// before this frame: a later scan may still agree with it.
  bool recentWithinWindow() const
  {
    return recent_placement &&
           frames - recent_placement->frame <=
               static_cast<std::size_t>(params.tentative_window_frames);
  }

  /// Whether the attempts are backed off: placement_backoff_after of them failed in a
  /// row (never with the back-off off).
  bool backedOff() const
  {
    return params.placement_backoff_after > 0 &&
           failed_placements >= params.placement_backoff_after;
  }

  /// Whether this frame tries a placement
  /// (MapLocalizationParams::placement_backoff_after; \a far: its prediction is far from
  /// the map, farFromMap()).
  bool placementDue(bool far) const
  {
    if (!backedOff())
      return true;
    if (pending)
      return false; // the back-off's attempt still runs (one with a longer lag than
                    // the interval now, started far from the map)
    if (recentWithinWindow())
      return true; // a tentative placement waits for a second one to agree
    return frames - last_attempt_frame >= static_cast<std::size_t>(placementEvery(far));
  }

  /// Whether this frame's placement will likely use the odometry's features of the
  /// scan (MapLocalizationParams::features_on_demand): when one is due by the previous
  /// frame's schedule, near the map or far from it (this frame's is known only after the
  /// odometry ran), and the map did not confirm the previous frame (this one is then
  /// likely aligned). An attempt due when the odometry made none describes the scan
  /// itself: so does the rare one that agrees at once with a tentative placement that a
  /// background attempt, taken this frame, left.
  bool featuresWanted() const
  {
    return !params.features_on_demand ||
           (!previous_confirmed && placementDue(far_before));
  }

  /// Whether \a kf is a key-frame of the map the localization is in: of the session's
  /// main component. A drive a merge could not join is a separate map in a frame of
  /// its own, which no pose of this localization refers to.
  bool inMapFrame(const KeyFrame& kf) const
  {
    return sessionComponentOf(localizer.session(), kf.id) == 0;
  }

  /// Distance [m] from \a predicted to the nearest session key-frame of the map when
  /// that is farther than the dead reckoning can be off (MapLocalizationParams::
  /// far_radius_m), else none.
  std::optional<double> farFromMap(const std::optional<Pose3d>& predicted) const
  {
    if (!predicted || params.far_radius_m <= 0.0)
      return std::nullopt;
    const double radius = params.far_radius_m + params.far_drift_ratio * travelled_m;
    double nearest = std::numeric_limits<double>::infinity();
    // Every key-frame of the map counts, also one without a cloud or features that no
    // placement can use: near it the usual schedule holds, the safer side.
    for (const KeyFrame::Ptr& kf : localizer.session().keyframes) {
      if (!inMapFrame(*kf))
        continue;
      nearest = std::min(
          nearest,
          (kf->T_world_keyframe.translation() - predicted->translation()).norm());
      if (nearest <= radius)
        return std::nullopt;
    }
    return nearest;
  }

  /// Whether a drive at \a predicted, the map's last motion \a step, leaves the map
  /// where it ends (MapLocalizationParams::leaving_map_corridor_m): it moves, and no
  /// session key-frame lies ahead within map_radius_m and the corridor.
  bool leavingMap(const Pose3d& predicted, const Pose3d& step) const
  {
    if (!(params.leaving_map_corridor_m > 0.0))
      return false;
    const Eigen::Vector3d motion = predicted.linear() * step.translation();
    if (motion.norm() < kLeavingMinStepM)
      return false; // standing: it leaves nothing
    const Eigen::Vector3d ahead = motion.normalized();
    for (const KeyFrame::Ptr& kf : localizer.session().keyframes) {
      if (!inMapFrame(*kf))
        continue;
      const Eigen::Vector3d d =
          kf->T_world_keyframe.translation() - predicted.translation();
      const double along = d.dot(ahead);
      if (along > 0.0 && along <= params.map_radius_m &&
          (d - along * ahead).norm() <= params.leaving_map_corridor_m)
        return false;
    }
    return true;
  }
  /// Slower than this a frame (0.5 m/s at 10 Hz), a drive is taken as standing.
  static constexpr double kLeavingMinStepM = 0.05;

  /// The back-off's attempt interval and background lag, \a far from the map or not:
  /// never more often or sooner far from the map than near it.
  int placementEvery(bool far) const
  {
    return far ? std::max(params.far_placement_every, params.placement_every)
               : params.placement_every;
  }
  int placementLag(bool far) const
  {
    return far && params.background_placement_lag > 0
               ? std::max(params.far_placement_lag, params.background_placement_lag)
               : params.background_placement_lag;
  }

  /// Why an alignment with residual \a rmse_m fits suspiciously worse than the last
  /// ones (empty: it does not; MapLocalizationParams::max_rmse_ratio).
  std::string suddenlyWorse(double rmse_m) const
  {
    return suddenlyWorse(rmse_m, recent_rmse);
  }
  /// ... than \a recent.
  std::string suddenlyWorse(double rmse_m, const std::deque<double>& recent) const
  {
    if (params.max_rmse_ratio <= 0.0 || recent.size() < 3)
      return {};
    std::vector<double> sorted(recent.begin(), recent.end());
    std::nth_element(sorted.begin(), sorted.begin() + sorted.size() / 2, sorted.end());
    const double median = sorted[sorted.size() / 2];
    if (rmse_m <= std::max(params.rmse_ratio_floor_m, params.max_rmse_ratio * median))
      return {};
    char text[128];
    std::snprintf(text,
                  sizeof text,
                  "rmse %.3f m is %.1f times the last frames' %.3f m: another place?",
                  rmse_m,
                  rmse_m / median,
                  median);
    return text;
  }
  /// Alignment targets of session key-frames (their own frame), the newest used last.
  std::map<KeyFrameId, std::shared_ptr<const PointToPlaneTarget>> targets;
  std::deque<KeyFrameId> target_order;
  static constexpr std::size_t kMaxTargets = 32;
  /// The last target built from several key-frames' clouds together (alignToMerged()),
  /// in the world frame, and whose clouds it holds.
  std::shared_ptr<const PointToPlaneTarget> merged_target;
  std::vector<KeyFrameId> merged_ids;
  /// A placement attempt running in the background (background_placement_lag), with
  /// what taking it later needs. Declared after what it uses: it is waited for first.
  struct Pending
  {
    std::future<Placement> result;
    Pose3d T_odom_lidar = Pose3d::Identity(); ///< the odometry's pose of its scan
    std::size_t frame = 0;                    ///< frame count of its scan
    int lag = 1;                              ///< frames after which it is taken
  };
  std::optional<Pending> pending;
  std::optional<AheadSource> ahead_source;
  /// The look-ahead's thread for sources, started by its first use and kept. Last
  /// member: joined before anything its task uses goes.
  std::unique_ptr<slam_detail::TaskThread<Source>> source_thread;

  /// Whether this frame's attempt, when due, runs in the background: backed off, with
  /// no tentative placement waiting for a second one, and room for one at a time.
  bool placeInBackground(bool far) const
  {
    const int lag = placementLag(far);
    return lag > 0 && placementEvery(far) > lag && backedOff() && !recentWithinWindow() &&
           !pending;
  }

  /// The motion of the last two frames the map confirmed, over \a dt seconds (none
  /// without such a motion or an interval).
  std::optional<Pose3d> velocityStep(double dt) const
  {
    if (!map_velocity || !(dt > 0.0))
      return std::nullopt;
    return normalizedPose(expSE3(*map_velocity * dt));
  }

  /// Seconds since the last scan (0 when unknown or not increasing).
  double interval(double timestamp_s) const
  {
    if (!last_timestamp_s)
      return 0.0;
    const double dt =
        (timestamp_s - *last_timestamp_s) * odometry_params.deskew.seconds_per_timestamp;
    return dt > 0.0 && std::isfinite(dt) ? dt : 0.0;
  }

  /// A new frame, scanned or skipped, counted: its record with the index and time.
  LocalizationFrame beginFrame(double timestamp_s, std::size_t frame_index)
  {
    started = true;
    ++frames;
    far_before = std::exchange(far_now, false);
    LocalizationFrame f;
    f.frame_index = frame_index;
    f.timestamp_s = timestamp_s;
    return f;
  }

  /// The scan motion-compensated with this frame's motion \a step over \a dt seconds,
  /// as the odometry compensates what it tracks: point times from the scan
  /// (\a point_times_s) or, with DeskewMode::kOn, from the azimuth. The scan itself
  /// when there are no times or no motion (dt 0).
  pcl::PointCloud<pcl::PointXYZI>::ConstPtr
  compensated(const pcl::PointCloud<pcl::PointXYZI>::ConstPtr& scan,
              const std::vector<float>& point_times_s,
              double dt,
              const Pose3d& step) const
  {
    std::vector<float> azimuth;
    const std::vector<float>* times = sweepTimes(scan, point_times_s, dt, azimuth);
    if (!times)
      return scan;
    return deskewCloud(*scan, *times, logSE3(step) / dt, odometry_params.deskew.bins);
  }

  /// The times compensated() moves the points of \a scan by (\a dt s after the scan
  /// before): \a point_times_s itself, or the azimuth's, computed into \a azimuth; null
  /// when it leaves the scan as it is.
  const std::vector<float>*
  sweepTimes(const pcl::PointCloud<pcl::PointXYZI>::ConstPtr& scan,
             const std::vector<float>& point_times_s,
             double dt,
             std::vector<float>& azimuth) const
  {
    const DeskewParams& d = odometry_params.deskew;
    if (!scan || scan->empty() || d.mode == DeskewMode::kOff || !(dt > 0.0))
      return nullptr;
    if (point_times_s.size() == scan->size())
      return &point_times_s;
    if (d.mode == DeskewMode::kOn) {
      azimuth =
          azimuthTimes(*scan, d.sweep_period_s > 0.0 ? d.sweep_period_s : dt, d.sweep);
      return &azimuth;
    }
    return nullptr;
  }

  /// The source of \a scan with \a times (sweepTimes(); empty: none), not moved yet.
  static Source prepareRaw(const pcl::PointCloud<pcl::PointXYZI>& scan,
                           const std::vector<float>& times,
                           const PointToPlaneParams& alignment)
  {
    Source source;
    try {
      const PointToPlaneTarget prepared =
          times.empty() ? prepareSource(scan, alignment)
                        : prepareSource(scan, times, alignment, source.times);
      source.points = prepared.points();
      source.normals = prepared.normals();
    } catch (const std::invalid_argument& e) {
      source = Source();
      source.error = std::string("scan: ") + e.what();
    }
    return source;
  }

  /// The look-ahead's source when it is for this scan (\a scan, its index, and the
  /// interval from the frame at \a previous_s), taken; none otherwise (an unused one is
  /// dropped).
  std::optional<AheadSource> takeAhead(const pcl::PointCloud<pcl::PointXYZI>* scan,
                                       std::size_t frame_index,
                                       const std::optional<double>& previous_s)
  {
    std::optional<AheadSource> a = std::move(ahead_source);
    ahead_source.reset();
    if (a && (a->cloud != scan || a->frame_index != frame_index || !previous_s ||
              a->after_s != *previous_s))
      a.reset(); // waits for its thread
    return a;
  }

  /// Whether the next frame will likely be aligned to the map (so the look-ahead
  /// prepares its source): the map confirmed a recent frame, or a tentative placement
  /// waits for confirmation.
  bool alignmentLikely() const
  {
    return (T_world_previous && tracking_only < params.max_realign_frames) ||
           tentativeToConfirm();
  }

  /// Prepare the look-ahead scan \a next's source on the source thread, for the frame
  /// after the one at \a timestamp_s.
  void prepareAhead(const OdometryInput& next, double timestamp_s)
  {
    ahead_source.reset(); // waits for an earlier one that was not taken
    if (!next.cloud || next.cloud->empty())
      return;
    const double next_dt =
        (next.timestamp_s - timestamp_s) * odometry_params.deskew.seconds_per_timestamp;
    std::vector<float> azimuth;
    const std::vector<float>* next_times =
        sweepTimes(next.cloud,
                   next.point_times_s,
                   next_dt > 0.0 && std::isfinite(next_dt) ? next_dt : 0.0,
                   azimuth);
    // A copy for the source thread: the caller's times may go before it runs.
    std::vector<float> times = next_times ? *next_times : std::vector<float>();
    try {
      if (!source_thread)
        source_thread = std::make_unique<slam_detail::TaskThread<Source>>();
    } catch (const std::system_error&) {
      return; // no thread to be had: the next frame prepares its own
    }
    AheadSource a;
    a.cloud = next.cloud.get();
    a.frame_index = next.frame_index;
    a.after_s = timestamp_s;
    a.job = source_thread->run(
        [cloud = next.cloud, times = std::move(times), alignment = params.alignment] {
          return prepareRaw(*cloud, times, alignment);
        });
    ahead_source.emplace(std::move(a));
  }

  /// This frame's source, moved by its motion \a step over \a dt s: the one the
  /// look-ahead prepared for this scan (\a ahead, taken), else prepared now.
  Source source(std::optional<AheadSource>& ahead,
                const pcl::PointCloud<pcl::PointXYZI>::ConstPtr& scan,
                const std::vector<float>& point_times_s,
                double dt,
                const Pose3d& step) const
  {
    Source out;
    if (ahead) {
      out = ahead->job.get();
      ahead.reset();
    } else {
      if (!scan || scan->empty()) {
        out.error = "scan: no points";
        return out;
      }
      static const std::vector<float> kNoTimes;
      std::vector<float> azimuth;
      const std::vector<float>* times = sweepTimes(scan, point_times_s, dt, azimuth);
      out = prepareRaw(*scan, times ? *times : kNoTimes, params.alignment); // no copy
    }
    compensate(out, dt, step);
    return out;
  }

  /// Move a source's points and normals by the motion \a step over \a dt s (nothing
  /// when it has no times).
  void compensate(Source& source, double dt, const Pose3d& step) const
  {
    if (!source.times.empty() && dt > 0.0)
      deskewPointsAndNormals(source.points,
                             source.normals,
                             source.times,
                             logSE3(step) / dt,
                             odometry_params.deskew.bins);
  }

  /// A frame the map did not confirm, kept for a later placement to localize backwards
  /// (MapLocalizationParams::backtrack_frames).
  struct Unconfirmed
  {
    LocalizationFrame frame; ///< as addScan returned it
    Pose3d T_odom_lidar = Pose3d::Identity();
    int odometry_run = 0;
    bool odometry_tracked = false; ///< by features or the dense step (not predicted only)
    /// At most kBacktrackPoints of the scan's points, evenly strided, in centimetres,
    /// with its time as a fraction of [time_min_s, time_max_s] when the scan is
    /// compensated: 8 bytes a point.
    struct Packed
    {
      std::int16_t x, y, z;
      std::uint16_t t;
    };
    std::vector<Packed> points;
    bool timed = false;
    float time_min_s = 0.0f, time_max_s = 0.0f;
    double dt = 0.0;                  ///< from the scan before
    Pose3d step = Pose3d::Identity(); ///< the motion it is compensated with
  };
  std::deque<Unconfirmed> unconfirmed;
  /// Points kept of each unconfirmed scan, at most: a quarter of a simulated HDL-64
  /// scan (100000-125000 points), which the alignment's 0.5 m voxel planes need no
  /// more of (simulated KITTI 00 second drive: 60 frames localized backwards with every
  /// fourth point, 49 with every second; 0.26 m from ground truth either way, the map's
  /// own error there). A VLP-16 scan (under 30000 points) is kept whole.
  static constexpr std::size_t kBacktrackPoints = 32768;

  /// Keep frame \a f (not confirmed; the odometry ran on it; compensated with the
  /// motion \a motion.step over motion.dt s) with a thinned copy of its scan
  /// (kBacktrackPoints), for a later placement.
  void keepUnconfirmed(const LocalizationFrame& f,
                       const FrameMotion& motion,
                       const pcl::PointCloud<pcl::PointXYZI>::ConstPtr& scan_ptr,
                       const std::vector<float>& point_times_s)
  {
    const pcl::PointCloud<pcl::PointXYZI>& scan = *scan_ptr;
    Unconfirmed u;
    u.frame = f;
    u.T_odom_lidar = T_odom_previous;
    u.odometry_run = odometry_run;
    u.odometry_tracked = motion.odometry_tracked;
    u.dt = motion.dt;
    u.step = motion.step;
    std::vector<float> azimuth;
    const std::vector<float>* times =
        sweepTimes(scan_ptr, point_times_s, motion.dt, azimuth);
    const std::size_t stride =
        std::max<std::size_t>((scan.size() + kBacktrackPoints - 1) / kBacktrackPoints, 1);
    u.timed = times != nullptr;
    if (u.timed) {
      u.time_min_s = u.time_max_s = (*times)[0];
      for (std::size_t i = 0; i < scan.size(); i += stride) {
        u.time_min_s = std::min(u.time_min_s, (*times)[i]);
        u.time_max_s = std::max(u.time_max_s, (*times)[i]);
      }
    }
    const float time_scale =
        u.time_max_s > u.time_min_s ? 65535.0f / (u.time_max_s - u.time_min_s) : 0.0f;
    constexpr float kMaxM = 327.0f; // int16 centimetres
    u.points.reserve(scan.size() / stride + 1);
    for (std::size_t i = 0; i < scan.size(); i += stride) {
      const Eigen::Vector3f p = scan[i].getVector3fMap();
      if (!(std::abs(p.x()) < kMaxM && std::abs(p.y()) < kMaxM &&
            std::abs(p.z()) < kMaxM))
        continue; // also NaN
      const float t = u.timed ? ((*times)[i] - u.time_min_s) * time_scale : 0.0f;
      u.points.push_back(
          {static_cast<std::int16_t>(fast_math::roundSmall(100.0f * p.x())),
           static_cast<std::int16_t>(fast_math::roundSmall(100.0f * p.y())),
           static_cast<std::int16_t>(fast_math::roundSmall(100.0f * p.z())),
           static_cast<std::uint16_t>(fast_math::roundSmall(t))});
    }
    unconfirmed.push_back(std::move(u));
    while (unconfirmed.size() > static_cast<std::size_t>(params.backtrack_frames))
      unconfirmed.pop_front();
  }

  /// The frames kept before the placement \a f (unconfirmed), nearest first, aligned
  /// to the map from the pose of the frame after each moved back by the odometry, until
  /// one is not confirmed: into f.backtracked_frames.
  void backtrack(LocalizationFrame& f, const FrameMotion& motion)
  {
    Pose3d T_world_next = f.T_world_lidar;
    Pose3d T_odom_next = T_odom_previous;
    bool next_tracked = motion.odometry_tracked;
    std::deque<double> rmse; // of the last frames backtracked, for suddenlyWorse
    // Targets built for these frames stay out of the cache: the frames after the
    // placement align as they would without backtracking.
    std::map<KeyFrameId, std::shared_ptr<const PointToPlaneTarget>> scratch;
    std::string stop;
    for (auto it = unconfirmed.rbegin(); it != unconfirmed.rend(); ++it) {
      const Unconfirmed& u = *it;
      // The odometry's motion between the two: same run, and measured at the later.
      if (u.odometry_run != odometry_run || !next_tracked) {
        stop = "frame " + std::to_string(u.frame.frame_index) +
               ": the odometry's motion from it is unknown (it restarted or lost track)";
        break;
      }
      const Pose3d predicted =
          normalizedPose(T_world_next * (T_odom_next.inverse() * u.T_odom_lidar));
      pcl::PointCloud<pcl::PointXYZI> cloud;
      cloud.resize(u.points.size());
      std::vector<float> times(u.timed ? u.points.size() : 0);
      const float time_step = (u.time_max_s - u.time_min_s) / 65535.0f;
      for (std::size_t i = 0; i < u.points.size(); ++i) {
        const Unconfirmed::Packed& q = u.points[i];
        cloud[i].x = 0.01f * q.x;
        cloud[i].y = 0.01f * q.y;
        cloud[i].z = 0.01f * q.z;
        cloud[i].intensity = 0.0f;
        if (u.timed)
          times[i] = u.time_min_s + time_step * q.t;
      }
      Source source = prepareRaw(cloud, times, params.alignment);
      compensate(source, u.dt, u.step);
      std::string why;
      std::optional<Alignment> a =
          alignToMap([&]() -> const Source& { return source; }, predicted, why, &scratch);
      refuseUnconstrained(a, why); // moved back from a placement
      if (a) {
        if (std::string worse = suddenlyWorse(a->rmse_m, rmse); !worse.empty()) {
          why = a->target + ": " + worse;
          a.reset();
        }
      }
      if (!a) {
        stop = "frame " + std::to_string(u.frame.frame_index) + ": " + why;
        break;
      }
      rmse.push_back(a->rmse_m);
      if (rmse.size() > 10) // as many as a tracked frame is compared with
        rmse.pop_front();
      LocalizationFrame b = u.frame;
      b.status = LocalizationStatus::kLocalized;
      b.T_world_lidar = a->T_world_lidar;
      b.keyframe = a->keyframe;
      b.correspondences = a->correspondences;
      b.rmse_m = a->rmse_m;
      b.backtracked = true;
      b.message = "aligned to " + a->target + " backwards from the placement of frame " +
                  std::to_string(f.frame_index) + " (before: " + u.frame.message + ")";
      f.backtracked_frames.push_back(std::move(b));
      T_world_next = a->T_world_lidar;
      T_odom_next = u.T_odom_lidar;
      next_tracked = u.odometry_tracked;
    }
    if (unconfirmed.empty())
      return;
    if (stop.empty() &&
        unconfirmed.size() >= static_cast<std::size_t>(params.backtrack_frames))
      stop = "the first of the " + std::to_string(params.backtrack_frames) +
             " kept (backtrack_frames)";
    f.message += "; " + std::to_string(f.backtracked_frames.size()) + " of the " +
                 std::to_string(unconfirmed.size()) +
                 " unconfirmed frames kept before it localized backwards";
    if (!stop.empty())
      f.message += " (stopped at " + stop + ")";
  }

  /// The alignment target of \a kf: from the cache, else built and cached, or kept in
  /// \a scratch instead when given.
  std::shared_ptr<const PointToPlaneTarget> target(
      const KeyFrame& kf,
      std::map<KeyFrameId, std::shared_ptr<const PointToPlaneTarget>>* scratch = nullptr)
  {
    if (auto it = targets.find(kf.id); it != targets.end())
      return it->second;
    if (scratch) {
      if (auto it = scratch->find(kf.id); it != scratch->end())
        return it->second;
    }
    auto t = std::make_shared<PointToPlaneTarget>();
    if (const auto cloud = sessionCloud(localizer.session(), kf.id))
      t->build(*cloud, params.alignment); // else empty: skipped by the alignment
    if (scratch) {
      scratch->emplace(kf.id, t);
      return t;
    }
    if (targets.size() >= kMaxTargets) {
      targets.erase(target_order.front());
      target_order.pop_front();
    }
    targets.emplace(kf.id, t);
    target_order.push_back(kf.id);
    return t;
  }

  /// The session key-frames with a cloud nearest to \a T_world (within the radius).
  std::vector<const KeyFrame*> nearestKeyFrames(const Pose3d& T_world) const
  {
    std::vector<std::pair<double, const KeyFrame*>> near;
    for (const KeyFrame::Ptr& kf : localizer.session().keyframes) {
      if (!sessionHasCloud(localizer.session(), kf->id) || !inMapFrame(*kf))
        continue;
      const double d =
          (kf->T_world_keyframe.translation() - T_world.translation()).norm();
      if (d <= params.map_radius_m)
        near.emplace_back(d, kf.get());
    }
    // Built targets within reuse_target_m first, then the rest, each nearest first.
    const auto built = [&](const std::pair<double, const KeyFrame*>& n) {
      return n.first <= params.reuse_target_m && targets.count(n.second->id) > 0;
    };
    std::sort(near.begin(), near.end(), [&](const auto& a, const auto& b) {
      const bool ba = built(a), bb = built(b);
      return ba != bb ? ba : a.first < b.first;
    });
    std::vector<const KeyFrame*> out;
    for (std::size_t i = 0; i < near.size() && static_cast<int>(i) < params.map_keyframes;
         ++i)
      out.push_back(near[i].second);
    return out;
  }

  /// Align the scan to the nearest key-frames from \a predicted; the first that
  /// confirms the pose wins.
  std::optional<Alignment> alignToMap(
      const std::function<const Source&()>& scan,
      const Pose3d& predicted,
      std::string& why,
      std::map<KeyFrameId, std::shared_ptr<const PointToPlaneTarget>>* scratch = nullptr)
  {
    const std::vector<const KeyFrame*> near = nearestKeyFrames(predicted);
    if (near.empty()) {
      why =
          "no key-frame of the map within " + std::to_string(params.map_radius_m) + " m";
      return std::nullopt;
    }
    const Source& source = scan();
    if (source.points.empty()) {
      why = source.error;
      return std::nullopt;
    }
    for (const KeyFrame* kf : near) {
      const auto map = target(*kf, scratch);
      if (map->empty())
        continue;
      const Pose3d guess = kf->T_world_keyframe.inverse() * predicted;
      const PointToPlaneResult r = refinePointToPlane(
          source.points, source.normals, *map, guess, params.alignment);
      if (std::optional<Alignment> a = confirmed(r,
                                                 kf->T_world_keyframe,
                                                 kf->id,
                                                 "key-frame " + std::to_string(kf->id),
                                                 why))
        return a;
    }
    return std::nullopt;
  }

  /// A tracked frame: aligned to the nearest key-frames one by one (alignToMap()), and
  /// when none confirms it and the map confirmed the frame before, to their clouds
  /// together (tracked_together), where a drive at the map's edge or on the other side
  /// of a road pairs too little with any one. Once the clouds together confirmed a
  /// frame, they are tried first on the next.
  std::optional<Alignment> alignTracked(const std::function<const Source&()>& scan,
                                        const Pose3d& predicted,
                                        std::string& why)
  {
    const bool together = params.tracked_together && previous_confirmed;
    std::optional<Alignment> a;
    std::string why_not_together; // "; ..." when the clouds together did not confirm it
    if (together && previous_together)
      a = alignTrackedTogether(scan, predicted, why_not_together);
    if (!a)
      a = alignToMap(scan, predicted, why);
    if (!a && together && !previous_together)
      a = alignTrackedTogether(scan, predicted, why_not_together);
    if (!a)
      why += why.empty() && !why_not_together.empty() ? why_not_together.substr(2)
                                                      : why_not_together;
    return a;
  }

  /// The clouds together pair with any street that looks alike far more than one
  /// key-frame's does (a simulated straight street of another world: 40-44 % of its
  /// points), so a tracked frame aligned to them must pair at least
  /// tracked_together_min_overlap_ratio of its points, and (with a degeneracy-aware
  /// alignment) keep no direction at the prediction. \a why gains "; ..." when not.
  std::optional<Alignment>
  alignTrackedTogether(const std::function<const Source&()>& scan,
                       const Pose3d& predicted,
                       std::string& why)
  {
    std::optional<Alignment> a = alignToNearestTogether(scan, predicted, why);
    if (!a)
      return a;
    if (a->overlap < params.tracked_together_min_overlap_ratio) {
      char shares[96];
      std::snprintf(shares,
                    sizeof shares,
                    ": %.0f %% of the source points paired, %.0f %% asked of a tracked "
                    "frame",
                    100.0 * a->overlap,
                    100.0 * params.tracked_together_min_overlap_ratio);
      why += "; " + a->target + shares;
      a.reset();
    } else if (a->degenerate_directions > 0) {
      why += "; " + a->target + ": " + std::to_string(a->degenerate_directions) +
             " direction(s) the scan does not constrain";
      a.reset();
    }
    return a;
  }

  /// Where the prediction is no measurement of its own (moved back from a placement, or
  /// a tentative placement moved on by the odometry), it cannot stand for a direction
  /// the scan does not constrain: such an alignment is refused, and \a why says so.
  static void refuseUnconstrained(std::optional<Alignment>& a, std::string& why)
  {
    if (!a || a->degenerate_directions == 0)
      return;
    why = a->target + ": " + std::to_string(a->degenerate_directions) +
          " direction(s) the scan does not constrain";
    a.reset();
  }

  /// The same where the prediction is the odometry's step \a odo and that step measured
  /// nothing (degenerate_needs_tracked_odometry): degraded, unless strong features set
  /// the pose (a features frame is also flagged for its dense step's degeneracy).
  void refuseWhereOdometryDegraded(std::optional<Alignment>& a,
                                   const OdometryFrameResult& odo,
                                   std::string& why) const
  {
    const bool measured =
        !odo.degraded || (odo.status == TrackingStatus::kFeatures &&
                          odo.num_inliers >= odometry_params.strong_feature_inliers);
    if (!a || a->degenerate_directions == 0 ||
        !params.degenerate_needs_tracked_odometry || measured)
      return;
    refuseUnconstrained(a, why);
    why += std::string(" and the odometry's step there was degraded (") +
           toString(odo.status) + ")";
  }

  /// The refinement \a r of the scan to a target whose frame is \a T_world_target
  /// (\a target names it, \a keyframe is the key-frame reported), when it confirms the
  /// pose (success, RMS at most max_rmse_m); else none, and \a why_not says why.
  std::optional<Alignment> confirmed(const PointToPlaneResult& r,
                                     const Pose3d& T_world_target,
                                     KeyFrameId keyframe,
                                     std::string target,
                                     std::string& why_not) const
  {
    if (!r.success) {
      why_not = target + ": " + r.message;
      return std::nullopt;
    }
    if (r.rmse_m > params.max_rmse_m) {
      char text[64];
      std::snprintf(
          text, sizeof text, ": rmse %.3f m > %.3f m", r.rmse_m, params.max_rmse_m);
      why_not = target + text;
      return std::nullopt;
    }
    Alignment a;
    a.T_world_lidar = normalizedPose(T_world_target * r.T_target_source);
    a.keyframe = keyframe;
    a.correspondences = r.num_correspondences;
    a.rmse_m = r.rmse_m;
    a.target = std::move(target);
    a.degenerate_directions = r.degenerate_directions;
    a.overlap = r.num_source_points > 0
                    ? static_cast<double>(r.num_correspondences) / r.num_source_points
                    : 0.0;
    return a;
  }

  /// The scan aligned to the clouds of the nearest key-frames together, when the
  /// nearest is within MapLocalizationParams::merged_keyframes_within_m of
  /// \a predicted; \a why gains the reason when it does not confirm the pose.
  std::optional<Alignment>
  alignToNearestTogether(const std::function<const Source&()>& scan,
                         const Pose3d& predicted,
                         std::string& why)
  {
    const std::vector<const KeyFrame*> near = nearestKeyFrames(predicted);
    if (near.size() < 2 ||
        nearestDistance(near, predicted) > params.merged_keyframes_within_m)
      return std::nullopt;
    const Source& source = scan();
    if (source.points.empty())
      return std::nullopt;
    return alignToMerged(source, near, predicted, why);
  }

  /// The distance from \a T_world to the nearest of \a near [m].
  static double nearestDistance(const std::vector<const KeyFrame*>& near,
                                const Pose3d& T_world)
  {
    double best = std::numeric_limits<double>::infinity();
    for (const KeyFrame* kf : near)
      best = std::min(
          best, (kf->T_world_keyframe.translation() - T_world.translation()).norm());
    return best;
  }

  /// The world-frame target of the clouds of \a near together: the last one when it
  /// holds the same key-frames, else built (and kept for the next frame).
  std::shared_ptr<const PointToPlaneTarget>
  mergedTarget(const std::vector<const KeyFrame*>& near)
  {
    std::vector<KeyFrameId> ids;
    for (const KeyFrame* kf : near)
      ids.push_back(kf->id);
    std::sort(ids.begin(), ids.end());
    if (merged_target && ids == merged_ids)
      return merged_target;
    PointVector world;
    for (const KeyFrame* kf : near) {
      const auto cloud = sessionCloud(localizer.session(), kf->id);
      if (!cloud)
        continue;
      const Eigen::Isometry3d T = kf->T_world_keyframe;
      for (const auto& p : cloud->points)
        world.push_back(T * Eigen::Vector3d(p.x, p.y, p.z));
    }
    auto target = std::make_shared<PointToPlaneTarget>();
    try {
      target->build(world, params.alignment);
    } catch (const std::invalid_argument&) {
      target = std::make_shared<PointToPlaneTarget>(); // empty: nothing to align to
    }
    merged_target = target;
    merged_ids = std::move(ids);
    return target;
  }

  /// The scan aligned to the clouds of \a near together
  /// (MapLocalizationParams::merged_keyframes_within_m); \a why gains the reason when it
  /// does not confirm the pose. The alignment names the first of them (the nearest,
  /// or the nearest with a target built already, as nearestKeyFrames() orders them).
  std::optional<Alignment> alignToMerged(const Source& source,
                                         const std::vector<const KeyFrame*>& near,
                                         const Pose3d& predicted,
                                         std::string& why)
  {
    const auto map = mergedTarget(near);
    if (map->empty())
      return std::nullopt;
    const PointToPlaneResult r = refinePointToPlane(
        source.points, source.normals, *map, predicted, params.alignment);
    std::string which = "key-frames ";
    for (std::size_t i = 0; i < near.size(); ++i)
      which += (i == 0 ? "" : "/") + std::to_string(near[i]->id);
    which += " together";
    std::string why_not;
    std::optional<Alignment> a =
        confirmed(r, Pose3d::Identity(), near.front()->id, std::move(which), why_not);
    if (a)
      a->together = true;
    else
      why += "; " + why_not;
    return a;
  }

  /// The odometry on this frame (started afresh when stale), and its motion since
  /// the frame before (identity for its first frame).
  OdometryFrameResult runOdometry(const pcl::PointCloud<pcl::PointXYZI>::ConstPtr& scan,
                                  double timestamp_s,
                                  std::size_t frame_index,
                                  const std::vector<float>& point_times_s,
                                  const OdometryInput* next,
                                  Pose3d& step)
  {
    restartOdometryIfStale();
    odometry->setFeaturesWanted(featuresWanted());
    const OdometryFrameResult odo =
        next
            ? odometry->processFrame(scan, timestamp_s, frame_index, point_times_s, *next)
            : odometry->processFrame(scan, timestamp_s, frame_index, point_times_s);
    step = odometryStep(odo);
    return odo;
  }

  void restartOdometryIfStale()
  {
    if (!odometry_stale)
      return;
    odometry = std::make_unique<Odometry>(odometry_params);
    have_odom_previous = false;
    odometry_stale = false;
    ++odometry_run;
    // Right after a jump: from the scan the jump was found on, whose pose the map gave.
    if (jump_scan && jump_scan->frame + 1 == frames) {
      const OdometryFrameResult first = odometry->processFrame(jump_scan->scan,
                                                               jump_scan->timestamp_s,
                                                               jump_scan->frame_index,
                                                               jump_scan->point_times_s);
      T_odom_previous = first.T_world_lidar;
      have_odom_previous = true;
    }
    jump_scan.reset();
  }

  /// The odometry's motion since the previous frame (identity for the first).
  Pose3d odometryStep(const OdometryFrameResult& odo)
  {
    const Pose3d step = have_odom_previous ? T_odom_previous.inverse() * odo.T_world_lidar
                                           : Pose3d::Identity();
    T_odom_previous = odo.T_world_lidar;
    have_odom_previous = true;
    return normalizedPose(step);
  }

  /// The map confirmed \a T_world_lidar this frame (\a dt s after the last scan).
  void confirm(const Pose3d& T_world_lidar, double dt)
  {
    if (previous_confirmed && T_world_previous && dt > 0.0)
      map_velocity = logSE3(T_world_previous->inverse() * T_world_lidar) / dt;
    else
      map_velocity.reset();
    previous_confirmed = true;
    previous_together = false; // the caller sets it for a tracked frame aligned together
    tracking_only = 0;
    travelled_m = 0.0;
    T_world_previous = T_world_lidar;
    pending.reset(); // an attempt in the background has nothing to add (waits for it)
  }

  /// Whether the placement of an earlier scan (recent_placement), moved by the
  /// odometry to this scan (odometry pose \a T_odom_lidar), agrees with \a placement;
  /// \a how says by how much.
  bool agreesWithRecent(const Placement& placement,
                        const Pose3d& T_odom_lidar,
                        std::string& how) const
  {
    if (!recentWithinWindow() || recent_placement->odometry_run != odometry_run)
      return false;
    const Pose3d moved = recent_placement->T_world_lidar *
                         (recent_placement->T_odom_lidar.inverse() * T_odom_lidar);
    const Pose3d d = moved.inverse() * placement.T_world_lidar;
    const double d_m = d.translation().norm();
    const double d_deg = slam_detail::rotationDeg(d);
    char text[120];
    std::snprintf(text,
                  sizeof text,
                  "agrees with the placement %zu frames before within %.2f m, %.2f deg; ",
                  frames - recent_placement->frame,
                  d_m,
                  d_deg);
    how = text;
    return d_m <= params.agree_m && d_deg <= params.agree_deg;
  }

  /// A recent tentative placement of this odometry run that the map's alignment may
  /// confirm (MapLocalizationParams::confirm_tentative_by_alignment).
  bool tentativeToConfirm() const
  {
    return params.confirm_tentative_by_alignment && recentWithinWindow() &&
           recent_placement->tentative && recent_placement->odometry_run == odometry_run;
  }

  /// The map's alignment of this scan from the recent tentative placement, moved by
  /// the odometry to the scan (odometry pose \a T_odom_lidar)
  /// (MapLocalizationParams::confirm_tentative_by_alignment); nullopt when there is
  /// none to confirm or the map does not confirm it. \a how says what confirmed what,
  /// or why the map did not.
  std::optional<Alignment> confirmTentative(const std::function<const Source&()>& scan,
                                            const Pose3d& T_odom_lidar,
                                            std::string& how)
  {
    if (!tentativeToConfirm())
      return std::nullopt;
    const Pose3d moved =
        normalizedPose(recent_placement->T_world_lidar *
                       (recent_placement->T_odom_lidar.inverse() * T_odom_lidar));
    std::string why;
    std::optional<Alignment> a = alignToMap(scan, moved, why);
    if (!a)
      a = alignToNearestTogether(scan, moved, why);
    refuseUnconstrained(a, why); // what a tentative placement lacks is confirmation
    const std::size_t ago = frames - recent_placement->frame;
    if (!a) {
      how = "the tentative placement " + std::to_string(ago) +
            (ago == 1 ? " frame" : " frames") + " before not confirmed (" + why + ")";
    } else {
      char text[96];
      std::snprintf(text,
                    sizeof text,
                    " from the tentative placement %zu frames before "
                    "(%d points paired, rmse %.3f m)",
                    ago,
                    a->correspondences,
                    a->rmse_m);
      how = "aligned to " + a->target + text;
    }
    return a;
  }

  /// No alignment and no placement: carried on by the odometry, or given up.
  void carryOn(LocalizationFrame& f, const Pose3d& predicted, const std::string& why)
  {
    ++tracking_only;
    previous_confirmed = false;
    previous_together = false;
    f.T_world_lidar = predicted;
    T_world_previous = predicted;
    f.status = tracking_only > params.max_tracking_only_frames
                   ? LocalizationStatus::kLost
                   : LocalizationStatus::kTrackingOnly;
    f.message = why;
  }

  /// \a not_aligned: why the map did not confirm the prediction, if there was one.
  void takePlacement(LocalizationFrame& f,
                     const Placement& placement,
                     const std::optional<Pose3d>& predicted,
                     double dt,
                     const std::string& not_aligned)
  {
    f.status = LocalizationStatus::kLocalized;
    f.placed = true;
    f.T_world_lidar = placement.T_world_lidar;
    f.keyframe = placement.keyframe;
    f.message = placement.message;
    if (predicted) {
      if (!not_aligned.empty())
        f.message += "; the prediction was not confirmed (" + not_aligned + ")";
      f.jump_m =
          (placement.T_world_lidar.translation() - predicted->translation()).norm();
      f.jump = f.jump_m > params.jump_m;
      if (f.jump) {
        // Kidnapped: the odometry's local map is of another place, and the motion
        // since the last frame is unknown.
        odometry_stale = true;
        previous_confirmed = false;
        char text[64];
        std::snprintf(text, sizeof text, "jump of %.1f m: ", f.jump_m);
        f.message = text + f.message;
      }
    }
    recent_rmse.clear(); // residuals from here on are of this placement's place
    confirm(placement.T_world_lidar, dt);
  }
};

MapLocalization::MapLocalization(const SessionLocalizer& localizer,
                                 const OdometryParams& odometry,
                                 const MapLocalizationParams& params)
{
  std::string why;
  if (!params.isValid(&why))
    throw std::invalid_argument("MapLocalization: invalid parameters: " + why);
  impl_ = std::make_unique<Impl>(localizer, odometry, params);
}

MapLocalization::~MapLocalization() = default;

void
MapLocalization::setInitialPose(const Pose3d& T_world_lidar)
{
  if (impl_->started)
    throw std::logic_error("MapLocalization::setInitialPose after the first scan");
  if (!T_world_lidar.matrix().allFinite())
    throw std::invalid_argument(
        "MapLocalization::setInitialPose: the pose is not finite");
  impl_->T_world_previous = normalizedPose(T_world_lidar);
}

LocalizationFrame
MapLocalization::addScan(const pcl::PointCloud<pcl::PointXYZI>::ConstPtr& scan,
                         double timestamp_s,
                         std::size_t frame_index)
{
  return addScan(scan, timestamp_s, frame_index, {});
}

LocalizationFrame
MapLocalization::addScan(const pcl::PointCloud<pcl::PointXYZI>::ConstPtr& raw_scan,
                         double timestamp_s,
                         std::size_t frame_index,
                         const std::vector<float>& point_times_s)
{
  return impl_->add(raw_scan, timestamp_s, frame_index, point_times_s, nullptr);
}

LocalizationFrame
MapLocalization::addScan(const pcl::PointCloud<pcl::PointXYZI>::ConstPtr& raw_scan,
                         double timestamp_s,
                         std::size_t frame_index,
                         const std::vector<float>& point_times_s,
                         const OdometryInput& next)
{
  if (next.frame_index <= frame_index)
    throw std::invalid_argument("MapLocalization: the look-ahead scan's frame index " +
                                std::to_string(next.frame_index) +
                                " is not after this frame's " +
                                std::to_string(frame_index));
  return impl_->add(raw_scan, timestamp_s, frame_index, point_times_s, &next);
}

LocalizationFrame
MapLocalization::Impl::add(const pcl::PointCloud<pcl::PointXYZI>::ConstPtr& raw_scan,
                           double timestamp_s,
                           std::size_t frame_index,
                           const std::vector<float>& point_times_s,
                           const OdometryInput* next)
{
  FrameMotion motion;
  LocalizationFrame f =
      localize(raw_scan, timestamp_s, frame_index, point_times_s, next, motion);
  if (f.jump && raw_scan && !raw_scan->empty())
    jump_scan = JumpScan{raw_scan, timestamp_s, frame_index, point_times_s, frames};
  else
    jump_scan.reset();
  if (params.backtrack_frames == 0)
    return f;
  const pcl::StopWatch watch;
  if (f.status == LocalizationStatus::kLocalized) {
    if (f.placed && f.odometry_ran)
      backtrack(f, motion);
    unconfirmed.clear();
  } else if (f.odometry_ran && raw_scan && !raw_scan->empty()) {
    keepUnconfirmed(f, motion, raw_scan, point_times_s);
  } else {
    unconfirmed.clear(); // no odometry pose to move it by
  }
  f.time_ms += watch.getTime();
  return f;
}

LocalizationFrame
MapLocalization::Impl::localize(const pcl::PointCloud<pcl::PointXYZI>::ConstPtr& raw_scan,
                                double timestamp_s,
                                std::size_t frame_index,
                                const std::vector<float>& point_times_s,
                                const OdometryInput* next,
                                FrameMotion& motion)
{
  const pcl::StopWatch watch;
  Impl& m = *this;
  LocalizationFrame f = m.beginFrame(timestamp_s, frame_index);
  const double dt = m.interval(timestamp_s);
  const std::optional<Pose3d> velocity_step = m.velocityStep(dt);
  // The source of this scan the look-ahead prepared; the next scan's is prepared
  // meanwhile, when it will likely be aligned too.
  std::optional<Impl::AheadSource> ahead =
      m.takeAhead(raw_scan.get(), frame_index, m.last_timestamp_s);
  if (next && m.alignmentLikely())
    m.prepareAhead(*next, timestamp_s);

  // The frame's motion: from the map's velocity while the map tracks (the odometry
  // rests), else from the odometry (from the map's velocity for its first frame).
  Pose3d step = Pose3d::Identity();
  std::optional<OdometryFrameResult> odo;
  const auto track = [&] {
    const bool fresh = m.odometry_stale || !m.have_odom_previous;
    odo = m.runOdometry(raw_scan, timestamp_s, frame_index, point_times_s, next, step);
    if (fresh && velocity_step)
      step = *velocity_step;
    f.odometry_ran = true;
    f.odometry_prepared_ahead = odo->extracted_ahead;
    f.odometry_features_skipped = odo->features_skipped;
    motion.odometry_tracked = odo->status == TrackingStatus::kFeatures ||
                              odo->status == TrackingStatus::kDenseFallback;
  };
  const bool map_tracks = m.params.track_on_map && m.previous_confirmed &&
                          velocity_step && raw_scan && !raw_scan->empty();
  if (map_tracks) {
    step = *velocity_step;
    m.odometry_stale = true;
  } else {
    track();
  }
  // The map's key-frames were compensated: so is the scan aligned or placed on them,
  // with this step. Made when first needed: most frames off the map need none.
  const bool has_points = raw_scan && !raw_scan->empty();
  const Pose3d compensation_step = step;
  motion.dt = dt;
  motion.step = step;
  pcl::PointCloud<pcl::PointXYZI>::ConstPtr compensated_scan;
  const auto scan = [&]() -> const pcl::PointCloud<pcl::PointXYZI>::ConstPtr& {
    if (!compensated_scan)
      compensated_scan = m.compensated(raw_scan, point_times_s, dt, compensation_step);
    return compensated_scan;
  };
  // Its source for the map alignment, compensated with the same step.
  std::optional<Impl::Source> source;
  const std::function<const Impl::Source&()> alignment_source =
      [&]() -> const Impl::Source& {
    if (!source) {
      f.alignment_prepared_ahead = ahead.has_value();
      source = m.source(ahead, raw_scan, point_times_s, dt, compensation_step);
    }
    return *source;
  };
  m.last_timestamp_s = timestamp_s; // the next step starts from this frame's pose
  std::optional<Pose3d> predicted;
  if (m.T_world_previous)
    predicted = normalizedPose(*m.T_world_previous * step);
  m.travelled_m += step.translation().norm();

  std::string why;
  if (predicted && m.tracking_only >= m.params.max_realign_frames) {
    why =
        std::to_string(m.tracking_only) +
        " frames since the map last confirmed the pose: only a placement localizes again";
  } else if (predicted && has_points) {
    std::optional<Impl::Alignment> a = m.alignTracked(alignment_source, *predicted, why);
    if (odo)
      m.refuseWhereOdometryDegraded(a, *odo, why);
    if (a) {
      if (std::string worse = m.suddenlyWorse(a->rmse_m); !worse.empty()) {
        why = a->target + ": " + worse;
        a.reset();
      }
    }
    if (a) {
      m.recent_rmse.push_back(a->rmse_m);
      if (m.recent_rmse.size() > 10)
        m.recent_rmse.pop_front();
      f.status = LocalizationStatus::kLocalized;
      f.T_world_lidar = a->T_world_lidar;
      f.keyframe = a->keyframe;
      f.correspondences = a->correspondences;
      f.rmse_m = a->rmse_m;
      f.message = "aligned to " + a->target;
      if (a->degenerate_directions > 0)
        f.message += " (" + std::to_string(a->degenerate_directions) +
                     " direction(s) it does not constrain kept at the prediction)";
      m.failed_placements = 0;
      m.confirm(a->T_world_lidar, dt);
      m.previous_together = a->together;
      f.time_ms = watch.getTime();
      return f;
    }
  }
  // The map did not confirm the prediction (or there is none): the odometry carries
  // the pose from here, and the scan is placed anew with its features. Features the
  // odometry could not compensate yet (its first two frames) are computed again from
  // the compensated scan. A drive that left the map where it ends starts backed off.
  if (m.previous_confirmed && predicted && velocity_step &&
      m.params.placement_backoff_after > 0 && !m.backedOff() &&
      m.leavingMap(*predicted, *velocity_step)) {
    m.failed_placements = m.params.placement_backoff_after;
    why += "; no key-frame of the map ahead: leaving it, attempts backed off";
  }
  if (!odo)
    track();
  // A placement started in the background is taken once its lag has passed: recorded
  // for its own scan, as an attempt at once would have been, and moved to this one by
  // the odometry.
  std::string collected;
  if (m.pending &&
      m.frames - m.pending->frame >= static_cast<std::size_t>(m.pending->lag)) {
    Impl::Pending job = std::move(*m.pending);
    m.pending.reset();
    Placement p = job.result.get();
    const std::size_t ago = m.frames - job.frame;
    const std::string from = "in the background from the scan " + std::to_string(ago) +
                             (ago == 1 ? " frame" : " frames") + " before: ";
    // The odometry is the run that tracked its scan: it starts afresh only after a jump
    // or a frame the map confirmed, and both drop the attempt (confirm). An attempt
    // starts with no tentative placement in the window (placeInBackground), so there
    // is none for this one to agree with.
    {
      const Pose3d T_world_found = p.T_world_lidar;
      p.T_world_lidar = normalizedPose(T_world_found *
                                       (job.T_odom_lidar.inverse() * odo->T_world_lidar));
      p.message = from + p.message;
      if (p.success || p.tentative)
        m.recent_placement = Impl::Recent{
            T_world_found, job.T_odom_lidar, m.odometry_run, job.frame, !p.success};
      m.failed_placements = p.success ? 0 : m.failed_placements + 1;
      if (p.success) {
        m.takePlacement(f, p, predicted, dt, why);
        f.time_ms = watch.getTime();
        return f;
      }
      collected = p.message;
    }
  }
  // A recent tentative placement that this scan's alignment to the map confirms.
  std::string how;
  if (const std::optional<Impl::Alignment> a =
          has_points && m.tentativeToConfirm()
              ? m.confirmTentative(alignment_source, odo->T_world_lidar, how)
              : std::nullopt) {
    Placement confirmed;
    confirmed.success = true;
    confirmed.T_world_lidar = a->T_world_lidar;
    confirmed.keyframe = a->keyframe;
    confirmed.message = how;
    m.failed_placements = 0;
    m.recent_placement.reset();
    m.takePlacement(f, confirmed, predicted, dt, why);
    m.recent_rmse.push_back(a->rmse_m);
    f.correspondences = a->correspondences;
    f.rmse_m = a->rmse_m;
    f.time_ms = watch.getTime();
    return f;
  }
  Placement placement;
  bool started_in_background = false;
  const std::optional<PlacementPrior> prior = m.placementPrior(predicted);
  const std::optional<double> far_m =
      m.backedOff() ? m.farFromMap(predicted)
                    : std::nullopt; // only the back-off's schedule depends on it
  const bool far = far_m.has_value();
  m.far_now = far;
  // The candidates' neighbourhoods are verified unless the back-off found the
  // prediction far from the map: there a placement is unlikely, and on every attempt
  // they cost a run that starts off the map 30 % of its frame rate (simulated;
  // doc/session.md, session 47).
  PlacementOptions options;
  options.neighbourhoods = !far;
  // A start or a relocalization waits for its first attempts: more neighbours there,
  // and the key-frames the polar descriptor finds (off the map, later attempts would
  // only pay for them).
  options.polar_candidates = m.failed_placements < m.params.first_attempts;
  if (options.polar_candidates)
    options.min_neighbourhood_keyframes = m.params.first_attempts_neighbourhood_keyframes;
  // Features the odometry did not make (features_on_demand) come from the scan itself.
  const bool no_features = !odo->features || odo->features->empty();
  if (!has_points || (no_features && !odo->features_skipped)) {
    placement.message = "no features: " + odo->message;
  } else if (!m.placementDue(far)) {
    placement.message = !collected.empty()
                            ? collected
                            : "not tried: " + std::to_string(m.failed_placements) +
                                  " failed placements in a row, one every " +
                                  std::to_string(m.placementEvery(far)) + " frames" +
                                  farNote(far_m);
  } else if (m.placeInBackground(far)) {
    // The odometry goes on with the next frames meanwhile (the query is a copy).
    f.placement_tried = true;
    f.placement_with_neighbourhoods = options.neighbourhoods;
    KeyFrame query;
    const bool own_features = (scan() != raw_scan && !odo->deskew_applied) || no_features;
    if (!own_features)
      query.features = *odo->features;
    query.cloud = scan();
    const SessionLocalizer& localizer = m.localizer;
    m.pending = Impl::Pending{
        std::async(std::launch::async,
                   [&localizer, own_features, prior, options, query = std::move(query)] {
                     return own_features
                                ? placeWithPrior(localizer, query.cloud, prior, options)
                                : placeWithPrior(localizer, query, prior, options);
                   }),
        odo->T_world_lidar,
        m.frames,
        m.placementLag(far)};
    m.last_attempt_frame = m.frames;
    const int lag = m.placementLag(far);
    placement.message = "started in the background, taken " + std::to_string(lag) +
                        (lag == 1 ? " frame" : " frames") + " later" + farNote(far_m);
    if (!collected.empty()) // the one taken this frame placed nothing
      placement.message = collected + "; another " + placement.message;
    started_in_background = true;
  } else {
    f.placement_tried = true;
    f.placement_with_neighbourhoods = options.neighbourhoods;
    if ((scan() != raw_scan && !odo->deskew_applied) || no_features) {
      placement = placeWithPrior(m.localizer, scan(), prior, options);
    } else {
      KeyFrame query;
      query.features = *odo->features;
      query.cloud = scan();
      placement = placeWithPrior(m.localizer, query, prior, options);
    }
    m.last_attempt_frame = m.frames;
  }
  // A tentative placement is taken when an earlier scan's placement agrees with it.
  std::string agreement;
  if (placement.tentative && m.params.tentative_window_frames > 0 &&
      m.agreesWithRecent(placement, odo->T_world_lidar, agreement)) {
    placement.success = true;
    placement.message = agreement + placement.message;
  }
  if (placement.success || placement.tentative)
    m.recent_placement = Impl::Recent{placement.T_world_lidar,
                                      odo->T_world_lidar,
                                      m.odometry_run,
                                      m.frames,
                                      !placement.success};
  if (f.placement_tried && !started_in_background) // that one counts when it is taken
    m.failed_placements = placement.success ? 0 : m.failed_placements + 1;
  if (placement.success)
    m.takePlacement(f, placement, predicted, dt, why);
  else if (predicted)
    m.carryOn(f,
              *predicted,
              "not confirmed (" + why + "); not placed (" + placement.message + ")" +
                  (how.empty() ? "" : "; " + how));
  else
    f.message = "not placed: " + placement.message + (how.empty() ? "" : "; " + how);
  f.time_ms = watch.getTime();
  return f;
}

LocalizationFrame
MapLocalization::addSkippedScan(double timestamp_s,
                                std::size_t frame_index,
                                const std::string& reason)
{
  Impl& m = *impl_;
  LocalizationFrame f = m.beginFrame(timestamp_s, frame_index);
  // The odometry predicts the skipped frame; after resting it has nothing to predict
  // from, and the map's velocity does.
  const double dt = m.interval(timestamp_s);
  Pose3d step = Pose3d::Identity();
  if (m.odometry_stale || !m.have_odom_previous) {
    step = m.velocityStep(dt).value_or(Pose3d::Identity());
  } else {
    step = m.odometryStep(m.odometry->skipFrame(timestamp_s, frame_index, reason));
    f.odometry_ran = true;
  }
  m.last_timestamp_s = timestamp_s;
  m.travelled_m += step.translation().norm();
  m.unconfirmed.clear(); // no scan to align: a later placement goes back to here only
  if (m.T_world_previous)
    m.carryOn(f, normalizedPose(*m.T_world_previous * step), "skipped: " + reason);
  else
    f.message = "skipped: " + reason;
  return f;
}

} // namespace rast
} // namespace pcl
