#pragma once
/// \file session_localizer.h
/// \brief Placing a scan on a saved session's map with no prior pose (issue 13: cold
/// start and relocalization). The scan's raster ORB features retrieve the session's
/// key-frames that look most alike (the appearance index, rebuilt from the saved
/// features), and each is verified as a loop would be: descriptor matching, RANSAC,
/// guided matching, spread, uniqueness and self-similarity checks, then the dense
/// point-to-plane check on the key-frame's cloud. The first candidate that passes
/// places the scan; none passing is a failure, never a guess.
/// \ingroup slam

#include <pcl/slam/loop_types.h>
#include <pcl/slam/odometry.h>
#include <pcl/slam/session.h>
#include <pcl/registration/point_to_plane_refinement.h>

#include <pcl/point_cloud.h>
#include <pcl/point_types.h>

#include <memory>
#include <string>
#include <vector>

namespace pcl {
namespace rast {

/// \brief Settings of SessionLocalizer.
struct SessionLocalizerParams
{
  /// The front end that extracts the scan's features (ground removal, raster, ORB):
  /// the session's sensor preset applied to it is what the session was made with. Its
  /// dense step keeps 1000 source points, not the odometry's 2000: between the map's
  /// alignments it only predicts. On the simulated KITTI 00 second drive (seed 101,
  /// session 36) 2000 cost 15 % of the frame rate (51.0 against 59.9 fps), for the
  /// same ATE on mapped roads (0.124 m) and 16 instead of 18 of 20 cold starts.
  OdometryParams odometry = [] {
    OdometryParams o;
    o.dense.max_source_points = 1000;
    return o;
  }();
  /// Retrieval and verification. The key-frame and travel gaps that keep a loop away
  /// from its own recent past do not apply to a map from another run: they are set so
  /// that every key-frame is eligible. Another run pairs few features by the ratio
  /// test: rotation_filtered_matching is on. Another run also shares fewer words with
  /// the map than a loop within one run does, so a key-frame needs an appearance score
  /// of 15 instead of the loop closure's 20 to be verified: on the simulated KITTI 00
  /// second drive of the tuning seed 42, 615 instead of 604 of 620 mapped-road frames
  /// localized, none wrong (session 33). The verification's checks are the same, but
  /// for a scan with fewer than 50 structure points (min_dense_structure): the dense
  /// check cannot decide there, and a candidate that passes the features' checks makes
  /// a tentative placement. On open highways the dense check had refused right
  /// placements of 60-80 inliers over 13-20 points (simulated OS1-64 KITTI 05 world,
  /// tuning seed 41: cold starts on 95 of 113 mapped-road frames, 113 with it;
  /// doc/session.md, "Session 64"). Likewise a candidate of whose structure points
  /// between 25 % (tentative_dense_overlap) and 35 % (min_dense_overlap) pair makes a
  /// tentative placement: along a road lined with porous trees and at the map's edges
  /// right candidates paired 21-33 %, and the next scan's alignment to the map confirms
  /// such a placement or not (simulated HDL-64 KITTI 05 world, tuning seed 42: cold
  /// starts on 110 instead of 105 of 113 mapped-road frames, none wrong, none of 104
  /// off the map placed; doc/session.md, "Session 68").
  LoopDetectorParams verification = [] {
    LoopDetectorParams p;
    p.rotation_filtered_matching = true;
    p.min_appearance_score = 15;
    p.min_dense_structure = 50;
    p.tentative_dense_overlap = 0.25;
    return p;
  }();
  /// Key-frames retrieved by appearance verified per scan, best first (>= 1); the
  /// prior's and the polar descriptor's candidates come on top.
  int max_candidates = 6;
  /// A candidate that passes every check with fewer guided inliers than
  /// verification.min_inliers, but at least this many, makes a tentative placement
  /// (Placement::tentative): not a placement by itself, one when the tentative
  /// placement of another scan agrees with it (MapLocalization). 0: none (and no polar
  /// candidates, which make tentative placements only).
  int tentative_min_inliers = 20;
  /// With a PlacementPrior: the key-frames nearest the prior (within its radius) verified
  /// first, under the prior as the guess and whatever their appearance score, as the
  /// paper closes loops with the nearest key-frames. 0: the prior is not used.
  int max_prior_candidates = 2;
  /// A candidate key-frame is verified together with up to this many key-frames of the
  /// map nearest it (within neighbourhood_radius_m): their features, moved into its
  /// frame, join its own where no feature of it lies within 0.5 m, and their dense
  /// targets join its target. One scan sees some of a place's corners and walls, and
  /// the scans around it see others. 0: the candidate alone.
  int neighbourhood_keyframes = 0;
  /// How far from the candidate those key-frames may lie [m] (> 0).
  double neighbourhood_radius_m = 10.0;
  /// When neither the prior nor appearance places the scan, up to this many key-frames
  /// whose polar max-height descriptor (a Scan Context: the greatest height in 20 rings
  /// to 60 m by 60 sectors of 6 deg around the sensor) is nearest the scan's are
  /// verified too (PlacementOptions::polar_candidates), each under the guess that the
  /// scan stands at the key-frame, turned by the yaw of the descriptors' best column
  /// shift, within polar_guess_radius_m and polar_guess_rotation_deg. Where two drives
  /// share few corners the features retrieve the wrong key-frames, and the descriptor
  /// (heights of walls, trees and cars all around) still finds the place; the checks
  /// are a prior's: matching gated by the guess, RANSAC, guided matching, spread,
  /// self-similarity and the dense check. Such a candidate that passes them makes a
  /// tentative placement only, however many its inliers: the guess lets matches in
  /// that the ratio test would refuse, and on a simulated VLP-16 highway (KITTI 05
  /// world, tuning seed 43) one passed with 30 inliers 2.3 m along the road from the
  /// map's pose of the place, where the next scan's placement was 3.7 m from it. A
  /// second scan must agree (MapLocalization). 0: none (no descriptors are kept).
  int polar_candidates = 3;
  double polar_guess_radius_m = 6.0;      ///< (> 0)
  double polar_guess_rotation_deg = 12.0; ///< (> 0)
  /// \brief Whether all values are usable; on failure \a why (if not null) says which.
  bool isValid(std::string* why = nullptr) const;
};

/// \brief Change \a params as \a preset suggests (other members stay): the odometry's
/// preset (applySensorPreset(SensorPreset, OdometryParams&)) and the placement
/// thresholds. A 16-beam scan's raster holds about a quarter of the corners of a 64-beam
/// one, and a true revisit pairs fewer of them: for `vlp16` a placement needs 8 inliers
/// of the first RANSAC instead of 12 (verification.min_initial_inliers) and 30 guided
/// inliers instead of 40 (verification.min_inliers; 20-29 make a tentative one), and a
/// candidate that fails alone is verified again with its 2 nearest key-frames
/// (neighbourhood_keyframes). The dense check and the other verification steps are
/// unchanged (doc/session.md, "Session 44" and "Session 47"). The other presets change
/// only the odometry.
void applySensorPreset(SensorPreset preset, SessionLocalizerParams& params);

/// \brief Where the scan is believed to be on the map, and how far off that may be: the
/// pose dead-reckoned by the odometry since the map last confirmed one (MapLocalization).
struct PlacementPrior
{
  Pose3d T_world_lidar = Pose3d::Identity();
  /// Key-frames within this distance are candidates, and a verified pose must lie
  /// within it of the prior [m] (> 0).
  double radius_m = 10.0;
  double rotation_deg = 20.0; ///< how far a verified pose may turn from it (> 0)
  /// The dense check's least overlap for the key-frames near the prior (negative:
  /// LoopDetectorParams::min_dense_overlap, as for the others).
  double min_dense_overlap = -1.0;
};

/// \brief Per call choices of SessionLocalizer::place.
struct PlacementOptions
{
  /// When no candidate places the scan alone, verify them again with their
  /// neighbourhoods (SessionLocalizerParams::neighbourhood_keyframes). That matches the
  /// scan with several times the features: a caller that tries every few frames for
  /// long where a placement is unlikely turns it off (MapLocalization does far from
  /// the map).
  bool neighbourhoods = true;
  /// ... with at least this many nearest key-frames each, more than
  /// SessionLocalizerParams::neighbourhood_keyframes when that is less (MapLocalization
  /// asks for them where a start or a relocalization waits for the placement).
  int min_neighbourhood_keyframes = 0;
  /// Verify the key-frames nearest by the polar descriptor when the others fail
  /// (SessionLocalizerParams::polar_candidates). MapLocalization asks for them only
  /// where a start or a relocalization waits for the placement.
  bool polar_candidates = true;
};

/// \brief Where a scan was placed on the map, or why it was not.
struct Placement
{
  /// Placed: a candidate passed every check with the full thresholds.
  bool success = false;
  /// Not placed, but a candidate passed every check with at least
  /// tentative_min_inliers guided inliers, or a polar candidate passed them
  /// (SessionLocalizerParams::polar_candidates), or one passed the features' checks
  /// on a scan too bare for the dense check (LoopVerification::dense_undecided), or
  /// with a dense overlap short of the full threshold
  /// (LoopVerification::dense_short): the pose fields below are filled in, for a
  /// caller that accepts it once another scan's placement or alignment agrees with it.
  bool tentative = false;
  /// Pose of the scan's LiDAR frame in the session's world frame (when success).
  Pose3d T_world_lidar = Pose3d::Identity();
  KeyFrameId keyframe = 0; ///< the session key-frame it was verified against
  int num_inliers = 0;     ///< feature inliers of that verification
  double dense_overlap = 0.0;
  double dense_rmse_m = 0.0;
  int num_features = 0;         ///< ORB features of the scan
  int candidates_retrieved = 0; ///< key-frames that shared appearance with it
  /// key-frames verified before one passed (or all failed): near the prior, retrieved,
  /// found by the polar descriptor
  int candidates_verified = 0;
  /// of which verified again with their neighbourhoods (neighbourhood_keyframes)
  int neighbourhoods_verified = 0;
  /// key-frames verified because their polar descriptor is near the scan's
  /// (SessionLocalizerParams::polar_candidates)
  int polar_verified = 0;
  double time_ms = 0.0;         ///< features, retrieval and verification
  std::string message;          ///< what placed it, or why nothing did
};

/// \brief A loaded session ready to place scans on (see the file comment).
///
/// \code
/// pcl::rast::Session session = pcl::rast::loadSession("session");
/// pcl::rast::SessionLocalizerParams params;
/// pcl::rast::applySensorPreset(
///     pcl::rast::sensorPresetFromName(session.info.sensor_preset), params);
/// pcl::rast::SessionLocalizer localizer(std::move(session), params);
/// const pcl::rast::Placement p = localizer.place(scan);
/// if (p.success) use(p.T_world_lidar);
/// \endcode
class SessionLocalizer
{
public:
  /// \brief Index the session's key-frames (those with features and a cloud).
  /// \throws std::invalid_argument on invalid params or a session without key-frames
  SessionLocalizer(Session session, const SessionLocalizerParams& params);
  ~SessionLocalizer();
  SessionLocalizer(const SessionLocalizer&) = delete;
  SessionLocalizer& operator=(const SessionLocalizer&) = delete;

