/// \file test_correspondence_rigid_registration.cpp
/// \brief The whole chain on synthetic features (known transform, 40 % wrong matches),
/// with and without dense refinement, and its failure paths.

#include <pcl/registration/correspondence_rigid_registration.h>

#include <gtest/gtest.h>

#include <random>

// This file's names stay its own: a test program compiles several test files as
// one translation unit (test/CMakeLists.txt).
namespace test_correspondence_rigid_registration {

namespace {

using pcl::rast::CorrespondenceRigidRegistration;
using pcl::rast::RasterFeatureSet;
using pcl::rast::RegistrationParams;
using Cloud = pcl::PointCloud<pcl::PointXYZI>;

Eigen::Isometry3d
makeTransform(double yaw_deg, const Eigen::Vector3d& t)
{
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() =
      Eigen::AngleAxisd(yaw_deg * M_PI / 180.0, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  T.translation() = t;
  return T;
}

double
translationError(const Eigen::Isometry3d& a, const Eigen::Isometry3d& b)
{
  return (a.inverse() * b).translation().norm();
}

double
rotationErrorDeg(const Eigen::Isometry3d& a, const Eigen::Isometry3d& b)
{
  return Eigen::AngleAxisd((a.inverse() * b).rotation()).angle() * 180.0 / M_PI;
}

/// Dense scene in the world (= target) frame: ground, two facades, boxes.
Cloud::Ptr
denseScene(std::uint32_t seed, const Eigen::Isometry3d& T_frame_world)
{
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::normal_distribution<double> noise(0.0, 0.01);
  auto cloud = std::make_shared<Cloud>();
  auto rectangle = [&](int axis, double value, Eigen::Vector3d lo, Eigen::Vector3d hi) {
    lo[axis] = hi[axis] = value;
    Eigen::Vector3d size = hi - lo;
    size[axis] = 1.0;
    for (int i = 0; i < static_cast<int>(size.prod() * 3.0); ++i) {
      Eigen::Vector3d p;
      for (int a = 0; a < 3; ++a)
        p[a] = lo[a] + u(rng) * (hi[a] - lo[a]) + noise(rng);
      pcl::PointXYZI q;
      q.getVector3fMap() = (T_frame_world * p).cast<float>();
      q.intensity = 0.f;
      cloud->push_back(q);
    }
  };
  auto box = [&](const Eigen::Vector3d& lo, const Eigen::Vector3d& hi) {
    for (int axis = 0; axis < 3; ++axis) {
      rectangle(axis, lo[axis], lo, hi);
      rectangle(axis, hi[axis], lo, hi);
    }
  };
  rectangle(2, 0.0, {-30, -12, 0}, {30, 12, 0});
  rectangle(1, 8.0, {-30, 8, 0}, {30, 8, 8});
  rectangle(1, -10.0, {-30, -10, 0}, {30, -10, 6});
  rectangle(0, 30.0, {30, -10, 0}, {30, 8, 5}); // back wall: constrains x
  box({4, 4, 0}, {8.5, 6, 1.5});
  box({-12, -8, 0}, {-7.5, -6.2, 1.6});
  box({15, 2, 0}, {17, 4, 2.5});
  return cloud;
}

/// Feature pair: n landmarks seen in both scans (descriptors with 6 flipped bits, 3 cm
/// noise); a fraction `wrong` of the source features copy the descriptor of a random
/// target feature but sit somewhere else (matches that RANSAC must reject).
void
makeFeatures(int n,
             double wrong,
             const Eigen::Isometry3d& T_target_source,
             std::uint32_t seed,
             RasterFeatureSet& source,
             RasterFeatureSet& target,
             bool collinear = false)
{
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-25.0, 25.0);
  std::normal_distribution<double> noise(0.0, 0.03);
  std::uniform_int_distribution<int> bit(0, 255);
  auto point = [](const Eigen::Vector3d& p) {
    pcl::rast::RasterFeaturePoint f{};
    f.getVector3fMap() = p.cast<float>();
    return f;
  };
  const Eigen::Isometry3d T_source_target = T_target_source.inverse();
  for (int i = 0; i < n; ++i) {
    const Eigen::Vector3d p_target = collinear ? Eigen::Vector3d(i * 0.5, i * 0.2, 0.0)
                                               : Eigen::Vector3d(u(rng), u(rng), 0.1 * u(rng));
    pcl::rast::OrbDescriptor d;
    for (auto& byte : d)
      byte = static_cast<std::uint8_t>(rng() & 0xFF);
    target.points.push_back(point(p_target));
    target.descriptors.push_back(d);
    for (int k = 0; k < 6; ++k) {
      const int b = bit(rng);
      d[b / 8] ^= static_cast<std::uint8_t>(1u << (b % 8));
    }
    Eigen::Vector3d p_source =
        T_source_target * p_target + Eigen::Vector3d(noise(rng), noise(rng), noise(rng));
    if (i < static_cast<int>(wrong * n))
      p_source = Eigen::Vector3d(u(rng), u(rng), 0.1 * u(rng)); // wrong place
    source.points.push_back(point(p_source));
    source.descriptors.push_back(d);
  }
}

class Registration : public ::testing::Test
{
protected:
  void
  SetUp() override
  {
    T_target_source_ = makeTransform(6.0, Eigen::Vector3d(1.1, 0.3, 0.02));
    source_ = std::make_shared<RasterFeatureSet>();
    target_ = std::make_shared<RasterFeatureSet>();
    makeFeatures(300, 0.4, T_target_source_, 3, *source_, *target_);
  }
  Eigen::Isometry3d T_target_source_;
  std::shared_ptr<RasterFeatureSet> source_, target_;
};

TEST_F(Registration, FeaturesOnlyWithFortyPercentWrongMatches)
{
  CorrespondenceRigidRegistration registration;
  registration.setInputSource(source_);
  registration.setInputTarget(target_);
  const auto result = registration.align();
  ASSERT_TRUE(result.success) << result.message;
  EXPECT_FALSE(result.refined);
  EXPECT_EQ(result.num_correspondences, 300);
  EXPECT_EQ(result.num_inliers, 180);
  EXPECT_LT(translationError(result.T_target_source, T_target_source_), 0.02);
  EXPECT_LT(rotationErrorDeg(result.T_target_source, T_target_source_), 0.1);
  EXPECT_EQ(registration.getInliers().size(), 180u);
  for (const auto& c : registration.getInliers())
    EXPECT_GE(c.index_query, 120); // the first 120 source features are misplaced
}

TEST_F(Registration, InverseDirection)
{
  CorrespondenceRigidRegistration registration;
  registration.setInputSource(target_);
  registration.setInputTarget(source_);
  const auto result = registration.align();
  ASSERT_TRUE(result.success) << result.message;
  EXPECT_LT(translationError(result.T_target_source, T_target_source_.inverse()), 0.02);
}

TEST_F(Registration, DenseRefinementImprovesTheFeatureEstimate)
{
  const Cloud::Ptr target_cloud = denseScene(10, Eigen::Isometry3d::Identity());
  const Cloud::Ptr source_cloud = denseScene(11, T_target_source_.inverse());
  RegistrationParams params;
  params.ransac.inlier_threshold_m = 1.0;
  CorrespondenceRigidRegistration registration(params);
  registration.setInputSource(source_, source_cloud);
  registration.setInputTarget(target_, target_cloud);
  const auto result = registration.align();
  ASSERT_TRUE(result.success) << result.message;
  EXPECT_TRUE(result.refined);
  EXPECT_GT(result.refinement_iterations, 0);
  EXPECT_LT(translationError(result.T_target_source, T_target_source_), 0.005);
  EXPECT_LT(rotationErrorDeg(result.T_target_source, T_target_source_), 0.02);

  // The prepared target is reusable for a second source.
  ASSERT_TRUE(registration.getPreparedTarget());
  CorrespondenceRigidRegistration second(params);
  second.setInputTarget(target_, registration.getPreparedTarget());
  second.setInputSource(source_, source_cloud);
  const auto again = second.align();
  ASSERT_TRUE(again.refined) << again.message;
  EXPECT_TRUE(again.T_target_source.isApprox(result.T_target_source, 1e-9));
}

TEST_F(Registration, RefinementDivergenceIsAFailure)
{
  // The dense source scan is 50 m away from where the features put it.
  const Cloud::Ptr target_cloud = denseScene(10, Eigen::Isometry3d::Identity());
  const Cloud::Ptr source_cloud =
      denseScene(11, makeTransform(0.0, Eigen::Vector3d(0, 0, 50)) * T_target_source_.inverse());
  CorrespondenceRigidRegistration registration;
  registration.setInputSource(source_, source_cloud);
  registration.setInputTarget(target_, target_cloud);
  const auto result = registration.align();
  EXPECT_FALSE(result.success);
  EXPECT_FALSE(result.refined);
  EXPECT_GT(result.num_inliers, 0);
  EXPECT_NE(result.message.find("refinement"), std::string::npos) << result.message;
}

TEST(RegistrationFailure, TooFewCorrespondences)
{
  auto source = std::make_shared<RasterFeatureSet>();
  auto target = std::make_shared<RasterFeatureSet>();
  makeFeatures(8, 0.0, Eigen::Isometry3d::Identity(), 4, *source, *target);
  CorrespondenceRigidRegistration registration;
  registration.setInputSource(source);
  registration.setInputTarget(target);
  const auto result = registration.align();
  EXPECT_FALSE(result.success);
  EXPECT_EQ(result.num_correspondences, 8);
  EXPECT_NE(result.message.find("too few correspondences"), std::string::npos)
      << result.message;
}

TEST(RegistrationFailure, CollinearFeaturesAreDegenerate)
{
  auto source = std::make_shared<RasterFeatureSet>();
  auto target = std::make_shared<RasterFeatureSet>();
  makeFeatures(60, 0.0, makeTransform(10, Eigen::Vector3d(1, 0, 0)), 5, *source, *target, true);
  RegistrationParams params;
  params.ransac.max_iterations = 300;
  CorrespondenceRigidRegistration registration(params);
  registration.setInputSource(source);
  registration.setInputTarget(target);
  const auto result = registration.align();
  EXPECT_FALSE(result.success);
  EXPECT_NE(result.message.find("RANSAC failed"), std::string::npos) << result.message;
}

TEST(RegistrationFailure, InvalidParamsAndMissingInputThrow)
{
  RegistrationParams params;
  params.refinement.max_iterations = 0;
  std::string why;
  EXPECT_FALSE(params.isValid(&why));
  EXPECT_NE(why.find("refinement.max_iterations"), std::string::npos) << why;
  EXPECT_THROW(CorrespondenceRigidRegistration{params}, std::invalid_argument);
  params = RegistrationParams();
  params.min_correspondences = 2;
  EXPECT_FALSE(params.isValid());

  CorrespondenceRigidRegistration registration;
  EXPECT_THROW(registration.align(), std::invalid_argument);
  registration.setInputSource(std::make_shared<RasterFeatureSet>());
  EXPECT_THROW(registration.align(), std::invalid_argument);
}

} // namespace

} // namespace test_correspondence_rigid_registration
