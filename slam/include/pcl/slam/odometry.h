#pragma once
/// \file odometry.h
/// \brief The tracking stage (the paper's sections 4-7): ground removal, raster, ORB,
/// feature registration against the last key-frame with a constant-velocity prior,
/// dense point-to-plane refinement, the feature-consistency check with fallbacks, and
/// the key-frame decision.
/// \ingroup slam
///
/// Poses are in the odometry world frame (the first scan's LiDAR frame). The back end
/// (local BA, loop closure) never moves this frame: it corrects key-frame poses, and a
/// frame's corrected pose is T_world_keyframe(corrected) * T_keyframe_lidar.

#include <cstddef>
#include <memory>
#include <pcl/features/orb_raster_features.h>
#include <pcl/features/range_raster_image.h>
#include <pcl/point_cloud.h>
#include <pcl/point_types.h>
#include <pcl/rast/rigid_pose.h>
#include <pcl/registration/correspondence_rigid_registration.h>
#include <pcl/segmentation/sac_ground_removal.h>
#include <pcl/slam/deskew.h>
#include <pcl/slam/keyframe.h>
#include <string>
#include <utility>
#include <vector>

namespace pcl {
namespace rast {

/// \brief How a frame's pose was obtained.
enum class TrackingStatus
{
  kFirstFrame,       ///< the first frame: identity, becomes key-frame 0
  kFeatures,         ///< ORB feature registration (+ dense refinement) succeeded
  kDenseFallback,    ///< too few consistent features: dense ICP from the motion prior
  kConstantVelocity, ///< features and dense ICP failed: constant-velocity prediction
  kSkipped           ///< no usable scan (unreadable, empty): constant-velocity prediction
};

/// \brief Short name of a status ("features", "dense_fallback", ...).
const char* toString(TrackingStatus status);

/// \brief Wall time of each stage of one frame, milliseconds.
struct OdometryTimings
{
  double ground_ms = 0.0;   ///< SAC ground removal (and levelling)
  double raster_ms = 0.0;   ///< rasterization
  double orb_ms = 0.0;      ///< ORB extraction
  double match_ms = 0.0;    ///< matching + RANSAC + pose from correspondences
  double refine_ms = 0.0;   ///< dense point-to-plane refinement
  double keyframe_ms = 0.0; ///< key-frame decision and local-map update
  double deskew_ms = 0.0;   ///< motion compensation (both passes)
  double visibility_ms = 0.0; ///< moving objects: visibility image, hidden map voxels
  double elevation_ms = 0.0;  ///< the beams' elevation correction (and its estimate)
  /// The whole frame on the caller's thread (what a look-ahead prepared on its own
  /// thread is not in it; OdometryFrameResult::extracted_ahead).
  double total_ms = 0.0;
};

/// \brief The outcome of tracking one frame.
struct OdometryFrameResult
{
  std::size_t frame_index = 0;
  double timestamp_s = 0.0;
  TrackingStatus status = TrackingStatus::kSkipped;
  /// True when the pose is less trustworthy than usual (any fallback or skip).
  bool degraded = false;
  std::string message;

  /// Pose of the scan in the odometry world frame.
  Pose3d T_world_lidar = Pose3d::Identity();
  /// The key-frame this frame was tracked against and the pose relative to it, so
  /// that the back end's corrections carry over: T_world_lidar = T_world_kf * T_kf_lidar.
  KeyFrameId reference_keyframe = 0;
  Pose3d T_keyframe_lidar = Pose3d::Identity();

  /// Non-null when this frame became a key-frame (then reference_keyframe is its id).
  KeyFrame::Ptr keyframe;

  /// This frame's ORB features in its LiDAR frame (null when the scan was skipped
  /// before feature extraction): for a placement on a map, say, without computing them
  /// again. A key-frame holds its own copy.
  std::shared_ptr<const RasterFeatureSet> features;

