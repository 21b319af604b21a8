/// \file trajectory_evaluation.cpp
/// \brief ATE after Umeyama alignment, KITTI devkit relative errors, per-frame RPE.

#include <Eigen/SVD>
#include <algorithm>
#include <cmath>
#include <iomanip>
#include <nlohmann/json.hpp>
#include <numeric>
#include <pcl/evaluation/trajectory_evaluation.h>
#include <sstream>
#include <stdexcept>
#include <tuple>

namespace pcl {
namespace rast {
namespace {

constexpr double kRadToDeg = 180.0 / M_PI;

/// Mean and root mean square of \a values (zeros when empty).
std::pair<double, double>
meanAndRmse(const std::vector<double>& values)
{
  if (values.empty())
    return {0.0, 0.0};
  double sum = 0.0, sum_sq = 0.0;
  for (const double v : values) {
    sum += v;
    sum_sq += v * v;
  }
  const double n = static_cast<double>(values.size());
  return {sum / n, std::sqrt(sum_sq / n)};
}

/// Cumulative path length of the positions (devkit: trajectoryDistances).
std::vector<double>
trajectoryDistances(const PoseVector& poses)
{
  std::vector<double> dist(poses.size(), 0.0);
  for (std::size_t i = 1; i < poses.size(); ++i)
    dist[i] = dist[i - 1] + (poses[i].translation() - poses[i - 1].translation()).norm();
  return dist;
}

/// First frame whose distance exceeds dist[first] + len, or -1 (devkit:
/// lastFrameFromSegmentLength, with its strict '>').
long
lastFrameFromSegmentLength(const std::vector<double>& dist, std::size_t first, double len)
{
  for (std::size_t i = first; i < dist.size(); ++i)
    if (dist[i] > dist[first] + len)
      return static_cast<long>(i);
  return -1;
}

/// KITTI devkit calcSequenceErrors + the pooled and per-length averages.
void
computeKittiErrors(const PoseVector& est,
                   const PoseVector& gt,
                   const EvaluationParams& params,
                   EvaluationResult& result)
{
  const auto dist = trajectoryDistances(gt);
  const std::size_t num_lengths = params.segment_lengths_m.size();
  std::vector<double> t_sum(num_lengths, 0.0), r_sum(num_lengths, 0.0);
  std::vector<std::size_t> count(num_lengths, 0);
  double t_total = 0.0, r_total = 0.0; // t: [m/m], r: [rad/m], as the devkit stores them
  std::size_t n_total = 0;

  const std::size_t step = static_cast<std::size_t>(params.step_size_frames);
  for (std::size_t first = 0; first < gt.size(); first += step) {
    for (std::size_t l = 0; l < num_lengths; ++l) {
      const double len = params.segment_lengths_m[l];
      const long last = lastFrameFromSegmentLength(dist, first, len);
      if (last < 0)
        continue;
      const Pose3d delta_gt = gt[first].inverse() * gt[last];
      const Pose3d delta_est = est[first].inverse() * est[last];
      const Pose3d error = delta_est.inverse() * delta_gt;
      const double r_err = rotationAngleRad(error) / len;
      const double t_err = error.translation().norm() / len;
      t_sum[l] += t_err;
      r_sum[l] += r_err;
      ++count[l];
      t_total += t_err;
      r_total += r_err;
      ++n_total;
    }
  }

  const auto to_pct = [](double t_m_per_m) { return t_m_per_m * 100.0; };
  const auto to_deg_per_100m = [](double r_rad_per_m) {
    return r_rad_per_m * kRadToDeg * 100.0;
  };
  result.kitti_num_segments = n_total;
  if (n_total > 0) {
    result.kitti_t_err_pct = to_pct(t_total / n_total);
    result.kitti_r_err_deg_per_100m = to_deg_per_100m(r_total / n_total);
  }
  result.kitti_per_length.clear();
  for (std::size_t l = 0; l < num_lengths; ++l) {
    SegmentLengthError e;
    e.length_m = params.segment_lengths_m[l];
    e.num_segments = count[l];
    if (count[l] > 0) {
      e.t_err_pct = to_pct(t_sum[l] / count[l]);
      e.r_err_deg_per_100m = to_deg_per_100m(r_sum[l] / count[l]);
    }
    result.kitti_per_length.push_back(e);
  }
}

/// ATE statistics of the position errors after alignment.
void
computeAte(const PoseVector& est_aligned, const PoseVector& gt, EvaluationResult& result)
{
  std::vector<double> errors(gt.size());
  for (std::size_t i = 0; i < gt.size(); ++i)
    errors[i] = (gt[i].translation() - est_aligned[i].translation()).norm();
  const auto [mean, rmse] = meanAndRmse(errors);
  result.ate_mean_m = mean;
  result.ate_rmse_m = rmse;
  result.ate_std_m = std::sqrt(std::max(0.0, rmse * rmse - mean * mean));
  result.ate_max_m = *std::max_element(errors.begin(), errors.end());
  std::vector<double> sorted = errors;
  std::sort(sorted.begin(), sorted.end());
  const std::size_t n = sorted.size();
  result.ate_median_m =
      n % 2 == 1 ? sorted[n / 2] : 0.5 * (sorted[n / 2 - 1] + sorted[n / 2]);
}

/// Per-frame relative pose error between consecutive frames.
void
computeRpe(const PoseVector& est, const PoseVector& gt, EvaluationResult& result)
{
  std::vector<double> trans, rot;
  for (std::size_t i = 1; i < gt.size(); ++i) {
    const Pose3d delta_gt = gt[i - 1].inverse() * gt[i];
    const Pose3d delta_est = est[i - 1].inverse() * est[i];
    const Pose3d error = delta_est.inverse() * delta_gt;
    trans.push_back(error.translation().norm());
    rot.push_back(rotationAngleRad(error) * kRadToDeg);
  }
  std::tie(result.rpe_trans_mean_m, result.rpe_trans_rmse_m) = meanAndRmse(trans);
  std::tie(result.rpe_rot_mean_deg, result.rpe_rot_rmse_deg) = meanAndRmse(rot);
}

nlohmann::json
optionalToJson(const std::optional<double>& value)
{
  return value ? nlohmann::json(*value) : nlohmann::json(nullptr);
}

} // namespace

bool
EvaluationParams::isValid(std::string* why) const
{
  const auto fail = [why](const std::string& message) {
    if (why)
      *why = message;
    return false;
  };
  if (!(max_time_difference_s >= 0.0) || !std::isfinite(max_time_difference_s))
    return fail("max_time_difference_s must be finite and >= 0, got " +
                std::to_string(max_time_difference_s));
  if (step_size_frames < 1)
    return fail("step_size_frames must be >= 1, got " + std::to_string(step_size_frames));
  for (const double len : segment_lengths_m)
    if (!(len > 0.0) || !std::isfinite(len))
      return fail("segment_lengths_m must be finite and > 0, got " + std::to_string(len));
  return true;
}

Pose3d
umeyamaAlignment(const std::vector<Eigen::Vector3d>& src,
                 const std::vector<Eigen::Vector3d>& dst,
                 bool with_scale,
                 double* scale)
{
  if (src.size() != dst.size() || src.size() < 2)
    throw std::invalid_argument(
        "umeyamaAlignment: need equally many points (>= 2), got " +
        std::to_string(src.size()) + " and " + std::to_string(dst.size()));
  const std::size_t n = src.size();
  Eigen::Vector3d mu_src = Eigen::Vector3d::Zero(), mu_dst = Eigen::Vector3d::Zero();
  for (std::size_t i = 0; i < n; ++i) {
    mu_src += src[i];
    mu_dst += dst[i];
  }
  mu_src /= n;
  mu_dst /= n;
  // Covariance Sigma = 1/n sum (dst - mu_dst)(src - mu_src)^T and variance of src (eq.
  // 36-38).
  Eigen::Matrix3d sigma = Eigen::Matrix3d::Zero();
  double var_src = 0.0, var_dst = 0.0;
  for (std::size_t i = 0; i < n; ++i) {
    sigma += (dst[i] - mu_dst) * (src[i] - mu_src).transpose();
    var_src += (src[i] - mu_src).squaredNorm();
    var_dst += (dst[i] - mu_dst).squaredNorm();
  }
  sigma /= n;
  var_src /= n;
  var_dst /= n;
  // A scale between point sets is only defined when both spread: against a trajectory
  // that stands still it would come out 0 and shrink the estimate onto it (ATE 0).
  constexpr double kMinSpreadM = 1e-6;
  if (with_scale && (var_src < kMinSpreadM * kMinSpreadM || var_dst < kMinSpreadM * kMinSpreadM))
    throw std::invalid_argument(
        "umeyamaAlignment: a Sim(3) alignment needs positions that spread, but the " +
        std::string(var_src < var_dst ? "source" : "target") + " positions stay within " +
        std::to_string(std::sqrt(std::min(var_src, var_dst))) +
        " m (rms) of their mean; use an SE(3) alignment");

  const Eigen::JacobiSVD<Eigen::Matrix3d> svd(sigma,
                                              Eigen::ComputeFullU | Eigen::ComputeFullV);
  // S = diag(1, 1, -1) when det(U) det(V) < 0, to get a proper rotation (eq. 39-40).
  Eigen::Vector3d s_diag = Eigen::Vector3d::Ones();
  if (svd.matrixU().determinant() * svd.matrixV().determinant() < 0.0)
    s_diag(2) = -1.0;
  const Eigen::Matrix3d R =
      svd.matrixU() * s_diag.asDiagonal() * svd.matrixV().transpose();
  // c = tr(D S) / var_src (eq. 42).
  double c = 1.0;
  if (with_scale)
    c = svd.singularValues().dot(s_diag) / var_src;

  Pose3d T = Pose3d::Identity();
  T.linear() = R;
  T.translation() = mu_dst - c * R * mu_src; // eq. 41
  if (scale)
    *scale = c;
  return T;
}

double
rotationAngleRad(const Pose3d& T)
{
  const Eigen::Matrix3d R = T.linear();
  const double d = 0.5 * (R(0, 0) + R(1, 1) + R(2, 2) - 1.0);
  return std::acos(std::max(std::min(d, 1.0), -1.0));
}

EvaluationResult
evaluateTrajectory(const PoseVector& T_world_estimate,
                   const PoseVector& T_world_gt,
                   const EvaluationParams& params)
{
  std::string why;
  if (!params.isValid(&why))
    throw std::invalid_argument("evaluateTrajectory: invalid params: " + why);
  if (T_world_estimate.size() != T_world_gt.size())
    throw std::invalid_argument("evaluateTrajectory: the estimate has " +
                                std::to_string(T_world_estimate.size()) +
                                " poses but the ground truth has " +
                                std::to_string(T_world_gt.size()));
  if (T_world_gt.size() < 2)
    throw std::invalid_argument("evaluateTrajectory: need at least 2 poses, got " +
                                std::to_string(T_world_gt.size()));

  EvaluationResult result;
  result.num_frames = T_world_gt.size();
  result.num_estimate_poses = T_world_estimate.size();
  result.num_ground_truth_poses = T_world_gt.size();
  result.alignment = params.alignment;
  result.gt_length_m = trajectoryDistances(T_world_gt).back();

  // 1. Align the estimate's positions to the ground truth's.
  if (params.alignment != TrajectoryAlignment::kNone) {
    std::vector<Eigen::Vector3d> src, dst;
    for (std::size_t i = 0; i < T_world_gt.size(); ++i) {
      src.push_back(T_world_estimate[i].translation());
      dst.push_back(T_world_gt[i].translation());
    }
    result.T_gt_estimate = umeyamaAlignment(
        src, dst, params.alignment == TrajectoryAlignment::kSim3, &result.scale);
  }
  // Apply p -> s R p + t to every pose (rotation R R_i); SE(3) leaves relative
  // motions unchanged, Sim(3) scales their translations.
  const Eigen::Matrix3d& R_align = result.T_gt_estimate.linear();
  PoseVector est_aligned = T_world_estimate;
  for (auto& T : est_aligned) {
    T.translation() =
        R_align * (result.scale * T.translation()) + result.T_gt_estimate.translation();
    T.linear() = R_align * T.linear();
  }

  // 2. Metrics.
  computeAte(est_aligned, T_world_gt, result);
  computeKittiErrors(est_aligned, T_world_gt, params, result);
  computeRpe(est_aligned, T_world_gt, result);
  return result;
}

std::vector<std::pair<std::size_t, std::size_t>>
associateByTimestamp(const std::vector<double>& estimate_s,
                     const std::vector<double>& ground_truth_s,
                     double max_difference_s)
{
  // Ground-truth indices sorted by time, to find candidates by binary search.
  std::vector<std::size_t> gt_order(ground_truth_s.size());
  std::iota(gt_order.begin(), gt_order.end(), 0);
  std::sort(gt_order.begin(), gt_order.end(), [&](std::size_t a, std::size_t b) {
    return ground_truth_s[a] < ground_truth_s[b];
  });
  std::vector<double> gt_sorted;
  for (const std::size_t j : gt_order)
    gt_sorted.push_back(ground_truth_s[j]);

  // All candidate pairs within the window, then greedily the closest first.
  std::vector<std::tuple<double, std::size_t, std::size_t>> candidates;
  for (std::size_t i = 0; i < estimate_s.size(); ++i) {
    const double t = estimate_s[i];
    auto it = std::lower_bound(gt_sorted.begin(), gt_sorted.end(), t - max_difference_s);
    for (; it != gt_sorted.end() && *it <= t + max_difference_s; ++it)
      candidates.emplace_back(std::abs(*it - t), i, gt_order[it - gt_sorted.begin()]);
  }
  std::sort(candidates.begin(), candidates.end());
  std::vector<bool> est_used(estimate_s.size(), false),
      gt_used(ground_truth_s.size(), false);
  std::vector<std::pair<std::size_t, std::size_t>> pairs;
  for (const auto& [diff, i, j] : candidates) {
    if (est_used[i] || gt_used[j])
      continue;
    est_used[i] = gt_used[j] = true;
    pairs.emplace_back(i, j);
  }
  std::sort(pairs.begin(), pairs.end(), [&](const auto& a, const auto& b) {
    return estimate_s[a.first] < estimate_s[b.first];
  });
  return pairs;
}

EvaluationResult
evaluateTrajectory(const Trajectory& estimate,
                   const Trajectory& ground_truth,
                   const EvaluationParams& params)
{
  std::string why;
  if (!params.isValid(&why))
    throw std::invalid_argument("evaluateTrajectory: invalid params: " + why);
  const bool by_timestamp =
      params.association == PoseAssociation::kByTimestamp ||
      (params.association == PoseAssociation::kAuto &&
       estimate.format == PoseFormat::kTum && ground_truth.format == PoseFormat::kTum);
  if (!by_timestamp)
    return evaluateTrajectory(estimate.poses, ground_truth.poses, params);

  if (estimate.timestamps_s.size() != estimate.poses.size() ||
      ground_truth.timestamps_s.size() != ground_truth.poses.size())
    throw std::invalid_argument(
        "evaluateTrajectory: timestamps and poses differ in number");
  const auto pairs = associateByTimestamp(
      estimate.timestamps_s, ground_truth.timestamps_s, params.max_time_difference_s);
  if (pairs.size() < 2)
    throw std::invalid_argument(
        "evaluateTrajectory: only " + std::to_string(pairs.size()) + " of " +
        std::to_string(estimate.poses.size()) + " estimate and " +
        std::to_string(ground_truth.poses.size()) +
        " ground-truth poses associate within " +
        std::to_string(params.max_time_difference_s) + " s; need at least 2");
  PoseVector est, gt;
  for (const auto& [i, j] : pairs) {
    est.push_back(estimate.poses[i]);
    gt.push_back(ground_truth.poses[j]);
  }
  EvaluationResult result = evaluateTrajectory(est, gt, params);
  result.num_estimate_poses = estimate.poses.size();
  result.num_ground_truth_poses = ground_truth.poses.size();
  return result;
}

std::string
toString(TrajectoryAlignment alignment)
{
  switch (alignment) {
  case TrajectoryAlignment::kNone:
    return "none";
  case TrajectoryAlignment::kSE3:
    return "se3";
  case TrajectoryAlignment::kSim3:
    return "sim3";
  }
  return "unknown";
}

std::string
toText(const EvaluationResult& r)
{
  std::ostringstream out;
  out << std::fixed << std::setprecision(4);
  out << "frames:          " << r.num_frames << " (estimate " << r.num_estimate_poses
      << ", ground truth " << r.num_ground_truth_poses << ")\n";
  out << "gt length:       " << r.gt_length_m << " m\n";
  out << "alignment:       " << toString(r.alignment);
  if (r.alignment == TrajectoryAlignment::kSim3)
    out << " (scale " << r.scale << ")";
  out << "\n";
  out << "ATE [m]:         rmse " << r.ate_rmse_m << "  mean " << r.ate_mean_m
      << "  median " << r.ate_median_m << "  std " << r.ate_std_m << "  max "
      << r.ate_max_m << "\n";
  out << "RPE per frame:   trans rmse " << r.rpe_trans_rmse_m << " m  mean "
      << r.rpe_trans_mean_m << " m;  rot rmse " << r.rpe_rot_rmse_deg << " deg  mean "
      << r.rpe_rot_mean_deg << " deg\n";
  if (!r.kitti_t_err_pct) {
    out << "KITTI:           n/a (no segment: ground truth shorter than the shortest "
           "length)\n";
    return out.str();
  }
  out << "KITTI:           t_err " << *r.kitti_t_err_pct << " %  r_err "
      << *r.kitti_r_err_deg_per_100m << " deg/100m  (" << r.kitti_num_segments
      << " segments)\n";
  for (const auto& e : r.kitti_per_length) {
    out << "  " << std::setw(6) << std::setprecision(0) << e.length_m
        << " m: " << std::setprecision(4);
    if (e.t_err_pct)
      out << "t_err " << *e.t_err_pct << " %  r_err " << *e.r_err_deg_per_100m
          << " deg/100m  (" << e.num_segments << " segments)\n";
    else
      out << "n/a (0 segments)\n";
  }
  return out.str();
}

std::string
toJson(const EvaluationResult& r)
{
  nlohmann::json j;
  j["frames"] = r.num_frames;
  j["estimate_poses"] = r.num_estimate_poses;
  j["ground_truth_poses"] = r.num_ground_truth_poses;
  j["gt_length_m"] = r.gt_length_m;
  j["alignment"] = toString(r.alignment);
  j["scale"] = r.scale;
  std::vector<double> T;
  for (int row = 0; row < 4; ++row)
    for (int col = 0; col < 4; ++col)
      T.push_back(r.T_gt_estimate.matrix()(row, col));
  j["T_gt_estimate"] = T;
  j["ate_rmse_m"] = r.ate_rmse_m;
  j["ate_mean_m"] = r.ate_mean_m;
  j["ate_median_m"] = r.ate_median_m;
  j["ate_std_m"] = r.ate_std_m;
  j["ate_max_m"] = r.ate_max_m;
  j["kitti_t_err_pct"] = optionalToJson(r.kitti_t_err_pct);
  j["kitti_r_err_deg_per_100m"] = optionalToJson(r.kitti_r_err_deg_per_100m);
  j["kitti_num_segments"] = r.kitti_num_segments;
  nlohmann::json per_length = nlohmann::json::array();
  for (const auto& e : r.kitti_per_length)
    per_length.push_back({{"length_m", e.length_m},
                          {"segments", e.num_segments},
                          {"t_err_pct", optionalToJson(e.t_err_pct)},
                          {"r_err_deg_per_100m", optionalToJson(e.r_err_deg_per_100m)}});
  j["kitti_per_length"] = per_length;
  j["rpe_trans_rmse_m"] = r.rpe_trans_rmse_m;
  j["rpe_trans_mean_m"] = r.rpe_trans_mean_m;
  j["rpe_rot_rmse_deg"] = r.rpe_rot_rmse_deg;
  j["rpe_rot_mean_deg"] = r.rpe_rot_mean_deg;
  return j.dump(2);
}

} // namespace rast
} // namespace pcl
