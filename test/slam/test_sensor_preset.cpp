/// Sensor presets: names, what they change, and the guess from one scan (simulated
/// HDL-64, VLP-16, OS1-64 and a tilted handheld OS0-128; a real KITTI scan).

#include "test_data.h"

#include <gtest/gtest.h>
#include <iostream>
#include <pcl/io/sequence_reader.h>
#include <pcl/simulation/lidar_simulator.h>
#include <pcl/slam/odometry.h>
#include <pcl/slam/session_localizer.h>
#include <stdexcept>
#include <string>

// This file's names stay its own: a test program compiles several test files as
// one translation unit (test/CMakeLists.txt).
namespace test_sensor_preset {

namespace {

using namespace pcl::rast;

pcl::PointCloud<pcl::PointXYZI>
simulatedScan(SensorModel model)
{
  PathParams path;
  path.type = PathType::kLoop;
  path.num_frames = 10; // the OS0-128 model is handheld: tilted and swaying
  LidarSimulatorParams params;
  params.sensor = model;
  params.seed = 5;
  params.num_threads = 2;
  LidarSimulator sim(params, generatePath(path));
  pcl::PointCloud<pcl::PointXYZI> cloud;
  sim.simulateFrame(3, cloud);
  return cloud;
}

TEST(SensorPreset, NamesRoundTripAndBadNamesAreNamed)
{
  for (const auto preset : {SensorPreset::kHdl64, SensorPreset::kVlp16, SensorPreset::kOs1_64,
                            SensorPreset::kOs0_128})
    EXPECT_EQ(sensorPresetFromName(toString(preset)), preset);
  try {
    sensorPresetFromName("lidar9000");
    FAIL() << "expected std::invalid_argument";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("lidar9000"), std::string::npos);
  }
}

TEST(SensorPreset, PresetsChangeWhatTheySay)
{
  OdometryParams defaults, p;
  applySensorPreset(SensorPreset::kHdl64, p);
  EXPECT_EQ(p.keyframe_voxel_size_m, defaults.keyframe_voxel_size_m);
  applySensorPreset(SensorPreset::kOs0_128, p);
  EXPECT_TRUE(p.ground.level_cloud);
  EXPECT_GT(p.ground.max_tilt_deg, defaults.ground.max_tilt_deg);
  // Handheld: no vehicle dynamics, the height gate included (a walker steps up a stair).
  EXPECT_GT(defaults.prior_gate_vertical_accel_mps2, 0.0);
  EXPECT_EQ(p.prior_gate_vertical_accel_mps2, 0.0);
  EXPECT_EQ(p.prior_gate_accel_mps2, 0.0);
  EXPECT_TRUE(p.isValid());
  OdometryParams v;
  applySensorPreset(SensorPreset::kVlp16, v);
  EXPECT_LT(v.min_feature_inliers, defaults.min_feature_inliers);
  // Its weak features are blended with the prior; the defaults' and the handheld's
  // are not.
  EXPECT_EQ(defaults.weak_feature_share, 0.0);
  EXPECT_EQ(p.weak_feature_share, 0.0);
  EXPECT_GT(v.weak_feature_share, 0.0);
  EXPECT_TRUE(v.isValid());
}

/// The localizer's preset: the odometry's, and for a 16-beam sensor placements with
/// fewer inliers (a tentative placement still below a full one).
TEST(SensorPreset, ASixteenBeamPlacementNeedsFewerInliers)
{
  const SessionLocalizerParams defaults;
  for (const auto preset : {SensorPreset::kHdl64,
                            SensorPreset::kVlp16,
                            SensorPreset::kOs1_64,
                            SensorPreset::kOs0_128}) {
    SessionLocalizerParams p;
    applySensorPreset(preset, p);
    OdometryParams odometry;
    applySensorPreset(preset, odometry);
    EXPECT_EQ(p.odometry.min_feature_inliers, odometry.min_feature_inliers)
        << toString(preset);
    EXPECT_EQ(p.odometry.ground.level_cloud, odometry.ground.level_cloud)
        << toString(preset);
    EXPECT_EQ(p.odometry.dense.map_voxel_size_m, odometry.dense.map_voxel_size_m)
        << toString(preset);
    EXPECT_TRUE(p.isValid()) << toString(preset);
    if (preset != SensorPreset::kVlp16) {
      EXPECT_EQ(p.verification.min_initial_inliers,
                defaults.verification.min_initial_inliers);
      EXPECT_EQ(p.verification.min_inliers, defaults.verification.min_inliers);
      EXPECT_EQ(p.neighbourhood_keyframes, 0) << toString(preset);
      continue;
    }
    EXPECT_EQ(p.verification.min_initial_inliers, 8);
    EXPECT_EQ(p.verification.min_inliers, 30);
    EXPECT_EQ(p.neighbourhood_keyframes, 2);
    EXPECT_LT(p.tentative_min_inliers, p.verification.min_inliers);
  }
}

TEST(SensorPreset, GuessesTheSimulatedSensors)
{
  const struct
  {
    SensorModel model;
    SensorPreset expected;
  } cases[] = {{SensorModel::kHdl64, SensorPreset::kHdl64},
               {SensorModel::kVlp16, SensorPreset::kVlp16},
               {SensorModel::kOs1_64, SensorPreset::kHdl64}, // same settings
               {SensorModel::kOs0_128, SensorPreset::kOs0_128},
               // 32 beams 1.33 deg apart: the car-mounted defaults (doc/odometry.md,
               // "A 32-beam sensor").
               {SensorModel::kHdl32, SensorPreset::kHdl64}};
  for (const auto& c : cases) {
    const SensorGuess guess = guessSensorPreset(simulatedScan(c.model));
    EXPECT_EQ(guess.preset, c.expected)
        << "simulated model " << static_cast<int>(c.model) << ": " << guess.reason;
    std::cout << "model " << static_cast<int>(c.model) << ": " << toString(guess.preset)
              << " (" << guess.reason << "; spacing " << guess.beam_spacing_deg << ", span "
              << guess.vertical_span_deg << ", tilt " << guess.ground_tilt_deg << ")\n";
  }
  // Too little to tell: the defaults, said so.
  const SensorGuess empty = guessSensorPreset(pcl::PointCloud<pcl::PointXYZI>());
  EXPECT_EQ(empty.preset, SensorPreset::kHdl64);
  EXPECT_NE(empty.reason.find("too few"), std::string::npos);
}

TEST(SensorPreset, GuessesRealKittiAsHdl64)
{
  PCL_RAST_REQUIRE_SHARED_DATA(data);
  SequenceReader reader((data / "kitti-raw-22").string());
  const SensorGuess guess = guessSensorPreset(*reader.read(0).cloud);
  EXPECT_EQ(guess.preset, SensorPreset::kHdl64) << guess.reason;
  std::cout << "kitti-raw-22: " << guess.reason << " (spacing " << guess.beam_spacing_deg
            << ", span " << guess.vertical_span_deg << ", tilt " << guess.ground_tilt_deg << ")\n";
}

/// The real scan pair is an HDL-32E (beams 1.33 deg apart): 32 beams keep the defaults,
/// which register it within 5 cm and 0.2 deg of the reference (the 16-beam preset: 4.6
/// cm, 0.36 deg).
TEST(SensorPreset, GuessesRealHdl32AsDenseEnoughForTheDefaults)
{
  PCL_RAST_REQUIRE_SHARED_DATA(data);
  for (const char* set : {"scan-pair-pcd", "scan-pair-ply"}) {
    SequenceReader reader((data / set).string());
    const SensorGuess guess = guessSensorPreset(*reader.read(0).cloud);
    EXPECT_GT(guess.beam_spacing_deg, 1.2) << set;
    EXPECT_LT(guess.beam_spacing_deg, 1.5) << set;
    EXPECT_EQ(guess.preset, SensorPreset::kHdl64) << set << ": " << guess.reason;
  }
}

} // namespace

} // namespace test_sensor_preset