  bool ground_found = false;
  int num_features = 0; ///< ORB features of this frame
  int num_matches = 0;  ///< descriptor matches with the reference key-frame
  int num_inliers = 0;  ///< RANSAC inliers: "points in common" with the key-frame
  bool refined = false; ///< the dense refinement ran and was used
  int dense_correspondences = 0; ///< source points paired with map planes (last run)
  int dense_degenerate_directions = 0; ///< unconstrained directions of the dense step
  double dense_rmse_m = 0.0;           ///< RMS point-to-plane residual of the dense step
  /// Moving objects (OdometryParams::visibility_margin_m): local-map voxels this scan
  /// saw through, left out of this frame's dense step, and the dense step's source
  /// points the key-frame's scan saw through, dropped.
  int hidden_map_voxels = 0;
  int dropped_moving_points = 0;
  /// Dense fallback against a rival optimum: features paired under its motion (0: not
  /// checked).
  int guided_pairs = 0;
  /// The times the scan was motion-compensated with ("field": its own point times,
  /// "azimuth": from the azimuth; empty: none; the first two frames have no motion to
  /// apply yet), and whether it was compensated again with the estimated motion.
  std::string deskew_times;
  /// The points (features, dense step) were compensated with a motion: times and a
  /// motion from the frames before (not the first two frames of a run).
  bool deskew_applied = false;
  bool deskew_second_pass = false;
  /// This scan was prepared on a second thread while the frame before was tracked
  /// (Odometry::processFrame with a look-ahead scan): its ground removal and, unless it
  /// is motion-compensated, its raster and ORB features. Their timings are those of that
  /// thread.
  bool extracted_ahead = false;
  /// Tracked by the dense step alone from the constant-velocity prior, with no raster
  /// or ORB features made (Odometry::setFeaturesWanted): features is null and
  /// num_features 0, unless the frame became a key-frame, which always has them.
  bool features_skipped = false;
  OdometryTimings timings;
};

/// \brief A scan handed to Odometry::processFrame one call ahead of its turn
/// (look-ahead): the same arguments its own processFrame call will get.
struct OdometryInput
{
  pcl::PointCloud<pcl::PointXYZI>::ConstPtr cloud;
  double timestamp_s = 0.0;
  std::size_t frame_index = 0;
  std::vector<float> point_times_s; ///< as processFrame's (empty: none)
};

/// \brief When scans are motion-compensated (deskew.h).
enum class DeskewMode
{
  kAuto, ///< when the scan comes with point times (a time field); never from the azimuth
  kOn,   ///< always: the scan's point times, else times from the azimuth
  kOff   ///< never
};

/// \brief "auto", "on", "off".
const char* toString(DeskewMode mode);

/// \brief Motion compensation of raw sweeps before registration (doc/odometry.md).
struct DeskewParams
{
  DeskewMode mode = DeskewMode::kAuto;
  /// Times from the azimuth (DeskewMode::kOn without point times): spin direction and
  /// the column that fires at the frame time; KITTI-style defaults.
  SweepParams sweep;
  /// Duration of a sweep for azimuth times [s]; <= 0: the time between frames (wrong
  /// when frames are skipped: the tools set it from times.txt or -deskew-period).
  double sweep_period_s = 0.0;
  /// Seconds per unit of the frames' timestamps, for every rate the odometry uses
  /// (the sweep's motion, the cold start's search range): 1 for timestamps in seconds;
  /// for file indices of a 10 Hz sensor, 0.1.
  double seconds_per_timestamp = 1.0;
  /// First pass: the motion of the previous frame. When the estimate's motion differs
  /// from it by more than this over one frame (translation [m] or rotation [deg]), the
  /// scan is compensated again with the estimated motion and refined once more.
  double second_pass_translation_m = 0.02;
  double second_pass_rotation_deg = 0.1;
  /// Time bins of deskewCloud (one transform each).
  int bins = 512;

