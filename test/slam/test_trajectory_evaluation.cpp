// Trajectory evaluation: ATE after alignment, KITTI devkit relative errors, RPE.
#include "test_data.h"

#include <cmath>
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>
#include <pcl/evaluation/trajectory_evaluation.h>
#include <random>

// This file's names stay its own: a test program compiles several test files as
// one translation unit (test/CMakeLists.txt).
namespace test_trajectory_evaluation {

namespace {

using namespace pcl::rast;

constexpr double kDegToRad = M_PI / 180.0;

/// A planar vehicle path: \a n frames \a step_m apart with a gently varying heading
/// and a little height change. Rotations are yaw only.
PoseVector
generatePath(std::size_t n, double step_m)
{
  PoseVector poses;
  Eigen::Vector3d p = Eigen::Vector3d::Zero();
  for (std::size_t i = 0; i < n; ++i) {
    const double s = step_m * i;
    const double yaw = 0.05 * std::sin(s / 100.0);
    Pose3d T = Pose3d::Identity();
    T.linear() = Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()).toRotationMatrix();
    T.translation() = p;
    poses.push_back(T);
    p += step_m * Eigen::Vector3d(std::cos(yaw), std::sin(yaw), 0.0);
  }
  return poses;
}

/// Positions scaled by \a factor about the origin, rotations unchanged: every relative
/// translation is \a factor times too long.
PoseVector
scaled(PoseVector poses, double factor)
{
  for (auto& T : poses)
    T.translation() *= factor;
  return poses;
}

/// The same relative motions with an extra yaw of \a yaw_rad per frame.
PoseVector
withYawDrift(const PoseVector& gt, double yaw_rad)
{
  PoseVector est{gt.front()};
  for (std::size_t i = 1; i < gt.size(); ++i)
    est.push_back(est.back() * (gt[i - 1].inverse() * gt[i]) *
                  Eigen::AngleAxisd(yaw_rad, Eigen::Vector3d::UnitZ()));
  return est;
}

Pose3d
someRigidTransform()
{
  Pose3d T = Pose3d::Identity();
  T.linear() = (Eigen::AngleAxisd(0.7, Eigen::Vector3d::UnitZ()) *
                Eigen::AngleAxisd(0.2, Eigen::Vector3d::UnitX()))
                   .toRotationMatrix();
  T.translation() << 12.0, -3.0, 4.5;
  return T;
}

TEST(TrajectoryEvaluation, IdenticalTrajectoriesGiveZeros)
{
  const auto gt = generatePath(2000, 0.5); // 1000 m
  const auto r = evaluateTrajectory(gt, gt);
  EXPECT_EQ(r.num_frames, 2000u);
  EXPECT_NEAR(r.gt_length_m, 999.5, 1e-6);
  EXPECT_NEAR(r.ate_rmse_m, 0.0, 1e-9);
  EXPECT_NEAR(r.ate_max_m, 0.0, 1e-9);
  ASSERT_TRUE(r.kitti_t_err_pct && r.kitti_r_err_deg_per_100m);
  EXPECT_NEAR(*r.kitti_t_err_pct, 0.0, 1e-9);
  EXPECT_NEAR(*r.kitti_r_err_deg_per_100m, 0.0, 1e-4); // acos near 1 is coarse
  EXPECT_GT(r.kitti_num_segments, 0u);
  EXPECT_NEAR(r.rpe_trans_rmse_m, 0.0, 1e-9);
  EXPECT_NEAR(r.rpe_rot_rmse_deg, 0.0, 1e-4);
  ASSERT_EQ(r.kitti_per_length.size(), 8u);
  EXPECT_EQ(r.kitti_per_length.back().length_m, 800.0);
}

TEST(TrajectoryEvaluation, RigidOffsetIsRemovedByAlignment)
{
  const auto gt = generatePath(800, 0.5);
  PoseVector est;
  for (const auto& T : gt)
    est.push_back(someRigidTransform() * T);

  const auto r = evaluateTrajectory(est, gt);
  EXPECT_NEAR(r.ate_rmse_m, 0.0, 1e-6);
  EXPECT_TRUE(r.T_gt_estimate.isApprox(someRigidTransform().inverse(), 1e-6));
  EXPECT_NEAR(*r.kitti_t_err_pct, 0.0, 1e-6);
  EXPECT_NEAR(r.rpe_trans_rmse_m, 0.0, 1e-6);

  EvaluationParams none;
  none.alignment = TrajectoryAlignment::kNone;
  const auto raw = evaluateTrajectory(est, gt, none);
  EXPECT_GT(raw.ate_rmse_m, 1.0);
  EXPECT_NEAR(*raw.kitti_t_err_pct, 0.0, 1e-6); // relative errors ignore the offset
}

TEST(TrajectoryEvaluation, Sim3AlignmentRecoversScale)
{
  const auto gt = generatePath(800, 0.5);
  PoseVector est;
  for (const auto& T : scaled(gt, 0.5))
    est.push_back(someRigidTransform() * T);
  EvaluationParams sim3;
  sim3.alignment = TrajectoryAlignment::kSim3;
  const auto r = evaluateTrajectory(est, gt, sim3);
  EXPECT_NEAR(r.scale, 2.0, 1e-9);
  EXPECT_NEAR(r.ate_rmse_m, 0.0, 1e-6);
  EXPECT_NEAR(*r.kitti_t_err_pct, 0.0, 1e-6); // the scale is corrected for all metrics
  EXPECT_GT(evaluateTrajectory(est, gt).ate_rmse_m, 10.0); // SE(3) cannot fix scale
}

TEST(TrajectoryEvaluation, Sim3AgainstAStandingTrajectoryIsAnError)
{
  // Ground truth that never moves: a "scale" of 0 would shrink the estimate onto it and
  // report ATE 0 (issue 12). It is an error naming the cause; SE(3) still evaluates.
  const auto est = generatePath(200, 0.5);
  const PoseVector gt(est.size(), someRigidTransform());
  EvaluationParams sim3;
  sim3.alignment = TrajectoryAlignment::kSim3;
  try {
    evaluateTrajectory(est, gt, sim3);
    ADD_FAILURE() << "no error for a Sim(3) alignment to a standing trajectory";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("target positions stay within"), std::string::npos)
        << e.what();
  }
  EXPECT_THROW(evaluateTrajectory(gt, est, sim3), std::invalid_argument);
  EXPECT_GT(evaluateTrajectory(est, gt).ate_rmse_m, 1.0);
}

