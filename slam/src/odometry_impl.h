#pragma once
/// \file odometry_impl.h
/// \brief Internal to the odometry: Odometry::Impl, the state tracking keeps between
/// frames, and the helpers its two files share (odometry.cpp: parameters, prediction,
/// key-frames, motion compensation; odometry_tracking.cpp: the tracking steps). Not
/// installed.

#include "elevation_calibration.h"
#include "odometry_local_map.h"
#include "stage_util.h"
#include "work_queue.h"

#include <functional>
#include <future>
#include <memory>
#include <optional>
#include <pcl/features/orb_raster_features.h>
#include <pcl/registration/rigid_ransac.h>
#include <pcl/segmentation/sac_ground_removal.h>
#include <pcl/slam/deskew.h>
#include <pcl/slam/odometry.h>
#include <string>
#include <thread>
#include <utility>
#include <vector>

namespace pcl {
namespace rast {

using odometry_detail::DenseOptions;
using odometry_detail::DenseResult;
using odometry_detail::denseSeparation;
using odometry_detail::Points3f;
using odometry_detail::VoxelPlaneMap;

namespace odometry_detail {

inline double
angleDeg(const Pose3d& T)
{
  return Eigen::AngleAxisd(T.rotation()).angle() * 180.0 / M_PI;
}

/// The dense step's figures of the fit a frame's pose comes from.
inline void
keepDenseStats(const DenseResult& dense, OdometryFrameResult& result)
{
  result.dense_correspondences = dense.num_correspondences;
  result.dense_degenerate_directions = dense.degenerate_directions;
  result.dense_rmse_m = dense.rmse_m;
}

/// Whether \a a and \a b differ by more than \a metres or \a degrees.
inline bool
moved(const Pose3d& a, const Pose3d& b, double metres, double degrees)
{
  const Pose3d d = a.inverse() * b;
  return d.translation().norm() > metres || angleDeg(d) > degrees;
}

/// The moving-in test (visibility_margin_m) leaves points lower than this above the
/// scan's ground plane alone: the visibility image holds no ground, and near it a
/// point's surface may be ground in one scan and not in the next.
constexpr float kMinHeightAboveGroundM = 0.5f;

/// After this many frames without feature or dense tracking, a frame with features
/// becomes a key-frame anyway (re-anchoring, flagged), so that tracking recovers after
/// a featureless stretch instead of comparing forever against a stale key-frame.
constexpr int kReanchorAfterFrames = 3;

/// Dense ICP from the prior (no feature support) is accepted only when at least this
/// fraction of the source points pairs with map planes (well-tracked frames: 0.8-0.95).
constexpr double kMinFallbackPairedRatio = 0.6;
/// A frame tracked without features (Odometry::setFeaturesWanted) needs a dense step
/// that converged and constrains its weakest direction with at least this share of the
/// weight: from a prior a few decimetres off, a weaker direction kept the prior's error
/// (a simulated figure eight: 0.4 m a frame at 0.005-0.04 of the weight). Chosen on
/// the simulated tuning seed 42 among 0.01, 0.02 and 0.05 (doc/odometry.md, "Features
/// on demand").
constexpr double kDenseOnlyMinWeakestRatio = 0.02;
/// Such a frame becomes a key-frame by the paper's rule after this many times
/// keyframe_min_frames (or by the distance and rotation rules): its key-frame's features
/// serve only the frames that track by features, and the local map takes a scan with
/// each key-frame. Chosen on the simulated tuning seed 42 among 1, 2 and 3
/// (doc/odometry.md).
constexpr int kDenseOnlyKeyframeFactor = 2;
/// ... or fewer when the optimum is distinct: it pairs at least kDistinctPairsFactor
/// times as many points as any hypothesis that ended elsewhere. Little overlap with the
/// map is normal after a large motion against a single key-frame (cold start at 4 m per
/// scan: 33-60 % paired), while a wrong start settling on the ground plane is never
/// distinct: the ground pairs about as many points from anywhere.
constexpr double kDistinctPairsFactor = 1.25;
/// ... but never below this fraction.
constexpr double kMinDistinctPairedRatio = 0.2;

/// A cold start's motion solved with the first scan and the second both compensated by
/// it (solveColdStartMotion): at most this many rounds, done when a round moves the pose
/// less than kColdStartConvergedM.
constexpr int kColdStartRounds = 4;
constexpr double kColdStartConvergedM = 0.01;
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

inline int
inliersOf(const RigidRansacResult& fit)
{
  return fit.success ? static_cast<int>(fit.inlier_indices.size()) : 0;
}

/// The motion from \a T_world_last with the features' planar part (x, y, yaw in the
/// last scan's frame, which top-down raster features measure well) and the prior's
/// height, roll and pitch (which max-height pixels of few inliers do not).
Pose3d planarFromFeatures(const Pose3d& T_world_last,
                          const Pose3d& T_world_features,
                          const Pose3d& T_world_prior);

} // namespace odometry_detail

struct Odometry::Impl
{
  explicit Impl(const OdometryParams& p)
      : params(p), front_end(p), front_end_ahead(p), local_map(p.dense)
  {
    if (p.elevation_calibration.enabled)
      elevation = std::make_unique<odometry_detail::ElevationCalibration>(
          p.elevation_calibration);
  }