  bool isValid(std::string* why = nullptr) const;
};

/// \brief Self-calibration of the beams' elevation angles (doc/odometry.md, "Beam
/// elevation self-calibration").
///
/// A spinning LiDAR's beams fire a little above or below their nominal elevation (KITTI's
/// HDL-64 by about 0.2 deg as a whole, and each beam by some hundredths of a degree on
/// its own), while the points are placed along the nominal one: a beam e off puts its
/// points R * e too high or too low at range R, 2.6 cm at 30 m for 0.05 deg. Each ring of
/// the ground then lies at a height of its own; as the vehicle moves, a stretch of ground
/// passes from ring to ring, and the odometry follows the pattern with a small pitch
/// every frame: a vertical drift that grows with the distance driven.
///
/// The odometry estimates the offset of each elevation bin (a beam falls in one: the
/// points of a spinning sensor keep their beam's elevation in its frame) from the
/// point-to-plane residuals of frames tracked without degradation against the local
/// map, by least squares
/// over windows of frames, and turns the points of the later scans by it before
/// everything else. The local map averages many beams, so the world's own shape cancels
/// out of the residuals; a scan whose elevation bins hold no beam (a non-repetitive
/// pattern) averages to no correction. An offset common to all beams and one in
/// proportion to the elevation are hardly told from the world by the residuals and are
/// left as they are: the beams' differences are corrected, not a whole sensor's elevation
/// error. Off in the vlp16 and os0-128 presets.
struct ElevationCalibrationParams
{
  /// Off: the points stay as the sensor placed them.
  bool enabled = true;
  /// Width of an elevation bin [deg]: less than the gap between two beams.
  double bin_deg = 0.05;
  /// The table is updated from the residuals of this many tracked frames ...
  int window_frames = 50;
  /// ... in the bins with at least this many point-to-plane pairs among them ...
  int min_pairs = 100;
  /// ... whose mean lever (range times the share of the plane's normal along the
  /// beam's elevation) is at least this [m]. A beam that sees the ground near the
  /// vehicle holds little of its angle: its points lie a few millimetres off, below
  /// what the residuals tell from the ground's roughness. (Those bins drifted by up to
  /// 0.5 deg in simulated drives, while bins of more than 10 m stayed within 0.01 deg
  /// of the truth.)
  double min_mean_lever_m = 10.0;
  /// A pair farther than this from its plane is not used (another surface) [m].
  double max_residual_m = 0.2;
  /// A bin whose residuals scatter about its step more than this many times the
  /// median bin's is not updated in that window: its level surfaces are the crowns of
  /// trees, whose points scatter through the foliage. (On a simulated 05 drive the
  /// beams above the horizon scattered 0.10-0.11 m about such crowns, against 0.04-0.06
  /// m for the ground's, and were turned by up to 0.39 deg where they were off by 0.04.)
  double max_scatter_ratio = 1.5;
  /// No bin is turned by more than this [deg].
  double max_correction_deg = 0.5;

