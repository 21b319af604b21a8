/// The odometry in traffic and degenerate scenes (simulated): an HDL-64 drives, brakes
/// to a stop at a light, stands while cars stop beside it, pull away and cross ahead,
/// then drives on. The standing ego must not be moved by the traffic, and the
/// stop-and-go must not break the constant-velocity prior. A drive at 20 m/s into a
/// tunnel, whose smooth walls hardly tell the motion along it, must keep its speed, and a
/// VLP-16 accelerating on a highway must follow its speed. And KITTI 08's simulated climb
/// must keep its height.

#include "simulated_drive.h"
#include "test_data.h"

#include <algorithm>
#include <filesystem>
#include <gtest/gtest.h>
#include <iostream>
#include <memory>
#include <pcl/evaluation/trajectory_evaluation.h>
#include <pcl/io/pose_io.h>
#include <pcl/io/sequence_reader.h>
#include <pcl/simulation/lidar_simulator.h>
#include <pcl/slam/odometry.h>
#include <string>
#include <vector>

// This file's names stay its own: a test program compiles several test files as
// one translation unit (test/CMakeLists.txt).
namespace test_odometry_traffic {

namespace {

using namespace pcl::rast;

using pcl_rast_test::streetParams;

/// The largest error of a frame-to-frame motion [m], \a estimate starting at frame
/// \a first of \a sim.
double
worstStep(const PoseVector& estimate, const LidarSimulator& sim, std::size_t first = 0)
{
  double worst = 0.0;
  for (std::size_t i = 1; i < estimate.size(); ++i) {
    const Pose3d truth =
        sim.sensorPose(first + i - 1).inverse() * sim.sensorPose(first + i);
    const Pose3d estimated = estimate[i - 1].inverse() * estimate[i];
    worst = std::max(worst, (truth.inverse() * estimated).translation().norm());
  }
  return worst;
}

/// The start of a KITTI sequence in the realistic world of `pcl_rast_simulate -traj
/// SEQ.txt -seed SEED -raw-sweep -moving-cars -traffic realistic -imperfections -scene
/// mixed -rough-ground -porous-vegetation` (or of \a params' sensor and scene), its
/// \a frames scans from frame \a first on read back through the PCD files as
/// pcl_rast_odometry reads them (time field since the sweep's start): the outcome of such
/// a drive hangs on the last bits of the point times.
struct KittiStart
{
  std::unique_ptr<LidarSimulator> sim;
  std::vector<ScanFrame> scans;
};

LidarSimulatorParams
kittiWorldParams(std::uint64_t seed)
{
  LidarSimulatorParams params = streetParams(seed);
  params.world.mixed_scenes = true;
  params.world.porous_vegetation = true;
  return params;
}

KittiStart
kittiStart(const std::filesystem::path& data,
           const std::string& sequence,
           const LidarSimulatorParams& params,
           std::size_t frames,
           std::size_t first = 0)
{
  const Trajectory gt =
      readTrajectory((data / "kitti-gt-poses" / (sequence + ".txt")).string());
  KittiStart start;
  start.sim = std::make_unique<LidarSimulator>(
      params, cameraToLidarPoses(gt.poses, kittiAxisChangeCamLidar()));
  const std::filesystem::path dir = ::pcl_rast_test::makeTempDir("kitti_start");
  start.sim->writeSequence(dir.string(), ScanFormat::kPcd, first, first + frames - 1, 1);
  const SequenceReader reader(dir.string());
  for (std::size_t i = 0; i < frames; ++i)
    start.scans.push_back(reader.read(i));
  std::filesystem::remove_all(dir);
  return start;
}

/// Every scan of \a scans through one odometry, in order.
std::vector<OdometryFrameResult>
trackScans(const OdometryParams& params, const std::vector<ScanFrame>& scans)
{
  Odometry odometry(params);
  std::vector<OdometryFrameResult> results;
  for (std::size_t i = 0; i < scans.size(); ++i)
    results.push_back(odometry.processFrame(
        scans[i].cloud, scans[i].timestamp_s, i, scans[i].point_times_s));
  return results;
}

PoseVector
posesOf(const std::vector<OdometryFrameResult>& results)
{
  PoseVector poses;
  for (const OdometryFrameResult& r : results)
    poses.push_back(r.T_world_lidar);
  return poses;
}

TEST(OdometryTraffic, StandingEgoIsNotMovedByTrafficAndStopAndGoTracks)
{
  PathParams path;
  path.type = PathType::kStraight;
  path.num_frames = 260;
  path.speed_mps = 8.0;
  path.num_stops = 1;
  path.stop_duration_s = 6.0;
  path.acceleration_mps2 = 2.5;
  const LidarSimulatorParams params = streetParams(23);
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

TEST(OdometryTraffic, ATunnelAtSpeedKeepsTheVehiclesVelocity)
{
  // 26 m/s (KITTI 01's highway speed) down a straight road: a suburb, then a long
  // tunnel, then a highway; raw sweeps, sensor flaws, realistic traffic.
  PathParams path;
  path.type = PathType::kStraight;
  path.num_frames = 170;
  path.speed_mps = 26.0;
  LidarSimulatorParams params = streetParams(4);
  params.world.mixed_scenes = true;
  params.world.scene_min_length_m = 100.0;
  params.world.scene_max_length_m = 280.0;
  const PoseVector body = generatePath(path);
  LidarSimulator sim(params, body);
  std::vector<pcl::PointCloud<pcl::PointXYZI>::Ptr> clouds;
  std::vector<std::vector<float>> times(sim.numFrames());
  std::size_t tunnel_frames = 0;
  for (std::size_t i = 0; i < sim.numFrames(); ++i) {
    clouds.push_back(std::make_shared<pcl::PointCloud<pcl::PointXYZI>>());
    sim.simulateFrame(i, *clouds.back(), &times[i]);
    tunnel_frames += sim.world().sceneAtArcLength(26.0 * sim.timestamp(i)) ==
                     SceneType::kTunnel;
  }
  ASSERT_GE(tunnel_frames, 50u) << "the seed should drive through a tunnel";

  // The largest error of a frame-to-frame motion, and the drift over the drive.
  auto run = [&](const OdometryParams& odometry_params, double& drift_m) {
    Odometry odometry(odometry_params);
    PoseVector estimate;
    for (std::size_t i = 0; i < clouds.size(); ++i)
      estimate.push_back(
          odometry.processFrame(clouds[i], sim.timestamp(i), i, times[i]).T_world_lidar);
    const Pose3d T0_inv = sim.sensorPose(0).inverse();
    drift_m = (estimate.back().translation() -
               (T0_inv * sim.sensorPose(clouds.size() - 1)).translation())
                  .norm();
    return worstStep(estimate, sim);
  };
  // On a dense step of 1000 source points (the default until session 36), where the
  // prior is what holds the tunnel. With 2000 the dense step holds it by itself: drift
  // 1.12 m with the prior, 1.05 m without it (1000: 1.34 / 9.25 m).
  OdometryParams with_prior;
  with_prior.dense.max_source_points = 1000;
  double drift = 0.0, drift_without = 0.0;
  const double worst = run(with_prior, drift);
  OdometryParams without = with_prior;
  disableVehiclePrior(without);
  const double worst_without = run(without, drift_without);
  std::cout << "tunnel at 26 m/s (" << tunnel_frames << " frames): largest per-frame error "
            << worst << " m, drift " << drift << " m over " << 2.6 * (clouds.size() - 1)
            << " m; without the vehicle prior " << worst_without << " m, drift "
            << drift_without << " m\n";
  // Measured: 0.49 m and 1.3 m over 439 m; without the vehicle prior 1.27 m and 9.3 m.
  EXPECT_LT(worst, 0.7);
  EXPECT_LT(drift, 3.0);
  // The comparison run is a check too: the prior is what holds the tunnel.
  EXPECT_GT(drift_without, 2.0 * drift)
      << "the vehicle prior no longer makes the difference";
}

TEST(OdometryTraffic, AVlp16AcceleratingOnAHighwayFollowsItsSpeed)
{
  // KITTI 01's start as a pure highway (guard rails and embankments, nothing along the
  // road for the dense step) seen by a VLP-16: the car speeds up from 10 to 27 m/s, and
  // the sparse raster gives 10-25 feature inliers, too few to set the pose alone. With
  // the constant-velocity prior alone along the road (weak_feature_share 0) the speed
  // stuck at 1.42 m a frame from frame 64 on, the car reaching 2.1 by frame 110.
  // Tuning seed 42's world, its first 250 frames.
  PCL_RAST_REQUIRE_SHARED_DATA(data);
  LidarSimulatorParams params = kittiWorldParams(42);
  params.sensor = SensorModel::kVlp16;
  params.world.mixed_scenes = false;
  params.world.scene = SceneType::kHighway;
  const KittiStart start = kittiStart(data, "01", params, 250);
  PoseVector truth;
  const Pose3d T0_inv = start.sim->sensorPose(0).inverse();
  for (std::size_t i = 0; i < start.scans.size(); ++i)
    truth.push_back(T0_inv * start.sim->sensorPose(i));
  auto run = [&](double share) {
    OdometryParams odometry_params;
    applySensorPreset(SensorPreset::kVlp16, odometry_params);
    odometry_params.weak_feature_share = share;
    return evaluateTrajectory(posesOf(trackScans(odometry_params, start.scans)), truth);
  };
  OdometryParams vlp16;
  applySensorPreset(SensorPreset::kVlp16, vlp16);
  ASSERT_GT(vlp16.weak_feature_share, 0.0)
      << "the VLP-16 preset should blend weak features";
  const EvaluationResult blended = run(vlp16.weak_feature_share);
  const EvaluationResult prior_alone = run(0.0);
  std::cout << "VLP-16 accelerating on a highway, " << blended.gt_length_m << " m: ATE "
            << blended.ate_rmse_m << " m; with the prior alone " << prior_alone.ate_rmse_m
            << " m\n";
  // Measured (pcl_rast_odometry on the same world): ATE 5.0 m (t_err 3.4 %; half way
  // to the features 2.1 m); with the prior alone 90 m (55 %).
  EXPECT_LT(blended.ate_rmse_m, 10.0);
  EXPECT_GT(prior_alone.ate_rmse_m, 4.0 * blended.ate_rmse_m)
      << "the weak features' share no longer makes the difference";
}

TEST(OdometryTraffic, ASteepClimbKeepsItsHeight)
{
  // The start of KITTI 08 as its ground truth has it: the car slows from 8 m/s to a
  // crawl while it climbs 0.185 m a frame, so the ground the simulator builds along it
  // steepens to a ramp the scan holds the height on poorly. Tuning seed 42's world, its
  // first 130 frames: at frame 99 the climb stops from one frame to the next, where a
  // gate that held the prior's height on fresh velocities too kept climbing (0.38 m off
  // a frame).
  PCL_RAST_REQUIRE_SHARED_DATA(data);
  const std::size_t frames = 130;
  const KittiStart start = kittiStart(data, "08", kittiWorldParams(42), frames);
  auto run = [&](const OdometryParams& odometry_params) {
    return worstStep(posesOf(trackScans(odometry_params, start.scans)), *start.sim);
  };
  const double worst = run(OdometryParams());
  OdometryParams without;
  without.prior_gate_vertical_accel_mps2 = 0.0;
  const double worst_without = run(without);
  std::cout << "steep climb: largest per-frame error " << worst
            << " m; without the vertical gate " << worst_without << " m\n";
  // Measured: 0.085 m; without the gate 0.39 m (after a constant-velocity frame a dense
  // fallback slid 0.37 m down, and weak features followed for three frames).
  EXPECT_LT(worst, 0.25);
  EXPECT_GT(worst_without, 1.5 * worst)
      << "the vertical gate no longer makes the difference";
}

TEST(OdometryTraffic, AColdStartThatTrackedNothingSolvesItsMotionFromBothScans)
{
  // A run that starts at 8 m/s in a place with few features: the second scan tracks
  // neither by features (0 inliers) nor densely, and its constant-velocity branch has
  // no motion to predict. Both raw sweeps, the first one in the map and this one, are
  // distorted by the motion nobody knew yet. Tuning seed 66's world of KITTI 08's
  // start, its first 6 frames: the one start of 276 on tuning seeds 40-64 (first frames
  // of KITTI 00-10) known to take that branch.
  PCL_RAST_REQUIRE_SHARED_DATA(data);
  const std::size_t frames = 6;
  const KittiStart start = kittiStart(data, "08", kittiWorldParams(66), frames);
  const std::vector<OdometryFrameResult> results =
      trackScans(OdometryParams(), start.scans);
  const OdometryFrameResult& second = results[1];
  EXPECT_EQ(second.status, TrackingStatus::kDenseFallback) << second.message;
  EXPECT_NE(second.message.find("as a cold start, the motion solved with both scans"),
            std::string::npos)
      << second.message;
  const double worst = worstStep(posesOf(results), *start.sim);
  std::cout << "cold start without tracking: largest per-frame error " << worst
            << " m over the first " << frames << " frames\n";
  // Measured: 0.048 m. Before, frame 1 kept the constant-velocity branch's fit from no
  // motion (0.50 m for 0.83 m: 0.33 m off) and the first scan stayed distorted in the
  // map.
  EXPECT_LT(worst, 0.1);
}

TEST(OdometryTraffic, AVlp16StartingAtSpeedInAStreetTakesItsWeakFeatures)
{
  // A VLP-16 run that starts at 10.6 m/s in a street whose axis the scan hardly
  // constrains. The second scan pairs 10-39 feature inliers, weak ones, and before any
  // velocity is measured the constant-velocity prior is no motion at all: taking the
  // prior's side against the weak features, the second frame measured 0.32 m for 1.06
  // and the next four 0.33-0.50 m. The features set the street's axis now. Tuning seed
  // 43's world of KITTI 05 driven again with another drive seed (243: other traffic,
  // noise and calibration), frames 1617-1631.
  PCL_RAST_REQUIRE_SHARED_DATA(data);
  LidarSimulatorParams params = kittiWorldParams(43);
  params.sensor = SensorModel::kVlp16;
  params.drive_seed = 243;
  const std::size_t first = 1617, frames = 15;
  const KittiStart start = kittiStart(data, "05", params, frames, first);
  OdometryParams vlp16;
  applySensorPreset(SensorPreset::kVlp16, vlp16);
  const std::vector<OdometryFrameResult> results = trackScans(vlp16, start.scans);
  const OdometryFrameResult& second = results[1];
  EXPECT_EQ(second.status, TrackingStatus::kFeatures) << second.message;
  const double worst = worstStep(posesOf(results), *start.sim, first);
  std::cout << "VLP-16 starting at speed in a street: largest per-frame error " << worst
            << " m over " << frames << " frames\n";
  // Measured (pcl_rast_odometry on the same scans): 0.09 m; 0.74 m before.
  EXPECT_LT(worst, 0.25);
}

TEST(OdometryTraffic, A32BeamSensorTracksWithTheGuessedPreset)
{
  // A Velodyne HDL-32E, for which no preset was made: 32 beams 1.33 deg apart, about
  // half an HDL-64's points and 2.6 times a VLP-16's. The preset is guessed from the
  // first scan, as pcl_rast_odometry -sensor auto does: the car-mounted defaults. Tuning
  // seed 42's world of KITTI 00, its first 80 frames (a street at up to 8.5 m/s).
  PCL_RAST_REQUIRE_SHARED_DATA(data);
  LidarSimulatorParams params = kittiWorldParams(42);
  params.sensor = SensorModel::kHdl32;
  const std::size_t frames = 80;
  const KittiStart start = kittiStart(data, "00", params, frames);
  const SensorGuess guess = guessSensorPreset(*start.scans.front().cloud);
  EXPECT_EQ(guess.preset, SensorPreset::kHdl64) << guess.reason;
  OdometryParams guessed;
  applySensorPreset(guess.preset, guessed);
  const std::vector<OdometryFrameResult> results = trackScans(guessed, start.scans);
  int features = 0;
  for (const OdometryFrameResult& r : results)
    features += r.status == TrackingStatus::kFeatures;
  const double worst = worstStep(posesOf(results), *start.sim);
  std::cout << "HDL-32E, preset " << toString(guess.preset)
            << ": largest per-frame error " << worst << " m, " << features << " of "
            << frames << " frames by features\n";
  EXPECT_LT(worst, 0.1);
  EXPECT_GT(features, static_cast<int>(frames) / 2);
}

} // namespace

} // namespace test_odometry_traffic
