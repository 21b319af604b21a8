/// Motion compensation: the SE(3) log / exp pair, times from the azimuth (KITTI
/// convention), and a raw sweep made from a known motion brought back to the reference
/// time to within the time binning.

#include <cmath>
#include <cstdio>
#include <gtest/gtest.h>
#include <limits>
#include <pcl/registration/point_to_plane_refinement.h>
#include <pcl/slam/deskew.h>
#include <random>
#include <stdexcept>

// This file's names stay its own: a test program compiles several test files as
// one translation unit (test/CMakeLists.txt).
namespace test_deskew {

namespace {

using namespace pcl::rast;

constexpr double kPi = 3.14159265358979323846;

pcl::PointXYZI
point(double x, double y, double z)
{
  pcl::PointXYZI p;
  p.x = static_cast<float>(x);
  p.y = static_cast<float>(y);
  p.z = static_cast<float>(z);
  p.intensity = 0.5f;
  return p;
}

TEST(Deskew, LogAndExpOfSE3AreInverse)
{
  std::mt19937 rng(3);
  std::normal_distribution<double> n(0.0, 1.0);
  for (const double angle_scale : {0.0, 1e-9, 1e-4, 0.05, 1.0, 3.0}) {
    for (int k = 0; k < 20; ++k) {
      Twist xi;
      xi << 5.0 * n(rng), 5.0 * n(rng), n(rng), angle_scale * n(rng),
          angle_scale * n(rng), angle_scale * n(rng);
      if (xi.tail<3>().norm() >= kPi)
        continue; // log is the principal branch
      const Pose3d T = expSE3(xi);
      EXPECT_LE(rotationError(T.linear()), 1e-12);
      EXPECT_LE((logSE3(T) - xi).cwiseAbs().maxCoeff(), 1e-9) << xi.transpose();
    }
  }
  // Pure translation and a quarter turn about z with motion: known values.
  Twist xi = Twist::Zero();
  xi.head<3>() << 1.0, 2.0, 3.0;
  EXPECT_LE((expSE3(xi).translation() - Eigen::Vector3d(1, 2, 3)).norm(), 1e-12);
  xi << kPi / 2.0, 0.0, 0.0, 0.0, 0.0, kPi / 2.0; // an arc of radius 1 to (1, 1)
  EXPECT_LE((expSE3(xi).translation() - Eigen::Vector3d(1, 1, 0)).norm(), 1e-12);
}

TEST(Deskew, AzimuthTimesFollowTheKittiSweep)
{
  pcl::PointCloud<pcl::PointXYZI> cloud;
  cloud.push_back(point(10, 0, 0));      // forward: the frame time
  cloud.push_back(point(0, 10, 0));      // left (+90 deg): a quarter sweep earlier
  cloud.push_back(point(0, -10, 0));     // right: a quarter sweep later
  cloud.push_back(point(-10, 1e-3, 0));  // just left of behind: the sweep's start
  cloud.push_back(point(-10, -1e-3, 0)); // just right of behind: its end
  const double T = 0.1;
  const std::vector<float> cw = azimuthTimes(cloud, T);
  EXPECT_NEAR(cw[0], 0.0, 1e-6);
  EXPECT_NEAR(cw[1], -T / 4, 1e-6);
  EXPECT_NEAR(cw[2], T / 4, 1e-6);
  EXPECT_NEAR(cw[3], -T / 2, 1e-5);
  EXPECT_NEAR(cw[4], T / 2, 1e-5);

  SweepParams ccw;
  ccw.clockwise = false;
  EXPECT_NEAR(azimuthTimes(cloud, T, ccw)[1], T / 4, 1e-6);
  SweepParams from_behind; // stamped at the start of a sweep behind the sensor
  from_behind.reference_azimuth_deg = 180.0;
  const std::vector<float> behind = azimuthTimes(cloud, T, from_behind);
  EXPECT_NEAR(std::abs(behind[0]), T / 2, 1e-5);
  EXPECT_NEAR(behind[3], 0.0, 1e-5);

  // The fast atan2 against std::atan2 on random points: within 2e-7 s of a 0.1 s sweep
  // (1.2e-5 rad; 6 micrometres at 30 m/s).
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> u(-80.0, 80.0);
  pcl::PointCloud<pcl::PointXYZI> random;
  for (int i = 0; i < 10000; ++i)
    random.push_back(point(u(rng), u(rng), 0.1 * u(rng)));
  const std::vector<float> t = azimuthTimes(random, T);
  for (std::size_t i = 0; i < random.size(); ++i) {
    const double exact = -std::atan2(random[i].y, random[i].x) / (2.0 * kPi) * T;
    EXPECT_NEAR(t[i], exact, 2e-7) << i;
  }
  // The same with another reference column and spin: the wrap into (-pi, pi] (branch-
  // free, like the atan2) on every side of the reference.
  SweepParams turned;
  turned.reference_azimuth_deg = 135.0;
  turned.clockwise = false;
  const std::vector<float> t_turned = azimuthTimes(random, T, turned);
  for (std::size_t i = 0; i < random.size(); ++i) {
    const double a = std::remainder(
        std::atan2(random[i].y, random[i].x) - 135.0 * kPi / 180.0, 2.0 * kPi);
    EXPECT_NEAR(t_turned[i], a / (2.0 * kPi) * T, 2e-7) << i;
  }
  // The times of some points only: the same values, in the order of the indices.
  const pcl::Indices some = {9999, 5, 17, 5, 0};
  const std::vector<float> t_some = azimuthTimes(random, some, T);
  ASSERT_EQ(t_some.size(), some.size());
  for (std::size_t k = 0; k < some.size(); ++k)
    EXPECT_EQ(t_some[k], t[static_cast<std::size_t>(some[k])]) << k;
  EXPECT_TRUE(azimuthTimes(random, pcl::Indices{}, T).empty());
  EXPECT_THROW(azimuthTimes(random, pcl::Indices{10000}, T), std::out_of_range);
  EXPECT_THROW(azimuthTimes(random, pcl::Indices{-1}, T), std::out_of_range);
  EXPECT_THROW(azimuthTimes(cloud, 0.0), std::invalid_argument);
  SweepParams bad;
  bad.reference_azimuth_deg = std::nan("");
  EXPECT_THROW(azimuthTimes(cloud, T, bad), std::invalid_argument);
}

/// A raw sweep of a static scene from a sensor at 10 m/s turning at 0.5 rad/s: each
/// point is seen from the pose at its firing time. Compensation with the true twist
/// recovers the reference-time scan to the binning error; without it points are
/// decimetres off.
TEST(Deskew, RawSweepOfAKnownMotionIsRecovered)
{
  Twist xi;
  xi << 10.0, 0.3, 0.0, 0.0, 0.02, 0.5; // v [m/s], w [rad/s]
  std::mt19937 rng(9);
  std::uniform_real_distribution<double> u(-40.0, 40.0), h(-1.5, 3.0);
  pcl::PointCloud<pcl::PointXYZI> reference, raw;
  for (int i = 0; i < 20000; ++i)
    reference.push_back(point(u(rng), u(rng), h(rng)));
  const std::vector<float> times = azimuthTimes(reference, 0.1);
  for (std::size_t i = 0; i < reference.size(); ++i) {
    // Sensor at its firing time in the reference frame: exp(tau xi); a raw point is the
    // reference point in that frame.
    const Pose3d T_ref_fire = expSE3(static_cast<double>(times[i]) * xi);
    const Eigen::Vector3d p =
        T_ref_fire.inverse() * reference[i].getVector3fMap().cast<double>();
    raw.push_back(point(p.x(), p.y(), p.z()));
  }
  auto maxError = [&](const pcl::PointCloud<pcl::PointXYZI>& cloud) {
    double worst = 0.0;
    for (std::size_t i = 0; i < cloud.size(); ++i)
      worst = std::max(
          worst,
          static_cast<double>(
              (cloud[i].getVector3fMap() - reference[i].getVector3fMap()).norm()));
    return worst;
  };
  EXPECT_GT(maxError(raw), 0.4); // half a sweep at 10 m/s
  const auto deskewed = deskewCloud(raw, times, xi);
  ASSERT_EQ(deskewed->size(), raw.size());
  // 512 bins of 0.195 ms: at most half a bin off in time, times the speed of the
  // farthest point (10 m/s + 0.5 rad/s * 57 m) = 3.7 mm.
  EXPECT_LT(maxError(*deskewed), 3.8e-3);
  EXPECT_LT(maxError(*deskewCloud(raw, times, xi, 65536)), 1e-4);
  EXPECT_FLOAT_EQ((*deskewed)[7].intensity, raw[7].intensity);
  // The wrong sign of the motion makes it worse, not better.
  EXPECT_GT(maxError(*deskewCloud(raw, times, -xi)), maxError(raw));

  EXPECT_THROW(deskewCloud(raw, std::vector<float>(3, 0.0f), xi), std::invalid_argument);
  EXPECT_THROW(deskewCloud(raw, times, xi, 0), std::invalid_argument);
  EXPECT_TRUE(deskewCloud(pcl::PointCloud<pcl::PointXYZI>(), {}, xi)->empty());
}

/// A NaN time or point leaves that point as it is and the others compensated: no NaN
/// spreads over the scan, no time outside the range indexes a bin.
TEST(Deskew, NonFiniteTimesAndPointsAreLeftAsTheyAre)
{
  pcl::PointCloud<pcl::PointXYZI> cloud;
  for (int i = 0; i < 100; ++i)
    cloud.push_back(point(10.0, 0.1 * i, 0.0));
  cloud[5].x = std::numeric_limits<float>::quiet_NaN();
  std::vector<float> times(cloud.size());
  for (std::size_t i = 0; i < times.size(); ++i)
    times[i] = -0.05f + 0.001f * static_cast<float>(i);
  times[0] = std::numeric_limits<float>::quiet_NaN(); // was the minimum's place
  times[1] = std::numeric_limits<float>::infinity();
  Twist xi = Twist::Zero();
  xi(0) = 10.0;
  const auto out = deskewCloud(cloud, times, xi);
  EXPECT_FLOAT_EQ((*out)[0].x, cloud[0].x); // NaN time: as it is
  EXPECT_FLOAT_EQ((*out)[1].x, cloud[1].x); // infinite time: as it is
  EXPECT_TRUE(std::isnan((*out)[5].x));     // a NaN point stays NaN, alone
  for (std::size_t i = 2; i < cloud.size(); ++i) {
    if (i == 5)
      continue;
    ASSERT_TRUE(std::isfinite((*out)[i].x)) << i;
    EXPECT_NEAR((*out)[i].x - cloud[i].x, 10.0 * times[i], 2e-3) << i;
  }
  // A NaN twist leaves the whole cloud as it is.
  const auto same = deskewCloud(cloud, times, Twist::Constant(std::nan("")));
  EXPECT_FLOAT_EQ((*same)[50].x, cloud[50].x);
}

/// Points and normals move as deskewCloud() moves the points; a size mismatch throws.
TEST(Deskew, PointsAndNormalsMoveAsTheCloudDoes)
{
  Twist xi;
  xi << 8.0, -0.2, 0.1, 0.01, -0.02, 0.4;
  std::mt19937 rng(4);
  std::uniform_real_distribution<double> u(-30.0, 30.0);
  pcl::PointCloud<pcl::PointXYZI> cloud;
  PointVector points, normals;
  for (int i = 0; i < 500; ++i) {
    cloud.push_back(point(u(rng), u(rng), 0.05 * u(rng)));
    points.push_back(cloud.back().getVector3fMap().cast<double>());
    normals.push_back(Eigen::Vector3d(u(rng), u(rng), u(rng)).normalized());
  }
  std::vector<float> times = azimuthTimes(cloud, 0.1);
  times[3] = std::numeric_limits<float>::quiet_NaN();
  const PointVector normals_before = normals;
  const auto moved_cloud = deskewCloud(cloud, times, xi);
  deskewPointsAndNormals(points, normals, times, xi);
  for (std::size_t i = 0; i < points.size(); ++i) {
    // The same bins: float (the cloud) against double.
    ASSERT_LT((points[i] - (*moved_cloud)[i].getVector3fMap().cast<double>()).norm(),
              1e-4)
        << i;
    Eigen::Matrix3d R = Eigen::Matrix3d::Identity();
    if (std::isfinite(times[i]))
      R = expSE3(times[i] * xi).linear();
    ASSERT_LT((normals[i] - R * normals_before[i]).norm(), 1e-3) << i;
  }
  EXPECT_EQ(normals[3], normals_before[3]); // NaN time: as it is
  PointVector no_normals;
  deskewPointsAndNormals(points, no_normals, times, xi); // normals may be empty
  EXPECT_THROW(deskewPointsAndNormals(points, normals, std::vector<float>(2, 0.0f), xi),
               std::invalid_argument);
  PointVector three(3, Eigen::Vector3d::UnitZ());
  EXPECT_THROW(deskewPointsAndNormals(points, three, times, xi), std::invalid_argument);
  EXPECT_THROW(deskewPointsAndNormals(points, normals, times, xi, 0),
               std::invalid_argument);
}

/// A street seen in a raw sweep at 12 m/s, turning at 0.3 rad/s: its source prepared
/// from the raw points with their times, then moved by the motion
/// (prepareSource() with times, deskewPointsAndNormals()), aligns to the street seen at
/// the reference time as the source prepared from the compensated scan does; the raw
/// source without the motion does not.
TEST(Deskew, ASourcePreparedFromTheRawSweepThenMovedAlignsAsTheCompensatedScan)
{
  std::mt19937 rng(12);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::normal_distribution<double> noise(0.0, 0.01);
  // Ground, two facades with a gap, a back wall, cars and posts, in the reference frame.
  pcl::PointCloud<pcl::PointXYZI> reference;
  const auto rectangle =
      [&](int axis, double value, Eigen::Vector3d lo, Eigen::Vector3d hi, int n) {
        lo[axis] = hi[axis] = value;
        for (int i = 0; i < n; ++i) {
          Eigen::Vector3d p;
          for (int a = 0; a < 3; ++a)
            p[a] = lo[a] + u(rng) * (hi[a] - lo[a]) + noise(rng);
          reference.push_back(point(p.x(), p.y(), p.z()));
        }
      };
  rectangle(2, -1.7, {-40, -12, 0}, {40, 12, 0}, 40000);
  rectangle(1, 7.0, {-40, 7, -1.7}, {-5, 7, 8}, 15000);
  rectangle(1, 7.0, {3, 7, -1.7}, {40, 7, 8}, 15000);
  rectangle(1, -9.0, {-40, -9, -1.7}, {40, -9, 6}, 20000);
  rectangle(0, 40.0, {40, -9, -1.7}, {40, 7, 5}, 5000);
  rectangle(0, -40.0, {-40, -9, -1.7}, {-40, 7, 5}, 5000);
  for (const double x : {-25.0, -6.0, 12.0, 30.0}) {
    rectangle(0, x, {x, 4, -1.7}, {x, 6, -0.2}, 1500);
    rectangle(1, 4.0, {x, 4, -1.7}, {x + 4.5, 4, -0.2}, 2500);
    rectangle(0, x + 2.0, {x + 2, -7, -1.7}, {x + 2, -6.8, 2.5}, 400);
  }
  const std::vector<float> times = azimuthTimes(reference, 0.1);
  Twist xi;
  xi << 12.0, 0.0, 0.0, 0.0, 0.0, 0.3;
  pcl::PointCloud<pcl::PointXYZI> raw;
  for (std::size_t i = 0; i < reference.size(); ++i) {
    const Eigen::Vector3d p = expSE3(static_cast<double>(times[i]) * xi).inverse() *
                              reference[i].getVector3fMap().cast<double>();
    raw.push_back(point(p.x(), p.y(), p.z()));
  }
  PointToPlaneParams params;
  params.max_source_points = 2000;
  PointToPlaneTarget target;
  target.build(reference, params);
  const auto alignmentError = [&](const PointVector& points, const PointVector& normals) {
    const PointToPlaneResult r = refinePointToPlane(
        points, normals, target, Eigen::Isometry3d::Identity(), params);
    EXPECT_TRUE(r.success) << r.message;
    return r.T_target_source.translation().norm();
  };
  const PointToPlaneTarget compensated =
      prepareSource(*deskewCloud(raw, times, xi), params);
  std::vector<float> prepared_times;
  const PointToPlaneTarget prepared = prepareSource(raw, times, params, prepared_times);
  PointVector points = prepared.points(), normals = prepared.normals();
  const double raw_error = alignmentError(points, normals);
  deskewPointsAndNormals(points, normals, prepared_times, xi);
  const double moved_error = alignmentError(points, normals);
  const double compensated_error =
      alignmentError(compensated.points(), compensated.normals());
  std::printf(
      "street raw sweep at 12 m/s: aligned %.4f m off as prepared and moved, %.4f m "
      "as compensated and prepared, %.4f m raw\n",
      moved_error,
      compensated_error,
      raw_error);
  EXPECT_LT(moved_error, 0.01);
  EXPECT_LT(moved_error, compensated_error + 0.005);
  EXPECT_GT(raw_error, 5.0 * moved_error);
}

} // namespace

} // namespace test_deskew