  /// \brief True when every member is valid; otherwise says why in *why.
  bool isValid(std::string* why = nullptr) const;
};

/// \brief What the elevation self-calibration has estimated
/// (Odometry::elevationCalibration).
struct ElevationCalibrationState
{
  bool enabled = false;
  int updates = 0;                 ///< windows of frames the table was updated from
  int bins_corrected = 0;          ///< elevation bins with a correction
  double rms_correction_deg = 0.0; ///< over those bins
  double max_abs_correction_deg = 0.0;
  /// (bin's centre elevation [deg], correction [deg]) of the bins corrected, ascending.
  std::vector<std::pair<double, double>> corrections;
};

/// \brief Dense point-to-plane tracking of a scan against the local map: a KISS-ICP-like
/// voxel hash map of the key-frames' points in the world frame, one plane per voxel,
/// robust Gauss-Newton with degeneracy-aware updates (doc/odometry.md).
struct DenseTrackingParams
{
  /// The scan is voxelized with this leaf before refinement [m] ...
  double source_voxel_size_m = 1.0;
  /// ... and then subsampled (deterministic stride) to at most this many points. 2000
  /// since session 36 (1000 before): on an open field, where the features find nothing
  /// and yaw rests on the few hundred points above the ground, 1000 let a dozen frames
  /// turn 1-2 deg the wrong way (doc/odometry.md, "Dense source points").
  int max_source_points = 2000;
  /// Leaf of the local map: one plane is fitted per voxel [m].
  double map_voxel_size_m = 1.0;
  /// Points kept per map voxel: the first ones inserted, as in KISS-ICP, unless
  /// map_nearer_ratio replaces them.
  int map_max_points_per_voxel = 20;
  /// A full map voxel takes a new point in place of the point it saw from farthest away
  /// when the new one is seen from less than this fraction of that range (0: never, the
  /// first points stay, as in KISS-ICP: the default). A point's error grows with its
  /// range (beam elevation and divergence), and a car approaches most surfaces, so a
  /// voxel's first points are its farthest. Measured with 0.5 (doc/odometry.md, "Nearer
  /// points in place of the first ones"): better on the tuning seed, not on the
  /// reporting seeds (simulated), so not the default.
  double map_nearer_ratio = 0.0;
  /// Map voxels farther than this from the newest key-frame are dropped [m].
  double map_radius_m = 100.0;
  /// While the local map holds fewer scans than this, every tracked frame's scan goes
  /// into it, not only the key-frames' (1: key-frames only, the default). Registered
  /// against one or two scans, the first frames' planes are few and fitted to one
  /// sampling of the surface (a VLP-16's rings 2 deg apart), and their rotation errors
  /// tilt the whole drive. Measured with 10 (doc/odometry.md): a procedural VLP-16 loop
  /// 2.0 -> 0.5 deg over its first 10 frames (SLAM ATE 0.094 -> 0.037 m), but simulated
  /// VLP-16 07 / 08 0.17 -> 0.17 % / 0.62 -> 0.74 % and HDL-64 00-08 within +-10 %: the
  /// early scans stay in the map (the first points of a voxel are kept), errors and all.
  int young_map_scans = 1;
  /// A voxel is a plane when lambda_min / (lambda_0 + lambda_1 + lambda_2) <= this.
  double max_surface_variation = 0.04;
  /// Residuals larger than this are not paired [m].
  double max_correspondence_distance_m = 1.0;
  /// Gauss-Newton iterations at most. Most frames converge in 3-6; a start decimetres
  /// and a degree off (weak features, 2 Hz) needs 10-15 under the annealed kernel.
  int max_iterations = 15;
  /// The Geman-McClure scale anneals from max_correspondence_distance_m / 3, halving
  /// per iteration, down to this [m] (about the sensor noise).
  double min_kernel_scale_m = 0.05;
  /// Converged when an update moves less than this [m] ...
  double convergence_translation_m = 1e-3;
  /// ... and rotates less than this [rad].
  double convergence_rotation_rad = 1e-4;
  /// A direction of the 6x6 normal equations (rotations scaled by 10 m) is degenerate
  /// when its eigenvalue is below this fraction of the total weight; the update is
  /// not applied along it (the initial guess is kept there, e.g. x/y/yaw on an open
  /// field).
  double degeneracy_min_ratio = 0.003;
  /// A direction that passes that test must also be supported: the robust weight of
  /// the points whose residual changes by at least degeneracy_support_derivative per
  /// metre along it (surfaces that face along it) must reach this; otherwise it is
  /// degenerate too. 0 disables the test. Noisy normals of long walls give a tunnel's
  /// axis a fair eigenvalue, but only a few fixtures face along it.
  double degeneracy_min_support = 0.0;
  /// |d residual / d step| [m/m] from which a point supports a direction.
  double degeneracy_support_derivative = 0.3;
  /// Fewer paired source points than this: failure.
  int min_correspondences = 100;
  /// Failure when the result moved farther than this from its initial guess [m] ...
  double max_correction_m = 1.5;
  /// ... or rotated more than this [deg].
  double max_correction_deg = 5.0;