  /// \brief Place \a scan (its LiDAR frame) on the map with no prior pose. Safe to call
  /// from several threads at once.
  Placement place(const pcl::PointCloud<pcl::PointXYZI>::ConstPtr& scan) const;

  /// \brief Place a scan whose features are known already (a key-frame of another
  /// run, say): its features and cloud are used, its id and pose are not.
  Placement place(const KeyFrame& query) const;

  /// \brief place() with a prior: the key-frames nearest it are verified first
  /// (SessionLocalizerParams::max_prior_candidates), then those retrieved by
  /// appearance. The prior only adds candidates: the checks are the same.
  /// \throws std::invalid_argument when the prior's radius or rotation is not positive
  /// or its pose not finite
  Placement place(const pcl::PointCloud<pcl::PointXYZI>::ConstPtr& scan,
                  const PlacementPrior& prior) const;
  Placement place(const KeyFrame& query, const PlacementPrior& prior) const;

  /// \brief place() with per call \a options, and a prior when \a prior is not null.
  Placement place(const pcl::PointCloud<pcl::PointXYZI>::ConstPtr& scan,
                  const PlacementPrior* prior,
                  const PlacementOptions& options) const;
  Placement place(const KeyFrame& query,
                  const PlacementPrior* prior,
                  const PlacementOptions& options) const;