  /// The stateless extractors of steps 1-3: one for the frames prepared in order, one
  /// for the look-ahead's thread (the two run at the same time).
  struct FrontEnd
  {
    explicit FrontEnd(const OdometryParams& p) : ground(p.ground)
    {
      orb.setParams(p.orb);
      orb.setRasterParams(p.raster);
    }
    SACGroundRemoval<pcl::PointXYZI> ground;
    OrbRasterFeatureEstimator<pcl::PointXYZI> orb;
  };

  const OdometryParams params;
  FrontEnd front_end, front_end_ahead;
  /// Odometry::setFeaturesWanted: false lets a frame the dense step tracks alone skip
  /// its features.
  bool features_wanted = true;
  /// The local map: read through localMap(), which waits for an insertion running.
  VoxelPlaneMap local_map;
  /// The beams' elevation self-calibration (params.elevation_calibration); null when off.
  std::unique_ptr<odometry_detail::ElevationCalibration> elevation;
  int map_scans = 0; ///< scans inserted into the map so far
  /// A scan's insertion into local_map running on map_thread (insertIntoMap).
  mutable std::future<void> map_insertion;
  /// The local map once the insertion running (if any) has finished.
  VoxelPlaneMap& localMap()
  {
    finishMapInsertion();
    return local_map;
  }
  const VoxelPlaneMap& localMap() const
  {
    finishMapInsertion();
    return local_map;
  }
  /// Waits for the insertion running, if any; its exception, if it threw, is thrown
  /// here.
  void finishMapInsertion() const
  {
    if (map_insertion.valid())
      std::exchange(map_insertion, {}).get();
  }
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
  odometry_detail::VisibilityImage keyframe_image; ///< the key-frame's Frame::image
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
  /// Frames since velocity_tracked was last true (0: it is now); -1: never yet. A
  /// velocity carried over a frame or two (a constant-velocity frame in a tunnel)
  /// still bounds the motion, with a gate that widens with its age (priorGate).
  int velocity_age_frames = -1;
  /// The last frame's pose came from the prior's fit over strong features
  /// (check_strong_features); the next frame's features are not checked again.
  bool prior_overruled_features = false;
  /// Frames tracked without features since a frame whose features failed the
  /// consistency check (OdometryParams::failed_features_skip_frames); -1: the last
  /// frame that made them passed it, or none did yet.
  int frames_since_failed_features = -1;

  Pose3d predict(double timestamp_s) const;
  /// Seconds since the last frame (timestamps scaled by deskew.seconds_per_timestamp).
  double frameInterval(double timestamp_s) const { return interval(t_last, timestamp_s); }
  /// Seconds from \a t0 to \a t1 (scaled timestamps); 0.1 when not positive or not
  /// finite, at most 5.
  double interval(double t0, double t1) const;
  void checkIndex(std::size_t frame_index);
  void commitPose(const OdometryFrameResult& result);
  OdometryFrameResult
  skip(double timestamp_s, std::size_t frame_index, const std::string& reason);
  /// The motion a scan's compensation assumes before it is tracked (sweepMotion).
  struct SweepMotion
  {
    double dt = 0.1; ///< the scan's frame interval [s] (the azimuth times' period)
    std::optional<Twist> xi;              ///< none before the run has two poses
    Pose3d T_motion = Pose3d::Identity(); ///< the prior's motion over dt
  };
  /// For a scan at \a timestamp_s, from the last two poses: the prior's motion.
  SweepMotion sweepMotion(double timestamp_s) const;