  /// \brief True when every member is valid; otherwise says why in *why.
  bool isValid(std::string* why = nullptr) const;
};

/// \brief Recovery from large motion (a sharp turn at a low frame rate) when the
/// feature-consistency check fails: dense ICP is started from several motion
/// hypotheses instead of the constant-velocity prior alone, and the start whose result
/// pairs the most scan points with the local map wins (doc/odometry.md).
struct MotionHypothesisParams
{
  /// Off: dense ICP from the prior only (the paper's fallback).
  bool enabled = true;
  /// The prior's rotation is turned by +-k * yaw_step_deg about the LiDAR z axis ...
  double max_yaw_deg = 45.0;
  /// ... in steps of this [deg] (also the rotation a coarse run may correct).
  double yaw_step_deg = 7.5;
  /// A RANSAC estimate with at least this many inliers (but too few to pass the
  /// consistency check) is a hypothesis too.
  int min_weak_inliers = 5;
  /// The coarse runs pair residuals up to this [m] ...
  double coarse_correspondence_distance_m = 1.5;
  /// ... and may move up to this from their start [m].
  double coarse_max_correction_m = 2.5;
  /// Without a tracked velocity (the cold start, or after frames tracked by neither
  /// features nor dense ICP) the prior says nothing about the speed: the prior is also
  /// shifted along the LiDAR x axis (the direction of travel) by +-k * this [m] ...
  double cold_start_step_m = 2.0;
  /// ... up to this speed times the frame interval [m/s] (72 km/h: 10 m at 2 Hz).
  double cold_start_max_speed_mps = 20.0;
  /// A dense result that a rival optimum elsewhere nearly matches is still accepted
  /// when the features back it: matched under its motion (each feature only against
  /// key-frame features within this distance of where the motion puts it, nearest
  /// descriptor, no ratio test) [m]; 0 disables ...
  double guided_gate_m = 0.5;
  /// ... when at least min_feature_inliers pair, and this many times as many as under
  /// the rival's motion.
  double guided_support_factor = 2.0;
  /// A dense fallback result is re-fitted: features matched under it within this gate
  /// [m], RANSAC, dense ICP from their x, y and yaw; the result under which more
  /// features pair (guided_gate_m) is kept. 0 disables.
  double guided_refit_gate_m = 1.0;
  /// Threads the coarse runs are spread over: 1 runs them one after the other on the
  /// caller's thread; 2 runs every other one on a thread of the odometry's own. The
  /// runs are independent, so the result is the same.
  int threads = 2;

  /// \brief True when every member is valid; otherwise says why in *why.
  bool isValid(std::string* why = nullptr) const;
};

/// \brief Everything tracking can be tuned with; defaults suit a car-mounted
/// HDL-64/VLP-16/Ouster at 10 Hz.
///
/// Which members are used: ground, raster, orb as named; registration.matching and
/// registration.ransac for the feature estimate against the last key-frame;
/// registration.refine switches the dense refinement, whose parameters are \a dense
/// (registration.refinement and registration.min_correspondences are not used here).
struct OdometryParams
{
  SACGroundRemovalParams ground;
  RangeRasterParams raster;
  OrbRasterFeatureParams orb;
  RegistrationParams registration;
  /// Paper, sec. 7.3 A: at least this many frames since the last key-frame.
  int keyframe_min_frames = 5;
  /// Paper, sec. 7.3 B: at most this many points in common (RANSAC inliers) with it.
  int keyframe_max_common_points = 100;

  // ---- input ----
  /// Points closer to the sensor than this are dropped (vehicle body, operator) [m].
  double min_range_m = 0.5;
  /// Points farther than this are dropped (far outliers) [m].
  double max_range_m = 200.0;

