/// Moving objects in the odometry's dense step: a scan's visibility image tells where
/// it saw through, the local map hides the voxels it sees through (what moved out of
/// them), and in simulated traffic the odometry hides what the cars left while a
/// static world keeps its map. Also how the map's voxels keep their points.

#include "../../slam/src/odometry_local_map.h"

#include <cmath>
#include <gtest/gtest.h>
#include <iostream>
#include <memory>
#include <numeric>
#include <pcl/simulation/lidar_simulator.h>
#include <pcl/slam/odometry.h>
#include <random>
#include <string>
#include <vector>

// This file's names stay its own: a test program compiles several test files as
// one translation unit (test/CMakeLists.txt).
namespace test_odometry_visibility {

namespace {

using pcl::rast::odometry_detail::toPoints;
using pcl::rast::odometry_detail::VisibilityImage;
using pcl::rast::odometry_detail::VoxelPlaneMap;

/// A wall across the x axis at \a x_m, |y| <= \a half_width_m, z from -1 to
/// \a top_m, on a grid of \a step_m.
void
addWall(double x_m,
        pcl::PointCloud<pcl::PointXYZI>& cloud,
        double step_m = 0.05,
        double half_width_m = 5.0,
        double top_m = 2.0)
{
  for (double y = -half_width_m; y <= half_width_m; y += step_m)
    for (double z = -1.0; z <= top_m; z += step_m) {
      pcl::PointXYZI p;
      p.x = static_cast<float>(x_m);
      p.y = static_cast<float>(y);
      p.z = static_cast<float>(z);
      p.intensity = 0.5f;
      cloud.push_back(p);
    }
}

TEST(VisibilityImage, SeesPastOnlyWhereTheScanDid)
{
  pcl::PointCloud<pcl::PointXYZI> scan;
  addWall(20.0, scan);
  const VisibilityImage image(scan);
  ASSERT_FALSE(image.empty());
  // In front of the wall, the scan saw through: free space.
  EXPECT_TRUE(image.seenPast({10.0f, 0.0f, 0.5f}, 1.0f));
  EXPECT_TRUE(image.seenPast({18.5f, 1.0f, 0.0f}, 1.0f));
  // On the wall, within the margin, or behind it: not seen past.
  EXPECT_FALSE(image.seenPast({19.5f, 0.0f, 0.5f}, 1.0f));
  EXPECT_FALSE(image.seenPast({20.0f, 0.0f, 0.5f}, 1.0f));
  EXPECT_FALSE(image.seenPast({30.0f, 0.0f, 0.5f}, 1.0f));
  // Where the scan has no return at all (behind the sensor, the sky): nothing known.
  EXPECT_FALSE(image.seenPast({-10.0f, 0.0f, 0.5f}, 1.0f));
  EXPECT_FALSE(image.seenPast({10.0f, 0.0f, 8.0f}, 1.0f));
  EXPECT_FALSE(VisibilityImage().seenPast({10.0f, 0.0f, 0.5f}, 1.0f));
}

TEST(VoxelPlaneMap, HidesWhatTheScanSeesThroughUntilTheNextCall)
{
  // The map: the back of a truck 10 m ahead and a wall at 30 m, seen from the origin.
  // (A 0.25 m grid: the first 20 points of each 1 m voxel span a plane.)
  pcl::PointCloud<pcl::PointXYZI> before;
  addWall(10.0, before, 0.25);
  addWall(30.0, before, 0.25);
  VoxelPlaneMap map;
  map.insert(toPoints(before), Eigen::Vector3f::Zero());
  Eigen::Vector3f centroid, normal;
  const Eigen::Vector3f truck(10.0f, 0.2f, 0.5f), wall(30.0f, 0.2f, 0.5f);
  ASSERT_TRUE(map.plane(truck, centroid, normal));
  ASSERT_TRUE(map.plane(wall, centroid, normal));

  // The truck drove off: the next scan sees the wall (higher and wider than the truck
  // seen from the sensor) through where it stood.
  pcl::PointCloud<pcl::PointXYZI> after;
  addWall(30.0, after, 0.05, 20.0, 7.0);
  const VisibilityImage image(after);
  const int hidden =
      map.hideSeenThrough(&image, Eigen::Isometry3f::Identity(), 40.0f, 1.0f);
  EXPECT_GT(hidden, 0);
  EXPECT_FALSE(map.plane(truck, centroid, normal)) << "the truck's voxels pair no more";
  EXPECT_TRUE(map.plane(wall, centroid, normal)) << "the wall it saw stays";

  // Beyond the radius nothing is hidden; without an image everything shows again.
  EXPECT_EQ(map.hideSeenThrough(&image, Eigen::Isometry3f::Identity(), 5.0f, 1.0f), 0);
  EXPECT_TRUE(map.plane(truck, centroid, normal));
  map.hideSeenThrough(&image, Eigen::Isometry3f::Identity(), 40.0f, 1.0f);
  map.hideSeenThrough(nullptr, Eigen::Isometry3f::Identity(), 40.0f, 1.0f);
  EXPECT_TRUE(map.plane(truck, centroid, normal));
  // A margin larger than the 20 m the scan saw past the truck hides nothing.
  EXPECT_EQ(map.hideSeenThrough(&image, Eigen::Isometry3f::Identity(), 40.0f, 25.0f), 0);
}

/// A full map voxel takes points seen from much nearer in place of those it saw from
/// farthest (DenseTrackingParams::map_nearer_ratio): a level patch first seen from 40 m
/// with a height error, then from 4 m without, gives the near patch's plane; points from
/// a range not below the ratio, or the ratio 0 (KISS-ICP's first points), leave it.
TEST(VoxelPlaneMap, NearerPointsReplaceTheFarthestOfAFullVoxel)
{
  // 25 points of a level patch inside the voxel [0, 1)^3 at height z.
  const auto patch = [](float z) {
    pcl::PointCloud<pcl::PointXYZI> cloud;
    for (int i = 0; i < 5; ++i)
      for (int j = 0; j < 5; ++j) {
        pcl::PointXYZI p;
        p.x = 0.1f + 0.2f * static_cast<float>(i);
        p.y = 0.1f + 0.2f * static_cast<float>(j);
        p.z = z;
        cloud.push_back(p);
      }
    return toPoints(cloud);
  };
  const Eigen::Vector3f far_sensor(40.5f, 0.5f, 0.0f), near_sensor(4.5f, 0.5f, 0.0f),
      middle_sensor(30.5f, 0.5f, 0.0f);
  const auto heightAfter = [&](double ratio, const Eigen::Vector3f& second_sensor) {
    pcl::rast::DenseTrackingParams params;
    params.map_nearer_ratio = ratio;
    VoxelPlaneMap map(params);
    map.insert(patch(0.56f), far_sensor);
    map.insert(patch(0.44f), second_sensor);
    Eigen::Vector3f centroid, normal;
    EXPECT_TRUE(map.plane({0.5f, 0.5f, 0.5f}, centroid, normal));
    EXPECT_GT(std::abs(normal.z()), 0.99f);
    return centroid.z();
  };
  EXPECT_NEAR(heightAfter(0.5, near_sensor), 0.44f, 1e-4f) << "all 20 replaced";
  EXPECT_NEAR(heightAfter(0.0, near_sensor), 0.56f, 1e-4f) << "the first points stay";
  EXPECT_NEAR(heightAfter(0.5, middle_sensor), 0.56f, 1e-4f)
      << "30 m is not < 0.5 * 40 m";
  EXPECT_NEAR(heightAfter(0.8, middle_sensor), 0.44f, 1e-4f);

  pcl::rast::DenseTrackingParams bad;
  bad.map_nearer_ratio = 1.5;
  std::string why;
  EXPECT_FALSE(bad.isValid(&why));
  EXPECT_NE(why.find("map_nearer_ratio"), std::string::npos) << why;
}

/// The dense step keeps each source point's last plane lookup for its next query
/// (VoxelPlaneMap::PlaneLookup): the pairs must be those a fresh lookup gives, when a
/// point stays in its voxel, when it moves into another, between planes of two
/// neighbours (the nearest centroid changes inside one voxel) and around hidden voxels.
TEST(VoxelPlaneMap, AKeptLookupGivesThePlaneAFreshOneGives)
{
  // Walls across x and along y at several offsets, a slanted roof: planar voxels with
  // non-planar ones (corners, edges) between them.
  pcl::PointCloud<pcl::PointXYZI> scene;
  addWall(6.3, scene, 0.25);
  addWall(9.7, scene, 0.25, 3.0, 4.0);
  for (double x = 2.0; x <= 12.0; x += 0.25)
    for (double z = -1.0; z <= 2.0; z += 0.25) {
      pcl::PointXYZI p;
      p.x = static_cast<float>(x);
      p.y = static_cast<float>(-3.4 + 0.1 * z);
      p.z = static_cast<float>(z);
      scene.push_back(p);
      p.y = 4.6f;
      p.z = static_cast<float>(z + 0.3 * x);
      scene.push_back(p);
    }
  VoxelPlaneMap map;
  map.insert(toPoints(scene), Eigen::Vector3f::Zero());

  std::mt19937 rng(29);
  std::uniform_int_distribution<std::size_t> any_point(0, scene.size() - 1);
  std::normal_distribution<float> off(0.0f, 0.4f), step(0.0f, 0.08f);
  const auto compare = [&](const char* when, int& reused, int& paired, int& chosen) {
    // 400 points near the surfaces, each queried 30 times along a small random walk
    // (Gauss-Newton's steps), with a kept lookup against a fresh one every time.
    for (int point = 0; point < 400; ++point) {
      Eigen::Vector3f q = scene[any_point(rng)].getVector3fMap() +
                          Eigen::Vector3f(off(rng), off(rng), off(rng));
      VoxelPlaneMap::PlaneLookup kept;
      for (int query = 0; query < 30; ++query) {
        const pcl::rast::VoxelKey before = kept.key;
        Eigen::Vector3f c_kept, n_kept, c_fresh, n_fresh;
        const bool with_kept = map.plane(q, kept, c_kept, n_kept);
        const bool fresh = map.plane(q, c_fresh, n_fresh);
        ASSERT_EQ(with_kept, fresh) << when << ": point " << point << ", query " << query;
        if (fresh) {
          ASSERT_EQ(c_kept, c_fresh)
              << when << ": point " << point << ", query " << query;
          ASSERT_EQ(n_kept, n_fresh)
              << when << ": point " << point << ", query " << query;
          ++paired;
          // Between neighbours' planes: the nearest centroid is chosen per query.
          chosen += !kept.own && kept.count >= 2 ? 1 : 0;
        }
        reused += kept.key == before ? 1 : 0;
        q += Eigen::Vector3f(step(rng), step(rng), step(rng));
      }
    }
  };
  int reused = 0, paired = 0, chosen = 0;
  compare("whole map", reused, paired, chosen);
  // The walk stays in its voxel most of the time, pairs often and often between two
  // neighbours: the comparison is not between two empty answers.
  std::cout << "of 12000 queries: " << reused << " in the kept voxel, " << paired
            << " paired, " << chosen << " between neighbours\n";
  EXPECT_GT(reused, 6000) << "of 12000 queries";
  EXPECT_GT(paired, 3000) << "of 12000 queries";
  EXPECT_GT(chosen, 300) << "of 12000 queries";

  // Hide what a scan from the origin sees through (the near wall, seen past by a wider
  // one behind it); the lookups of a map changed so are made afresh.
  pcl::PointCloud<pcl::PointXYZI> after;
  addWall(9.7, after, 0.05, 20.0, 7.0);
  const VisibilityImage image(after);
  ASSERT_GT(map.hideSeenThrough(&image, Eigen::Isometry3f::Identity(), 40.0f, 1.0f), 0);
  reused = paired = chosen = 0;
  compare("with hidden voxels", reused, paired, chosen);
  EXPECT_GT(paired, 1000) << "of 12000 queries";
}

/// Hidden map voxels and dropped points per frame of a simulated HDL-64 drive.
struct VisibilityCounts
{
  std::vector<int> hidden, dropped;
  int total(const std::vector<int>& v) const
  {
    return std::accumulate(v.begin(), v.end(), 0);
  }
};

VisibilityCounts
drive(bool moving_cars)
{
  pcl::rast::PathParams path;
  path.type = pcl::rast::PathType::kStraight;
  path.num_frames = 40;
  path.speed_mps = 10.0;
  pcl::rast::LidarSimulatorParams params;
  params.seed = 31;
  params.num_threads = 2;
  params.world.moving_cars = moving_cars;
  params.world.traffic.mode = pcl::rast::TrafficMode::kRealistic;
  pcl::rast::LidarSimulator sim(params, pcl::rast::generatePath(path));
  pcl::rast::OdometryParams odometry_params;
  odometry_params.visibility_margin_m = 1.0;
  pcl::rast::Odometry odometry(odometry_params);
  VisibilityCounts counts;
  for (std::size_t i = 0; i < sim.numFrames(); ++i) {
    auto cloud = std::make_shared<pcl::PointCloud<pcl::PointXYZI>>();
    sim.simulateFrame(i, *cloud);
    const auto r = odometry.processFrame(cloud, sim.timestamp(i), i);
    counts.hidden.push_back(r.hidden_map_voxels);
    counts.dropped.push_back(r.dropped_moving_points);
  }
  return counts;
}

TEST(OdometryVisibility, TrafficIsHiddenAndAStaticWorldIsNot)
{
  const VisibilityCounts traffic = drive(true), still = drive(false);
  std::cout << "hidden voxels: traffic " << traffic.total(traffic.hidden) << ", static "
            << still.total(still.hidden) << "; dropped points: traffic "
            << traffic.total(traffic.dropped) << ", static " << still.total(still.dropped)
            << "\n";
  // The cars leave voxels behind that later scans see through, and drive into space
  // the key-frame saw empty.
  EXPECT_GT(traffic.total(traffic.hidden), 100);
  EXPECT_GT(traffic.total(traffic.dropped), 10);
  // In a static world almost nothing is seen through: no map voxel, and a few of the
  // dense step's ~1000 points a frame (silhouettes seen from another place).
  EXPECT_LT(still.total(still.hidden), traffic.total(traffic.hidden) / 20);
  EXPECT_LT(still.total(still.dropped), 5 * static_cast<int>(still.dropped.size()));
  EXPECT_GT(traffic.total(traffic.dropped), 2 * still.total(still.dropped));
  // The first frames have no tracked velocity to place points by: no test there.
  EXPECT_EQ(traffic.hidden[0] + traffic.hidden[1], 0);
}

TEST(OdometryVisibility, OffByDefault)
{
  EXPECT_EQ(pcl::rast::OdometryParams().visibility_margin_m, 0.0);
}

} // namespace

} // namespace test_odometry_visibility
