#pragma once
/// \file loop_types.h
/// \brief The parameters and results of loop closing: LoopDetectorParams, the
/// candidates the key-frame database retrieves (LoopCandidate) and the verifier's
/// verdicts (LoopVerification, LoopDetection). See loop_detector.h, doc/loop_closure.md.
/// \ingroup slam

#include <pcl/rast/rigid_pose.h>
#include <pcl/registration/hamming_matching.h>
#include <pcl/registration/point_to_plane_refinement.h>
#include <pcl/registration/rigid_ransac.h>
#include <pcl/slam/keyframe.h>

#include <string>
#include <vector>

namespace pcl {
namespace rast {

/// \brief How key-frames that look like the query are retrieved.
enum class AppearanceRetrieval
{
  /// None: distance candidates only (the paper).
  kNone,
  /// Every 16-bit descriptor substring shared with a database feature votes for its
  /// key-frame, weighted by log(N / bucket size) (an inverted index, tf-idf like).
  kSubstringVotes,
  /// Multi-index hashing: the shared substrings only propose database features; a
  /// query feature votes for a key-frame when its nearest proposed descriptor there is
  /// within retrieval_max_hamming bits. Default (best recall, see the doc).
  kHammingVotes
};

/// \brief Parameters of LoopDetector. Distances in metres, angles in degrees.
struct LoopDetectorParams
{
  // ---- candidates by distance (the paper) ----
  /// Key-frames within this distance of the query's current estimate are candidates.
  double search_radius_m = 15.0;
  /// At most this many distance candidates, nearest first.
  int max_distance_candidates = 3;
  /// A key-frame is "recent" (never a candidate) when fewer than this many key-frames
  /// separate it from the query ...
  int min_keyframe_gap = 20;
  /// ... or when less than this distance was travelled between them (summed
  /// key-frame-to-key-frame motion at insertion, so later corrections do not change it).
  double min_travel_gap_m = 60.0;

  // ---- candidates by appearance (beyond the paper) ----
  AppearanceRetrieval retrieval = AppearanceRetrieval::kHammingVotes;
  /// Top-k key-frames by appearance (normalised score) that become candidates.
  int max_appearance_candidates = 3;
  /// Descriptor substrings (hash tables) of 16 bits used, 1..16 (16: the whole
  /// 256-bit descriptor is indexed).
  int num_hash_tables = 16;
  /// kHammingVotes: a proposed database descriptor counts within this many bits.
  int retrieval_max_hamming = 50;
  /// Substring buckets holding more than this fraction of all indexed features (and
  /// more than 64) are skipped: generic patterns, "stop words".
  double max_bucket_fraction = 0.01;
  /// ... and buckets holding more than this many features whatever the database size
  /// (bounds the retrieval cost, which otherwise grows with the database). 0: no cap.
  int max_bucket_size = 256;
  /// kHammingVotes: votes of a key-frame are histogrammed by the keypoint rotation they
  /// imply (ORB angle difference) in bins of this size, and its score is the best
  /// three-bin window: a real revisit votes for one relative yaw, chance look-alikes
  /// for any. 0 disables the rotation consistency (all votes count).
  double rotation_bin_deg = 10.0;
  /// A key-frame needs at least this appearance score (votes) to be a candidate.
  int min_appearance_score = 20;

