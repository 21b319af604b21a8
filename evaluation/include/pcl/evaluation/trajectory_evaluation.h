#pragma once
/// \file trajectory_evaluation.h
/// \brief Trajectory accuracy against ground truth: absolute trajectory error (ATE)
/// after Umeyama alignment, the KITTI odometry benchmark's relative errors (exactly as
/// its devkit `evaluate_odometry.cpp` defines them) and per-frame relative pose error.
/// \ingroup evaluation

#include <cstddef>
#include <optional>
#include <pcl/io/pose_io.h>
#include <string>
#include <vector>

namespace pcl {
namespace rast {

/// \brief How the estimate is aligned to the ground truth before the ATE.
enum class TrajectoryAlignment
{
  kNone, ///< compare positions as they are
  kSE3,  ///< rotation + translation (Umeyama without scale)
  kSim3  ///< rotation + translation + scale (Umeyama with scale)
};

/// \brief How estimate and ground-truth poses are paired.
enum class PoseAssociation
{
  kAuto,       ///< by timestamp when both trajectories are TUM files, else by index
  kByIndex,    ///< pose i with pose i; the lengths must be equal
  kByTimestamp ///< nearest timestamps within max_time_difference_s, each used once
};

/// \brief Settings of evaluateTrajectory.
struct EvaluationParams
{
  /// Alignment of the estimate before all metrics. Relative metrics (KITTI, RPE) are
  /// invariant to an SE(3) alignment; a Sim(3) alignment also corrects their scale.
  TrajectoryAlignment alignment = TrajectoryAlignment::kSE3;
  /// Pairing of estimate and ground-truth poses (Trajectory overload only).
  PoseAssociation association = PoseAssociation::kAuto;
  /// Largest timestamp difference of an associated pair [s].
  double max_time_difference_s = 0.01;
  /// KITTI segment lengths along the ground truth [m] (devkit: 100, 200, ..., 800).
  std::vector<double> segment_lengths_m = {100, 200, 300, 400, 500, 600, 700, 800};
  /// KITTI: a segment starts every step_size frames (devkit: 10, "every second").
  int step_size_frames = 10;

  /// \brief Whether the settings are usable; otherwise \a why (if given) says why.
  bool isValid(std::string* why = nullptr) const;
};

/// \brief KITTI relative errors of the segments of one length.
struct SegmentLengthError
{
  double length_m = 0.0;
  std::size_t num_segments = 0;
  /// Mean translation error [%]; unset when there is no segment of this length.
  std::optional<double> t_err_pct;
  /// Mean rotation error [deg / 100 m]; unset when there is no segment of this length.
  std::optional<double> r_err_deg_per_100m;
};

/// \brief All metrics of one estimate against its ground truth.
struct EvaluationResult
{
  std::size_t num_frames = 0;             ///< evaluated (associated) pose pairs
  std::size_t num_estimate_poses = 0;     ///< poses in the estimate
  std::size_t num_ground_truth_poses = 0; ///< poses in the ground truth
  TrajectoryAlignment alignment = TrajectoryAlignment::kSE3;
  /// The alignment applied: p_gt ~ scale * R * p_est + t (rotation/translation here).
  Pose3d T_gt_estimate = Pose3d::Identity();
  double scale = 1.0;
  double gt_length_m = 0.0; ///< path length of the (associated) ground truth

  // ATE: position error after alignment [m].
  double ate_rmse_m = 0.0;
  double ate_mean_m = 0.0;
  double ate_median_m = 0.0;
  double ate_std_m = 0.0; ///< population standard deviation
  double ate_max_m = 0.0;

  // KITTI devkit relative errors, pooled over all segments of all lengths; unset
  // when there is no segment (ground truth shorter than the shortest length).
  std::size_t kitti_num_segments = 0;
  std::optional<double> kitti_t_err_pct;
  std::optional<double> kitti_r_err_deg_per_100m;
  std::vector<SegmentLengthError> kitti_per_length;

  // Per-frame RPE between consecutive evaluated frames.
  double rpe_trans_rmse_m = 0.0;
  double rpe_trans_mean_m = 0.0;
  double rpe_rot_rmse_deg = 0.0;
  double rpe_rot_mean_deg = 0.0;
};

/// \brief Umeyama alignment of point sets: the transform minimizing
/// sum ||dst_i - (s R src_i + t)||^2 (Umeyama 1991, eq. 40-42).
/// \param[in] src, dst equally many positions (at least 2)
/// \param[in] with_scale estimate s (Sim(3)); otherwise s = 1 (SE(3))
/// \param[out] scale the estimated scale (may be null)
/// \return the rotation and translation (R, t)
/// \throws std::invalid_argument on a size mismatch, fewer than 2 points, or, with
/// \a with_scale, when either set stays within 1 um (rms) of its mean: no scale exists.
Pose3d umeyamaAlignment(const std::vector<Eigen::Vector3d>& src,
                        const std::vector<Eigen::Vector3d>& dst,
                        bool with_scale,
                        double* scale = nullptr);

/// \brief Evaluate an estimate against ground truth paired by index.
/// \throws std::invalid_argument when the lengths differ (naming both), when there are
/// fewer than 2 poses or when \a params is invalid.
EvaluationResult evaluateTrajectory(const PoseVector& T_world_estimate,
                                    const PoseVector& T_world_gt,
                                    const EvaluationParams& params = {});

/// \brief Evaluate trajectories read from files, paired as params.association says.
/// \throws std::invalid_argument as above, or when fewer than 2 pairs associate.
EvaluationResult evaluateTrajectory(const Trajectory& estimate,
                                    const Trajectory& ground_truth,
                                    const EvaluationParams& params = {});

/// \brief Pairs (estimate index, ground-truth index) of timestamps closer than
/// \a max_difference_s, nearest first, each pose used at most once (like TUM's
/// associate.py), sorted by estimate timestamp.
std::vector<std::pair<std::size_t, std::size_t>>
associateByTimestamp(const std::vector<double>& estimate_s,
                     const std::vector<double>& ground_truth_s,
                     double max_difference_s);

/// \brief The rotation angle of a pose's rotation [rad], as the devkit computes it:
/// acos(clamp(0.5 * (trace(R) - 1), -1, 1)).
double rotationAngleRad(const Pose3d& T);

/// \brief Name of an alignment: "none", "se3", "sim3".
std::string toString(TrajectoryAlignment alignment);

/// \brief Human-readable multi-line summary.
std::string toText(const EvaluationResult& result);

/// \brief One JSON object with the fields `frames`, `ate_rmse_m`, `ate_mean_m`,
/// `ate_median_m`, `ate_std_m`, `ate_max_m`, `kitti_t_err_pct`,
/// `kitti_r_err_deg_per_100m` (null without segments), `kitti_num_segments`,
/// `kitti_per_length` (array), `rpe_trans_rmse_m`, `rpe_trans_mean_m`,
/// `rpe_rot_rmse_deg`, `rpe_rot_mean_deg`, `alignment`, `scale`, `T_gt_estimate`
/// (4x4 row-major), `gt_length_m`, `estimate_poses`, `ground_truth_poses`.
std::string toJson(const EvaluationResult& result);

} // namespace rast
} // namespace pcl