TEST(TrajectoryEvaluation, OnePercentScaleErrorIsOnePercent)
{
  const auto gt = generatePath(5000, 0.25); // 1250 m
  const auto r = evaluateTrajectory(scaled(gt, 1.01), gt);
  ASSERT_TRUE(r.kitti_t_err_pct);
  EXPECT_NEAR(*r.kitti_t_err_pct, 1.00, 0.01);
  EXPECT_NEAR(*r.kitti_r_err_deg_per_100m, 0.0, 1e-3);
  for (const auto& e : r.kitti_per_length) {
    ASSERT_TRUE(e.t_err_pct) << e.length_m;
    EXPECT_NEAR(*e.t_err_pct, 1.00, 0.01) << e.length_m;
  }
  // Per frame each 0.25 m step is 2.5 mm too long.
  EXPECT_NEAR(r.rpe_trans_mean_m, 0.0025, 1e-6);
}

TEST(TrajectoryEvaluation, ConstantYawDriftGivesExpectedRotationError)
{
  const double step_m = 0.25;
  const double drift_deg_per_100m = 2.0;
  const double yaw_per_frame_rad = drift_deg_per_100m * kDegToRad / 100.0 * step_m;
  const auto gt = generatePath(5000, step_m);
  const auto r = evaluateTrajectory(withYawDrift(gt, yaw_per_frame_rad), gt);
  ASSERT_TRUE(r.kitti_r_err_deg_per_100m);
  // A segment spans at most one frame more than its length (devkit's strict '>').
  EXPECT_NEAR(*r.kitti_r_err_deg_per_100m, drift_deg_per_100m, 0.01 * drift_deg_per_100m);
  EXPECT_GT(*r.kitti_t_err_pct, 1.0); // a drifting heading bends the path
  EXPECT_NEAR(r.rpe_rot_mean_deg, yaw_per_frame_rad / kDegToRad, 1e-6);
  EXPECT_NEAR(r.rpe_rot_rmse_deg, yaw_per_frame_rad / kDegToRad, 1e-6);
}

TEST(TrajectoryEvaluation, SegmentEndIsTheFirstFrameBeyondTheLength)
{
  // Straight line, exactly 1 m per frame. The devkit ends a 100 m segment starting at
  // frame 0 at frame 101 (distance 101 > 100), never at frame 100, and no segment
  // starts at frame 100 (it would need frame 201). Disturbing frame 100 alone must
  // therefore leave every KITTI error at zero.
  PoseVector gt;
  for (int i = 0; i < 150; ++i)
    gt.push_back(Pose3d(Eigen::Translation3d(i, 0, 0)));
  PoseVector est = gt;
  est[100].translation().y() += 5.0;
  EvaluationParams none;
  none.alignment = TrajectoryAlignment::kNone;
  const auto r = evaluateTrajectory(est, gt, none);
  EXPECT_EQ(r.kitti_num_segments, 5u); // first frames 0, 10, 20, 30, 40
  EXPECT_NEAR(*r.kitti_t_err_pct, 0.0, 1e-12);
  est[101].translation().y() += 5.0; // the end of segment 0: now 5 m / 100 m
  const auto r2 = evaluateTrajectory(est, gt, none);
  EXPECT_NEAR(*r2.kitti_t_err_pct, 5.0 / 5.0, 1e-9); // 5 % in one of 5 segments
}