  const Session& session() const;
  /// \brief Key-frames in the appearance index.
  std::size_t numIndexed() const;

private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

/// \brief What a localization knows about one frame.
enum class LocalizationStatus
{
  kLocalized,    ///< aligned to the map this frame (or placed on it)
  kTrackingOnly, ///< the map did not confirm it: the odometry carried the pose on
  kLost          ///< no pose on the map (before the first placement, or given up)
};

/// \brief "localized", "tracking_only", "lost".
const char*
toString(LocalizationStatus status);

/// \brief Settings of MapLocalization.
struct MapLocalizationParams
{
  /// The scan is aligned to the clouds of the session key-frames within this distance
  /// of its predicted position (the nearest few, see map_keyframes) [m].
  double map_radius_m = 30.0;
  int map_keyframes = 3; ///< key-frames aligned to per frame, nearest first (>= 1)
  /// A key-frame whose alignment target is built already comes first while it is
  /// within this distance of the prediction [m]: building a target costs about 20 ms
  /// (simulated HDL-64), a third of a localized frame's time when every new nearest
  /// key-frame, one every 2 m, was built; a key-frame's cloud covers this much
  /// further on as well. 0: always the nearest first.
  double reuse_target_m = 10.0;
  /// The alignment: point-to-plane on a key-frame's cloud, from the prediction. It
  /// confirms the pose when it succeeds: at least min_correspondences source points
  /// paired, at least min_overlap_ratio of them, within the allowed correction ...
  PointToPlaneParams alignment = [] {
    PointToPlaneParams p;
    p.source_voxel_size_m = 0.5;
    p.target_voxel_size_m = 0.3;
    p.max_correspondence_distance_m = 1.0;
    p.max_source_points = 2000;
    p.max_iterations = 20;
    p.min_correspondences = 150;
    p.min_overlap_ratio = 0.3;
    p.max_correction_m = 2.0;
    p.max_correction_rad = 5.0 * 3.14159265358979323846 / 180.0;
    p.threads = 2; // the scan and new key-frames are prepared on both cores
    // Plain steps (degeneracy_min_ratio 0): the vlp16 preset keeps a direction the scan
    // hardly constrains at the prediction, which the map's velocity cannot carry (see
    // applySensorPreset).
    return p;
  }();
  /// ... with an RMS point-to-plane residual at most this [m] ...
  double max_rmse_m = 0.15;
  /// ... and at most this multiple of the median residual of the last 10 frames the map
  /// confirmed (once there are 3, and never below rmse_ratio_floor_m). A fit suddenly
  /// much worse than the frames before is another place that looks alike: an input
  /// that jumped 149 m (simulated kidnapping) aligned to the stale street at 0.14 m
  /// against 0.03 m before, while tracked frames stay within 1.9 times the median.
  /// 0 disables.
  double max_rmse_ratio = 3.0;
  double rmse_ratio_floor_m = 0.05;
  /// A placement this far from where the frame was predicted is a jump ("kidnapped")
  /// [m]; the jump is reported and the placement taken. The odometry restarts from the
  /// placed scan: the next frame's step is measured, also along a direction the map
  /// alignment keeps at the prediction (simulated VLP-16 at 3 m a frame: 32-39 frames
  /// more than 2 m behind along the street without it, none with it).
  double jump_m = 2.0;
  /// Frames the odometry may carry the pose alone before it is given up (lost).
  int max_tracking_only_frames = 30;
  /// A dense alignment to the map confirms the predicted pose only while the map last
  /// confirmed it fewer than this many frames ago (>= 1). Later (the odometry alone for longer,
  /// or the input jumped) only a placement, verified by features, localizes again: a
  /// dense alignment from a stale prediction can lock onto a street that looks the
  /// same (a 200-frame kidnapping was "localized" 137 m off that way).
  int max_realign_frames = 5;
  /// A tentative placement (SessionLocalizerParams::tentative_min_inliers) is taken
  /// when the tentative or full placement of a scan at most this many frames before
  /// agrees with it, moved by the odometry in between: within agree_m and agree_deg.
  /// Between two runs many true placements fall short of the paper's 40 inliers; two
  /// independent scans agreeing on one pose are as hard to get wrong as one strong
  /// match. 0: tentative placements are never taken.
  int tentative_window_frames = 3;
  double agree_m = 0.5;
  double agree_deg = 2.0;
  /// A tentative placement is also taken when a later scan within
  /// tentative_window_frames aligns to the map from it (moved by the odometry) as a
  /// tracked frame does: the features of one scan and the points of the next agree on
  /// the place. One dense alignment instead of a second placement, which between two
  /// runs often falls short (a 200-frame kidnapping on simulated KITTI 00: tentative
  /// placements 8 frames apart, none agreeing within 3). false: only two placements.
  bool confirm_tentative_by_alignment = true;
  /// When a scan's alignment would confirm a tentative placement
  /// (confirm_tentative_by_alignment) but it aligns to none of the nearest key-frames
  /// alone, it is aligned once more to their clouds together, with the same checks,
  /// provided the nearest of them is within this distance of the prediction [m]. A
  /// drive that passes a place the other way, or higher or lower than the mapping drive
  /// (simulated KITTI 00: the second drive 1 m above the first), pairs only 19-21 % of
  /// its scan with any one key-frame and half of it with three together. A tracked
  /// frame is aligned to them with stricter checks (tracked_together): clouds together
  /// can confirm a street of another world (a simulated one paired 40-44 % of its scans
  /// with the three nearest key-frames of a test's map, from the map's first pose),
  /// where one key-frame at a time does not. 0: key-frames one by one only, for both.
  double merged_keyframes_within_m = 10.0;
  /// A tracked frame that no nearest key-frame confirms alone, right after a frame the
  /// map confirmed, is aligned to their clouds together (within
  /// merged_keyframes_within_m), with the same checks, and confirmed only when that
  /// alignment pairs at least tracked_together_min_overlap_ratio of the scan's source
  /// points and, where the alignment is degeneracy-aware (the vlp16 preset), keeps no
  /// direction at the prediction. A drive at the map's edge, or passing a place the
  /// other way, pairs too little with any one key-frame (simulated HDL-64 KITTI 05:
  /// 67-75 % with three together where one pairs under 30 %); a street of another world
  /// paired 40-44 % with three together (doc/session.md, "Session 57"). Once they
  /// confirmed a frame, they are tried first on the next. false: only a tentative
  /// placement's confirmation aligns to them together.
  bool tracked_together = true;
  double tracked_together_min_overlap_ratio = 0.5; ///< (0, 1]
  /// While the map confirms every frame, the odometry rests: the motion between the
  /// last two confirmed frames predicts the next one (and compensates its sweep), as a
  /// map-based localizer tracks. The first frame the map does not confirm starts the
  /// odometry afresh, and it carries the pose until the map confirms it again. false:
  /// the odometry tracks every frame and predicts each alignment (slower: the front end
  /// and the map alignment both run on every frame).
  bool track_on_map = true;
  /// An alignment that keeps directions the scan does not constrain at the prediction
  /// (alignment.degeneracy_min_ratio > 0) confirms a frame only when the odometry that
  /// predicted them tracked that frame (OdometryFrameResult::degraded false, or strong
  /// features, OdometryParams::strong_feature_inliers): a degraded step (features
  /// failed, a dense fallback, constant velocity) is no measurement of those
  /// directions. A simulated VLP-16 crossing a field (KITTI 00 world, tuning seed
  /// 44) was otherwise "localized" on 60 frames while its odometry drifted 5 m
  /// sideways; on the streets of the other worlds 0-2 frames change (doc/session.md,
  /// "Session 51"). A frame the map tracks (track_on_map) ran no odometry: there the
  /// prediction is the map's own velocity, and this does not apply. false: any such
  /// alignment confirms the frame, as before.
  bool degenerate_needs_tracked_odometry = true;
  /// A frame the map does not confirm tries a placement (30-40 ms: retrieval and the
  /// verification of every candidate). Off the map they keep failing, and a second
  /// drive through a KITTI 00 world spent 86 % of its time on them. After this many
  /// failed attempts in a row, a placement is tried only every placement_every frames
  /// (and on the frames after a tentative placement, for a second one to agree with
  /// it). Any localized frame ends the back-off; cold starts and jumps try every frame
  /// until then. 0: every frame tries.
  int placement_backoff_after = 20;
  int placement_every = 4; ///< frames between two attempts while backed off (>= 1)
  /// The first first_attempts attempts of the run and after each frame the map
  /// confirmed (a cold start; a relocalization after a jump) verify a candidate that
  /// fails alone again with at least first_attempts_neighbourhood_keyframes of its
  /// nearest key-frames (PlacementOptions::min_neighbourhood_keyframes), whatever
  /// SessionLocalizerParams::neighbourhood_keyframes says; later attempts keep that
  /// setting. A start or a relocalization waits for these attempts, and 5 attempts are
  /// the 5 frames a relocalization has. Simulated KITTI 00 second drive (seed 101): the
  /// kidnapped run is right again after 1 frame instead of 5, at a frame rate within
  /// the runs' noise; every attempt before the back-off ran 3-4 % slower in the two
  /// rounds measured (doc/session.md, "Session 49").
  /// 0 neighbours or attempts: that setting throughout.
  int first_attempts = 5;
  int first_attempts_neighbourhood_keyframes = 2;
  /// While backed off, an attempt runs on a thread of its own and is taken this many
  /// frames later (0: at once, on the caller's thread). Off the map an attempt costs
  /// 20-35 ms and the odometry tracks a frame in about 13 ms (simulated HDL-64): most
  /// of the attempt overlaps the next frames, and the frame that takes it waits for the
  /// rest. The placement, found for its own scan, is moved to the frame that takes it
  /// by the odometry in between. A tentative one is recorded for its own scan and waits
  /// for agreement from there, so the lag must not exceed tentative_window_frames; with
  /// a lag of 1 the next scan confirms it just as it would an attempt made at once,
  /// with more, the frames before the lag cannot. Taken at a fixed lag, never when it
  /// happens to finish: the output does not depend on the machine's speed. A frame
  /// localized meanwhile waits for the attempt and drops it (an exception it threw
  /// too). Cold starts, the frames after a jump, and every attempt when
  /// placement_every is at most the lag (one attempt at a time) run at once.
  int background_placement_lag = 1;
  /// While the odometry carries the pose, a placement attempt verifies the session
  /// key-frames nearest the dead-reckoned pose first (PlacementPrior;
  /// SessionLocalizerParams::max_prior_candidates), with whatever appearance score: the
  /// prior is wrong by at most prior_radius_m plus prior_radius_per_m of the distance
  /// travelled since the map last confirmed a pose (the odometry's drift), and beyond
  /// prior_max_radius_m there is no prior. In open scenes and where a drive comes back
  /// from a road the map lacks, appearance retrieval alone often finds no key-frame to
  /// verify (simulated KITTI 05 second drive: 335 of 338 frames on mapped roads localized
  /// without the prior, 338 with it). The attempts keep their schedule (placement_every):
  /// trying every frame near the map cost 11 % of the frame rate for 2 frames more.
  /// prior_radius_m 0: no prior.
  double prior_radius_m = 10.0;
  double prior_radius_per_m = 0.02;
  double prior_max_radius_m = 40.0;
  /// Once the run is lost (more than max_tracking_only_frames since the map confirmed a
  /// pose), the key-frames near the prior need only this dense overlap
  /// (PlacementPrior::min_dense_overlap): a car entering the map from a road the map
  /// lacks sees much that the key-frame does not (simulated KITTI 00: overlaps of
  /// 0.19-0.34 against the verification's 0.35 over the 20 frames before it was placed).
  /// A placement short of the full inliers still waits for a second scan to agree. Until
  /// then the full overlap stands: soon after the map confirmed a pose, a scan it does
  /// not confirm overlaps it poorly, and with the lower overlap a drive beside the mapped
  /// road was placed, lost and placed again, each attempt in the foreground (simulated
  /// KITTI 05: the frame rate fell by a quarter). Negative: the full overlap throughout.
  double lost_prior_min_dense_overlap = -1.0;
  /// Off the map, far from it, attempts are made less often and taken later: once the
  /// run has a pose on the map (placed, or given by setInitialPose), its dead-reckoned
  /// pose is far from the map when no session
  /// key-frame lies within far_radius_m plus far_drift_ratio of the distance travelled
  /// since the map last confirmed a pose (an odometry drifting 16 % in open fields,
  /// simulated KITTI 00, is still near by that measure). There, backed off, an attempt
  /// is made every far_placement_every frames and taken far_placement_lag frames later,
  /// so that the odometry's frames do not wait for it: such attempts fail, and they
  /// cost a quarter of the frame rate of a drive mostly off the map (simulated KITTI
  /// 00 second drive: 61.6 fps with them, 81.7 fps with none after the back-off). A
  /// run with no pose on the map yet has no dead-reckoned pose and keeps the usual
  /// schedule, as do cold starts and the frames after a jump. Never more often than
  /// placement_every nor sooner than background_placement_lag (0: at once, near or
  /// far); the lag at most tentative_window_frames, so that a tentative placement taken
  /// then can still be confirmed by that frame's alignment; far_placement_every at
  /// most the lag runs the far attempts at once, as for background_placement_lag. No
  /// attempt starts while one runs. far_radius_m 0: no such schedule.
  double far_radius_m = 30.0;
  double far_drift_ratio = 0.2;
  int far_placement_every = 8;
  int far_placement_lag = 3;
  /// A drive that leaves the map where it ends: when the map stops confirming the pose
  /// and no session key-frame lies ahead of the prediction (along the map's last motion,
  /// within map_radius_m, and within leaving_map_corridor_m of that line), the attempts
  /// back off at once (placement_backoff_after), in the background, instead of one a
  /// frame on the tracking thread. A jump or a loss on the map, with key-frames ahead,
  /// tries every frame as before. Simulated KITTI 05 second drive: the 20 attempts after
  /// each of its 3 exits took 1.8 of its 14.4 s (doc/session.md, "Session 61"). 0: every
  /// loss tries every frame first.
  double leaving_map_corridor_m = 10.0;
  /// After a placement, the frames just before it that the map did not confirm are
  /// localized after the fact: each, nearest first, is aligned to the map from the pose
  /// of the frame after it moved back by the odometry, to the nearest key-frames one by
  /// one with a tracked frame's checks, until one is not confirmed, the odometry did not
  /// track the step between the two (it restarted, or only predicted it), or
  /// backtrack_frames were; a skipped or empty scan ends the frames kept. A car entering
  /// the map from a road the map lacks is placed only 14-17 frames after it is on mapped
  /// road (simulated KITTI 00 second drive): placements need the features of a scan that
  /// overlaps the map well, a tracked frame's alignment does not. Those frames come
  /// back in the placing frame's LocalizationFrame::backtracked_frames; a caller that
  /// reports frames as they come reports them late. Targets built for them are not
  /// cached: the frames after the placement come out as without backtracking. A thinned
  /// copy of each such scan is kept meanwhile (at most 32768 points, 256 kB). 0: none.
  int backtrack_frames = 20;
  /// The odometry makes a scan's raster features only when a placement may need them
  /// this frame (Odometry::setFeaturesWanted): not between the back-off's attempts,
  /// and not after a frame the map confirmed (where the odometry runs on the map,
  /// track_on_map false: a placement then is rare, and makes the scan's features
  /// itself). There a frame its dense step tracks alone from the prior skips them. The
  /// poses of those frames come from the dense step as before; only the features'
  /// cross-checks are left out there. Simulated VLP-16 on the 00 world: 5-9 % more
  /// frames a second (doc/session.md, "Session 50"). false: every frame has its
  /// features.
  bool features_on_demand = true;
  /// \brief Whether all values are usable; on failure \a why (if not null) says which.
  bool isValid(std::string* why = nullptr) const;
};

/// \brief Change \a params as \a preset suggests (other members stay). A 16-beam
/// sensor's key-frame clouds hold few points per 0.3 m voxel away from the sensor (rings
/// 2 deg apart), too few for the map alignment's planes: it fits them in 1 m voxels
/// (alignment.target_voxel_size_m). Those leave a street's axis unconstrained on many
/// frames (0.1 % of the weight): such a direction keeps the prediction
/// (alignment.degeneracy_min_ratio 0.002), and the odometry runs on every frame
/// (track_on_map false) and carries the pose along it (doc/session.md, "Session 43").
/// The other presets change nothing: with the map's velocity as the prediction, a kept
/// direction slowed an HDL-64's pose on a street of weak structure until it was 2-29 m
/// off, where the plain step had followed it ("Session 44").
void applySensorPreset(SensorPreset preset, MapLocalizationParams& params);

/// \brief One localized frame.
struct LocalizationFrame
{
  std::size_t frame_index = 0;
  double timestamp_s = 0.0;
  LocalizationStatus status = LocalizationStatus::kLost;
  /// Pose in the session's world frame (meaningful unless lost; lost frames keep the
  /// last pose carried on by the odometry, or identity before any placement).
  Pose3d T_world_lidar = Pose3d::Identity();
  bool placed = false;   ///< placed by retrieval this frame (cold start, relocalization)
  /// A placement was tried this frame (not backed off: placement_backoff_after), or
  /// started in the background (background_placement_lag).
  bool placement_tried = false;
  /// ... and that placement could verify candidates with their neighbourhoods
  /// (PlacementOptions::neighbourhoods: not when the back-off found the prediction far
  /// from the map).
  bool placement_with_neighbourhoods = false;
  bool odometry_ran = false; ///< the odometry tracked this frame (see track_on_map)
  /// ... without making the scan's features: no placement could use them this frame
  /// (MapLocalizationParams::features_on_demand).
  bool odometry_features_skipped = false;
  /// ... and took the scan prepared ahead (addScan with a look-ahead scan).
  bool odometry_prepared_ahead = false;
  /// The map alignment took its source (the scan's voxel planes) prepared ahead, while
  /// the frame before was processed (addScan with a look-ahead scan).
  bool alignment_prepared_ahead = false;
  bool jump = false;     ///< that placement was a jump away from the prediction
  double jump_m = 0.0;   ///< how far
  KeyFrameId keyframe = 0; ///< the session key-frame it was aligned to or placed on
  int correspondences = 0; ///< of the map alignment
  double rmse_m = 0.0;     ///< of the map alignment
  double time_ms = 0.0;
  std::string message;
  /// Localized after the fact, by the placement of a later frame
  /// (MapLocalizationParams::backtrack_frames): this is the frame as revised then.
  bool backtracked = false;
  /// Earlier frames this frame's placement localized after the fact, the nearest
  /// first (backtracked set): they replace what addScan returned for them.
  std::vector<LocalizationFrame> backtracked_frames;
};

/// \brief Localization of a sequence on a session (issue 13): the first scan is placed
/// by SessionLocalizer (or given a pose), then every scan is aligned to the session's
/// key-frame clouds near its prediction. The prediction is the motion of the last two
/// frames while the map confirms them (MapLocalizationParams::track_on_map), else the
/// odometry's frame-to-frame motion. When the map does not confirm a frame, retrieval
/// runs again on the odometry's features of the scan: a placement far from the
/// prediction is reported as a jump (kidnapping) and taken.
class MapLocalization
{
public:
  /// \param[in] localizer the session (kept by reference: it must outlive this)
  /// \param[in] odometry the front end for frame-to-frame tracking
  /// \throws std::invalid_argument on invalid params
  MapLocalization(const SessionLocalizer& localizer,
                  const OdometryParams& odometry,
                  const MapLocalizationParams& params = MapLocalizationParams());
  ~MapLocalization();
  MapLocalization(const MapLocalization&) = delete;
  MapLocalization& operator=(const MapLocalization&) = delete;