  // ---- verification ----
  /// At most this many candidates are verified per query (best first).
  int max_verifications = 4;
  /// Verification stops once this many candidates are accepted (the dense check of an
  /// accepted loop costs ~60-100 ms; one loop per key-frame is enough for the graph).
  int max_accepted = 1;
  /// ORB matching (query -> candidate): at most 64 bits, Lowe's ratio 0.8, mutual
  /// check, no spatial gate (the guess may be far off).
  HammingMatchParams matching = [] {
    HammingMatchParams p;
    p.max_hamming_distance = 64;
    p.ratio = 0.8;
    p.mutual_check = true;
    p.spatial_gate_radius_m = 0.0;
    return p;
  }();
  /// Seeded RANSAC on the matched 3D feature points (0.5 m inlier threshold, seed 42);
  /// its min_inliers is replaced by min_initial_inliers / min_inliers below.
  RigidRansacParams ransac = [] {
    RigidRansacParams p;
    p.inlier_threshold_m = 0.5;
    p.max_iterations = 2000;
    p.seed = 42;
    return p;
  }();
  /// First RANSAC (on the ratio-test matches): fewer inliers than this, rejected.
  int min_initial_inliers = 12;
  /// Fewer first-RANSAC inliers / ratio-test matches than this: rejected (many
  /// matches, few consistent: typical of repetitive scenes).
  double min_inlier_ratio = 0.25;
  /// Distance candidates whose ratio-tested matches fail (a place passed the other way:
  /// rotated 130-175 deg, the raster's ORB descriptors pair 1-6 true matches) are
  /// matched again under the odometry guess: each query feature against the candidate
  /// features within min(odometry tolerance, this) of where the guess puts it, nearest
  /// descriptor, no ratio test; then the same checks as below. 0 disables [m].
  double guess_gate_max_m = 4.0;
  /// Final (guided) RANSAC inliers needed on that path, instead of min_inliers: a place
  /// passed the other way pairs 21-36 features even under the true motion (KITTI 00,
  /// simulated), and the odometry guess, the gate and the dense check below already
  /// rule out the look-alikes the paper's 40 guard against.
  int min_guess_inliers = 20;
  /// When the ratio-tested matches fail and there is no guess to gate by (a placement
  /// on a map, whatever the pose): the nearest descriptor of every query feature
  /// (mutual, no ratio test), kept when the ORB rotation it implies falls in the
  /// best window of three rotation_bin_deg bins, then RANSAC on those. A revisit in
  /// another run pairs few features that pass the ratio test (other traffic, another
  /// lane, other noise), while its nearest descriptors agree on one relative yaw.
  /// Off for loops within a run (their ratio test works, and distance candidates have
  /// the odometry guess); SessionLocalizer turns it on.
  bool rotation_filtered_matching = false;
  /// Guided matching: from the first estimate, every query feature is matched among the
  /// candidate features within this radius (ratio test 0.9, mutual), then RANSAC again.
  double guided_radius_m = 1.0;
  /// Final (guided) RANSAC inliers: fewer than this, rejected (the paper's minimum).
  int min_inliers = 40;
  /// Spatial spread: inliers must occupy at least min_inlier_cells cells of this size
  /// in the query's x-y plane ...
  double spread_cell_size_m = 8.0;
  int min_inlier_cells = 6;
  /// ... and their smaller principal standard deviation in x-y must reach this (not all
  /// on one wall or one object).
  double min_inlier_spread_m = 3.0;
  /// Uniqueness: RANSAC is run again on the outliers of the best model; a second,
  /// different model (more than 2 m or 10 deg away) with at least this fraction of the
  /// best model's inliers makes the pair ambiguous (repetitive scene): rejected.
  /// 1 disables the test.
  double max_second_model_ratio = 0.5;

  /// Self-similarity: the candidate's and the query's features are matched against
  /// themselves at other places (more than 3 m away); a rigid shift explaining at least
  /// this fraction of the loop's inliers (and min_initial_inliers) means the scene
  /// repeats (measured: 23-36 self inliers in a street of equal blocks, 0-3 in the
  /// simulated town, for loops of 70-100 inliers)
  /// and appearance cannot tell the copies apart. Such a loop is accepted only from a
  /// distance candidate whose odometry tolerance is below half that shift. 1 disables.
  double max_self_similarity_ratio = 0.2;

