/// \file test_rigid_ransac.cpp
/// \brief Rigid RANSAC: 40 % outliers rejected (forward and inverse), determinism,
/// degenerate (collinear) input and too few correspondences fail with a reason.

#include <pcl/registration/rigid_ransac.h>

#include <gtest/gtest.h>

#include <random>

// This file's names stay its own: a test program compiles several test files as
// one translation unit (test/CMakeLists.txt).
namespace test_rigid_ransac {

namespace {

using pcl::rast::RigidRansacParams;

Eigen::Isometry3d
makeTransform(double yaw, double pitch, const Eigen::Vector3d& t)
{
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = (Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()) *
                Eigen::AngleAxisd(pitch, Eigen::Vector3d::UnitY()))
                   .toRotationMatrix();
  T.translation() = t;
  return T;
}

double
rotationErrorDeg(const Eigen::Isometry3d& a, const Eigen::Isometry3d& b)
{
  return Eigen::AngleAxisd((a.inverse() * b).rotation()).angle() * 180.0 / M_PI;
}

/// n pairs: the first (1 - outlier_ratio) n follow T with 2 cm noise, the rest are random.
void
makePairs(int n,
          double outlier_ratio,
          const Eigen::Isometry3d& T_target_source,
          std::uint32_t seed,
          Eigen::Matrix3Xd& source,
          Eigen::Matrix3Xd& target,
          int& num_inliers)
{
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-30.0, 30.0);
  std::normal_distribution<double> noise(0.0, 0.02);
  source.resize(3, n);
  target.resize(3, n);
  num_inliers = static_cast<int>(n * (1.0 - outlier_ratio));
  for (int i = 0; i < n; ++i) {
    source.col(i) = Eigen::Vector3d(u(rng), u(rng), 0.2 * u(rng));
    if (i < num_inliers)
      target.col(i) = T_target_source * source.col(i) +
                      Eigen::Vector3d(noise(rng), noise(rng), noise(rng));
    else
      target.col(i) = Eigen::Vector3d(u(rng), u(rng), 0.2 * u(rng));
  }
}

TEST(RigidRansac, RejectsFortyPercentOutliersForwardAndInverse)
{
  const Eigen::Isometry3d T = makeTransform(0.35, 0.05, Eigen::Vector3d(2.0, -1.0, 0.3));
  Eigen::Matrix3Xd source, target;
  int num_inliers = 0;
  makePairs(200, 0.4, T, 11, source, target, num_inliers);

  const auto forward = pcl::rast::estimateRigidRansac(source, target);
  ASSERT_TRUE(forward.success) << forward.message;
  EXPECT_LT((forward.T_target_source.translation() - T.translation()).norm(), 0.02);
  EXPECT_LT(rotationErrorDeg(forward.T_target_source, T), 0.05);
  // All true inliers kept, (almost) no outlier accepted.
  int true_kept = 0, false_kept = 0;
  for (const int i : forward.inlier_indices)
    (i < num_inliers ? true_kept : false_kept)++;
  EXPECT_EQ(true_kept, num_inliers);
  EXPECT_LE(false_kept, 2);
  EXPECT_LT(forward.inlier_rmse_m, 0.06);
  EXPECT_LT(forward.iterations, 1000); // adaptive stop, well below max_iterations

  const auto inverse = pcl::rast::estimateRigidRansac(target, source);
  ASSERT_TRUE(inverse.success) << inverse.message;
  EXPECT_LT((inverse.T_target_source.translation() - T.inverse().translation()).norm(), 0.02);
  EXPECT_LT(rotationErrorDeg(inverse.T_target_source, T.inverse()), 0.05);
}

TEST(RigidRansac, SameSeedSameResult)
{
  const Eigen::Isometry3d T = makeTransform(-0.2, 0.0, Eigen::Vector3d(0.5, 0.5, 0.0));
  Eigen::Matrix3Xd source, target;
  int num_inliers = 0;
  makePairs(120, 0.4, T, 12, source, target, num_inliers);
  RigidRansacParams params;
  params.seed = 5;
  const auto a = pcl::rast::estimateRigidRansac(source, target, params);
  const auto b = pcl::rast::estimateRigidRansac(source, target, params);
  EXPECT_EQ(a.iterations, b.iterations);
  EXPECT_EQ(a.inlier_indices, b.inlier_indices);
  EXPECT_TRUE(a.T_target_source.isApprox(b.T_target_source, 0.0));
}