  /// \brief Start from a known pose instead of placing the first scan by retrieval
  /// (before the first addScan). \throws std::logic_error after it.
  void setInitialPose(const Pose3d& T_world_lidar);

  /// \brief Localize the next scan. The scan is not copied: it must not change while
  /// a placement of it runs in the background (MapLocalizationParams::
  /// background_placement_lag), until the addScan that takes or drops it returns.
  LocalizationFrame addScan(const pcl::PointCloud<pcl::PointXYZI>::ConstPtr& scan,
                            double timestamp_s,
                            std::size_t frame_index);
  /// \brief addScan with the points' times [s] relative to the frame time
  /// (ScanFrame::point_times_s; empty: none). Raw sweeps are then motion-compensated
  /// (OdometryParams::deskew) for the odometry, the map alignment and the placement,
  /// with the motion the odometry estimated for the frame.
  LocalizationFrame addScan(const pcl::PointCloud<pcl::PointXYZI>::ConstPtr& scan,
                            double timestamp_s,
                            std::size_t frame_index,
                            const std::vector<float>& point_times_s);
  /// \brief addScan while, where the odometry runs on this scan, the steps of \a next
  /// that need no pose (ground removal, raster, ORB) are computed on a second thread
  /// (Odometry::processFrame with a look-ahead scan). \a next is the scan the next
  /// addScan will get; its cloud must not change until then.
  /// \throws std::invalid_argument when next.frame_index is not after \a frame_index
  LocalizationFrame addScan(const pcl::PointCloud<pcl::PointXYZI>::ConstPtr& scan,
                            double timestamp_s,
                            std::size_t frame_index,
                            const std::vector<float>& point_times_s,
                            const OdometryInput& next);
  /// \brief A scan that could not be read: carried on by the odometry's prediction.
  LocalizationFrame addSkippedScan(double timestamp_s,
                                   std::size_t frame_index,
                                   const std::string& reason);

private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

} // namespace rast
} // namespace pcl
