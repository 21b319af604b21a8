/// The odometry in traffic (simulated): an HDL-64 drives, brakes to a stop at a light,
/// stands while cars stop beside it, pull away and cross ahead, then drives on. The
/// standing ego must not be moved by the traffic, and the stop-and-go must not break
/// the constant-velocity prior.

#include <algorithm>
#include <gtest/gtest.h>
#include <iostream>
#include <memory>
#include <pcl/simulation/lidar_simulator.h>
#include <pcl/slam/odometry.h>
#include <pcl/evaluation/trajectory_evaluation.h>
#include <vector>

namespace {

using namespace pcl::rast;

TEST(OdometryTraffic, StandingEgoIsNotMovedByTrafficAndStopAndGoTracks)
{
  PathParams path;
  path.type = PathType::kStraight;
  path.num_frames = 260;
  path.speed_mps = 8.0;
  path.num_stops = 1;
  path.stop_duration_s = 6.0;
  path.acceleration_mps2 = 2.5;
  LidarSimulatorParams params;
  params.seed = 23;
  params.num_threads = 2;
  params.raw_sweep = true;
  params.imperfections = true;
  params.world.moving_cars = true;
  params.world.traffic.mode = TrafficMode::kRealistic;
  params.world.rough_ground = true;
  const PoseVector body = generatePath(path);
  LidarSimulator sim(params, body);

  Odometry odometry{OdometryParams()};
  PoseVector estimate, truth;
  const Pose3d T0_inv = sim.sensorPose(0).inverse();
  for (std::size_t i = 0; i < sim.numFrames(); ++i) {
    auto cloud = std::make_shared<pcl::PointCloud<pcl::PointXYZI>>();
    std::vector<float> times;
    sim.simulateFrame(i, *cloud, &times);
    const auto r = odometry.processFrame(cloud, sim.timestamp(i), i, times);
    estimate.push_back(r.T_world_lidar);
    truth.push_back(T0_inv * sim.sensorPose(i));
  }

  // The standing frames: the body does not move between them.
  std::vector<std::size_t> standing;
  for (std::size_t i = 1; i < body.size(); ++i)
    if ((body[i].translation() - body[i - 1].translation()).norm() < 1e-6)
      standing.push_back(i);
  ASSERT_GE(standing.size(), 50u) << "the path should stand for ~6 s";
  const std::size_t first = standing.front() - 1, last = standing.back();
  double max_move = 0.0;
  for (std::size_t i = first; i <= last; ++i)
    max_move = std::max(
        max_move, (estimate[i].translation() - estimate[first].translation()).norm());
  std::cout << "standing frames " << first << "-" << last << ": the estimate moves up to "
            << max_move * 100.0 << " cm\n";
  EXPECT_LT(max_move, 0.03);

  const EvaluationResult eval = evaluateTrajectory(estimate, truth);
  std::cout << "ATE " << eval.ate_rmse_m << " m over " << eval.gt_length_m << " m\n";
  EXPECT_LT(eval.ate_rmse_m, 0.1);
}

} // namespace