  /// Dense check: point-to-plane refinement of the query cloud on the candidate cloud
  /// from the feature estimate; off: the feature estimate is final.
  bool dense_check = true;
  /// Parameters of the refinement (voxel sizes, pairing distance, allowed correction).
  /// The feature estimate must already be close: at most 1.5 m and 5 deg of correction.
  PointToPlaneParams dense = [] {
    PointToPlaneParams p;
    p.source_voxel_size_m = 1.0; // query planes: one point per 1 m voxel
    p.target_voxel_size_m = 0.6;
    p.max_correspondence_distance_m = 1.0;
    p.max_iterations = 20;
    p.min_overlap_ratio = 0.1; // the overlap test below is stricter and ground-free
    p.max_correction_m = 1.5;
    p.max_correction_rad = 5.0 * 3.14159265358979323846 / 180.0;
    return p;
  }();
  /// Both clouds are cropped to this horizontal radius around their sensor (speed).
  double dense_crop_radius_m = 40.0;
  /// Of the query's structure points (planar, non-horizontal: walls, not ground), at
  /// least this fraction must lie on a candidate plane of similar normal after the
  /// refinement ...
  double min_dense_overlap = 0.35;
  /// A pair whose overlap falls short of min_dense_overlap but reaches this passes the
  /// check with LoopVerification::dense_short set, for a caller that takes it as a
  /// tentative result only (SessionLocalizer). Negative: none (the loop closure).
  double tentative_dense_overlap = -1.0;
  /// ... within this point-to-plane distance.
  double dense_inlier_distance_m = 0.25;
  /// RMS point-to-plane distance of those paired structure points at most.
  double max_dense_rmse_m = 0.12;
  /// A query with fewer structure points than this leaves the dense check undecided:
  /// an open highway (a low guard rail, a sloped embankment) holds 10-20 within the
  /// crop radius where a street holds hundreds, and a share of so few says nothing
  /// either way. Such a pair passes the check with LoopVerification::dense_undecided
  /// set, its pose the refinement's, for the caller to weigh (SessionLocalizer takes it
  /// as a tentative placement). 0: the share decides however few they are (the loop
  /// closure's choice: a loop it cannot confirm is left out).
  int min_dense_structure = 0;

  /// After a loop is accepted, its transform is refined once more: the query's whole
  /// cloud at 0.5 m voxels on the candidate's dense target, plane-to-plane (the check
  /// above fits 1 m query voxels, point-to-plane, to decide). On the procedural VLP-16
  /// loop the edge went from 3.6 cm / 0.065 deg to 1.0 cm / 0.010 deg off. Merging the
  /// candidate's neighbours into the target was tried and was worse there (8 cm /
  /// 0.3 deg): their relative poses carry the odometry's own errors. false: off.
  bool final_refinement = true;
  /// Its settings; a result farther than final_max_change_m / _deg from the checked
  /// transform is not used (the two disagree, keep the verified one).
  PointToPlaneParams final_refine = [] {
    PointToPlaneParams p;
    p.source_voxel_size_m = 0.5;
    p.target_voxel_size_m = 0.6; // the stored dense targets' voxel size
    p.max_correspondence_distance_m = 0.5;
    p.max_source_points = 3000;
    p.max_iterations = 20;
    p.max_correction_m = 0.5;
    p.max_correction_rad = 2.0 * 3.14159265358979323846 / 180.0;
    return p;
  }();
  double final_max_change_m = 0.3;
  double final_max_change_deg = 1.0;

  /// Consistency with odometry, for candidates found by distance only (not also by
  /// appearance; the drift since the candidate is assumed small there): the verified
  /// motion may differ from the estimate by at most this translation ...
  double max_odometry_deviation_m = 3.0;
  /// ... and rotation ...
  double max_odometry_deviation_deg = 10.0;
  /// ... plus this fraction of the distance travelled between candidate and query
  /// (odometry drift grows with it) ...
  double odometry_deviation_per_m = 0.05;
  /// ... and, for rotation, this many degrees per metre travelled.
  double odometry_deviation_deg_per_m = 0.02;

