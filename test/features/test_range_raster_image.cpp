/// \file test_range_raster_image.cpp
/// \brief RangeRasterImage: max height per pixel, exact lift-back, both projections.

#include <pcl/features/range_raster_image.h>

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <random>
#include <stdexcept>

// This file's names stay its own: a test program compiles several test files as
// one translation unit (test/CMakeLists.txt).
namespace test_range_raster_image {

using RangeRasterImage = pcl::rast::RangeRasterImage<pcl::PointXYZI>;
using pcl::rast::RangeRasterParams;
using pcl::rast::RasterProjection;
using Cloud = pcl::PointCloud<pcl::PointXYZI>;

namespace {

pcl::PointXYZI
makePoint(float x, float y, float z)
{
  pcl::PointXYZI p;
  p.x = x;
  p.y = y;
  p.z = z;
  p.intensity = 0.0f;
  return p;
}

RangeRasterParams
paramsFor(RasterProjection projection)
{
  RangeRasterParams params;
  params.projection = projection;
  return params;
}

/// Points clustered densely (many per pixel) inside the area both projections see:
/// the paper's pinhole covers x, y in about [25, 130] m, the default orthographic
/// view [-51.2, 51.2] m.
Cloud::Ptr
makeDenseCloud(unsigned seed)
{
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> xy(27.0f, 50.0f), z(-1.8f, 3.5f);
  auto cloud = std::make_shared<Cloud>();
  for (int i = 0; i < 60000; ++i)
    cloud->push_back(makePoint(xy(rng), xy(rng), z(rng)));
  return cloud;
}

} // namespace

class RangeRasterProjections : public ::testing::TestWithParam<RasterProjection>
{};

TEST_P(RangeRasterProjections, MaxHeightPerPixelAndExactLiftBack)
{
  const auto cloud = makeDenseCloud(11);
  RangeRasterImage raster(paramsFor(GetParam()));
  raster.setInputCloud(cloud);
  raster.compute();
  ASSERT_TRUE(raster.isComputed());
  ASSERT_EQ(raster.numProjectedPoints(), cloud->size());

  // Brute force: the highest point of every pixel.
  std::map<std::pair<int, int>, int> highest;
  for (int i = 0; i < static_cast<int>(cloud->size()); ++i) {
    int col, row;
    ASSERT_TRUE(raster.projectToPixel((*cloud)[i].getVector3fMap(), col, row));
    auto it = highest.find({col, row});
    if (it == highest.end() || (*cloud)[i].z > (*cloud)[it->second].z)
      highest[{col, row}] = i;
  }
  EXPECT_EQ(raster.numOccupiedPixels(), highest.size());
  EXPECT_LT(highest.size(), cloud->size()); // several points share pixels

  for (int i = 0; i < static_cast<int>(cloud->size()); ++i) {
    const auto& p = (*cloud)[i];
    int col, row;
    ASSERT_TRUE(raster.projectToPixel(p.getVector3fMap(), col, row));
    // pixelToPoint(project(p)) is exactly the highest point of p's pixel.
    pcl::PointXYZI lifted;
    ASSERT_TRUE(raster.pixelToPoint(col, row, lifted));
    const int expected = highest.at({col, row});
    ASSERT_EQ(raster.pixelIndex(col, row), expected);
    EXPECT_EQ(lifted.x, (*cloud)[expected].x);
    EXPECT_EQ(lifted.y, (*cloud)[expected].y);
    EXPECT_EQ(lifted.z, (*cloud)[expected].z);
    EXPECT_GE(lifted.z, p.z);
    EXPECT_EQ(raster.heightAt(col, row), lifted.z);
    EXPECT_EQ(raster.grayAt(col, row),
              pcl::rast::heightToGray(raster.getParams(), lifted.z));
  }
  // Every other pixel is empty.
  int empty = 0;
  for (int row = 0; row < raster.height(); ++row)
    for (int col = 0; col < raster.width(); ++col)
      if (raster.pixelIndex(col, row) < 0) {
        ++empty;
        EXPECT_EQ(raster.grayAt(col, row), 0);
        EXPECT_TRUE(std::isnan(raster.heightAt(col, row)));
      }
  EXPECT_EQ(static_cast<std::size_t>(empty),
            static_cast<std::size_t>(raster.width()) * raster.height() - highest.size());
}

TEST_P(RangeRasterProjections, RasterToPointInvertsProjection)
{
  const RangeRasterParams params = paramsFor(GetParam());
  std::mt19937 rng(12);
  std::uniform_real_distribution<float> xy(27.0f, 50.0f), z(-2.0f, 4.0f);
  for (int i = 0; i < 1000; ++i) {
    const Eigen::Vector3f p(xy(rng), xy(rng), z(rng));
    Eigen::Vector2f uv;
    ASSERT_TRUE(pcl::rast::projectToRaster(params, p, uv));
    const Eigen::Vector3f back = pcl::rast::rasterToPoint(params, uv, p.z());
    EXPECT_LT((back - p).norm(), 1e-3f);
  }
}

TEST_P(RangeRasterProjections, SkipsPointsOutsideTheImageAndNonFinite)
{
  RangeRasterImage raster(paramsFor(GetParam()));
  auto cloud = std::make_shared<Cloud>();
  const float nan = std::numeric_limits<float>::quiet_NaN();
  cloud->push_back(makePoint(40.0f, 40.0f, 0.0f));   // inside both
  cloud->push_back(makePoint(500.0f, 40.0f, 0.0f));  // far outside
  cloud->push_back(makePoint(-500.0f, -500.0f, 0.0f));
  cloud->push_back(makePoint(nan, 40.0f, 0.0f));
  cloud->push_back(makePoint(40.0f, 40.0f, -100.0f)); // behind the pinhole camera
  raster.setInputCloud(cloud);
  raster.compute();
  const std::size_t expected = GetParam() == RasterProjection::kPinhole ? 1u : 2u;
  EXPECT_EQ(raster.numProjectedPoints(), expected);
  int col, row;
  EXPECT_FALSE(raster.projectToPixel(Eigen::Vector3f(500.0f, 40.0f, 0.0f), col, row));
  EXPECT_FALSE(raster.projectToPixel(Eigen::Vector3f(nan, 0.0f, 0.0f), col, row));
  EXPECT_EQ(raster.pixelIndex(-1, 0), -1);
  EXPECT_EQ(raster.pixelIndex(raster.width(), 0), -1);
  EXPECT_EQ(raster.pixelIndex(0, raster.height()), -1);
  pcl::PointXYZI point;
  EXPECT_FALSE(raster.pixelToPoint(raster.width(), raster.height(), point));
}

TEST_P(RangeRasterProjections, EmptyCloudGivesEmptyImage)
{
  RangeRasterImage raster(paramsFor(GetParam()));
  raster.setInputCloud(std::make_shared<Cloud>());
  raster.compute();
  EXPECT_EQ(raster.numOccupiedPixels(), 0u);
  const std::size_t num_pixels = static_cast<std::size_t>(raster.width()) * raster.height();
  ASSERT_NE(raster.grayData(), nullptr);
  EXPECT_EQ(std::count(raster.grayData(), raster.grayData() + num_pixels, 0), num_pixels);
  EXPECT_EQ(std::count(raster.indexData(), raster.indexData() + num_pixels, -1), num_pixels);
  EXPECT_TRUE(std::all_of(raster.heightData(), raster.heightData() + num_pixels,
                          [](float h) { return std::isnan(h); }));
}

INSTANTIATE_TEST_SUITE_P(Projections,
                         RangeRasterProjections,
                         ::testing::Values(RasterProjection::kPinhole,
                                           RasterProjection::kOrthographic),
                         [](const auto& info) {
                           return info.param == RasterProjection::kPinhole ? "Pinhole"
                                                                           : "Orthographic";
                         });

TEST(RangeRasterImage, PinholeIsThePapersModel)
{
  // Paper Sec. 10: f = 500, (t_u, t_v) = (0, 0), R = I, t = [-25, -25, 70], 750 x 750.
  const RangeRasterParams params = paramsFor(RasterProjection::kPinhole);
  EXPECT_EQ(params.width(), 750);
  EXPECT_EQ(params.height(), 750);
  Eigen::Vector2f uv;
  ASSERT_TRUE(pcl::rast::projectToRaster(params, Eigen::Vector3f(50.0f, 40.0f, 2.0f), uv));
  EXPECT_NEAR(uv.x(), 500.0 * 25.0 / 72.0, 1e-3); // u = f X/Z + t_u, X = x - 25, Z = z + 70
  EXPECT_NEAR(uv.y(), 500.0 * 15.0 / 72.0, 1e-3);
  // Coverage at z = 0: x, y in [25, 25 + 750 * 70 / 500] = [25, 130] m.
  ASSERT_TRUE(pcl::rast::projectToRaster(params, Eigen::Vector3f(25.0f, 25.0f, 0.0f), uv));
  EXPECT_NEAR(uv.x(), 0.0f, 1e-4f);
  EXPECT_NEAR(uv.y(), 0.0f, 1e-4f);
  ASSERT_TRUE(pcl::rast::projectToRaster(params, Eigen::Vector3f(130.0f, 130.0f, 0.0f), uv));
  EXPECT_NEAR(uv.x(), 750.0f, 1e-3f);
  RangeRasterImage raster(params);
  int col, row;
  EXPECT_FALSE(raster.projectToPixel(Eigen::Vector3f(0.0f, 0.0f, 0.0f), col, row)); // the sensor
}

TEST(RangeRasterImage, OrthographicIsMetricBirdsEyeView)
{
  const RangeRasterParams params = paramsFor(RasterProjection::kOrthographic);
  EXPECT_EQ(params.width(), 512);
  EXPECT_EQ(params.height(), 512);
  RangeRasterImage raster(params);
  int col, row;
  ASSERT_TRUE(raster.projectToPixel(Eigen::Vector3f(0.1f, 0.1f, 0.0f), col, row));
  EXPECT_EQ(col, 255);
  EXPECT_EQ(row, 255);
  // 10 m forward is 50 rows up; 10 m left is 50 columns left.
  int col2, row2;
  ASSERT_TRUE(raster.projectToPixel(Eigen::Vector3f(10.1f, 0.1f, 0.0f), col2, row2));
  EXPECT_EQ(row2, row - 50);
  EXPECT_EQ(col2, col);
  ASSERT_TRUE(raster.projectToPixel(Eigen::Vector3f(0.1f, 10.1f, 0.0f), col2, row2));
  EXPECT_EQ(col2, col - 50);
  // Height does not move a point in the image.
  ASSERT_TRUE(raster.projectToPixel(Eigen::Vector3f(0.1f, 10.1f, 30.0f), col, row));
  EXPECT_EQ(col, col2);
  EXPECT_FALSE(raster.projectToPixel(Eigen::Vector3f(51.3f, 0.0f, 0.0f), col, row));
}

TEST(RangeRasterImage, HeightToGrayClampsToRange)
{
  RangeRasterParams params;
  params.min_height_m = -2.0f;
  params.max_height_m = 3.0f;
  EXPECT_EQ(pcl::rast::heightToGray(params, -10.0f), 1);
  EXPECT_EQ(pcl::rast::heightToGray(params, -2.0f), 1);
  EXPECT_EQ(pcl::rast::heightToGray(params, 3.0f), 255);
  EXPECT_EQ(pcl::rast::heightToGray(params, 30.0f), 255);
  EXPECT_EQ(pcl::rast::heightToGray(params, 0.5f), 128);
}

TEST(RangeRasterImage, NearestPixelIndexSearchesNeighbourhood)
{
  RangeRasterImage raster;
  auto cloud = std::make_shared<Cloud>();
  cloud->push_back(makePoint(0.1f, 0.1f, 1.0f));
  raster.setInputCloud(cloud);
  raster.compute();
  int col, row;
  ASSERT_TRUE(raster.projectToPixel(cloud->front().getVector3fMap(), col, row));
  EXPECT_EQ(raster.nearestPixelIndex(col, row, 0), 0);
  EXPECT_EQ(raster.nearestPixelIndex(col + 2, row - 1, 1), -1);
  EXPECT_EQ(raster.nearestPixelIndex(col + 2, row - 1, 2), 0);
}

TEST(RangeRasterImage, RejectsInvalidInput)
{
  RangeRasterImage raster;
  EXPECT_THROW(raster.setInputCloud(nullptr), std::invalid_argument);
  EXPECT_THROW(raster.compute(), std::invalid_argument);
  RangeRasterParams params;
  params.min_height_m = 2.0f;
  params.max_height_m = 1.0f;
  std::string why;
  EXPECT_FALSE(params.isValid(&why));
  EXPECT_NE(why.find("min_height_m"), std::string::npos);
  EXPECT_THROW(raster.setParams(params), std::invalid_argument);
  params = {};
  params.orthographic.resolution_m = 0.0;
  EXPECT_FALSE(params.isValid());
  params = {};
  params.projection = RasterProjection::kPinhole;
  params.pinhole.focal_px = -1.0;
  EXPECT_FALSE(params.isValid());
  params.pinhole.focal_px = 500.0;
  params.pinhole.width_px = 0;
  EXPECT_FALSE(params.isValid());
}

} // namespace test_range_raster_image
