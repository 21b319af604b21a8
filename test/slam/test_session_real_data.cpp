/// Issue 13 on real scans (../shared/data, KITTI raw, Velodyne HDL-64E): a session
/// mapped from every other scan of a street, saved and loaded back, localizes the scans
/// in between (a second pass the map never saw, with no initial pose), places a cold
/// start mid-street at once, and places nothing of two other KITTI drives.
/// There is no ground truth for these scans: the reference of an in-between scan is
/// the midpoint of the map's poses of its two neighbours (the car drives straight at
/// about 8 m/s, so the midpoint is off by far less than the tolerances).

#include "temp_cleanup.h"
#include "test_data.h"

#include <cstdio>
#include <filesystem>
#include <gtest/gtest.h>
#include <pcl/io/sequence_reader.h>
#include <pcl/slam/rast_slam.h>
#include <pcl/slam/session.h>
#include <pcl/slam/session_localizer.h>
#include <string>
#include <vector>

// This file's names stay its own: a test program compiles several test files as
// one translation unit (test/CMakeLists.txt).
namespace test_session_real_data {

namespace {

using namespace pcl::rast;
namespace fs = std::filesystem;

constexpr double kFrameInterval = 0.1; // KITTI's 10 Hz (the folder has no times.txt)

/// The map's pose of each mapped (even) scan of kitti-raw-22, and the session saved from
/// them, loaded back.
struct RealMap
{
  PoseVector even; ///< map pose of scan 2k, in the session's world frame
  std::unique_ptr<SessionLocalizer> localizer;
  OdometryParams odometry;
};

RealMap
mapEvenScans(const SequenceReader& reader)
{
  SlamParams slam_params;
  slam_params.deterministic = true;
  RastSlam slam(slam_params);
  for (std::size_t i = 0; i < reader.size(); i += 2)
    slam.addScan(reader.read(i).cloud, kFrameInterval * i, i);
  slam.finish();

  RealMap m;
  m.even = slam.framePoses();
  const fs::path dir = pcl_rast_test::makeTempDir("session_real_data") / "session";
  pcl_rast_test::removeAtExit(dir.parent_path());
  SessionInfo info;
  info.sensor_preset = toString(SensorPreset::kHdl64);
  saveSession(slam, dir.string(), info);
  Session session = loadSession(dir.string());
  SessionLocalizerParams params;
  applySensorPreset(sensorPresetFromName(session.info.sensor_preset), params);
  m.odometry = params.odometry;
  m.localizer = std::make_unique<SessionLocalizer>(std::move(session), params);
  return m;
}

double
rotationDeg(const Pose3d& a, const Pose3d& b)
{
  return Eigen::AngleAxisd((a.inverse() * b).rotation()).angle() * 180.0 / M_PI;
}

/// Midpoint of two poses (translation halfway, rotation by slerp).
Pose3d
midpoint(const Pose3d& a, const Pose3d& b)
{
  Pose3d m = Pose3d::Identity();
  m.linear() = Eigen::Quaterniond(a.rotation())
                   .slerp(0.5, Eigen::Quaterniond(b.rotation()))
                   .toRotationMatrix();
  m.translation() = 0.5 * (a.translation() + b.translation());
  return m;
}

} // namespace

TEST(SessionRealData, ScansBetweenTheMappedOnesAreLocalizedAndOtherDrivesAreNot)
{
  PCL_RAST_REQUIRE_SHARED_DATA(data);
  const SequenceReader street((data / "kitti-raw-22").string());
  ASSERT_EQ(street.size(), 22u);
  const RealMap m = mapEvenScans(street);
  ASSERT_EQ(m.even.size(), 11u);
  // The map itself: about 0.8 m a scan, straight ahead (SOURCE.txt: 17 m).
  const double length =
      (m.even.back().translation() - m.even.front().translation()).norm();
  EXPECT_GT(length, 14.0);
  EXPECT_LT(length, 19.0);

  // The second pass: the odd scans, 0.2 s apart, none of them in the map.
  MapLocalization pass(*m.localizer, m.odometry);
  int localized = 0, placed_at = -1;
  double worst_m = 0.0, worst_deg = 0.0;
  for (std::size_t i = 1; i < street.size(); i += 2) {
    LocalizationFrame f = pass.addScan(street.read(i).cloud, kFrameInterval * i, i);
    if (f.placed && placed_at < 0)
      placed_at = static_cast<int>(i);
    if (f.status != LocalizationStatus::kLocalized)
      continue;
    ++localized;
    if (i + 1 >= street.size()) // scan 21 has no mapped neighbour after it
      continue;
    const Pose3d reference = midpoint(m.even[(i - 1) / 2], m.even[(i + 1) / 2]);
    const double d_m = (f.T_world_lidar.translation() - reference.translation()).norm();
    const double d_deg = rotationDeg(f.T_world_lidar, reference);
    EXPECT_LT(d_m, 0.15) << "scan " << i << ": " << f.message;
    EXPECT_LT(d_deg, 0.5) << "scan " << i << ": " << f.message;
    worst_m = std::max(worst_m, d_m);
    worst_deg = std::max(worst_deg, d_deg);
  }
  std::printf(
      "real (kitti-raw-22): %d of the 11 in-between scans localized, placed at scan "
      "%d; largest offset from the neighbours' midpoint %.3f m, %.2f deg\n",
      localized,
      placed_at,
      worst_m,
      worst_deg);
  EXPECT_EQ(placed_at, 1) << "the first scan is placed with no initial pose";
  EXPECT_EQ(localized, 11);

  // A cold start mid-street: placed on its first scan.
  MapLocalization cold(*m.localizer, m.odometry);
  const LocalizationFrame c = cold.addScan(street.read(11).cloud, 0.0, 0);
  ASSERT_EQ(c.status, LocalizationStatus::kLocalized) << c.message;
  EXPECT_TRUE(c.placed);
  EXPECT_LT((c.T_world_lidar.translation() - midpoint(m.even[5], m.even[6]).translation())
                .norm(),
            0.15)
      << c.message;

  // Two other KITTI drives (kitti-raw-78: a slow approach behind a car; kitti-6: an
  // odometry sequence): never on this street, so nothing is placed.
  for (const char* other : {"kitti-raw-78", "kitti-6"}) {
    const SequenceReader elsewhere((data / other).string());
    MapLocalization off(*m.localizer, m.odometry);
    int tried = 0;
    for (std::size_t i = 0; i < elsewhere.size(); ++i) {
      const LocalizationFrame f =
          off.addScan(elsewhere.read(i).cloud, kFrameInterval * i, i);
      tried += f.placement_tried ? 1 : 0;
      EXPECT_NE(f.status, LocalizationStatus::kLocalized)
          << other << " scan " << i << ": " << f.message;
      EXPECT_FALSE(f.placed) << other << " scan " << i << ": " << f.message;
    }
    EXPECT_GT(tried, 0) << other << ": no placement was tried";
    std::printf(
        "real (%s, off the map): %zu scans, %d placements tried, none localized\n",
        other,
        elsewhere.size(),
        tried);
  }
}

} // namespace test_session_real_data