TEST(TrajectoryEvaluation, PooledAverageWeightsSegmentsNotLengths)
{
  const auto gt = generatePath(1200, 0.5); // 600 m: fewer long segments than short
  const auto r = evaluateTrajectory(withYawDrift(scaled(gt, 1.0), 1e-4), gt);
  double t_sum = 0.0, r_sum = 0.0;
  std::size_t n = 0;
  for (const auto& e : r.kitti_per_length) {
    if (!e.t_err_pct)
      continue;
    t_sum += *e.t_err_pct * e.num_segments;
    r_sum += *e.r_err_deg_per_100m * e.num_segments;
    n += e.num_segments;
  }
  EXPECT_EQ(n, r.kitti_num_segments);
  EXPECT_NEAR(*r.kitti_t_err_pct, t_sum / n, 1e-9);
  EXPECT_NEAR(*r.kitti_r_err_deg_per_100m, r_sum / n, 1e-9);
  EXPECT_EQ(r.kitti_per_length.back().num_segments, 0u); // no 800 m segment in 600 m
  EXPECT_FALSE(r.kitti_per_length.back().t_err_pct);
}

TEST(TrajectoryEvaluation, ShortTrajectoryHasNoKittiError)
{
  const auto gt = generatePath(200, 0.45); // < 90 m
  const auto r = evaluateTrajectory(scaled(gt, 1.01), gt);
  EXPECT_FALSE(r.kitti_t_err_pct);
  EXPECT_FALSE(r.kitti_r_err_deg_per_100m);
  EXPECT_EQ(r.kitti_num_segments, 0u);
  EXPECT_GT(r.ate_rmse_m, 0.0);
  const auto j = nlohmann::json::parse(toJson(r));
  EXPECT_TRUE(j.at("kitti_t_err_pct").is_null());
  EXPECT_TRUE(j.at("kitti_r_err_deg_per_100m").is_null());
  EXPECT_NE(toText(r).find("n/a"), std::string::npos);
}

TEST(TrajectoryEvaluation, InvalidInputThrows)
{
  const auto gt = generatePath(100, 1.0);
  const PoseVector est(gt.begin(), gt.begin() + 90);
  try {
    evaluateTrajectory(est, gt);
    FAIL() << "expected std::invalid_argument";
  } catch (const std::invalid_argument& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("90"), std::string::npos) << what;
    EXPECT_NE(what.find("100"), std::string::npos) << what;
  }
  EXPECT_THROW(evaluateTrajectory(PoseVector(1), PoseVector(1)), std::invalid_argument);
  EvaluationParams bad;
  bad.step_size_frames = 0;
  EXPECT_FALSE(bad.isValid());
  EXPECT_THROW(evaluateTrajectory(gt, gt, bad), std::invalid_argument);
  bad = {};
  bad.segment_lengths_m = {100.0, -1.0};
  std::string why;
  EXPECT_FALSE(bad.isValid(&why));
  EXPECT_NE(why.find("segment_lengths_m"), std::string::npos);
  EXPECT_TRUE(EvaluationParams().isValid());
}

TEST(TrajectoryEvaluation, AssociatesTumTrajectoriesByTimestamp)
{
  const auto poses = generatePath(400, 0.5);
  Trajectory gt, est;
  gt.format = est.format = PoseFormat::kTum;
  for (std::size_t i = 0; i < poses.size(); ++i) {
    gt.poses.push_back(poses[i]);
    gt.timestamps_s.push_back(1000.0 + 0.1 * i);
    if (i % 4 == 3) // the estimate skips every fourth frame and is 3 ms late
      continue;
    est.poses.push_back(poses[i]);
    est.timestamps_s.push_back(1000.0 + 0.1 * i + 0.003);
  }
  const auto r = evaluateTrajectory(est, gt);
  EXPECT_EQ(r.num_frames, 300u);
  EXPECT_EQ(r.num_estimate_poses, 300u);
  EXPECT_EQ(r.num_ground_truth_poses, 400u);
  EXPECT_NEAR(r.ate_rmse_m, 0.0, 1e-9);
  EXPECT_NEAR(r.rpe_trans_rmse_m, 0.0, 1e-9);

  EvaluationParams tight;
  tight.max_time_difference_s = 0.001;
  EXPECT_THROW(evaluateTrajectory(est, gt, tight), std::invalid_argument);
  EvaluationParams by_index;
  by_index.association = PoseAssociation::kByIndex;
  EXPECT_THROW(evaluateTrajectory(est, gt, by_index), std::invalid_argument);

  const auto pairs = associateByTimestamp({0.0, 1.0, 2.0}, {2.004, 0.9, 1.02, 5.0}, 0.05);
  ASSERT_EQ(pairs.size(), 2u);
  EXPECT_EQ(pairs[0], std::make_pair(std::size_t(1), std::size_t(2)));
  EXPECT_EQ(pairs[1], std::make_pair(std::size_t(2), std::size_t(0)));
}

