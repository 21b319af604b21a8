/// \file test_raster_orb_registration.cpp
/// \brief RasterORBRegistration on every point type on a real pair, its output cloud,
/// failures reported through hasConverged(), parameter validation.

#include "test_data.h"
#include "xyz_point_types.h"

#include <Eigen/Geometry>
#include <cmath>
#include <fstream>
#include <gtest/gtest.h>
#include <pcl/io/pcd_io.h>
#include <pcl/rast/point_types.h>
#include <pcl/registration/raster_orb_registration.h>

// This file's names stay its own: a test program compiles several test files as
// one translation unit (test/CMakeLists.txt).
namespace test_raster_orb_registration {

namespace {

using pcl_rast_test::readMatrix4;

double
translationError(const Eigen::Matrix4f& T, const Eigen::Matrix4f& reference)
{
  return (reference.inverse() * T).topRightCorner<3, 1>().norm();
}

double
rotationErrorDeg(const Eigen::Matrix4f& T, const Eigen::Matrix4f& reference)
{
  const Eigen::Matrix3f R = (reference.inverse() * T).topLeftCorner<3, 3>();
  return Eigen::AngleAxisf(R).angle() * 180.0 / M_PI;
}

/// fast_gicp's real pair: target 251370668.pcd, source 251371071.pcd, relative.txt is
/// T_target_source (0.49 m apart).
template <typename PointT> struct ScanPair
{
  typename pcl::PointCloud<PointT>::Ptr source{new pcl::PointCloud<PointT>};
  typename pcl::PointCloud<PointT>::Ptr target{new pcl::PointCloud<PointT>};
  Eigen::Matrix4f T_target_source;
};

template <typename PointT>
bool
loadScanPair(const std::filesystem::path& data, ScanPair<PointT>& pair)
{
  const auto dir = data / "scan-pair-pcd";
  if (pcl::io::loadPCDFile((dir / "251371071.pcd").string(), *pair.source) != 0 ||
      pcl::io::loadPCDFile((dir / "251370668.pcd").string(), *pair.target) != 0)
    return false;
  pair.T_target_source = readMatrix4(dir / "relative.txt").matrix().cast<float>();
  return true;
}

/// The source turned by \a yaw_deg about its z axis: the pair then differs by a turn
/// of that size on top of the real motion.
template <typename PointT>
void
turnSource(ScanPair<PointT>& pair, float yaw_deg)
{
  Eigen::Matrix4f R = Eigen::Matrix4f::Identity();
  R.topLeftCorner<3, 3>() =
      Eigen::AngleAxisf(yaw_deg * float(M_PI) / 180.0f, Eigen::Vector3f::UnitZ())
          .matrix();
  pcl::transformPointCloud(*pair.source, *pair.source, R);
  pair.T_target_source = pair.T_target_source * R.inverse();
}

} // namespace

// Through a pcl::Registration pointer in place of GICP, and the 30-degree turn GICP
// does not recover: doc/pcl_pipelines.md (compiled and run as doc_pcl_pipelines).

template <typename PointT> class RasterORBRegistrationTypes : public ::testing::Test
{
};

TYPED_TEST_SUITE(RasterORBRegistrationTypes, pcl_rast_test::XyzPointTypes);

TYPED_TEST(RasterORBRegistrationTypes, AlignsTheRealPairOnEveryPointType)
{
  PCL_RAST_REQUIRE_SHARED_DATA(data);
  ScanPair<TypeParam> pair;
  ASSERT_TRUE(loadScanPair(data, pair));
  turnSource(pair, -20.0f);
  pcl::rast::RasterORBRegistration<TypeParam, TypeParam> reg;
  reg.setInputSource(pair.source);
  reg.setInputTarget(pair.target);
  pcl::PointCloud<TypeParam> aligned;
  reg.align(aligned);
  ASSERT_TRUE(reg.hasConverged()) << reg.getResult().message;
  EXPECT_LT(translationError(reg.getFinalTransformation(), pair.T_target_source), 0.05);
  EXPECT_LT(rotationErrorDeg(reg.getFinalTransformation(), pair.T_target_source), 0.45);
  // The output is the source moved by the final transformation.
  ASSERT_EQ(aligned.size(), pair.source->size());
  const Eigen::Vector3f expected =
      (reg.getFinalTransformation() * (*pair.source)[100].getVector4fMap())
          .template head<3>();
  EXPECT_LT((aligned[100].getVector3fMap() - expected).norm(), 1e-4f);
}

TEST(RasterORBRegistration, FailureIsReportedNotHidden)
{
  // A featureless target (a flat floor) cannot be matched: no convergence, a message,
  // and the guess is not passed off as a result.
  auto floor = std::make_shared<pcl::PointCloud<pcl::PointXYZ>>();
  for (int i = 0; i < 200; ++i)
    for (int j = 0; j < 200; ++j)
      floor->push_back(pcl::PointXYZ(0.1f * i - 10.0f, 0.1f * j - 10.0f, -1.7f));
  pcl::rast::RasterORBRegistration<pcl::PointXYZ, pcl::PointXYZ> reg;
  reg.setInputSource(floor);
  reg.setInputTarget(floor);
  pcl::PointCloud<pcl::PointXYZ> aligned;
  reg.align(aligned);
  EXPECT_FALSE(reg.hasConverged());
  EXPECT_FALSE(reg.getResult().message.empty());
  EXPECT_NE(reg.getResult().message.find("correspondences"), std::string::npos)
      << reg.getResult().message;
}

TEST(RasterORBRegistration, NullOrEmptyCloudsThrowInsteadOfKeepingTheOldOnes)
{
  pcl::rast::RasterORBRegistration<pcl::PointXYZ, pcl::PointXYZ> reg;
  const auto empty = std::make_shared<pcl::PointCloud<pcl::PointXYZ>>();
  EXPECT_THROW(reg.setInputSource(empty), std::invalid_argument);
  EXPECT_THROW(reg.setInputTarget(empty), std::invalid_argument);
  EXPECT_THROW(reg.setInputSource(nullptr), std::invalid_argument);
  try {
    reg.setInputTarget(nullptr);
    FAIL() << "no exception";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("target cloud is null"), std::string::npos)
        << e.what();
  }
}

