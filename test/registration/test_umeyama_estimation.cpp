/// \file test_umeyama_estimation.cpp
/// \brief Eq. 4 closed form: exactness, inverse, weights, degenerate input, validation.

#include <pcl/registration/umeyama_estimation.h>

#include <gtest/gtest.h>

#include <random>

// This file's names stay its own: a test program compiles several test files as
// one translation unit (test/CMakeLists.txt).
namespace test_umeyama_estimation {

namespace {

using pcl::rast::estimateRigidTransform;

Eigen::Isometry3d
makeTransform(double roll, double pitch, double yaw, const Eigen::Vector3d& t)
{
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = (Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()) *
                Eigen::AngleAxisd(pitch, Eigen::Vector3d::UnitY()) *
                Eigen::AngleAxisd(roll, Eigen::Vector3d::UnitX()))
                   .toRotationMatrix();
  T.translation() = t;
  return T;
}

Eigen::Matrix3Xd
randomPoints(int n, std::uint32_t seed, double half_extent_m = 20.0)
{
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-half_extent_m, half_extent_m);
  Eigen::Matrix3Xd points(3, n);
  for (int i = 0; i < n; ++i)
    points.col(i) = Eigen::Vector3d(u(rng), u(rng), u(rng));
  return points;
}

Eigen::Matrix3Xd
apply(const Eigen::Isometry3d& T, const Eigen::Matrix3Xd& points)
{
  return (T.linear() * points).colwise() + T.translation();
}

TEST(UmeyamaEstimation, RecoversKnownTransformExactly)
{
  const Eigen::Isometry3d T_target_source =
      makeTransform(0.1, -0.2, 0.7, Eigen::Vector3d(3.0, -1.5, 0.4));
  const Eigen::Matrix3Xd source = randomPoints(50, 1);
  const Eigen::Matrix3Xd target = apply(T_target_source, source);

  const auto forward = estimateRigidTransform(source, target);
  EXPECT_TRUE(forward.well_conditioned);
  EXPECT_TRUE(forward.T_target_source.isApprox(T_target_source, 1e-10));
  EXPECT_LT(forward.rmse_m, 1e-10);

  const auto inverse = estimateRigidTransform(target, source);
  EXPECT_TRUE(inverse.T_target_source.isApprox(T_target_source.inverse(), 1e-10));
}

TEST(UmeyamaEstimation, MinimalAndPlanarSetsGiveRotationsNotReflections)
{
  const Eigen::Isometry3d T = makeTransform(0.3, 0.2, -1.0, Eigen::Vector3d(1, 2, 3));
  Eigen::Matrix3Xd source = randomPoints(3, 2);
  auto estimate = estimateRigidTransform(source, apply(T, source));
  EXPECT_TRUE(estimate.T_target_source.isApprox(T, 1e-9));

  source = randomPoints(20, 3);
  source.row(2).setZero(); // all on the plane z = 0
  estimate = estimateRigidTransform(source, apply(T, source));
  EXPECT_NEAR(estimate.T_target_source.linear().determinant(), 1.0, 1e-12);
  EXPECT_TRUE(estimate.T_target_source.isApprox(T, 1e-9));
}

TEST(UmeyamaEstimation, WeightsIgnoreZeroWeightedOutliers)
{
  const Eigen::Isometry3d T = makeTransform(0.0, 0.1, 0.4, Eigen::Vector3d(-2, 0.5, 0));
  const Eigen::Matrix3Xd source = randomPoints(30, 4);
  Eigen::Matrix3Xd target = apply(T, source);
  Eigen::VectorXd weights = Eigen::VectorXd::Ones(30);
  for (int i = 0; i < 5; ++i) {
    target.col(i) += Eigen::Vector3d(10, -7, 3);
    weights(i) = 0.0;
  }
  EXPECT_TRUE(estimateRigidTransform(source, target, weights).T_target_source.isApprox(T, 1e-9));
  // Unweighted, the outliers must pull the estimate away (the test can fail).
  EXPECT_FALSE(estimateRigidTransform(source, target).T_target_source.isApprox(T, 1e-3));
}

TEST(UmeyamaEstimation, CollinearPointsAreFlaggedIllConditioned)
{
  Eigen::Matrix3Xd source(3, 10);
  for (int i = 0; i < 10; ++i)
    source.col(i) = Eigen::Vector3d(1.0 * i, 2.0 * i, -0.5 * i);
  const Eigen::Isometry3d T = makeTransform(0.1, 0.2, 0.3, Eigen::Vector3d(1, 1, 1));
  const auto estimate = estimateRigidTransform(source, apply(T, source));
  EXPECT_FALSE(estimate.well_conditioned);
  EXPECT_LT(pcl::rast::secondaryExtent(source), 1e-6);
  EXPECT_GT(pcl::rast::secondaryExtent(randomPoints(10, 5)), 1.0);
}

TEST(UmeyamaEstimation, InvalidInputThrows)
{
  const Eigen::Matrix3Xd a = randomPoints(5, 6);
  EXPECT_THROW(estimateRigidTransform(a, randomPoints(4, 7)), std::invalid_argument);
  EXPECT_THROW(estimateRigidTransform(randomPoints(2, 8), randomPoints(2, 9)),
               std::invalid_argument);
  EXPECT_THROW(estimateRigidTransform(a, a, Eigen::VectorXd::Ones(4)), std::invalid_argument);
  EXPECT_THROW(estimateRigidTransform(a, a, -Eigen::VectorXd::Ones(5)), std::invalid_argument);
  EXPECT_THROW(estimateRigidTransform(a, a, Eigen::VectorXd::Zero(5)), std::invalid_argument);

  pcl::PointCloud<pcl::rast::RasterFeaturePoint> cloud;
  cloud.resize(4);
  pcl::Correspondences bad{{0, 1, 0.f}, {1, 2, 0.f}, {2, 7, 0.f}};
  try {
    estimateRigidTransform(cloud, cloud, bad);
    FAIL() << "no exception";
  }
  catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("estimateRigidTransform"), std::string::npos);
    EXPECT_NE(std::string(e.what()).find("out of range"), std::string::npos);
  }
}

} // namespace

} // namespace test_umeyama_estimation