  /// \brief Whether all values are usable; on failure \a why (if not null) says which.
  bool isValid(std::string* why = nullptr) const;
};

/// \brief Why a key-frame became a candidate.
enum class LoopCandidateSource
{
  kDistance,   ///< near the query's current estimate (the paper)
  kAppearance, ///< among the top-k by appearance
  kBoth        ///< both
};

/// \brief Short name of a source ("distance", "appearance", "both").
const char* toString(LoopCandidateSource source);
/// \brief Short name of a retrieval ("none", "substring_votes", "hamming_votes").
const char* toString(AppearanceRetrieval retrieval);

/// \brief A loop candidate of a query key-frame.
struct LoopCandidate
{
  KeyFrameId keyframe = 0;  ///< the candidate in the database
  double distance_m = 0.0;  ///< between the query's estimate and the candidate's pose
  int appearance_score = 0; ///< appearance votes (0 when retrieval is kNone)
  LoopCandidateSource source = LoopCandidateSource::kDistance;
};

/// \brief The verification of one (query, candidate) pair.
struct LoopVerification
{
  bool accepted = false;
  KeyFrameId query = 0, candidate = 0;
  /// p_candidate = T_candidate_query * p_query (LiDAR frames); the dense refinement's
  /// result when it ran, otherwise the feature estimate. Meaningful when accepted.
  Pose3d T_candidate_query = Pose3d::Identity();
  /// Ratio-test ORB matches; final RANSAC inliers (after guided matching).
  int num_matches = 0, num_inliers = 0;
  double inlier_rmse_m = 0.0; ///< RMS 3D residual of the RANSAC inliers
  double dense_rmse_m = 0.0;  ///< RMS point-to-plane distance of paired structure points
  double dense_overlap = 0.0; ///< fraction of query structure points paired
  /// The query held too few structure points for the dense check to decide
  /// (LoopDetectorParams::min_dense_structure): passed on the features' checks alone.
  bool dense_undecided = false;
  /// The overlap fell short of min_dense_overlap but reached
  /// LoopDetectorParams::tentative_dense_overlap: passed, for the caller to weigh.
  bool dense_short = false;
  std::string reason;         ///< why rejected, or a short summary when accepted
  // added beyond the contract
  int num_initial_inliers = 0;  ///< first RANSAC inliers among num_matches
  int num_guided_matches = 0;   ///< matches of the guided (gated) matching
  bool from_guess = false;      ///< first estimate from matches gated by the odometry guess
  double inlier_ratio = 0.0;    ///< num_initial_inliers / num_matches
  int inlier_cells = 0;         ///< occupied spread cells
  double inlier_spread_m = 0.0; ///< smaller principal std of the inliers (x-y)
  int second_model_inliers = 0; ///< inliers of the best different model (ambiguity)
  int self_similar_inliers = 0; ///< inliers of the best self-shift (repetitive scene)
  double self_similar_shift_m = 0.0; ///< length of that shift
  double verify_ms = 0.0;            ///< wall time of this verification
  /// Whether the final refinement (LoopDetectorParams::final_refinement) was used, and
  /// how far it moved the checked transform.
  bool refined = false;
  double refinement_change_m = 0.0;
  double refinement_change_deg = 0.0;
};

/// \brief Everything detect() found for one query.
struct LoopDetection
{
  std::vector<LoopCandidate> candidates;       ///< in verification order
  std::vector<LoopVerification> verifications; ///< of the first max_verifications
  int num_accepted = 0, num_rejected = 0;
  double retrieval_ms = 0.0; ///< candidate search (distance + appearance)
  double verify_ms = 0.0;    ///< all verifications

  /// \brief The accepted verification with the most inliers, or nullptr.
  const LoopVerification* best() const;
};

/// \brief How far a verified motion may be from a guess; negative: not checked.
struct GuessTolerance
{
  double translation_m = -1.0;
  double rotation_deg = -1.0;
  /// The dense check's least overlap for a pair verified under this guess (negative:
  /// LoopDetectorParams::min_dense_overlap). A scan entering the map from a road the
  /// map lacks sees much structure the key-frame does not: with a guess that already
  /// bounds the pose, a smaller share of it may be enough.
  double min_dense_overlap = -1.0;
};

} // namespace rast
} // namespace pcl
