/// \file test_orb_signature.cpp
/// \brief The ORB estimator as a pcl::Keypoint on every instantiated point type, and
/// its ORBSignature256 feature clouds through PCD files.

#include "xyz_point_types.h"

#include <cstdio>
#include <gtest/gtest.h>
#include <pcl/features/orb_raster_features.h>
#include <pcl/features/range_raster_image.h>
#include <pcl/io/pcd_io.h>
#include <pcl/rast/point_types.h>
#include <random>
#include <set>
#include <string>

// This file's names stay its own: a test program compiles several test files as
// one translation unit (test/CMakeLists.txt).
namespace test_orb_signature {

namespace {

/// Blocks of random footprint and height around the sensor, points every 5 cm on
/// their sloped roofs: corners for FAST at every block.
template <typename PointT>
typename pcl::PointCloud<PointT>::Ptr
makeBlocks(unsigned seed)
{
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> position(-35.0f, 35.0f), size(0.6f, 3.0f),
      height(0.3f, 4.0f);
  auto cloud = std::make_shared<pcl::PointCloud<PointT>>();
  for (int block = 0; block < 80; ++block) {
    const float cx = position(rng), cy = position(rng);
    const float sx = size(rng), sy = size(rng), top = -1.7f + height(rng);
    for (float dx = 0.0f; dx <= sx; dx += 0.05f)
      for (float dy = 0.0f; dy <= sy; dy += 0.05f) {
        PointT p;
        p.x = cx + dx;
        p.y = cy + dy;
        p.z = top + 0.1f * dy;
        cloud->push_back(p);
      }
  }
  return cloud;
}

} // namespace

template <typename PointT> class OrbKeypointTypes : public ::testing::Test
{
};

TYPED_TEST_SUITE(OrbKeypointTypes, pcl_rast_test::XyzPointTypes);

TYPED_TEST(OrbKeypointTypes, ComputesThroughThePclKeypointBase)
{
  const auto cloud = makeBlocks<TypeParam>(31);
  auto orb = std::make_shared<pcl::rast::OrbRasterFeatureEstimator<TypeParam>>();
  typename pcl::Keypoint<TypeParam, pcl::rast::ORBSignature256>::Ptr keypoints = orb;
  keypoints->setInputCloud(cloud);
  pcl::PointCloud<pcl::rast::ORBSignature256> features;
  keypoints->compute(features);
  ASSERT_GT(features.size(), 100u) << orb->getResult().message;
  EXPECT_TRUE(orb->getResult().success);

  // Every feature is the input point named by getKeypointsIndices().
  const auto indices = keypoints->getKeypointsIndices();
  ASSERT_EQ(indices->indices.size(), features.size());
  for (std::size_t k = 0; k < features.size(); ++k) {
    const auto& input = (*cloud)[indices->indices[k]];
    EXPECT_EQ(features[k].x, input.x);
    EXPECT_EQ(features[k].y, input.y);
    EXPECT_EQ(features[k].z, input.z);
  }

  // The SLAM's interface gives the same features.
  pcl::rast::RasterFeatureSet set;
  orb->compute(set);
  pcl::PointCloud<pcl::rast::ORBSignature256> converted;
  pcl::rast::toSignatureCloud(set, converted);
  ASSERT_EQ(converted.size(), features.size());
  for (std::size_t k = 0; k < features.size(); ++k) {
    EXPECT_EQ(converted[k].u, features[k].u);
    EXPECT_TRUE(std::equal(
        features[k].descriptor, features[k].descriptor + 32, converted[k].descriptor));
  }
}

TYPED_TEST(OrbKeypointTypes, IndicesRestrictTheRasterizedPoints)
{
  const auto cloud = makeBlocks<TypeParam>(32);
  auto left = std::make_shared<pcl::Indices>();
  for (std::size_t i = 0; i < cloud->size(); ++i)
    if ((*cloud)[i].y > 0.0f)
      left->push_back(static_cast<pcl::index_t>(i));
  pcl::rast::OrbRasterFeatureEstimator<TypeParam> orb;
  orb.setInputCloud(cloud);
  orb.setIndices(left);
  pcl::PointCloud<pcl::rast::ORBSignature256> features;
  orb.compute(features);
  ASSERT_GT(features.size(), 30u) << orb.getResult().message;
  const std::set<pcl::index_t> allowed(left->begin(), left->end());
  for (const auto index : orb.getKeypointsIndices()->indices)
    EXPECT_EQ(allowed.count(index), 1u)
        << "feature from point " << index << " outside the given indices";
}

TEST(OrbSignature256, FeatureCloudSavesToPcdAndBack)
{
  const auto cloud = makeBlocks<pcl::PointXYZ>(33);
  pcl::rast::OrbRasterFeatureEstimator<pcl::PointXYZ> orb;
  orb.setInputCloud(cloud);
  pcl::PointCloud<pcl::rast::ORBSignature256> features;
  orb.compute(features);
  ASSERT_GT(features.size(), 100u);

  for (const bool binary : {true, false}) {
    const std::string path = std::string(::testing::TempDir()) + "orb_signature_" +
                             (binary ? "binary" : "ascii") + ".pcd";
    ASSERT_EQ(pcl::io::savePCDFile(path, features, binary), 0);
    pcl::PointCloud<pcl::rast::ORBSignature256> loaded;
    ASSERT_EQ(pcl::io::loadPCDFile(path, loaded), 0);
    std::remove(path.c_str());
    ASSERT_EQ(loaded.size(), features.size());
    for (std::size_t k = 0; k < features.size(); ++k) {
      EXPECT_EQ(loaded[k].x, features[k].x);
      EXPECT_EQ(loaded[k].v, features[k].v);
      EXPECT_EQ(loaded[k].octave, features[k].octave);
      EXPECT_TRUE(std::equal(
          features[k].descriptor, features[k].descriptor + 32, loaded[k].descriptor))
          << "descriptor " << k << " changed through " << (binary ? "binary" : "ASCII")
          << " PCD";
    }
  }
}

TEST(OrbSignature256, ConvertsToAndFromTheFeatureSet)
{
  pcl::rast::RasterFeatureSet set;
  set.points.resize(2);
  set.descriptors.resize(2);
  set.points[1].x = 3.0f;
  set.points[1].u = 7.5f;
  set.descriptors[1].fill(0xA5);
  pcl::PointCloud<pcl::rast::ORBSignature256> cloud;
  pcl::rast::toSignatureCloud(set, cloud);
  pcl::rast::RasterFeatureSet back;
  pcl::rast::fromSignatureCloud(cloud, back);
  ASSERT_EQ(back.size(), 2u);
  EXPECT_EQ(back.points[1].x, 3.0f);
  EXPECT_EQ(back.points[1].u, 7.5f);
  EXPECT_EQ(back.descriptors[1], set.descriptors[1]);

  set.descriptors.pop_back();
  EXPECT_THROW(pcl::rast::toSignatureCloud(set, cloud), std::invalid_argument);
}

TEST(RangeRasterImage, IndicesOutsideTheCloudThrow)
{
  const auto cloud = makeBlocks<pcl::PointXYZ>(34);
  pcl::rast::RangeRasterImage<pcl::PointXYZ> raster;
  raster.setInputCloud(cloud);
  raster.setIndices(std::make_shared<pcl::Indices>(pcl::Indices{0, 5, -3}));
  try {
    raster.compute();
    FAIL() << "no exception";
  } catch (const std::out_of_range& e) {
    EXPECT_NE(std::string(e.what()).find("-3"), std::string::npos) << e.what();
  }
}

} // namespace test_orb_signature