  /// Everything the steps of one frame's tracking share.
  struct Frame
  {
    /// \a cloud as the sensor placed it, \a corrected by the elevation calibration (or
    /// null: the same).
    Frame(const pcl::PointCloud<pcl::PointXYZI>::ConstPtr& cloud,
          const pcl::PointCloud<pcl::PointXYZI>::ConstPtr& corrected)
        : raw_ptr(cloud), input_ptr(corrected ? corrected : cloud), input(*input_ptr)
    {}
    const pcl::StopWatch watch; ///< since the frame came in
    /// The scan as given: its points' elevation tells their beam (ElevationCalibration).
    pcl::PointCloud<pcl::PointXYZI>::ConstPtr raw_ptr;
    /// The scan every step uses: the elevation-corrected one.
    pcl::PointCloud<pcl::PointXYZI>::ConstPtr input_ptr;
    const pcl::PointCloud<pcl::PointXYZI>& input;
    /// The correction it was made with (null: none).
    std::shared_ptr<const odometry_detail::ElevationTable> elevation_table;
    /// Enough finite points within the range limits (else the frame is skipped).
    bool usable = true;
    /// Why the point times given were not used (empty: they were, or none were given).
    std::string times_message;
    /// The point times, when the frame keeps its own copy (prepared ahead: the
    /// caller's outlive only the call).
    std::vector<float> own_times;
    Pose3d T_world_prior = Pose3d::Identity();        ///< constant-velocity prediction
    double dt = 0.1;                                  ///< frameInterval [s]
    std::optional<odometry_detail::PointTimes> times; ///< for the motion compensation
    std::optional<Twist> xi_sweep; ///< the motion the kept points are compensated with
    /// The motion the first compensation assumed over the frame (the second pass
    /// compares the estimate with it).
    Pose3d T_motion_deskew = Pose3d::Identity();
    std::shared_ptr<RasterFeatureSet> features;
    std::vector<int> source_indices; ///< the dense step's source points ...
    Points3f source;                 ///< ... compensated
    pcl::PointCloud<pcl::PointXYZI>::ConstPtr kept_cloud; ///< see keptCloud
    /// The prior's fit overruled strong features in the frame before (trackDense).
    bool prior_overruled_before = false;
    /// The compensated non-ground points' visibility image (visibility_margin_m > 0) ...
    odometry_detail::VisibilityImage image;
    /// ... and whether the prior is tight enough to test against it (useVisibility).
    bool check_visibility = false;
    /// The scan's ground plane (normal up); zero without a ground.
    Eigen::Vector4f ground_plane = Eigen::Vector4f::Zero();
    /// Step 1: the points off the ground, and the levelling of the sensor's tilt.
    pcl::Indices non_ground_indices;
    Eigen::Isometry3f T_level_lidar = Eigen::Isometry3f::Identity();
    /// Steps 2-3 are done (the non-ground points compensated, the features).
    bool extracted = false;
    /// The caller wants no features (setFeaturesWanted): the dense step alone is tried
    /// first, and steps 2-3, unless made ahead, are made by ensureFeatures with this
    /// front end only if the frame needs them after all.
    FrontEnd* deferred_front = nullptr;
  };
  /// The outcome of trackFeatures.
  struct FeatureTrack
  {
    bool ok = false; ///< passed the feature-consistency check
    RigidRansacResult ransac;
    Pose3d T_world_features = Pose3d::Identity();
    std::string reference = "the key-frame"; ///< what the features were matched with
    /// Estimates too weak for the check: starts for the hypothesis search.
    std::vector<Pose3d> weak_estimates;
  };

