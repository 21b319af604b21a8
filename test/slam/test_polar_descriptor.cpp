/// The polar max-height descriptor that finds a saved map's key-frame where the raster
/// features retrieve none (SessionLocalizerParams::polar_candidates): a turned scan
/// keeps its distance near zero and tells the turn, other places are farther, and
/// the ranking finds the right one among many.

#include "../../slam/src/polar_descriptor.h"

#include <Eigen/Geometry>
#include <cmath>
#include <gtest/gtest.h>
#include <limits>
#include <random>
#include <stdexcept>
#include <string>
#include <vector>

// This file's names stay its own: a test program compiles several test files as
// one translation unit (test/CMakeLists.txt).
namespace test_polar_descriptor {

namespace {

using pcl::rast::slam_detail::PolarDescriptor;
using pcl::rast::slam_detail::PolarDescriptorParams;
using Cloud = pcl::PointCloud<pcl::PointXYZI>;

/// A place: ground at z = -1.8 out to 50 m, and \a boxes boxes of random size and
/// height around the sensor, from \a seed.
Cloud
place(unsigned seed, int boxes = 25)
{
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> where(-45.0f, 45.0f), size(1.0f, 6.0f),
      height(0.5f, 8.0f);
  Cloud cloud;
  const auto add = [&cloud](float x, float y, float z) {
    pcl::PointXYZI p;
    p.x = x;
    p.y = y;
    p.z = z;
    p.intensity = 0.0f;
    cloud.push_back(p);
  };
  for (float x = -50.0f; x <= 50.0f; x += 1.0f)
    for (float y = -50.0f; y <= 50.0f; y += 1.0f)
      add(x, y, -1.8f);
  for (int b = 0; b < boxes; ++b) {
    const float cx = where(rng), cy = where(rng), s = size(rng), h = height(rng);
    for (float x = cx - s / 2; x <= cx + s / 2; x += 0.25f)
      for (float y = cy - s / 2; y <= cy + s / 2; y += 0.25f)
        for (float z = -1.8f; z <= -1.8f + h; z += 0.5f)
          add(x, y, z);
  }
  return cloud;
}

/// \a cloud seen from a sensor turned by \a yaw_deg and moved by (dx, dy): the points
/// in its frame.
Cloud
seenFrom(const Cloud& cloud, double yaw_deg, double dx = 0.0, double dy = 0.0)
{
  Eigen::Isometry3d T_world_sensor = Eigen::Isometry3d::Identity();
  T_world_sensor.linear() =
      Eigen::AngleAxisd(yaw_deg * M_PI / 180.0, Eigen::Vector3d::UnitZ())
          .toRotationMatrix();
  T_world_sensor.translation() = Eigen::Vector3d(dx, dy, 0.0);
  const Eigen::Isometry3d T = T_world_sensor.inverse();
  Cloud out;
  for (const pcl::PointXYZI& p : cloud.points) {
    pcl::PointXYZI q = p;
    q.getVector3fMap() = (T * p.getVector3fMap().cast<double>()).cast<float>();
    out.push_back(q);
  }
  return out;
}

} // namespace

TEST(PolarDescriptor, ATurnedScanIsNearAndTellsTheTurn)
{
  const PolarDescriptorParams params;
  const Cloud scan = place(7);
  const PolarDescriptor map(scan, params);
  for (const double yaw : {0.0, 42.0, -90.0, 138.0, 179.0}) {
    SCOPED_TRACE(yaw);
    // The query is the map's scan seen turned by yaw: T_map_query has that yaw.
    const PolarDescriptor query(seenFrom(scan, yaw), params);
    const auto [d, shift] = query.distance(map);
    EXPECT_LT(d, 0.05);
    double error = query.yawDeg(shift) - yaw;
    error -= 360.0 * std::round(error / 360.0);
    EXPECT_LE(std::abs(error), 360.0 / params.sectors); // within one sector
  }
}

TEST(PolarDescriptor, AnotherPlaceIsFartherThanTheSamePlaceMovedAMetre)
{
  const PolarDescriptorParams params;
  const Cloud here = place(11);
  const PolarDescriptor map(here, params);
  const double same =
      PolarDescriptor(seenFrom(here, 75.0, 1.0, -0.5), params).distance(map).first;
  for (unsigned seed = 20; seed < 25; ++seed) {
    SCOPED_TRACE(seed);
    const double other = PolarDescriptor(place(seed), params).distance(map).first;
    EXPECT_GT(other, same + 0.05);
  }
}

TEST(PolarDescriptor, RankingFindsThePlaceAmongManyAndSkipsEmptyOnes)
{
  const PolarDescriptorParams params;
  std::vector<PolarDescriptor> map;
  for (unsigned seed = 100; seed < 160; ++seed)
    map.emplace_back(place(seed), params);
  map.emplace_back(Cloud(), params); // a key-frame with no points: never a match
  const unsigned right = 137;
  const PolarDescriptor query(seenFrom(place(right), -120.0, 0.8, 0.6), params);
  const auto ranked = pcl::rast::slam_detail::rankByPolarDescriptor(query, map, 3);
  ASSERT_EQ(ranked.size(), 3u);
  EXPECT_EQ(ranked[0].index, right - 100);
  EXPECT_NEAR(ranked[0].yaw_deg, -120.0, 360.0 / params.sectors);
  EXPECT_LE(ranked[0].distance, ranked[1].distance);
  EXPECT_LE(ranked[1].distance, ranked[2].distance);
  for (const auto& m : ranked)
    EXPECT_NE(m.index, map.size() - 1) << "the empty key-frame";
  // Asked for more than there are: every candidate that shares enough, once.
  EXPECT_EQ(pcl::rast::slam_detail::rankByPolarDescriptor(query, map, 1000).size(),
            map.size() - 1);
}

TEST(PolarDescriptor, InvalidShapeIsRejectedByName)
{
  PolarDescriptorParams params;
  params.sectors = 2;
  try {
    PolarDescriptor d(place(1), params);
    FAIL() << "no exception";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("sectors"), std::string::npos) << e.what();
  }
  params = PolarDescriptorParams();
  params.height_offset_m = std::numeric_limits<double>::infinity();
  EXPECT_THROW(PolarDescriptor(place(1), params), std::invalid_argument);
}

TEST(PolarDescriptor, LyingPointsDoNotSpoilTheRest)
{
  const PolarDescriptorParams params;
  const Cloud scan = place(5);
  Cloud lying = scan;
  pcl::PointXYZI p;
  p.intensity = 0.0f;
  // A point far up in a sector of its own, points with no value, one on the range's edge
  // and one whose azimuth rounds to 360 deg.
  for (const Eigen::Vector3f& v :
       {Eigen::Vector3f(-20.0f, -1e-7f, 3e30f),
        Eigen::Vector3f(std::nanf(""), 1.0f, 1.0f),
        Eigen::Vector3f(1.0f, std::numeric_limits<float>::infinity(), 1.0f),
        Eigen::Vector3f(60.0f, 0.0f, 1.0f),
        Eigen::Vector3f(10.0f, -1e-9f, 1.0f)}) {
    p.getVector3fMap() = v;
    lying.push_back(p);
  }
  const PolarDescriptor clean(scan, params), spoilt(lying, params);
  const auto [d, shift] = spoilt.distance(clean);
  EXPECT_LT(d, 0.05);
  EXPECT_EQ(shift, 0);
  EXPECT_TRUE(std::isfinite(d));
}

} // namespace test_polar_descriptor
