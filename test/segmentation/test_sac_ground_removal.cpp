/// \file test_sac_ground_removal.cpp
/// \brief SACGroundRemoval on synthetic plane + boxes scenes and on a real KITTI scan.

#include <pcl/rast/point_types.h>
#include <pcl/segmentation/sac_ground_removal.h>
#include <pcl/io/sequence_reader.h>

#include <gtest/gtest.h>

#include "test_data.h"
#include "xyz_point_types.h"

#include <chrono>
#include <cmath>
#include <limits>
#include <random>
#include <set>
#include <stdexcept>

// This file's names stay its own: a test program compiles several test files as
// one translation unit (test/CMakeLists.txt).
namespace test_sac_ground_removal {

using pcl::rast::SACGroundRemovalParams;
using Cloud = pcl::PointCloud<pcl::PointXYZI>;
using GroundRemovalResult = pcl::rast::GroundRemovalResult<pcl::PointXYZI>;
using SACGroundRemoval = pcl::rast::SACGroundRemoval<pcl::PointXYZI>;

namespace {

constexpr float kSensorHeight = 1.73f;

pcl::PointXYZI
makePoint(float x, float y, float z)
{
  pcl::PointXYZI p;
  p.x = x;
  p.y = y;
  p.z = z;
  p.intensity = 0.5f;
  return p;
}

/// A flat road 1.73 m below the sensor (first \a num_ground points, 2 cm noise)
/// followed by the surfaces of a few boxes standing on it, starting 0.3 m above it.
Cloud::Ptr
makePlaneAndBoxes(std::size_t num_ground, std::size_t num_per_box, unsigned seed)
{
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> xy(-30.0f, 30.0f);
  std::normal_distribution<float> noise(0.0f, 0.02f);
  auto cloud = std::make_shared<Cloud>();
  for (std::size_t i = 0; i < num_ground; ++i)
    cloud->push_back(makePoint(xy(rng), xy(rng), -kSensorHeight + noise(rng)));
  // Boxes: centre x, y, half sizes, height above ground.
  const float boxes[][5] = {{8, 3, 2, 1, 1.5f}, {-6, -8, 1, 1, 2.5f}, {15, -10, 3, 1.5f, 1.8f},
                            {-12, 12, 0.5f, 0.5f, 4.0f}};
  std::uniform_real_distribution<float> unit(0.0f, 1.0f);
  for (const auto& b : boxes) {
    for (std::size_t i = 0; i < num_per_box; ++i) {
      // A random point on one of the four walls or the top.
      const int face = static_cast<int>(unit(rng) * 5) % 5;
      float x = b[0] + (2 * unit(rng) - 1) * b[2];
      float y = b[1] + (2 * unit(rng) - 1) * b[3];
      float z = -kSensorHeight + 0.3f + unit(rng) * (b[4] - 0.3f);
      if (face == 0)
        x = b[0] - b[2];
      else if (face == 1)
        x = b[0] + b[2];
      else if (face == 2)
        y = b[1] - b[3];
      else if (face == 3)
        y = b[1] + b[3];
      else
        z = -kSensorHeight + b[4];
      cloud->push_back(makePoint(x, y, z));
    }
  }
  return cloud;
}

Cloud::Ptr
transformed(const Cloud& cloud, const Eigen::Matrix3f& R)
{
  auto out = std::make_shared<Cloud>(cloud);
  for (auto& p : *out)
    p.getVector3fMap() = R * p.getVector3fMap();
  return out;
}

GroundRemovalResult
segment(const Cloud::ConstPtr& cloud, const SACGroundRemovalParams& params = {})
{
  SACGroundRemoval ground(params);
  ground.setInputCloud(cloud);
  GroundRemovalResult result;
  ground.segment(result);
  return result;
}

} // namespace

TEST(SACGroundRemoval, FindsGroundAndExactInliers)
{
  const std::size_t num_ground = 20000;
  const auto cloud = makePlaneAndBoxes(num_ground, 2000, 1);
  const auto result = segment(cloud);
  ASSERT_TRUE(result.success) << result.message;
  ASSERT_TRUE(result.ground_found) << result.message;
  EXPECT_GT(result.plane_coefficients.z(), 0.9999f); // normal up
  EXPECT_NEAR(result.plane_coefficients[3], kSensorHeight, 0.01f);
  // Exactly the road points are ground; all box points are kept.
  ASSERT_EQ(result.ground_indices.size(), num_ground);
  for (std::size_t k = 0; k < num_ground; ++k)
    EXPECT_EQ(result.ground_indices[k], static_cast<pcl::index_t>(k));
  EXPECT_EQ(result.non_ground->size(), cloud->size() - num_ground);
  EXPECT_EQ(result.non_ground_indices.size(), result.non_ground->size());
  EXPECT_TRUE(result.T_level_lidar.matrix().isIdentity());
  for (std::size_t k = 0; k < result.non_ground->size(); ++k)
    EXPECT_EQ((*result.non_ground)[k].x, (*cloud)[result.non_ground_indices[k]].x);
}

TEST(SACGroundRemoval, IsDeterministic)
{
  const auto cloud = makePlaneAndBoxes(20000, 2000, 2);
  const auto a = segment(cloud), b = segment(cloud);
  EXPECT_EQ(a.plane_coefficients, b.plane_coefficients);
  EXPECT_EQ(a.ground_indices, b.ground_indices);
}

TEST(SACGroundRemoval, LevelsTiltedCloud)
{
  const auto flat = makePlaneAndBoxes(20000, 2000, 3);
  const Eigen::Matrix3f R_tilt =
      Eigen::AngleAxisf(10.0f * float(M_PI) / 180.0f, Eigen::Vector3f::UnitX()).toRotationMatrix();
  const auto tilted = transformed(*flat, R_tilt);

  SACGroundRemovalParams params;
  params.level_cloud = true;
  const auto result = segment(tilted, params);
  ASSERT_TRUE(result.ground_found) << result.message;
  // The plane normal in the (tilted) LiDAR frame is the tilted z axis.
  EXPECT_GT(result.plane_coefficients.head<3>().dot(R_tilt * Eigen::Vector3f::UnitZ()), 0.9999f);
  // Levelling undoes the tilt: the levelled box points are the original ones.
  ASSERT_EQ(result.non_ground->size(), flat->size() - 20000);
  float max_error = 0.0f;
  for (std::size_t k = 0; k < result.non_ground->size(); ++k) {
    const auto& original = (*flat)[result.non_ground_indices[k]];
    max_error = std::max(max_error, ((*result.non_ground)[k].getVector3fMap() -
                                     original.getVector3fMap())
                                        .norm());
  }
  EXPECT_LT(max_error, 0.03f);
  const Eigen::Matrix3f R_expected = R_tilt.transpose();
  EXPECT_TRUE(result.T_level_lidar.linear().isApprox(R_expected, 1e-3f));
}

TEST(SACGroundRemoval, StrongTiltNeedsUpAxisPrior)
{
  const auto flat = makePlaneAndBoxes(20000, 2000, 4);
  const Eigen::Matrix3f R_tilt =
      Eigen::AngleAxisf(35.0f * float(M_PI) / 180.0f, Eigen::Vector3f::UnitY()).toRotationMatrix();
  const auto tilted = transformed(*flat, R_tilt);
  // The default up axis (+z) allows 15 deg of tilt: a 35 deg road is not ground...
  SACGroundRemovalParams params;
  params.sample_max_height_m = 100.0; // sample everywhere: the prior below decides
  EXPECT_FALSE(segment(tilted, params).ground_found);
  // ...unless the expected up axis says so.
  params.up_axis = R_tilt * Eigen::Vector3f::UnitZ();
  const auto result = segment(tilted, params);
  ASSERT_TRUE(result.ground_found) << result.message;
  EXPECT_EQ(result.ground_indices.size(), 20000u);
}

TEST(SACGroundRemoval, ReportsSceneWithoutGround)
{
  // Boxes only, no road: the box tops are too small, the walls too steep.
  auto boxes = makePlaneAndBoxes(0, 3000, 5);
  const auto result = segment(boxes);
  EXPECT_TRUE(result.success);
  EXPECT_FALSE(result.ground_found);
  EXPECT_FALSE(result.message.empty());
  EXPECT_TRUE(result.ground_indices.empty());
  EXPECT_EQ(result.non_ground->size(), boxes->size());
  EXPECT_EQ(result.plane_coefficients, Eigen::Vector4f::Zero());

  // A ceiling 2 m above the sensor is not ground either.
  auto ceiling = std::make_shared<Cloud>();
  std::mt19937 rng(6);
  std::uniform_real_distribution<float> xy(-10.0f, 10.0f);
  for (int i = 0; i < 5000; ++i)
    ceiling->push_back(makePoint(xy(rng), xy(rng), 2.0f));
  SACGroundRemovalParams params;
  const auto r2 = segment(ceiling, params);
  EXPECT_FALSE(r2.ground_found);
  EXPECT_EQ(r2.non_ground->size(), ceiling->size());
}

TEST(SACGroundRemoval, EmptyAndNullInput)
{
  const auto result = segment(std::make_shared<Cloud>());
  EXPECT_FALSE(result.success);
  EXPECT_FALSE(result.ground_found);
  EXPECT_FALSE(result.message.empty());
  ASSERT_TRUE(result.non_ground);
  EXPECT_TRUE(result.non_ground->empty());

  SACGroundRemoval ground;
  EXPECT_THROW(ground.setInputCloud(nullptr), std::invalid_argument);
  GroundRemovalResult r;
  EXPECT_THROW(ground.segment(r), std::invalid_argument);
}

TEST(SACGroundRemoval, SkipsNonFinitePoints)
{
  const std::size_t num_ground = 20000;
  auto cloud = makePlaneAndBoxes(num_ground, 2000, 7);
  const float nan = std::numeric_limits<float>::quiet_NaN();
  const std::size_t num_finite = cloud->size();
  for (int i = 0; i < 500; ++i)
    cloud->push_back(makePoint(nan, 1.0f, i % 2 ? nan : -kSensorHeight));
  cloud->push_back(makePoint(std::numeric_limits<float>::infinity(), 0.0f, -kSensorHeight));
  cloud->is_dense = false;
  const auto result = segment(cloud);
  ASSERT_TRUE(result.ground_found) << result.message;
  EXPECT_EQ(result.num_non_finite, 501u);
  EXPECT_EQ(result.ground_indices.size(), num_ground);
  EXPECT_EQ(result.ground_indices.size() + result.non_ground->size(), num_finite);
  for (const auto& p : *result.non_ground)
    EXPECT_TRUE(std::isfinite(p.x) && std::isfinite(p.y) && std::isfinite(p.z));

  // Only non-finite points: processed, nothing found, no crash.
  auto all_nan = std::make_shared<Cloud>();
  all_nan->push_back(makePoint(nan, nan, nan));
  const auto r2 = segment(all_nan);
  EXPECT_FALSE(r2.success);
  EXPECT_EQ(r2.num_non_finite, 1u);
}

TEST(SACGroundRemoval, ValidatesParams)
{
  SACGroundRemovalParams params;
  std::string why;
  EXPECT_TRUE(params.isValid(&why));
  params.distance_threshold_m = 0.0;
  EXPECT_FALSE(params.isValid(&why));
  EXPECT_NE(why.find("distance_threshold_m"), std::string::npos);
  EXPECT_THROW(SACGroundRemoval{params}, std::invalid_argument);
  params = {};
  params.max_tilt_deg = 90.0;
  EXPECT_FALSE(params.isValid());
  params = {};
  params.up_axis = Eigen::Vector3f::Zero();
  EXPECT_FALSE(params.isValid());
  params = {};
  params.max_iterations = 0;
  EXPECT_FALSE(params.isValid());
  params = {};
  params.min_inlier_ratio = 1.5;
  EXPECT_FALSE(params.isValid());
}

TEST(SACGroundRemoval, RealKittiScan)
{
  PCL_RAST_REQUIRE_SHARED_DATA(data);
  const auto cloud = pcl::rast::readScan((data / "kitti-raw-22/pcd/0000000000.pcd").string());
  ASSERT_GT(cloud->size(), 100000u);
  SACGroundRemoval ground;
  ground.setInputCloud(cloud);
  GroundRemovalResult result;
  double best_ms = 1e9; // timing is informative only (the machine may be loaded)
  for (int i = 0; i < 20; ++i) {
    const auto start = std::chrono::steady_clock::now();
    ground.segment(result);
    best_ms = std::min(best_ms, std::chrono::duration<double, std::milli>(
                                    std::chrono::steady_clock::now() - start)
                                    .count());
  }
  std::cout << "[          ] " << cloud->size() << " points, best " << best_ms << " ms: "
            << result.message << std::endl;
  ASSERT_TRUE(result.ground_found) << result.message;
  EXPECT_GT(result.plane_coefficients.z(), std::cos(3.0 * M_PI / 180.0));
  EXPECT_NEAR(result.plane_coefficients[3], 1.73, 0.25); // KITTI: sensor 1.73 m above road
  EXPECT_GT(result.ground_indices.size(), cloud->size() / 5);
  EXPECT_LT(result.ground_indices.size(), cloud->size() * 4 / 5);
}

// ---- As a pcl::FilterIndices<PointT> -------------------------------------------------

namespace {

/// makePlaneAndBoxes as another point type (x, y, z copied; other fields zero).
template <typename PointT>
typename pcl::PointCloud<PointT>::Ptr
planeAndBoxesAs(std::size_t num_ground, std::size_t num_per_box, unsigned seed)
{
  const auto xyzi = makePlaneAndBoxes(num_ground, num_per_box, seed);
  auto cloud = std::make_shared<pcl::PointCloud<PointT>>();
  for (const auto& q : *xyzi) {
    PointT p{};
    p.x = q.x;
    p.y = q.y;
    p.z = q.z;
    cloud->push_back(p);
  }
  return cloud;
}

} // namespace

// Outside the anonymous namespace: the typed tests derive from it, and a class in a
// named namespace must not have a base of internal linkage (-Wsubobject-linkage, once
// this file is compiled in a unity batch).
template <typename PointT>
class GroundFilter : public ::testing::Test
{};
TYPED_TEST_SUITE(GroundFilter, pcl_rast_test::XyzPointTypes);

TYPED_TEST(GroundFilter, KeepsObjectsRemovesGroundThroughBasePointer)
{
  using PointT = TypeParam;
  const std::size_t num_ground = 20000, num_boxes = 4 * 2000;
  const auto cloud = planeAndBoxesAs<PointT>(num_ground, 2000, 1);
  const typename pcl::FilterIndices<PointT>::Ptr filter(
      new pcl::rast::SACGroundRemoval<PointT>(true));
  filter->setInputCloud(cloud);

  pcl::PointCloud<PointT> objects;
  filter->filter(objects);
  ASSERT_EQ(objects.size(), num_boxes);
  for (const auto& p : objects)
    EXPECT_GT(p.z, -kSensorHeight + 0.25f); // no road point among them
  const auto& removed = *filter->getRemovedIndices();
  ASSERT_EQ(removed.size(), num_ground);
  for (std::size_t k = 0; k < num_ground; ++k)
    EXPECT_EQ(removed[k], static_cast<pcl::index_t>(k));

  const auto* ground = dynamic_cast<pcl::rast::SACGroundRemoval<PointT>*>(filter.get());
  ASSERT_NE(ground, nullptr);
  EXPECT_TRUE(ground->groundFound()) << ground->getMessage();
  EXPECT_NEAR(ground->getGroundPlane()[3], kSensorHeight, 0.01f);
  EXPECT_GT(ground->getGroundPlane()[2], 0.9999f);

  // Negative: the ground instead, by index.
  filter->setNegative(true);
  pcl::Indices road;
  filter->filter(road);
  ASSERT_EQ(road.size(), num_ground);
  EXPECT_EQ(road.back(), static_cast<pcl::index_t>(num_ground - 1));
  EXPECT_EQ(filter->getRemovedIndices()->size(), num_boxes);
}

TYPED_TEST(GroundFilter, KeepsOrganizedAndHonoursIndices)
{
  using PointT = TypeParam;
  const std::size_t num_ground = 20000;
  auto cloud = planeAndBoxesAs<PointT>(num_ground, 2000, 3);
  // An organized layout: the points as 4 rows.
  cloud->height = 4;
  cloud->width = static_cast<std::uint32_t>(cloud->size() / 4);
  ASSERT_EQ(cloud->width * cloud->height, cloud->size());

  pcl::rast::SACGroundRemoval<PointT> filter(true);
  filter.setInputCloud(cloud);
  filter.setKeepOrganized(true);
  pcl::PointCloud<PointT> out;
  filter.filter(out);
  ASSERT_EQ(out.width, cloud->width);
  ASSERT_EQ(out.height, cloud->height);
  EXPECT_FALSE(out.is_dense);
  std::size_t nan = 0;
  for (std::size_t i = 0; i < out.size(); ++i) {
    if (!std::isfinite(out[i].x))
      ++nan;
    else
      EXPECT_EQ(out[i].x, (*cloud)[i].x); // kept points stay where they were
  }
  EXPECT_EQ(nan, num_ground);

  // Only the first half of the road and every box point: the fit and the output
  // stay inside the subset.
  auto subset = std::make_shared<pcl::Indices>();
  for (std::size_t i = 0; i < cloud->size(); ++i)
    if (i >= num_ground || i % 2 == 0)
      subset->push_back(static_cast<pcl::index_t>(i));
  pcl::rast::SACGroundRemoval<PointT> part(true);
  part.setInputCloud(cloud);
  part.setIndices(subset);
  pcl::Indices kept;
  part.filter(kept);
  EXPECT_EQ(kept.size(), cloud->size() - num_ground);
  EXPECT_EQ(part.getRemovedIndices()->size(), num_ground / 2);
  for (const auto i : *part.getRemovedIndices())
    EXPECT_EQ(i % 2, 0);

  // An index outside the cloud is an error naming it, not a read out of bounds.
  subset->push_back(static_cast<pcl::index_t>(cloud->size()));
  part.setIndices(subset);
  try {
    part.filter(kept);
    ADD_FAILURE() << "an index outside the cloud was accepted";
  }
  catch (const std::out_of_range& e) {
    EXPECT_NE(std::string(e.what()).find(std::to_string(cloud->size())), std::string::npos)
        << e.what();
  }
}

TEST(GroundFilter, NoGroundKeepsEverythingAndSaysSo)
{
  // Boxes only: no plane has the support.
  auto cloud = planeAndBoxesAs<pcl::PointXYZ>(0, 3000, 5);
  pcl::rast::SACGroundRemoval<pcl::PointXYZ> filter(true);
  filter.setInputCloud(cloud);
  pcl::PointCloud<pcl::PointXYZ> out;
  filter.filter(out);
  EXPECT_FALSE(filter.groundFound());
  EXPECT_NE(filter.getMessage().find("no ground"), std::string::npos) << filter.getMessage();
  EXPECT_EQ(out.size(), cloud->size());
  EXPECT_TRUE(filter.getRemovedIndices()->empty());
  EXPECT_TRUE(filter.getLevellingTransform().matrix().isIdentity());
  filter.setNegative(true);
  pcl::Indices ground;
  filter.filter(ground);
  EXPECT_TRUE(ground.empty());
}

TEST(GroundFilter, LevellingTransformOfATiltedCloud)
{
  // A cloud tilted 10 deg about x: the transform brings the plane's normal to +z.
  const Eigen::Matrix3f R = Eigen::AngleAxisf(10.0f * float(M_PI) / 180.0f,
                                              Eigen::Vector3f::UnitX())
                                .toRotationMatrix();
  const auto tilted = transformed(*makePlaneAndBoxes(20000, 2000, 5), R);
  pcl::rast::SACGroundRemoval<pcl::PointXYZI> filter;
  filter.setInputCloud(tilted);
  Cloud out;
  filter.filter(out);
  ASSERT_TRUE(filter.groundFound()) << filter.getMessage();
  const Eigen::Vector3f normal =
      filter.getLevellingTransform().linear() * filter.getGroundPlane().head<3>();
  EXPECT_GT(normal.z(), 0.99999f);
  // filter() never moves points.
  EXPECT_EQ(out[0].x, (*tilted)[20000].x);
}

} // namespace test_sac_ground_removal