TEST(TrajectoryEvaluation, UmeyamaRecoversSimilarity)
{
  std::mt19937 rng(7);
  std::normal_distribution<double> noise(0.0, 1.0);
  std::vector<Eigen::Vector3d> src, dst;
  const Pose3d T = someRigidTransform();
  for (int i = 0; i < 50; ++i) {
    src.emplace_back(noise(rng), noise(rng), noise(rng));
    dst.push_back(T.linear() * (3.0 * src.back()) + T.translation());
  }
  double scale = 0.0;
  EXPECT_TRUE(umeyamaAlignment(src, dst, true, &scale).isApprox(T, 1e-9));
  EXPECT_NEAR(scale, 3.0, 1e-9);
  EXPECT_THROW(umeyamaAlignment(src, {}, false), std::invalid_argument);
}

TEST(TrajectoryEvaluation, JsonAndTextOutput)
{
  const auto gt = generatePath(1000, 0.5);
  const auto r = evaluateTrajectory(scaled(gt, 1.01), gt);
  const auto j = nlohmann::json::parse(toJson(r));
  for (const char* key : {"frames",
                          "ate_rmse_m",
                          "ate_mean_m",
                          "ate_median_m",
                          "ate_std_m",
                          "ate_max_m",
                          "kitti_t_err_pct",
                          "kitti_r_err_deg_per_100m",
                          "rpe_trans_rmse_m",
                          "rpe_rot_rmse_deg",
                          "kitti_per_length"})
    EXPECT_TRUE(j.contains(key)) << key;
  EXPECT_EQ(j.at("frames").get<int>(), 1000);
  EXPECT_DOUBLE_EQ(j.at("kitti_t_err_pct").get<double>(), *r.kitti_t_err_pct);
  EXPECT_EQ(j.at("kitti_per_length").size(), 8u);
  EXPECT_EQ(j.at("T_gt_estimate").size(), 16u);
  EXPECT_NE(toText(r).find("t_err"), std::string::npos);
}

TEST(TrajectoryEvaluation, RealKitti00AgainstPerturbedSelf)
{
  PCL_RAST_REQUIRE_SHARED_DATA(data);
  const Trajectory gt = readTrajectory((data / "kitti-gt-poses" / "00.txt").string());
  ASSERT_EQ(gt.poses.size(), 4541u);

  const auto self = evaluateTrajectory(gt.poses, gt.poses);
  EXPECT_NEAR(self.ate_rmse_m, 0.0, 1e-6);
  EXPECT_NEAR(*self.kitti_t_err_pct, 0.0, 1e-6);
  EXPECT_GT(self.gt_length_m, 3700.0); // sequence 00 is ~3.7 km

  // Odometry-like perturbation: every relative motion 1 % too long and with a small
  // seeded random rotation.
  std::mt19937 rng(42);
  std::normal_distribution<double> noise(0.0, 0.5e-3);
  PoseVector est{gt.poses.front()};
  for (std::size_t i = 1; i < gt.poses.size(); ++i) {
    Pose3d delta = gt.poses[i - 1].inverse() * gt.poses[i];
    delta.translation() *= 1.01;
    const Eigen::Vector3d w(noise(rng), noise(rng), noise(rng));
    delta.linear() = delta.linear() * Eigen::AngleAxisd(w.norm(), w.normalized());
    est.push_back(est.back() * delta);
  }
  const auto r = evaluateTrajectory(est, gt.poses);
  ASSERT_TRUE(r.kitti_t_err_pct);
  EXPECT_GT(*r.kitti_t_err_pct, 0.5);
  EXPECT_LT(*r.kitti_t_err_pct, 20.0);
  EXPECT_GT(*r.kitti_r_err_deg_per_100m, 0.0);
  EXPECT_GT(r.ate_rmse_m, 0.0);
  EXPECT_GE(r.ate_max_m, r.ate_rmse_m);
  EXPECT_GE(r.ate_rmse_m, r.ate_mean_m);
  EXPECT_EQ(r.kitti_per_length.size(), 8u);
  for (const auto& e : r.kitti_per_length)
    EXPECT_GT(e.num_segments, 100u) << e.length_m;
}

} // namespace

} // namespace test_trajectory_evaluation