  // ---- feature tracking ----
  /// Feature-consistency check: fewer RANSAC inliers than this and the feature estimate
  /// is not used (dense ICP from the prior instead, flagged degraded).
  int min_feature_inliers = 15;
  /// A feature estimate with at least this many inliers is trusted even when it is far
  /// from the constant-velocity prior (large motion); below it, and far from the
  /// prior, both starts are refined and the better fit wins. Before a velocity has been
  /// measured (a run's second frame) every estimate that passed the consistency check
  /// counts as strong: the prior is then no motion at all.
  int strong_feature_inliers = 40;
  /// Below strong_feature_inliers, match the key-frame again by nearest neighbour alone
  /// (no ratio test, no mutual check) and keep whichever set RANSAC finds more inliers
  /// in. A top-down raster repeats itself (wall edges, rows of poles): most true pairs
  /// fail the ratio test, and under large motion the strict set is often too small.
  bool loose_rematch = true;
  /// "Far from the prior": translation [m] ...
  double prior_gate_m = 1.0;
  /// ... or rotation [deg].
  double prior_gate_deg = 5.0;
  /// With a tracked velocity the gates shrink with the frame interval dt to what a
  /// vehicle can deviate from constant velocity: translation min(prior_gate_m,
  /// prior_gate_accel_mps2 * dt^2), rotation min(prior_gate_deg,
  /// prior_gate_angular_accel_dps2 * dt^2). At 10 Hz 0.3 m and 1.5 deg; at 2 Hz the fixed
  /// gates above. Weak features (20 inliers on the parked cars of an open field) 0.5-0.8
  /// m and 0.8-1.8 deg off a tracked prior at 10 Hz were "near" it and set the pose
  /// (doc/odometry.md). 0: no shrinking (the handheld preset: a turning head accelerates
  /// far more).
  double prior_gate_accel_mps2 = 30.0;
  double prior_gate_angular_accel_dps2 = 150.0; ///< see prior_gate_accel_mps2
  /// A car's vertical velocity changes slowly (the road's grade). After
  /// constant-velocity frames (a velocity measured k >= 1 frames ago), a pose that did
  /// not come from strong features (a dense fallback, weak features) and lies more than
  /// prior_gate_vertical_accel_mps2 * dt^2 * (1 + k) above or below the prior keeps the
  /// prior's height, roll and pitch; its x, y and yaw stand. At 10 Hz 0.1 m after one
  /// such frame. Where the scan holds the height only weakly (a ramp of steep ground,
  /// few planes) a dense fallback otherwise slid 0.4-0.8 m in one frame, and constant
  /// velocity carried the slide on. With a velocity measured the frame before, the
  /// scan's height always stands: a prior held against it carries its own climb on
  /// where the grade changes (doc/odometry.md). 0: off (the handheld preset).
  double prior_gate_vertical_accel_mps2 = 5.0;
  /// Strong features whose refined pose lies beyond those shrunk gates (a motion the
  /// vehicle cannot make) are checked against dense ICP from the prior, which wins
  /// where it ends elsewhere and the scan cannot tell the two apart (nearly as many
  /// pairs, RMS residuals within indistinct_residual_m): a guard rail's posts alias
  /// dozens of keypoints by part of a post. Not in two frames running. false: strong
  /// features stand (doc/odometry.md).
  bool check_strong_features = true;
  /// Where the gates shrink (a tracked velocity at a high frame rate), a dense step
  /// anchored to the prior is also pulled toward it with this fraction of its total
  /// weight: a direction the scan constrains only weakly (a tunnel's axis, 0.3-1 % of
  /// the weight, mostly from wall normals tilted by noise and from moving cars)
  /// follows the prior instead of sliding, and a constrained one barely moves
  /// (doc/odometry.md). 0: off.
  double dense_prior_ratio = 0.003;
  /// Weak features (fewer than strong_feature_inliers) within those gates of a tracked
  /// prior: the dense step's anchor, which the directions the scan does not constrain
  /// take and which dense_prior_ratio pulls toward, is the prior moved this share of
  /// the way to their planar motion (x, y and yaw). 0 (the default): the prior alone.
  /// The VLP-16 preset takes 0.25: with 10-25 inliers on its sparse raster, the prior
  /// alone held a highway's speed at 1.42 m a frame while the car went to 2.1. An
  /// HDL-64's weak features in a tunnel (lamps, doors) pull it astray instead
  /// (doc/odometry.md). In [0, 1].
  double weak_feature_share = 0.0;
  /// Without features wanted (Odometry::setFeaturesWanted): for this many frames after
  /// a frame whose features failed the consistency check (fewer than
  /// min_feature_inliers), a dense step from the prior is taken even where the scan
  /// constrains a direction weakly or not at all; that direction keeps the prior, as
  /// the failed features' hypothesis search keeps it where it cannot tell the
  /// hypotheses apart. Every other condition of a frame tracked without features
  /// stands. In open fields such a frame made features that failed, then searched
  /// dense ICP from 15 motion hypotheses: 20 ms of an HDL-64's frame, where the dense
  /// step alone takes 2.4 (doc/odometry.md, "Features on demand"). 0: off.
  int failed_features_skip_frames = 3;
  /// Two dense results the scan cannot tell apart: their RMS point-to-plane residuals
  /// differ by less than this [m] (about half the range noise). Where weak features
  /// and the prior end this close, the prior wins; where dense ICP slid this
  /// indistinctly away from strong features, the features win (doc/odometry.md).
  double indistinct_residual_m = 0.01;
  /// Moving objects. Before the dense step, with a tracked velocity where the prior
  /// gates shrink (a vehicle at a high frame rate): the local map's voxels within
  /// visibility_radius_m that this scan, placed at the prior, sees through by more than
  /// visibility_margin_m are left out of this frame's pairing, and so are the scan's
  /// points that the key-frame's scan saw through by that much (what moved out of or
  /// into them). On a highway whose static scene hardly holds the road's axis, cars and
  /// trucks beside the ego otherwise hold it. 0: off, the default: with 1 m, simulated
  /// reporting drives came out worse on the whole (doc/odometry.md).
  double visibility_margin_m = 0.0;
  double visibility_radius_m = 40.0; ///< see visibility_margin_m

