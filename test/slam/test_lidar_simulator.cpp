/// \file test_lidar_simulator.cpp
/// \brief Tests of the LiDAR sequence simulator: parameters, generated paths,
/// determinism, frame independence, sensor plausibility, a clear road corridor,
/// world consistency between frames, sequence files and KITTI-driven simulation.

#include "test_data.h"

#include <algorithm>
#include <cmath>
#include <fstream>
#include <pcl/kdtree/kdtree_flann.h>
#include <pcl/slam/lidar_simulator.h>
#include <pcl/slam/pose_io.h>
#include <sstream>

namespace {

using pcl::rast::LidarSimulator;
using pcl::rast::LidarSimulatorParams;
using pcl::rast::PathParams;
using pcl::rast::PathType;
using pcl::rast::PoseVector;
using pcl::rast::SensorModel;
using Cloud = pcl::PointCloud<pcl::PointXYZI>;

PoseVector
makePath(PathType type, int frames, double height = 1.73)
{
  PathParams p;
  p.type = type;
  p.num_frames = frames;
  p.height_m = height;
  return pcl::rast::generatePath(p);
}

LidarSimulatorParams
makeParams(SensorModel sensor, std::uint64_t seed = 7)
{
  LidarSimulatorParams p;
  p.sensor = sensor;
  p.seed = seed;
  return p;
}

bool
sameCloud(const Cloud& a, const Cloud& b)
{
  if (a.size() != b.size())
    return false;
  for (std::size_t k = 0; k < a.size(); ++k)
    if (a[k].x != b[k].x || a[k].y != b[k].y || a[k].z != b[k].z ||
        a[k].intensity != b[k].intensity)
      return false;
  return true;
}

/// Points of frame \a i in the world frame, split by height above the ground.
void
worldPoints(const LidarSimulator& sim,
            std::size_t i,
            Cloud& ground,
            Cloud& above,
            double min_height = 0.3)
{
  Cloud cloud;
  sim.simulateFrame(i, cloud);
  const Eigen::Isometry3f T = sim.sensorPose(i).cast<float>();
  ground.clear();
  above.clear();
  for (const auto& p : cloud) {
    pcl::PointXYZI q = p;
    q.getVector3fMap() = T * p.getVector3fMap();
    const double h = q.z - sim.world().groundHeight(q.x, q.y);
    (h > min_height ? above : ground).push_back(q);
  }
}

/// Median nearest-neighbour distance from points of \a query (within \a radius of
/// \a center) to \a target.
double
medianNearest(const Cloud& query,
              const Cloud& target,
              const Eigen::Vector3d& center,
              double radius,
              std::size_t* used = nullptr)
{
  pcl::KdTreeFLANN<pcl::PointXYZI> tree;
  tree.setInputCloud(target.makeShared());
  std::vector<double> d;
  std::vector<int> idx(1);
  std::vector<float> d2(1);
  for (const auto& p : query) {
    if ((p.getVector3fMap().cast<double>() - center).head<2>().norm() > radius)
      continue;
    if (tree.nearestKSearch(p, 1, idx, d2) == 1)
      d.push_back(std::sqrt(d2[0]));
  }
  if (used)
    *used = d.size();
  if (d.empty())
    return 1e9;
  std::nth_element(d.begin(), d.begin() + d.size() / 2, d.end());
  return d[d.size() / 2];
}

std::vector<std::string>
readLines(const std::string& path)
{
  std::ifstream in(path);
  std::vector<std::string> lines;
  for (std::string line; std::getline(in, line);)
    if (!line.empty())
      lines.push_back(line);
  return lines;
}

// ---- parameters and names ----

TEST(LidarSimulator, ParamsValidation)
{
  std::string why;
  EXPECT_TRUE(LidarSimulatorParams().isValid(&why)) << why;
  EXPECT_TRUE(PathParams().isValid(&why)) << why;
  EXPECT_TRUE(pcl::rast::WorldParams().isValid(&why)) << why;

  LidarSimulatorParams p;
  p.num_threads = 0;
  EXPECT_FALSE(p.isValid(&why));
  EXPECT_NE(why.find("num_threads"), std::string::npos);
  p = LidarSimulatorParams();
  p.world.building_probability = 1.5;
  EXPECT_FALSE(p.isValid(&why));
  p = LidarSimulatorParams();
  p.frame_period_s = 0.0;
  EXPECT_FALSE(p.isValid());

  PathParams path;
  path.num_frames = 0;
  EXPECT_FALSE(path.isValid(&why));
  EXPECT_THROW(pcl::rast::generatePath(path), std::invalid_argument);
  path = PathParams();
  path.rate_hz = -1;
  EXPECT_FALSE(path.isValid());

  EXPECT_THROW(LidarSimulator(p, makePath(PathType::kStraight, 3)),
               std::invalid_argument);
  EXPECT_THROW(LidarSimulator(LidarSimulatorParams(), PoseVector()),
               std::invalid_argument);
  EXPECT_THROW(
      LidarSimulator(LidarSimulatorParams(), makePath(PathType::kStraight, 3), {0.0}),
      std::invalid_argument);
}

TEST(LidarSimulator, Names)
{
  for (auto m : {SensorModel::kHdl64,
                 SensorModel::kVlp16,
                 SensorModel::kOs1_64,
                 SensorModel::kOs0_128})
    EXPECT_EQ(pcl::rast::sensorModelFromString(pcl::rast::toString(m)), m);
  for (auto t : {PathType::kStraight, PathType::kLoop, PathType::kFigureEight})
    EXPECT_EQ(pcl::rast::pathTypeFromString(pcl::rast::toString(t)), t);
  EXPECT_THROW(pcl::rast::sensorModelFromString("hdl32"), std::invalid_argument);
  EXPECT_THROW(pcl::rast::pathTypeFromString("circle"), std::invalid_argument);
}

TEST(LidarSimulator, SensorSpecs)
{
  const auto hdl = pcl::rast::sensorSpec(SensorModel::kHdl64);
  EXPECT_EQ(hdl.beam_elevations_rad.size(), 64u);
  EXPECT_NEAR(hdl.beam_elevations_rad.front() * 180 / M_PI, 2.0, 1e-9);
  EXPECT_NEAR(hdl.beam_elevations_rad.back() * 180 / M_PI, -24.8, 1e-9);
  EXPECT_EQ(pcl::rast::sensorSpec(SensorModel::kVlp16).beam_elevations_rad.size(), 16u);
  EXPECT_EQ(pcl::rast::sensorSpec(SensorModel::kOs1_64).azimuth_steps, 1024);
  const auto os0 = pcl::rast::sensorSpec(SensorModel::kOs0_128);
  EXPECT_EQ(os0.beam_elevations_rad.size(), 128u);
  EXPECT_TRUE(os0.handheld);
  // Handheld: tilted forward-down by 20-30 deg, swaying over time.
  const Eigen::Vector3d x0 = pcl::rast::bodyToSensor(os0, 0.0).linear().col(0);
  EXPECT_LT(x0.z(), -std::sin(20 * M_PI / 180));
  EXPECT_GT(x0.z(), -std::sin(30 * M_PI / 180));
  EXPECT_FALSE(
      pcl::rast::bodyToSensor(os0, 0.0).isApprox(pcl::rast::bodyToSensor(os0, 0.3)));
  EXPECT_TRUE(pcl::rast::bodyToSensor(hdl, 0.3).isApprox(pcl::rast::Pose3d::Identity()));
}

// ---- generated paths ----

TEST(LidarSimulator, GeneratedPaths)
{
  for (auto type : {PathType::kStraight, PathType::kLoop, PathType::kFigureEight}) {
    SCOPED_TRACE(pcl::rast::toString(type));
    const PoseVector poses = makePath(type, 300);
    ASSERT_EQ(poses.size(), 300u);
    EXPECT_TRUE(poses[0].translation().head<2>().isZero(1e-9));
    double max_dz = 0.0;
    for (std::size_t i = 1; i < poses.size(); ++i) {
      // ~1 m per frame at 10 m/s and 10 Hz, gentle elevation change, upright.
      const Eigen::Vector3d d = poses[i].translation() - poses[i - 1].translation();
      EXPECT_NEAR(d.norm(), 1.0, 0.05);
      max_dz = std::max(max_dz, std::abs(d.z()));
      EXPECT_GT(poses[i].linear()(2, 2), 0.99);
      EXPECT_GT(poses[i].linear().col(0).dot(d.normalized()), 0.95);
    }
    EXPECT_LT(max_dz, 0.06);
  }
  // The loop comes back to its start after 1 / 1.15 of the drive: a revisit.
  const PoseVector loop = makePath(PathType::kLoop, 300);
  const double perimeter = 299.0 / 1.15;
  const std::size_t back = static_cast<std::size_t>(std::round(perimeter));
  EXPECT_LT((loop[back].translation() - loop[0].translation()).norm(), 1.0);
  EXPECT_GT(loop[0].linear().col(0).dot(loop[back].linear().col(0)), 0.95);
  double far = 0.0;
  for (const auto& T : loop)
    far = std::max(far, T.translation().norm());
  EXPECT_GT(far, 50.0);
}

// ---- determinism and independence ----

TEST(LidarSimulator, DeterministicForSeed)
{
  const PoseVector path = makePath(PathType::kStraight, 10);
  LidarSimulator a(makeParams(SensorModel::kHdl64, 3), path);
  LidarSimulator b(makeParams(SensorModel::kHdl64, 3), path);
  LidarSimulator c(makeParams(SensorModel::kHdl64, 4), path);
  Cloud ca, cb, cc;
  a.simulateFrame(4, ca);
  b.simulateFrame(4, cb);
  c.simulateFrame(4, cc);
  EXPECT_GT(ca.size(), 1000u);
  EXPECT_TRUE(sameCloud(ca, cb));
  EXPECT_FALSE(sameCloud(ca, cc));
  EXPECT_EQ(a.world().numPrimitives(), b.world().numPrimitives());
}

TEST(LidarSimulator, FrameIndependentOfOtherFramesAndThreads)
{
  const PoseVector path = makePath(PathType::kLoop, 40);
  LidarSimulator run(makeParams(SensorModel::kOs1_64), path);
  Cloud alone, in_run, tmp;
  run.simulateFrame(5, alone);
  LidarSimulator fresh(makeParams(SensorModel::kOs1_64), path);
  for (std::size_t i = 0; i < 5; ++i)
    fresh.simulateFrame(i, tmp);
  fresh.simulateFrame(5, in_run);
  EXPECT_TRUE(sameCloud(alone, in_run));

  LidarSimulatorParams threaded = makeParams(SensorModel::kOs1_64);
  threaded.num_threads = 3;
  LidarSimulator t(threaded, path);
  t.simulateFrame(5, tmp);
  EXPECT_TRUE(sameCloud(alone, tmp));

  // Noise differs between frames even at the same pose.
  PoseVector still(3, path[0]);
  LidarSimulator s(makeParams(SensorModel::kOs1_64), still);
  Cloud f0, f1;
  s.simulateFrame(0, f0);
  s.simulateFrame(1, f1);
  EXPECT_FALSE(sameCloud(f0, f1));
}

// ---- sensor plausibility ----

TEST(LidarSimulator, PointCountsAndRanges)
{
  struct Case
  {
    SensorModel model;
    std::size_t min_points, max_points;
  };
  // Rays per frame: HDL-64 128000, VLP-16 28800, OS1-64 65536, OS0-128 131072.
  const Case cases[] = {{SensorModel::kHdl64, 60000, 128000},
                        {SensorModel::kVlp16, 10000, 28800},
                        {SensorModel::kOs1_64, 25000, 65536},
                        {SensorModel::kOs0_128, 60000, 131072}};
  for (const auto& c : cases) {
    SCOPED_TRACE(pcl::rast::toString(c.model));
    const auto spec = pcl::rast::sensorSpec(c.model);
    const PoseVector path = makePath(PathType::kLoop, 100, spec.mount_height_m);
    LidarSimulator sim(makeParams(c.model), path);
    Cloud cloud;
    sim.simulateFrame(20, cloud);
    EXPECT_GE(cloud.size(), c.min_points);
    EXPECT_LE(cloud.size(), c.max_points);
    float max_i = 0.0f;
    for (const auto& p : cloud) {
      const double r = p.getVector3fMap().norm();
      ASSERT_GE(r, spec.min_range_m - 1e-3);
      ASSERT_LE(r, spec.max_range_m + 1e-3);
      ASSERT_GE(p.intensity, 0.0f);
      ASSERT_LE(p.intensity, 1.0f);
      max_i = std::max(max_i, p.intensity);
    }
    EXPECT_GT(max_i, 0.2f);
    // Ground seen at the right place: many points on it, none below it.
    Cloud ground, above;
    worldPoints(sim, 20, ground, above);
    std::size_t on = 0, below = 0;
    for (const auto& p : ground) {
      const double h = p.z - sim.world().groundHeight(p.x, p.y);
      on += std::abs(h) < 0.1;
      below += h < -0.2;
    }
    EXPECT_GT(on, cloud.size() / 5);
    EXPECT_LT(below, cloud.size() / 1000 + 1);
    EXPECT_GT(above.size(), cloud.size() / 20); // vertical structure
  }
}

TEST(LidarSimulator, HandheldSensorPoseIncludesTilt)
{
  const auto spec = pcl::rast::sensorSpec(SensorModel::kOs0_128);
  PathParams pp;
  pp.type = PathType::kStraight;
  pp.num_frames = 20;
  pp.speed_mps = 1.5;
  pp.height_m = spec.mount_height_m;
  const PoseVector body = pcl::rast::generatePath(pp);
  LidarSimulator sim(makeParams(SensorModel::kOs0_128), body);
  const pcl::rast::Pose3d T = sim.sensorPose(7);
  EXPECT_TRUE(T.isApprox(body[7] * pcl::rast::bodyToSensor(spec, sim.timestamp(7))));
  EXPECT_LT(T.linear().col(0).z(), -0.3); // looking down ahead
  // The ground, seen through the tilted sensor and its GT pose, lies on the ground.
  Cloud ground, above;
  worldPoints(sim, 7, ground, above);
  std::size_t on = 0;
  for (const auto& p : ground)
    on += std::abs(p.z - sim.world().groundHeight(p.x, p.y)) < 0.08;
  EXPECT_GT(on, 20000u);
  EXPECT_NEAR(T.translation().z() -
                  sim.world().groundHeight(T.translation().x(), T.translation().y()),
              1.5,
              0.1);
}

// ---- world ----

TEST(LidarSimulator, WorldDeterministicAndVaried)
{
  const PoseVector path = makePath(PathType::kLoop, 300);
  pcl::rast::SimulatedWorld w1(pcl::rast::WorldParams(), path, 1.73, 11);
  pcl::rast::SimulatedWorld w2(pcl::rast::WorldParams(), path, 1.73, 11);
  pcl::rast::SimulatedWorld w3(pcl::rast::WorldParams(), path, 1.73, 12);
  EXPECT_EQ(w1.numPrimitives(), w2.numPrimitives());
  EXPECT_GT(w1.numPrimitives(), 200u);
  EXPECT_NE(w1.numPrimitives(), w3.numPrimitives());
  // The ground follows the path's elevation, 1.73 m below the sensor.
  for (std::size_t i = 0; i < path.size(); i += 25) {
    const Eigen::Vector3d t = path[i].translation();
    EXPECT_NEAR(t.z() - w1.groundHeight(t.x(), t.y()), 1.73, 0.05);
    EXPECT_LT(w1.distanceToPath(t.x(), t.y()), 1.5);
  }
  // A ray straight down from above the road hits the ground; one along the road at
  // sensor height does not hit anything in the corridor within 3 m.
  pcl::rast::RayHit hit;
  const Eigen::Vector3d o = path[10].translation();
  ASSERT_TRUE(w1.castRay(o, -Eigen::Vector3d::UnitZ(), 100.0, 0.0, hit));
  EXPECT_TRUE(hit.is_ground);
  EXPECT_NEAR(hit.range_m, 1.73, 0.05);
  if (w1.castRay(o, path[10].linear().col(0), 3.0, 0.0, hit))
    ADD_FAILURE() << "object in the corridor at " << hit.range_m << " m";
}

TEST(LidarSimulator, RoadCorridorClearOnEveryPass)
{
  // Loop and figure eight (driven past the start, crossing itself): no non-ground
  // point within 2 m laterally of the path up to 4 m above the ground.
  for (auto type : {PathType::kLoop, PathType::kFigureEight}) {
    SCOPED_TRACE(pcl::rast::toString(type));
    const PoseVector path = makePath(type, 250);
    LidarSimulator sim(makeParams(SensorModel::kVlp16), path);
    // Dense path samples every 0.1 m.
    std::vector<Eigen::Vector2d> dense;
    for (std::size_t i = 0; i + 1 < path.size(); ++i)
      for (int k = 0; k < 10; ++k)
        dense.push_back(path[i].translation().head<2>() +
                        (path[i + 1].translation() - path[i].translation()).head<2>() *
                            k / 10.0);
    std::size_t checked = 0;
    for (std::size_t i = 0; i < path.size(); i += 20) {
      Cloud ground, above;
      worldPoints(sim, i, ground, above);
      for (const auto& p : above) {
        if (p.z - sim.world().groundHeight(p.x, p.y) > 4.0)
          continue;
        double d = 1e9;
        for (const auto& q : dense)
          d = std::min(d, (Eigen::Vector2d(p.x, p.y) - q).norm());
        ++checked;
        ASSERT_GT(d, 2.0) << "frame " << i << " point " << p.x << " " << p.y << " "
                          << p.z;
      }
    }
    EXPECT_GT(checked, 1000u);
  }
}

TEST(LidarSimulator, WorldConsistentBetweenFrames)
{
  // Non-ground points of frames seen from different poses coincide after GT alignment:
  // 5 m apart on a straight road, and on the loop's second pass (revisit).
  const PoseVector path = makePath(PathType::kLoop, 300);
  LidarSimulator sim(makeParams(SensorModel::kHdl64), path);
  const std::size_t revisit = static_cast<std::size_t>(std::round(299.0 / 1.15));
  const std::pair<std::size_t, std::size_t> pairs[] = {{10, 15}, {2, revisit + 2}};
  for (const auto& pr : pairs) {
    SCOPED_TRACE(std::to_string(pr.first) + " vs " + std::to_string(pr.second));
    Cloud g_i, a_i, g_j, a_j;
    worldPoints(sim, pr.first, g_i, a_i);
    worldPoints(sim, pr.second, g_j, a_j);
    const Eigen::Vector3d c = path[pr.first].translation();
    std::size_t used = 0;
    const double median = medianNearest(a_i, a_j, c, 30.0, &used);
    EXPECT_GT(used, 2000u);
    EXPECT_LT(median, 0.1);
  }
}

TEST(LidarSimulator, MovingCarsOptional)
{
  const PoseVector path = makePath(PathType::kLoop, 200);
  LidarSimulatorParams p = makeParams(SensorModel::kVlp16);
  LidarSimulator still(p, path);
  p.world.moving_cars = true;
  p.world.num_moving_cars = 40;
  LidarSimulator moving(p, path);
  LidarSimulator moving2(p, path);
  EXPECT_EQ(still.world().numPrimitives(), moving.world().numPrimitives());
  std::size_t differing = 0;
  for (std::size_t i = 0; i < 200; i += 20) {
    Cloud a, b, c;
    still.simulateFrame(i, a);
    moving.simulateFrame(i, b);
    moving2.simulateFrame(i, c);
    EXPECT_TRUE(sameCloud(b, c));
    differing += !sameCloud(a, b);
  }
  EXPECT_GT(differing, 0u);
}

// ---- sequences ----

TEST(LidarSimulator, WriteSequence)
{
  const auto dir = pcl_rast_test::makeTempDir("lidar_sim");
  const PoseVector path = makePath(PathType::kStraight, 12);
  LidarSimulator sim(makeParams(SensorModel::kVlp16), path);
  std::size_t calls = 0;
  const std::size_t n = sim.writeSequence(dir.string(),
                                          pcl::rast::ScanFormat::kBin,
                                          2,
                                          10,
                                          2,
                                          [&](std::size_t done, std::size_t total) {
                                            EXPECT_EQ(total, 5u);
                                            EXPECT_EQ(done, ++calls);
                                          });
  EXPECT_EQ(n, 5u);
  EXPECT_EQ(calls, 5u);
  for (int k = 0; k < 5; ++k) {
    char name[32];
    std::snprintf(name, sizeof(name), "%06d.bin", k);
    EXPECT_TRUE(std::filesystem::exists(dir / "velodyne" / name)) << name;
  }
  EXPECT_FALSE(std::filesystem::exists(dir / "velodyne" / "000005.bin"));

  // The written scan equals the simulated frame (float32 x y z intensity).
  Cloud frame4;
  sim.simulateFrame(4, frame4);
  EXPECT_EQ(std::filesystem::file_size(dir / "velodyne" / "000001.bin"),
            frame4.size() * 16u);

  const auto traj = pcl::rast::readTrajectory((dir / "poses.txt").string());
  ASSERT_EQ(traj.poses.size(), 5u);
  EXPECT_TRUE(traj.poses[0].isApprox(pcl::rast::Pose3d::Identity(), 1e-9));
  const pcl::rast::Pose3d expected = sim.sensorPose(2).inverse() * sim.sensorPose(8);
  EXPECT_TRUE(traj.poses[3].isApprox(expected, 1e-5));
  const auto times = readLines((dir / "times.txt").string());
  ASSERT_EQ(times.size(), 5u);
  EXPECT_NEAR(std::stod(times[0]), 0.0, 1e-9);
  EXPECT_NEAR(std::stod(times[4]), 0.8, 1e-6);

  const auto pcd_dir = pcl_rast_test::makeTempDir("lidar_sim_pcd");
  EXPECT_EQ(sim.writeSequence(pcd_dir.string(), pcl::rast::ScanFormat::kPcd, 0, 1), 2u);
  EXPECT_TRUE(std::filesystem::exists(pcd_dir / "pcd" / "000001.pcd"));
  EXPECT_THROW(sim.writeSequence(dir.string(), pcl::rast::ScanFormat::kBin, 5, 3),
               std::invalid_argument);
  EXPECT_THROW(sim.writeSequence(dir.string(), pcl::rast::ScanFormat::kBin, 0, 12),
               std::invalid_argument);
}

// ---- KITTI ground truth as the trajectory ----

TEST(LidarSimulator, DrivesKittiGroundTruth)
{
  PCL_RAST_REQUIRE_SHARED_DATA(data);
  const auto gt =
      pcl::rast::readTrajectory((data / "kitti-gt-poses" / "00.txt").string());
  ASSERT_GT(gt.poses.size(), 200u);
  const PoseVector cam(gt.poses.begin(), gt.poses.begin() + 200);
  const PoseVector lidar =
      pcl::rast::cameraToLidarPoses(cam, pcl::rast::kittiAxisChangeCamLidar());
  LidarSimulator sim(makeParams(SensorModel::kHdl64), lidar);
  EXPECT_GT(sim.world().numPrimitives(), 100u);
  // The LiDAR rides ~1.73 m above the ground along the whole drive.
  for (std::size_t i = 0; i < lidar.size(); i += 20) {
    const Eigen::Vector3d t = lidar[i].translation();
    EXPECT_NEAR(t.z() - sim.world().groundHeight(t.x(), t.y()), 1.73, 0.3) << i;
  }
  Cloud cloud;
  sim.simulateFrame(100, cloud);
  EXPECT_GT(cloud.size(), 60000u);
  Cloud g_i, a_i, g_j, a_j;
  worldPoints(sim, 100, g_i, a_i);
  worldPoints(sim, 104, g_j, a_j);
  std::size_t used = 0;
  EXPECT_LT(medianNearest(a_i, a_j, lidar[100].translation(), 30.0, &used), 0.1);
  EXPECT_GT(used, 2000u);
}

} // namespace
