/// Degenerate geometry in the dense step of the odometry: directions the scan does not
/// constrain take the anchor's value (the motion prior, or strong features), and the
/// scan's information tells which poses it cannot tell apart.

#include "../../slam/src/odometry_local_map.h"

#include <cmath>
#include <gtest/gtest.h>
#include <random>
#include <string>

// This file's names stay its own: a test program compiles several test files as
// one translation unit (test/CMakeLists.txt).
namespace test_odometry_degenerate {

namespace {

using pcl::rast::DenseTrackingParams;
using pcl::rast::odometry_detail::DenseOptions;
using pcl::rast::odometry_detail::denseSeparation;
using pcl::rast::odometry_detail::Points3f;
using pcl::rast::odometry_detail::registerToMap;
using pcl::rast::odometry_detail::VoxelPlaneMap;

/// A straight corridor along x: flat ground 1.7 m below the sensor and two smooth walls
/// 4 m to either side, 4 m tall; nothing along x fixes a position on it. Points on a
/// 0.2 m grid for x in [x0, x1], with range noise of \a noise_m (fixed seed).
Points3f
corridor(double x0, double x1, double noise_m, unsigned seed)
{
  std::mt19937 rng(seed);
  std::normal_distribution<float> noise(0.0f, static_cast<float>(noise_m));
  Points3f points;
  for (double x = x0; x <= x1; x += 0.2) {
    for (double y = -3.8; y <= 3.8; y += 0.4)
      points.emplace_back(x, y, -1.7f + noise(rng));
    for (double z = -1.6; z <= 2.3; z += 0.3) {
      points.emplace_back(x, -4.0f + noise(rng), z);
      points.emplace_back(x, 4.0f + noise(rng), z);
    }
  }
  return points;
}

/// Every k-th point, like the odometry's subsampled source.
Points3f
stride(const Points3f& points, std::size_t k)
{
  Points3f out;
  for (std::size_t i = 0; i < points.size(); i += k)
    out.push_back(points[i]);
  return out;
}

Eigen::Isometry3d
translation(double x, double y, double z)
{
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.translation() = Eigen::Vector3d(x, y, z);
  return T;
}

TEST(DenseDegeneracy, AlongTheCorridorTheAnchorDecides)
{
  DenseTrackingParams params;
  VoxelPlaneMap map(params);
  map.insert(corridor(-60.0, 60.0, 0.01, 1), Eigen::Vector3f::Zero());
  const Points3f source = stride(corridor(-30.0, 30.0, 0.01, 2), 7);

  // The guess is off across the corridor too (y, z), which the scan corrects.
  const Eigen::Isometry3d guess = translation(0.6, 0.2, 0.1);
  const auto kept = registerToMap(source, map, guess, params);
  ASSERT_TRUE(kept.success) << kept.message;
  EXPECT_GE(kept.degenerate_directions, 1);
  EXPECT_NEAR(kept.T_world_lidar.translation().y(), 0.0, 0.02);
  EXPECT_NEAR(kept.T_world_lidar.translation().z(), 0.0, 0.02);
  // Without an anchor x stays at the guess ...
  EXPECT_NEAR(kept.T_world_lidar.translation().x(), 0.6, 0.02);

  // ... with one, x takes the anchor's value; y and z are still the scan's.
  const Eigen::Isometry3d prior = translation(0.25, -0.3, 0.4);
  DenseOptions options;
  options.T_world_anchor = &prior;
  const auto anchored = registerToMap(source, map, guess, params, options);
  ASSERT_TRUE(anchored.success) << anchored.message;
  EXPECT_NEAR(anchored.T_world_lidar.translation().x(), 0.25, 0.02);
  EXPECT_NEAR(anchored.T_world_lidar.translation().y(), 0.0, 0.02);
  EXPECT_NEAR(anchored.T_world_lidar.translation().z(), 0.0, 0.02);
  EXPECT_LT(Eigen::AngleAxisd(anchored.T_world_lidar.rotation()).angle(), 0.002);
}

TEST(DenseDegeneracy, WellConstrainedScansIgnoreTheAnchor)
{
  // A corridor with a cross wall ahead: every direction is constrained, so the anchor
  // changes nothing.
  DenseTrackingParams params;
  Points3f scene = corridor(-60.0, 20.0, 0.01, 3);
  for (double y = -3.9; y <= 3.9; y += 0.1)
    for (double z = -1.6; z <= 2.3; z += 0.1)
      scene.emplace_back(20.0f, y, z);
  VoxelPlaneMap map(params);
  map.insert(scene, Eigen::Vector3f::Zero());
  const Points3f source = stride(scene, 5);
  const Eigen::Isometry3d guess = translation(0.3, 0.1, 0.05);
  const Eigen::Isometry3d far_anchor = translation(1.0, 1.0, 1.0);
  DenseOptions options;
  options.T_world_anchor = &far_anchor;
  const auto result = registerToMap(source, map, guess, params, options);
  ASSERT_TRUE(result.success) << result.message;
  EXPECT_EQ(result.degenerate_directions, 0);
  EXPECT_LT(result.T_world_lidar.translation().norm(), 0.02);
}

TEST(DenseDegeneracy, SeparationSaysWhatTheScanCannotTellApart)
{
  DenseTrackingParams params;
  VoxelPlaneMap map(params);
  map.insert(corridor(-60.0, 60.0, 0.01, 4), Eigen::Vector3f::Zero());
  const auto result = registerToMap(
      stride(corridor(-30.0, 30.0, 0.01, 5), 7), map, translation(0, 0, 0), params);
  ASSERT_TRUE(result.success) << result.message;
  // Half a metre along the corridor: indistinct (the map's plane normals, fitted to
  // noisy points, tilt by ~1 % and are all the scan has along it) ...
  const double indistinct = pcl::rast::OdometryParams().indistinct_residual_m;
  EXPECT_LT(denseSeparation(result, translation(0.5, 0.0, 0.0)), indistinct);
  // ... 5 cm across it or up: distinct.
  EXPECT_GT(denseSeparation(result, translation(0.0, 0.05, 0.0)), 2.0 * indistinct);
  EXPECT_GT(denseSeparation(result, translation(0.0, 0.0, 0.05)), 2.0 * indistinct);
  // A yaw of 1 deg turns the walls: distinct.
  Eigen::Isometry3d yawed = Eigen::Isometry3d::Identity();
  yawed.linear() =
      Eigen::AngleAxisd(M_PI / 180.0, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  EXPECT_GT(denseSeparation(result, yawed), 2.0 * indistinct);
}

} // namespace

namespace {

TEST(DenseDegeneracy, BadThresholdIsRejectedNamingTheValue)
{
  pcl::rast::OdometryParams params;
  std::string why;
  ASSERT_TRUE(params.isValid(&why)) << why;
  params.indistinct_residual_m = -0.5;
  EXPECT_FALSE(params.isValid(&why));
  EXPECT_NE(why.find("indistinct_residual_m"), std::string::npos) << why;
  EXPECT_NE(why.find("-0.5"), std::string::npos) << why;
  params.indistinct_residual_m = std::nan("");
  EXPECT_FALSE(params.isValid(&why));
  EXPECT_THROW(pcl::rast::Odometry{params}, std::invalid_argument);
}

} // namespace

} // namespace test_odometry_degenerate