  // ---- motion compensation ----
  DeskewParams deskew;

  // ---- the beams' elevation ----
  ElevationCalibrationParams elevation_calibration;

  // ---- dense refinement ----
  DenseTrackingParams dense;
  /// Dense search from several motion hypotheses when the features fail.
  MotionHypothesisParams turn_search;

  // ---- key-frames (safety rules besides the paper's two) ----
  /// Leaf of the voxelized scan a key-frame keeps (and adds to the local map) [m].
  double keyframe_voxel_size_m = 0.5;
  /// Key-frames keep their voxelized scan (KeyFrame::cloud), which a map, the loop
  /// closing and a saved session are made of. The odometry's own tracking does not
  /// read it: a caller that only tracks (MapLocalization) turns it off, and the
  /// key-frames' cloud is then null.
  bool keyframe_clouds = true;
  /// Force a key-frame when tracking against the current one degrades: fewer
  /// inliers than this (and the frame has at least min_feature_inliers features).
  int keyframe_min_inliers = 30;
  /// Force a key-frame beyond this distance from the current one [m] ...
  double keyframe_max_distance_m = 10.0;
  /// ... or this rotation [deg].
  double keyframe_max_rotation_deg = 20.0;

  /// \brief True when every member is valid; otherwise says why in *why.
  bool isValid(std::string* why = nullptr) const;
};

/// \brief Parameter presets for common sensors and mounts (doc/odometry.md).
enum class SensorPreset
{
  kHdl64,  ///< car-mounted 64-beam Velodyne (KITTI): the defaults
  kVlp16,  ///< 16 beams: sparser raster, smaller inlier sets accepted
  kOs1_64, ///< car-mounted 64-beam Ouster: the defaults
  kOs0_128 ///< wide field of view, handheld or tilted mount: levelled raster, finer maps
};

/// \brief "hdl64", "vlp16", "os1-64", "os0-128".
const char* toString(SensorPreset preset);
/// \brief The preset named \a name (see toString).
/// \throws std::invalid_argument naming \a name when it is none of them.
SensorPreset sensorPresetFromName(const std::string& name);
/// \brief Change \a params as \a preset suggests (other members stay).
void applySensorPreset(SensorPreset preset, OdometryParams& params);
/// \brief No vehicle-dynamics prior: the prior gates stay prior_gate_m / _deg and the
/// dense step is not pulled to the prior (prior_gate_accel_mps2,
/// prior_gate_angular_accel_dps2, dense_prior_ratio and weak_feature_share 0), as the
/// handheld preset has it.
void disableVehiclePrior(OdometryParams& params);

/// \brief What guessSensorPreset saw in a scan.
struct SensorGuess
{
  SensorPreset preset = SensorPreset::kHdl64;
  double beam_spacing_deg = 0.0; ///< median elevation gap of vertically adjacent returns
  double vertical_span_deg =
      0.0;                       ///< elevation range of the returns (1st-99th percentile)
  double ground_tilt_deg = -1.0; ///< angle of the ground plane to the x-y plane; -1: none
  std::string reason;            ///< which rule decided
};

/// \brief Guess the preset from one scan in the sensor frame: a ground plane tilted by
/// more than 10 deg, or returns spanning more than 45 deg of elevation, mean a handheld
/// or wide-angle sensor (kOs0_128); beams more than 1.2 deg apart mean kVlp16; else
/// kHdl64. Elevation is measured about the sensor's spin axis, so a tilted mount does not
/// blur the beams.
SensorGuess guessSensorPreset(const pcl::PointCloud<pcl::PointXYZI>& scan);

/// \brief Frame-to-key-frame LiDAR odometry on rasterized ORB features.
class Odometry
{
public:
  using Ptr = std::shared_ptr<Odometry>;