TEST(RasterORBRegistrationRealData, AKeptTargetGivesWhatAFreshOneGives)
{
  // The target's features and dense target are prepared once and reused for the next
  // source; the result must equal that of a registration that never saw another source.
  PCL_RAST_REQUIRE_SHARED_DATA(data);
  const auto dir = data / "kitti-raw-22" / "pcd";
  auto target = std::make_shared<pcl::PointCloud<pcl::PointXYZ>>();
  auto first = std::make_shared<pcl::PointCloud<pcl::PointXYZ>>();
  auto second = std::make_shared<pcl::PointCloud<pcl::PointXYZ>>();
  ASSERT_EQ(pcl::io::loadPCDFile((dir / "0000000000.pcd").string(), *target), 0);
  ASSERT_EQ(pcl::io::loadPCDFile((dir / "0000000001.pcd").string(), *first), 0);
  ASSERT_EQ(pcl::io::loadPCDFile((dir / "0000000002.pcd").string(), *second), 0);
  pcl::PointCloud<pcl::PointXYZ> aligned;
  pcl::rast::RasterORBRegistration<pcl::PointXYZ, pcl::PointXYZ> kept, fresh;
  kept.setInputTarget(target);
  kept.setInputSource(first);
  kept.align(aligned);
  kept.setInputSource(second);
  kept.align(aligned);
  fresh.setInputTarget(target);
  fresh.setInputSource(second);
  fresh.align(aligned);
  ASSERT_TRUE(kept.hasConverged()) << kept.getResult().message;
  EXPECT_EQ(kept.getFinalTransformation(), fresh.getFinalTransformation());
  EXPECT_EQ(kept.getTargetFeatures().size(), fresh.getTargetFeatures().size());
}

TEST(RasterORBRegistration, InvalidParametersThrowNamingTheValue)
{
  pcl::rast::RasterORBRegistrationParams params;
  params.orb.max_features = 0;
  try {
    pcl::rast::RasterORBRegistration<pcl::PointXYZ, pcl::PointXYZ> reg(params);
    FAIL() << "no exception";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("orb.max_features"), std::string::npos)
        << e.what();
  }
  params = {};
  params.registration.min_correspondences = 1;
  std::string why;
  EXPECT_FALSE(params.isValid(&why));
  EXPECT_NE(why.find("registration.min_correspondences"), std::string::npos) << why;
}

} // namespace test_raster_orb_registration
