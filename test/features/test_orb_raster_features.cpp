/// \file test_orb_raster_features.cpp
/// \brief OrbRasterFeatureEstimator on synthetic scenes (spread, rotation invariance,
/// exact 3D lift) and on real KITTI scans. Matching uses a small brute-force Hamming
/// matcher with ratio test and a 3-point rigid RANSAC defined here, independent of
/// the registration module.

#include <pcl/features/orb_raster_features.h>
#include <pcl/segmentation/sac_ground_removal.h>
#include <pcl/io/sequence_reader.h>

#include <gtest/gtest.h>

#include "test_data.h"

#include <Eigen/Geometry>

#include <chrono>
#include <cmath>
#include <fstream>
#include <map>
#include <random>
#include <set>
#include <stdexcept>

// This file's names stay its own: a test program compiles several test files as
// one translation unit (test/CMakeLists.txt).
namespace test_orb_raster_features {

using OrbRasterFeatureEstimator = pcl::rast::OrbRasterFeatureEstimator<pcl::PointXYZI>;
using pcl::rast::OrbRasterFeatureParams;
using pcl::rast::OrbRasterFeatureResult;
using RangeRasterImage = pcl::rast::RangeRasterImage<pcl::PointXYZI>;
using pcl::rast::RangeRasterParams;
using pcl::rast::RasterFeatureSet;
using pcl::rast::RasterProjection;
using Cloud = pcl::PointCloud<pcl::PointXYZI>;

namespace {

pcl::PointXYZI
makePoint(const Eigen::Vector3f& p)
{
  pcl::PointXYZI q;
  q.getVector3fMap() = p;
  q.intensity = 0.0f;
  return q;
}

/// A synthetic "town" within 40 m of the sensor (so it stays inside the default
/// 51.2 m raster under any yaw): boxes of random size, yaw and height, and poles,
/// sampled on their tops every 5 cm and on their walls.
Cloud::Ptr
makeTown(unsigned seed)
{
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> unit(0.0f, 1.0f);
  auto cloud = std::make_shared<Cloud>();
  const float ground = -1.73f;
  for (int b = 0; b < 90; ++b) {
    const float radius = 6.0f + 32.0f * std::sqrt(unit(rng));
    const float bearing = 2.0f * float(M_PI) * unit(rng);
    const Eigen::Vector2f centre(radius * std::cos(bearing), radius * std::sin(bearing));
    const bool pole = b % 6 == 0;
    const float half_x = pole ? 0.2f : 0.5f + 2.5f * unit(rng);
    const float half_y = pole ? 0.2f : 0.5f + 1.5f * unit(rng);
    const float top = ground + (pole ? 5.0f : 0.5f + 4.0f * unit(rng));
    const float yaw = float(M_PI) * unit(rng);
    const Eigen::Rotation2Df R(yaw);
    const float step = 0.05f;
    for (float x = -half_x; x <= half_x; x += step)
      for (float y = -half_y; y <= half_y; y += step) {
        const Eigen::Vector2f xy = centre + R * Eigen::Vector2f(x, y);
        // A sloped top gives texture inside the box too.
        cloud->push_back(makePoint({xy.x(), xy.y(), top + 0.15f * x}));
      }
  }
  return cloud;
}

Cloud::Ptr
rotated(const Cloud& cloud, const Eigen::Matrix3f& R, const Eigen::Vector3f& t)
{
  auto out = std::make_shared<Cloud>(cloud);
  for (auto& p : *out)
    p.getVector3fMap() = R * p.getVector3fMap() + t;
  return out;
}

RasterFeatureSet
extract(const Cloud::ConstPtr& cloud,
        OrbRasterFeatureResult* result = nullptr,
        const OrbRasterFeatureParams& params = {},
        const RangeRasterParams& raster_params = {})
{
  OrbRasterFeatureEstimator orb;
  orb.setParams(params);
  orb.setRasterParams(raster_params);
  orb.setInputCloud(cloud);
  RasterFeatureSet features;
  const auto r = orb.compute(features);
  if (result)
    *result = r;
  return features;
}

/// Brute-force Hamming matching with Lowe's ratio test: pairs (source, target).
std::vector<std::pair<int, int>>
matchRatio(const RasterFeatureSet& source, const RasterFeatureSet& target, double ratio = 0.8)
{
  std::vector<std::pair<int, int>> matches;
  for (std::size_t i = 0; i < source.size(); ++i) {
    int best = 257, second = 257, best_j = -1;
    for (std::size_t j = 0; j < target.size(); ++j) {
      const int d = pcl::rast::hammingDistance(source.descriptors[i], target.descriptors[j]);
      if (d < best) {
        second = best;
        best = d;
        best_j = static_cast<int>(j);
      }
      else if (d < second)
        second = d;
    }
    if (best_j >= 0 && best < ratio * second)
      matches.emplace_back(static_cast<int>(i), best_j);
  }
  return matches;
}

/// 3-point rigid RANSAC (Umeyama on samples and on the final inliers).
Eigen::Matrix4f
ransacRigid(const RasterFeatureSet& source,
            const RasterFeatureSet& target,
            const std::vector<std::pair<int, int>>& matches,
            float threshold_m,
            std::vector<int>* inliers)
{
  std::mt19937 rng(7);
  inliers->clear();
  if (matches.size() < 3)
    return Eigen::Matrix4f::Identity();
  auto src = [&](int m) {
    const auto& p = source.points[matches[m].first];
    return Eigen::Vector3f(p.x, p.y, p.z);
  };
  auto tgt = [&](int m) {
    const auto& p = target.points[matches[m].second];
    return Eigen::Vector3f(p.x, p.y, p.z);
  };
  auto fit = [&](const std::vector<int>& ms) {
    Eigen::Matrix3Xf a(3, ms.size()), b(3, ms.size());
    for (std::size_t k = 0; k < ms.size(); ++k) {
      a.col(k) = src(ms[k]);
      b.col(k) = tgt(ms[k]);
    }
    return Eigen::Matrix4f(Eigen::umeyama(a, b, false));
  };
  auto consensus = [&](const Eigen::Matrix4f& T) {
    std::vector<int> in;
    for (int m = 0; m < static_cast<int>(matches.size()); ++m)
      if ((T.topLeftCorner<3, 3>() * src(m) + T.topRightCorner<3, 1>() - tgt(m)).norm() <
          threshold_m)
        in.push_back(m);
    return in;
  };
  std::uniform_int_distribution<int> pick(0, static_cast<int>(matches.size()) - 1);
  Eigen::Matrix4f best_T = Eigen::Matrix4f::Identity();
  for (int it = 0; it < 2000; ++it) {
    const std::vector<int> sample{pick(rng), pick(rng), pick(rng)};
    if (sample[0] == sample[1] || sample[0] == sample[2] || sample[1] == sample[2])
      continue;
    const Eigen::Matrix4f T = fit(sample);
    if (!T.allFinite())
      continue;
    auto in = consensus(T);
    if (in.size() > inliers->size()) {
      *inliers = std::move(in);
      best_T = T;
    }
  }
  if (inliers->size() >= 3) {
    best_T = fit(*inliers);
    *inliers = consensus(best_T);
  }
  return best_T;
}

} // namespace

TEST(OrbRasterFeatures, FeaturesSpreadOverGridCells)
{
  const auto cloud = makeTown(21);
  OrbRasterFeatureParams params;
  params.max_per_cell = 2;
  params.grid_cell_px = 32;
  OrbRasterFeatureResult result;
  const auto features = extract(cloud, &result, params);
  ASSERT_TRUE(result.success) << result.message;
  ASSERT_GT(features.size(), 100u) << result.message;
  ASSERT_EQ(features.points.size(), features.descriptors.size());
  std::map<std::pair<int, int>, int> per_cell;
  for (const auto& p : features.points) {
    // Cells in padded coordinates (pad = patch + 1 = 32 = one cell): same grid.
    ++per_cell[{static_cast<int>(p.u + 32) / 32, static_cast<int>(p.v + 32) / 32}];
  }
  for (const auto& cell : per_cell)
    EXPECT_LE(cell.second, 2);
  // 16 x 16 cells; the town covers the disc of radius 38 m (~45 % of the image).
  EXPECT_GT(per_cell.size(), 60u);

  // One per cell: the 60 features come from 60 different cells.
  auto cellsOf = [](const RasterFeatureSet& f) {
    std::set<std::pair<int, int>> cells;
    for (const auto& p : f.points)
      cells.insert({static_cast<int>(p.u + 32) / 32, static_cast<int>(p.v + 32) / 32});
    return cells.size();
  };
  params.max_features = 60;
  params.max_per_cell = 1;
  const auto spread = extract(cloud, nullptr, params);
  ASSERT_EQ(spread.size(), 60u);
  EXPECT_EQ(cellsOf(spread), 60u);

}

TEST(OrbRasterFeatures, LiftsKeypointsToTheirSourcePoints)
{
  const auto cloud = makeTown(22);
  OrbRasterFeatureEstimator orb;
  orb.setInputCloud(cloud);
  RasterFeatureSet features;
  const auto result = orb.compute(features);
  ASSERT_GT(features.size(), 100u) << result.message;
  const RangeRasterImage& raster = orb.getRaster();
  const int radius = orb.getParams().lift_search_radius_px;
  for (const auto& f : features.points) {
    // x, y, z are exactly those of the highest point of a pixel near (u, v).
    const int index = raster.nearestPixelIndex(static_cast<int>(std::lround(f.u)),
                                               static_cast<int>(std::lround(f.v)), radius);
    ASSERT_GE(index, 0);
    EXPECT_EQ(f.x, (*cloud)[index].x);
    EXPECT_EQ(f.y, (*cloud)[index].y);
    EXPECT_EQ(f.z, (*cloud)[index].z);
    int col, row;
    ASSERT_TRUE(raster.projectToPixel(f.getVector3fMap(), col, row));
    EXPECT_LE(std::abs(col - f.u), radius + 0.5f);
    EXPECT_LE(std::abs(row - f.v), radius + 0.5f);
    EXPECT_GE(f.angle_deg, 0.0f);
    EXPECT_LT(f.angle_deg, 360.0f);
    EXPECT_EQ(f.octave, 0);
  }
  EXPECT_EQ(result.num_features + result.num_unlifted, result.num_bucketed);
}

TEST(OrbRasterFeatures, RotationAboutZGivesCorrectMatches)
{
  const auto cloud = makeTown(23);
  const Eigen::Matrix3f R =
      Eigen::AngleAxisf(40.0f * float(M_PI) / 180.0f, Eigen::Vector3f::UnitZ()).toRotationMatrix();
  const Eigen::Vector3f t(1.0f, -0.5f, 0.0f);
  const auto moved = rotated(*cloud, R, t);
  const auto source = extract(cloud), target = extract(moved);
  const auto matches = matchRatio(source, target);
  int correct = 0;
  for (const auto& m : matches) {
    const Eigen::Vector3f expected = R * source.points[m.first].getVector3fMap() + t;
    correct += (expected - target.points[m.second].getVector3fMap()).norm() < 0.6f;
  }
  std::cout << "[          ] " << source.size() << " / " << target.size() << " features, "
            << matches.size() << " ratio matches, " << correct << " correct" << std::endl;
  EXPECT_GT(correct, 100);
  EXPECT_GT(correct, static_cast<int>(matches.size()) / 2);

  std::vector<int> inliers;
  const Eigen::Matrix4f T = ransacRigid(source, target, matches, 0.5f, &inliers);
  EXPECT_GE(static_cast<int>(inliers.size()), correct * 9 / 10);
  const float yaw_deg = std::atan2(T(1, 0), T(0, 0)) * 180.0f / float(M_PI);
  EXPECT_NEAR(yaw_deg, 40.0f, 0.5f);
  EXPECT_LT((T.topRightCorner<3, 1>() - t).norm(), 0.15f);
}

TEST(OrbRasterFeatures, RasterInputEqualsCloudInput)
{
  const auto cloud = makeTown(24);
  const auto from_cloud = extract(cloud);
  RangeRasterImage raster;
  raster.setInputCloud(cloud);
  raster.compute();
  OrbRasterFeatureEstimator orb;
  orb.setInputRaster(raster);
  RasterFeatureSet from_raster;
  const auto result = orb.compute(from_raster);
  EXPECT_EQ(result.raster_ms, 0.0);
  ASSERT_EQ(from_raster.size(), from_cloud.size());
  for (std::size_t i = 0; i < from_cloud.size(); ++i) {
    EXPECT_EQ(from_raster.points[i].x, from_cloud.points[i].x);
    EXPECT_EQ(from_raster.descriptors[i], from_cloud.descriptors[i]);
  }
}

TEST(OrbRasterFeatures, AdaptsFastThreshold)
{
  const auto cloud = makeTown(25);
  OrbRasterFeatureParams params;
  OrbRasterFeatureResult plenty, starving;
  extract(cloud, &plenty, params);
  EXPECT_EQ(plenty.fast_threshold, params.fast_threshold);
  params.min_features = 1000000; // never enough: halve down to the minimum
  extract(cloud, &starving, params);
  EXPECT_EQ(starving.fast_threshold, params.min_fast_threshold);
  EXPECT_GT(starving.num_detected, plenty.num_detected);
}

TEST(OrbRasterFeatures, EmptyAndInvalidInput)
{
  OrbRasterFeatureResult result;
  const auto features = extract(std::make_shared<Cloud>(), &result);
  EXPECT_FALSE(result.success);
  EXPECT_TRUE(features.empty());
  EXPECT_FALSE(result.message.empty());

  OrbRasterFeatureEstimator orb;
  RasterFeatureSet out;
  EXPECT_THROW(orb.compute(out), std::invalid_argument);
  EXPECT_THROW(orb.setInputCloud(nullptr), std::invalid_argument);
  EXPECT_THROW(orb.setInputRaster(RangeRasterImage()), std::invalid_argument);

  OrbRasterFeatureParams params;
  std::string why;
  EXPECT_TRUE(params.isValid(&why));
  params.max_features = 0;
  EXPECT_FALSE(params.isValid(&why));
  EXPECT_NE(why.find("max_features"), std::string::npos);
  EXPECT_THROW(orb.setParams(params), std::invalid_argument);
  params = {};
  params.min_fast_threshold = params.fast_threshold + 1;
  EXPECT_FALSE(params.isValid());
  params = {};
  params.blur_sigma_px = -1.0;
  EXPECT_FALSE(params.isValid());
}

namespace {

/// Ground removal + features of one real scan; prints per-stage timings.
RasterFeatureSet
realFeatures(const std::string& path, double max_tilt_deg = 3.0)
{
  const auto cloud = pcl::rast::readScan(path);
  pcl::rast::SACGroundRemoval<pcl::PointXYZI> ground;
  ground.setInputCloud(cloud);
  pcl::rast::GroundRemovalResult<pcl::PointXYZI> ground_result;
  const auto start = std::chrono::steady_clock::now();
  ground.segment(ground_result);
  const double ground_ms =
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
  EXPECT_TRUE(ground_result.ground_found) << ground_result.message;
  EXPECT_GT(ground_result.plane_coefficients.z(), std::cos(max_tilt_deg * M_PI / 180.0));
  OrbRasterFeatureResult result;
  auto features = extract(ground_result.non_ground, &result);
  std::cout << "[          ] " << std::filesystem::path(path).filename().string() << ": "
            << result.message << "; ms ground " << ground_ms << " raster " << result.raster_ms
            << " detect " << result.detect_ms << " describe " << result.describe_ms
            << std::endl;
  return features;
}

} // namespace

TEST(OrbRasterFeatures, RealKittiScansMatch)
{
  PCL_RAST_REQUIRE_SHARED_DATA(data);
  const auto dir = data / "kitti-raw-22/pcd";
  const auto a = realFeatures((dir / "0000000000.pcd").string());
  const auto b = realFeatures((dir / "0000000001.pcd").string());
  EXPECT_GT(a.size(), 300u);
  EXPECT_GT(b.size(), 300u);
  // Consecutive frames ~0.8 m apart, driving forward (+x).
  const auto matches = matchRatio(b, a);
  std::vector<int> inliers;
  const Eigen::Matrix4f T_a_b = ransacRigid(b, a, matches, 0.3f, &inliers);
  std::cout << "[          ] " << matches.size() << " ratio matches, " << inliers.size()
            << " RANSAC inliers, t = " << T_a_b.topRightCorner<3, 1>().transpose() << std::endl;
  EXPECT_GT(inliers.size(), 30u);
  EXPECT_NEAR(T_a_b(0, 3), 0.8, 0.1);
  EXPECT_LT(std::abs(T_a_b(1, 3)), 0.1);
}

TEST(OrbRasterFeatures, RealScanPairMatchesReference)
{
  PCL_RAST_REQUIRE_SHARED_DATA(data);
  const auto dir = data / "scan-pair-pcd";
  Eigen::Matrix4f T_ref;
  std::ifstream in(dir / "relative.txt");
  for (int i = 0; i < 16; ++i)
    in >> T_ref(i / 4, i % 4);
  ASSERT_TRUE(in) << "cannot read relative.txt";
  // relative.txt maps the second scan (source) into the first (target).
  // This sensor is mounted ~6 deg off level.
  const auto target = realFeatures((dir / "251370668.pcd").string(), 10.0);
  const auto source = realFeatures((dir / "251371071.pcd").string(), 10.0);
  const auto matches = matchRatio(source, target);
  std::vector<int> inliers;
  const Eigen::Matrix4f T = ransacRigid(source, target, matches, 0.3f, &inliers);
  const Eigen::Matrix4f error = T_ref.inverse() * T;
  const float t_error = error.topRightCorner<3, 1>().norm();
  const float r_error_deg =
      Eigen::AngleAxisf(Eigen::Matrix3f(error.topLeftCorner<3, 3>())).angle() * 180.0f / M_PI;
  std::cout << "[          ] " << matches.size() << " ratio matches, " << inliers.size()
            << " inliers, error " << t_error << " m, " << r_error_deg << " deg" << std::endl;
  EXPECT_GT(inliers.size(), 20u);
  EXPECT_LT(t_error, 0.2f);
  EXPECT_LT(r_error_deg, 1.0f);
}

} // namespace test_orb_raster_features