  /// A frame whose steps 0-1 (and maybe 2-3) are done (prepare), with the result they
  /// began.
  struct Prepared
  {
    std::unique_ptr<Frame> frame;
    OdometryFrameResult result;
  };
  /// processFrame: \a next (may be null) is prepared on a second thread meanwhile.
  OdometryFrameResult process(const pcl::PointCloud<pcl::PointXYZI>::ConstPtr& cloud,
                              double timestamp_s,
                              std::size_t frame_index,
                              const std::vector<float>& point_times,
                              const OdometryInput* next);
  /// Starts preparing \a next on ahead_thread (the frame at \a timestamp_s being the one
  /// before it).
  void launchAhead(const OdometryInput& next, double timestamp_s);
  /// Steps 0-1 of a scan (range check, point times, ground removal), then, with
  /// \a motion or when the scan has no times to compensate, steps 2-3 (finishPrepare). No
  /// state of the tracking is read or written (only \a front and params): the look-ahead
  /// runs it on its thread. Without \a features, steps 2-3 wait for the caller
  /// (process). \a point_times are checked here (unusable ones are ignored);
  /// with \a keep_times the frame keeps a copy of them, else they must outlive the frame.
  /// \a frame_interval_s is the period of azimuth times. The scan is first corrected
  /// by \a elevation_table (null: none).
  Prepared
  prepare(FrontEnd& front,
          const pcl::PointCloud<pcl::PointXYZI>::ConstPtr& input,
          const std::shared_ptr<const odometry_detail::ElevationTable>& elevation_table,
          const std::vector<float>& point_times,
          bool keep_times,
          double frame_interval_s,
          const SweepMotion* motion,
          OdometryFrameResult result,
          bool features) const;
  /// Steps 2-3 of a prepared frame: the non-ground points compensated with \a motion
  /// (when the scan has times and the motion a velocity), the raster, ORB. (The dense
  /// step's source points are chosen and compensated on the caller's thread: process.)
  void finishPrepare(FrontEnd& front,
                     Frame& frame,
                     OdometryFrameResult& result,
                     const SweepMotion* motion) const;
  /// The compensation's motion of a prepared frame (the part of finishPrepare before
  /// its features).
  static void
  applySweepMotion(Frame& frame, OdometryFrameResult& result, const SweepMotion* motion);
  /// Steps 2-3 of a frame that deferred them, now (or the features made ahead, back in
  /// the result).
  void ensureFeatures(Frame& frame, OdometryFrameResult& result) const;
  /// One prepared frame, the steps below in order (odometry_tracking.cpp).
  OdometryFrameResult track(Frame& frame, OdometryFrameResult result);
  /// Step 4-5 without features (setFeaturesWanted false): the dense step from the
  /// prior, taken when it pairs most points, constrains every direction and stays near
  /// the prior. Returns whether it was taken (else nothing of the result changed).
  bool trackDenseOnly(const Frame& frame, OdometryFrameResult& result) const;
  /// Step 1: ground removal (and the levelling transform).
  void removeGround(FrontEnd& front, Frame& frame, OdometryFrameResult& result) const;
  /// Steps 2-3: raster of the (compensated, levelled) non-ground points, ORB.
  void extractFeatures(FrontEnd& front, Frame& frame, OdometryFrameResult& result) const;
  /// Step 4: match the key-frame (else the previous frame, else nearest neighbours) and
  /// rigid RANSAC.
  FeatureTrack trackFeatures(const Frame& frame, OdometryFrameResult& result) const;
  RigidRansacResult fitFeatures(const Frame& frame,
                                const RasterFeatureSet& target,
                                const pcl::Correspondences& matches) const;
  /// The dense step's source points: voxelized and subsampled (indices) ...
  void selectDenseSource(Frame& frame) const;
  /// ... then copied, compensated.
  void makeDenseSource(Frame& frame, OdometryFrameResult& result) const;
  /// The source points that moved in, dropped (visibility_margin_m; track).
  void dropMovedIn(Frame& frame, OdometryFrameResult& result) const;
  /// Step 5 with features: dense refinement from their estimate, anchored to them
  /// (strong, unless far from the prior where the scan is degenerate) or to the prior
  /// (weak), and the two cross-checks.
  /// Returns whether the prior's fit overruled strong features (check_strong_features).
  bool trackDense(const Frame& frame,
                  const FeatureTrack& track,
                  OdometryFrameResult& result) const;
  /// The gates of nearPrior for \a frame: OdometryParams::prior_gate_m / _deg, shrunk
  /// to what a vehicle can deviate from a tracked velocity within the frame interval.
  struct PriorGate
  {
    double metres, degrees;
    bool dynamics; ///< shrunk: beyond it the motion is implausible, not just large
  };
  PriorGate priorGate(const Frame& frame) const;
  /// dt^2 (1 + k) for \a frame, a velocity measured k frames ago: times an acceleration,
  /// how far the vehicle may have left that velocity by now (the gates above, and
  /// keepPriorHeight's).
  double velocityAgeDt2(const Frame& frame) const
  {
    return frame.dt * frame.dt * (1.0 + velocity_age_frames);
  }
  /// After constant-velocity frames (velocity_age_frames >= 1), outside
  /// prior_gate_vertical_accel_mps2's gate above or below the frame's prior: the prior's
  /// height, roll and pitch replace the result's, its x, y and yaw stay, and it is
  /// flagged degraded.
  void keepPriorHeight(const Frame& frame, OdometryFrameResult& result) const;
  /// Within \a gate of the frame's constant-velocity prior.
  static bool
  withinGate(const Frame& frame, const Pose3d& T_world_lidar, const PriorGate& gate);
  /// Within priorGate(frame) of the frame's constant-velocity prior.
  bool nearPrior(const Frame& frame, const Pose3d& T_world_lidar) const
  {
    return withinGate(frame, T_world_lidar, priorGate(frame));
  }
  /// The moving-object tests (visibility_margin_m) place points by the prior: only with
  /// a velocity tracked up to the last frame where the gates shrink (decimetres).
  bool useVisibility(const Frame& frame) const
  {
    return params.visibility_margin_m > 0.0 && velocity_tracked && !frame.image.empty() &&
           priorGate(frame).dynamics;
  }
  /// Dense options anchored to the frame's prior (degenerate directions take its
  /// value), pulled toward it by dense_prior_ratio where priorGate(frame).dynamics.
  DenseOptions priorAnchored(const Frame& frame) const
  {
    const PriorGate gate = priorGate(frame);
    return {0.0,
            &frame.T_world_prior,
            gate.dynamics ? params.dense_prior_ratio : 0.0,
            gate.metres,
            gate.degrees};
  }
  /// priorAnchored for weak features: within priorGate(frame) of a tracked prior the
  /// anchor is moved OdometryParams::weak_feature_share of the way to their planar
  /// motion, into \a T_world_anchor (which the options point to).
  DenseOptions weakAnchored(const Frame& frame,
                            const FeatureTrack& track,
                            Pose3d& T_world_anchor) const;
  /// Weak features: a second dense fit from their planar part or the prior, and the
  /// prior's fit where the scan cannot tell it from theirs; \a anchored from
  /// weakAnchored.
  void checkWeakFeatures(const Frame& frame,
                         const FeatureTrack& track,
                         const DenseOptions& anchored,
                         DenseResult& dense,
                         OdometryFrameResult& result) const;
  /// Step 5 without features: dense ICP from motion hypotheses, accepted when well
  /// paired, distinct or backed by features; else the prior.
  void searchHypotheses(const Frame& frame,
                        const FeatureTrack& track,
                        OdometryFrameResult& result) const;
  /// After the search, with a tracked velocity: dense ICP from the prior wins where it
  /// pairs nearly as well as \a dense or the scan cannot tell the two apart.
  void keepPriorWhereIndistinct(const DenseResult& dense,
                                const DenseResult& prior_dense,
                                OdometryFrameResult& result) const;
  /// The hypothesis search's result re-fitted from features matched under it, when more
  /// features pair after (a message part, empty when not).
  std::string refitFromGuidedFeatures(const Frame& frame,
                                      DenseResult& dense,
                                      int& dense_guided_pairs) const;
  /// Features matched with the key-frame's under a motion: within \a gate_m of where it
  /// puts them, nearest descriptor, no ratio test.
  pcl::Correspondences
  guidedMatches(const Frame& frame, const Pose3d& T_world_lidar, double gate_m) const;
  int guidedPairs(const Frame& frame, const Pose3d& T_world_lidar) const;
  bool canGuide(const Frame& frame) const;
  /// Step 6: the key-frame decision, the young map, the previous-frame reference.
  void decideKeyFrame(Frame& frame, OdometryFrameResult& result);
  /// The whole compensated scan, made once and only when a key-frame or the map keeps it.
  const pcl::PointCloud<pcl::PointXYZI>& keptCloud(Frame& frame,
                                                   OdometryFrameResult& result) const;
  /// Step 5b of track: where the estimated motion differs from the previous frame's (a
  /// stop, a start, a turn), the dense step's source points are compensated with it and
  /// refined once more from the estimate. When that is kept, \a xi_sweep becomes the
  /// twist the scan is compensated with (key-frame, young map).
  void secondDeskewPass(const pcl::PointCloud<pcl::PointXYZI>& input,
                        const odometry_detail::PointTimes& times,
                        const std::vector<int>& source_indices,
                        double dt,
                        const Pose3d& T_motion_prior,
                        OdometryFrameResult& result,
                        Twist& xi_sweep);
  /// The points \a indices of \a input compensated with \a xi (params.deskew.bins).
  pcl::PointCloud<pcl::PointXYZI>::Ptr
  deskewIndices(const pcl::PointCloud<pcl::PointXYZI>& input,
                const odometry_detail::PointTimes& times,
                const pcl::Indices& indices,
                const Twist& xi) const;
  /// Step 5d of track: the scan that started the map was used as it was (no motion
  /// before it). Once the next frame's motion is known, the local map is rebuilt from
  /// that scan compensated with it (the key-frame's own stored cloud stays as it was).
  void rebuildMapFromFirstScan(OdometryFrameResult& result);
  /// Seconds from the first scan to \a timestamp_s, when the first scan's motion can
  /// be told from it (more than 1 us, less than 1 s); else none.
  std::optional<double> sinceFirstScan(double timestamp_s) const;
  /// Step 5d of track, before 5e (rebuildMapFromFirstScan): the second scan of a run
  /// whose motion neither features nor the dense step measured (the constant-velocity
  /// branch). With no frame before, that branch had no motion to predict, and the
  /// first scan in the map is as distorted as this one. Both are compensated with the
  /// motion estimate and this scan is aligned again, until the motion stops moving;
  /// a converged result is taken as a dense fallback.
  void solveColdStartMotion(const Frame& frame, OdometryFrameResult& result) const;
  /// The times to compensate \a input with (params.deskew): the given ones (processFrame
  /// passes only usable ones), times from the azimuth, or none.
  std::optional<odometry_detail::PointTimes>
  sweepTimes(const pcl::PointCloud<pcl::PointXYZI>& input,
             const std::vector<float>& given,
             double frame_interval_s,
             std::string& source) const;
  KeyFrame::Ptr makeKeyFrame(const OdometryFrameResult& result,
                             const RasterFeatureSet& features,
                             const pcl::PointCloud<pcl::PointXYZI>::ConstPtr& cloud);
  /// \a cloud into the local map at \a T_world_lidar, on map_thread: the next frame's
  /// front end runs meanwhile and waits for it where it reads the map (localMap()).
  void insertIntoMap(const pcl::PointCloud<pcl::PointXYZI>::ConstPtr& cloud,
                     const Pose3d& T_world_lidar);
  /// insertIntoMap's work, on the calling thread.
  void insertNow(const pcl::PointCloud<pcl::PointXYZI>& cloud,
                 const Pose3d& T_world_lidar);
  /// A scan's points into \a map as the local map takes them (voxelized at a quarter
  /// of its voxel, in range).
  void insertScan(const pcl::PointCloud<pcl::PointXYZI>& cloud,
                  const Pose3d& T_world_lidar,
                  VoxelPlaneMap& map) const;
  /// The whole compensated scan as keptCloud() makes it, shared.
  const pcl::PointCloud<pcl::PointXYZI>::ConstPtr&
  keptCloudPtr(Frame& frame, OdometryFrameResult& result) const
  {
    keptCloud(frame, result);
    return frame.kept_cloud;
  }