  /// \throws std::invalid_argument when \a params are invalid (message says why)
  explicit Odometry(const OdometryParams& params = OdometryParams());
  ~Odometry();

  /// \brief Track one scan (LiDAR frame). Never throws on bad data: an empty or
  /// featureless cloud gives a degraded result. Frame indices must increase.
  OdometryFrameResult processFrame(const pcl::PointCloud<pcl::PointXYZI>::ConstPtr& cloud,
                                   double timestamp_s,
                                   std::size_t frame_index);

  /// \brief processFrame with the points' times [s] relative to the frame time, one per
  /// point of \a cloud (ScanFrame::point_times_s; empty: none), for motion compensation
  /// (OdometryParams::deskew). Times of the wrong count are ignored, with a message.
  OdometryFrameResult processFrame(const pcl::PointCloud<pcl::PointXYZI>::ConstPtr& cloud,
                                   double timestamp_s,
                                   std::size_t frame_index,
                                   const std::vector<float>& point_times_s);

  /// \brief processFrame of this scan while \a next, the scan the next call will get,
  /// is prepared on a second thread: its range check, point times and ground removal,
  /// and, when it will not be motion-compensated, its raster and ORB features (about
  /// half of a frame's work). The compensation needs this frame's
  /// motion, so a scan with point times is compensated, rasterized and described in its
  /// own call. The next call takes what was prepared when it comes right after this one
  /// with \a next's cloud pointer, frame index, timestamp and point times; otherwise it
  /// is dropped (and a skipFrame between drops it). The cloud must not change until
  /// then. The poses are the same as without the look-ahead.
  /// \throws std::invalid_argument when next.frame_index is not after \a frame_index
  OdometryFrameResult processFrame(const pcl::PointCloud<pcl::PointXYZI>::ConstPtr& cloud,
                                   double timestamp_s,
                                   std::size_t frame_index,
                                   const std::vector<float>& point_times_s,
                                   const OdometryInput& next);

  /// \brief Account for a frame without a usable scan: constant-velocity
  /// prediction, status kSkipped, never a key-frame.
  OdometryFrameResult
  skipFrame(double timestamp_s, std::size_t frame_index, const std::string& reason);

  /// \brief Whether the caller needs the next frames' features (default: yes).
  ///
  /// When not, a frame whose dense step from the constant-velocity prior alone pairs
  /// most of its points, constrains every direction and stays within the vehicle's
  /// dynamics of the prior (KISS-ICP's way of tracking) is taken as it is: no raster,
  /// ORB or matching, about 4 of the 10 ms of an HDL-64 frame (doc/odometry.md,
  /// "Features on demand"). Any other frame, one without a tracked velocity, and every
  /// key-frame are tracked and made as usual. For a caller that uses the features only
  /// now and then, as MapLocalization off the map does between its placements;
  /// RastSlam's tracking keeps them.
  void setFeaturesWanted(bool wanted);

  /// \brief The elevation self-calibration's estimate so far
  /// (OdometryParams::elevation_calibration).
  ElevationCalibrationState elevationCalibration() const;

  const OdometryParams& params() const;

  /// \brief Number of key-frames created so far.
  std::size_t numKeyFrames() const;
  /// \brief Number of voxels of the local map (memory diagnostics).
  std::size_t localMapSize() const;

private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

} // namespace rast
} // namespace pcl