TEST(RigidRansac, CollinearInputFailsAsDegenerate)
{
  Eigen::Matrix3Xd source(3, 40), target(3, 40);
  const Eigen::Isometry3d T = makeTransform(0.3, 0.0, Eigen::Vector3d(1, 0, 0));
  for (int i = 0; i < 40; ++i) {
    source.col(i) = Eigen::Vector3d(0.7 * i, 0.3 * i, 0.0);
    target.col(i) = T * source.col(i);
  }
  RigidRansacParams params;
  params.max_iterations = 500;
  const auto result = pcl::rast::estimateRigidRansac(source, target, params);
  EXPECT_FALSE(result.success);
  EXPECT_TRUE(result.degenerate);
  EXPECT_EQ(result.degenerate_samples, result.iterations);
  EXPECT_NE(result.message.find("degenerate"), std::string::npos) << result.message;
}

TEST(RigidRansac, TooFewCorrespondencesFail)
{
  Eigen::Matrix3Xd source, target;
  int num_inliers = 0;
  makePairs(8, 0.0, Eigen::Isometry3d::Identity(), 13, source, target, num_inliers);
  const auto result = pcl::rast::estimateRigidRansac(source, target); // min_inliers 10
  EXPECT_FALSE(result.success);
  EXPECT_FALSE(result.degenerate);
  EXPECT_NE(result.message.find("too few"), std::string::npos) << result.message;
}

TEST(RigidRansac, AllOutliersFail)
{
  Eigen::Matrix3Xd source, target;
  int num_inliers = 0;
  makePairs(60, 1.0, Eigen::Isometry3d::Identity(), 14, source, target, num_inliers);
  RigidRansacParams params;
  params.min_inliers = 15;
  params.max_iterations = 2000;
  const auto result = pcl::rast::estimateRigidRansac(source, target, params);
  EXPECT_FALSE(result.success) << result.message;
}

TEST(RigidRansac, RejectorKeepsInlierCorrespondences)
{
  const Eigen::Isometry3d T = makeTransform(0.1, 0.0, Eigen::Vector3d(0.0, 1.0, 0.0));
  Eigen::Matrix3Xd source, target;
  int num_inliers = 0;
  makePairs(50, 0.4, T, 15, source, target, num_inliers);
  auto source_cloud = std::make_shared<pcl::PointCloud<pcl::rast::RasterFeaturePoint>>();
  auto target_cloud = std::make_shared<pcl::PointCloud<pcl::rast::RasterFeaturePoint>>();
  pcl::Correspondences all;
  for (int i = 0; i < 50; ++i) {
    pcl::rast::RasterFeaturePoint p{};
    // Store in reverse order in the target to exercise index_match.
    p.getVector3fMap() = source.col(i).cast<float>();
    source_cloud->push_back(p);
  }
  target_cloud->resize(50);
  for (int i = 0; i < 50; ++i) {
    (*target_cloud)[49 - i].getVector3fMap() = target.col(i).cast<float>();
    all.emplace_back(i, 49 - i, 0.f);
  }
  pcl::rast::RigidRansacRejector rejector;
  pcl::Correspondences kept;
  EXPECT_THROW(rejector.getRemainingCorrespondences(all, kept), std::invalid_argument);
  rejector.setInputSource(source_cloud);
  rejector.setInputTarget(target_cloud);
  const auto result = rejector.getRemainingCorrespondences(all, kept);
  ASSERT_TRUE(result.success) << result.message;
  EXPECT_GE(static_cast<int>(kept.size()), num_inliers);
  for (const auto& c : kept)
    EXPECT_LT(c.index_query, num_inliers);

  all.emplace_back(0, 50, 0.f); // out of range
  EXPECT_THROW(rejector.getRemainingCorrespondences(all, kept), std::invalid_argument);
}

TEST(RigidRansac, ParamsValidation)
{
  RigidRansacParams params;
  std::string why;
  EXPECT_TRUE(params.isValid(&why)) << why;
  params.confidence = 1.0;
  EXPECT_FALSE(params.isValid(&why));
  EXPECT_NE(why.find("confidence"), std::string::npos);
  params = RigidRansacParams();
  params.min_inliers = 2;
  EXPECT_FALSE(params.isValid());
  params = RigidRansacParams();
  params.inlier_threshold_m = 0.0;
  Eigen::Matrix3Xd points(3, 20);
  points.setRandom();
  try {
    pcl::rast::estimateRigidRansac(points, points, params);
    FAIL() << "no exception";
  }
  catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("inlier_threshold_m"), std::string::npos);
  }
  EXPECT_THROW(pcl::rast::RigidRansacRejector{params}, std::invalid_argument);
}

} // namespace

} // namespace test_rigid_ransac