  /// The look-ahead's scan being prepared on its thread (front_end_ahead).
  struct Ahead
  {
    /// The scan it is for, as the next call must give it ...
    const pcl::PointCloud<pcl::PointXYZI>* cloud = nullptr;
    std::size_t frame_index = 0;
    double timestamp_s = 0.0;
    /// ... right after the frame at this time (its interval is the period of azimuth
    /// times): a skipFrame between drops it.
    double after_s = 0.0;
    std::future<Prepared> job;
  };
  std::optional<Ahead> ahead;
  /// \a work on the search thread (started by its first use and kept); an invalid
  /// future when no thread can be had, and then nothing runs.
  std::future<void> onSearchThread(std::function<void()> work) const;
  /// The dense search's thread (MotionHypothesisParams::threads).
  mutable std::unique_ptr<slam_detail::TaskThread<void>> search_thread;
  /// The local map's insertions (insertIntoMap), started by the first and kept.
  std::unique_ptr<slam_detail::TaskThread<void>> map_thread;
  /// The look-ahead's thread, started by the first look-ahead and kept: a thread
  /// started per scan began about 1.4 ms late (measured in bench_front_end), on the
  /// core of the thread that started it. Last member: destroyed first, its thread
  /// joined before anything it uses goes (the search thread just before it).
  std::unique_ptr<slam_detail::TaskThread<Prepared>> ahead_thread;
};

} // namespace rast
} // namespace pcl
