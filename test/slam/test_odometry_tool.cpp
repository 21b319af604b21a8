/// \file test_odometry_tool.cpp
/// \brief The command-line contract of pcl_rast_odometry: files written (one pose per
/// input frame, first pose identity), timing.csv columns, unreadable frames skipped
/// with the constant-velocity pose, exit codes on bad arguments.

#include "test_data.h"
#include "tracking_report.h"

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <fstream>
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>
#include <pcl/io/pose_io.h>
#include <pcl/io/sequence_reader.h>
#include <pcl/simulation/lidar_simulator.h>
#include <sstream>
#include <string>
#include <sys/wait.h>
#include <vector>

// This file's names stay its own: a test program compiles several test files as
// one translation unit (test/CMakeLists.txt).
namespace test_odometry_tool {

namespace {

namespace fs = std::filesystem;

int
runOdometry(const std::string& args, const fs::path& log)
{
  return pcl_rast_test::runTool("pcl_rast_odometry", args, log);
}

std::vector<std::string>
readLines(const fs::path& path)
{
  std::ifstream in(path);
  std::vector<std::string> lines;
  for (std::string line; std::getline(in, line);)
    if (!line.empty())
      lines.push_back(line);
  return lines;
}

std::string
readAll(const fs::path& path)
{
  std::ifstream in(path);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

class OdometryTool : public ::testing::Test
{
protected:
  void
  SetUp() override
  {
    if (!fs::exists(pcl_rast_test::toolPath("pcl_rast_odometry")))
      FAIL() << "pcl_rast_odometry is not built: build the tools target first";
    dir_ = pcl_rast_test::makeTempDir("odometry_tool");
    log_ = dir_ / "log.txt";
  }
  /// A 12-frame simulated HDL-64 sequence (KITTI layout with times.txt).
  fs::path
  sequence()
  {
    const fs::path seq = dir_ / "seq";
    rast_params_.seed = 3;
    rast_params_.num_threads = 2;
    pcl::rast::PathParams path;
    path.type = pcl::rast::PathType::kStraight;
    path.num_frames = 12;
    pcl::rast::LidarSimulator sim(rast_params_, pcl::rast::generatePath(path));
    sim.writeSequence(seq.string(), pcl::rast::ScanFormat::kBin, 0, 11);
    return seq;
  }
  fs::path dir_, log_;
  pcl::rast::LidarSimulatorParams rast_params_;
};

TEST_F(OdometryTool, WritesPosesAndTimingForEveryFrame)
{
  const fs::path seq = sequence();
  // An unreadable frame in the middle: skipped, constant-velocity pose, reported.
  std::ofstream(seq / "velodyne" / "000005.bin") << "garbage";
  const fs::path out = dir_ / "out";
  ASSERT_EQ(runOdometry("-input '" + seq.string() + "' -output '" + out.string() + "'", log_), 0)
      << readAll(log_);
  const std::string log = readAll(log_);
  EXPECT_NE(log.find("000005.bin"), std::string::npos) << log;
  EXPECT_NE(log.find("Odometry: 100%"), std::string::npos) << log; // the progress bar

  const auto kitti = pcl::rast::readTrajectory((out / "poses_kitti.txt").string());
  ASSERT_EQ(kitti.poses.size(), 12u);
  EXPECT_TRUE(kitti.poses[0].isApprox(pcl::rast::Pose3d::Identity(), 1e-9));
  const auto gt = pcl::rast::readTrajectory((seq / "poses.txt").string());
  for (std::size_t i = 0; i < 12; ++i)
    EXPECT_LT((kitti.poses[i].translation() - gt.poses[i].translation()).norm(), 0.1) << i;

  const auto tum = pcl::rast::readTrajectory((out / "poses_tum.txt").string());
  ASSERT_EQ(tum.poses.size(), 12u);
  const auto times = readLines(seq / "times.txt");
  ASSERT_EQ(times.size(), 12u);
  EXPECT_NEAR(tum.timestamps_s[7], std::stod(times[7]), 1e-6);

  const auto timing = readLines(out / "timing.csv");
  ASSERT_EQ(timing.size(), 13u);
  EXPECT_EQ(timing[0].rfind("frame,status,ground_ms,raster_ms,orb_ms,match_ms,refine_ms,"
                            "keyframe_ms,total_ms,num_features,num_inliers,keyframe",
                            0),
            0u)
      << timing[0];
  EXPECT_EQ(timing[1].rfind("0,first_frame,", 0), 0u) << timing[1];
  EXPECT_EQ(timing[6].rfind("5,skipped,", 0), 0u) << timing[6];
  EXPECT_EQ(timing[7].rfind("6,features,", 0), 0u) << timing[7];
  for (const auto& row : timing)
    EXPECT_EQ(std::count(row.begin(), row.end(), ','), std::count(timing[0].begin(), timing[0].end(), ','));
  const auto summary = nlohmann::json::parse(readAll(out / "summary.json"));
  EXPECT_EQ(summary["frames"].get<int>(), 12);
  EXPECT_EQ(summary["frames_tracked"].get<int>(), 11);
  EXPECT_TRUE(summary["error"].is_null());
  EXPECT_LE(summary["max_rotation_error"].get<double>(), 1e-9);
  // summary.json counts timing.csv's degraded rows (column 12), skipped scans left out;
  // a street tracked by features has no degraded stretch to warn about.
  int degraded_rows = 0;
  for (std::size_t k = 1; k < timing.size(); ++k) {
    std::vector<std::string> cells;
    std::stringstream row(timing[k]);
    for (std::string cell; std::getline(row, cell, ',');)
      cells.push_back(cell);
    ASSERT_GT(cells.size(), 12u) << timing[k];
    degraded_rows += cells[1] != "skipped" && cells[12] == "1";
  }
  EXPECT_EQ(summary["degraded_frames"].get<int>(), degraded_rows);
  EXPECT_LT(summary["longest_degraded_stretch"]["frames"].get<std::size_t>(),
            pcl_rast_tools::kDegradedStretchWarnFrames);
  EXPECT_EQ(readAll(log_).find("tracked degraded"), std::string::npos) << readAll(log_);
  // Atomic writes leave no temporaries behind.
  for (const auto& entry : fs::directory_iterator(out)) {
    const std::string ext = entry.path().extension().string();
    EXPECT_TRUE(ext == ".csv" || ext == ".txt" || ext == ".json") << entry.path();
  }
}

/// The look-ahead (the next scan prepared on a second thread) is on by default; it
/// changes no pose, and an unreadable scan ahead is simply not prepared.
TEST_F(OdometryTool, TheLookAheadChangesNoPose)
{
  const fs::path seq = sequence();
  std::ofstream(seq / "velodyne" / "000005.bin") << "garbage";
  const fs::path with = dir_ / "with", without = dir_ / "without";
  const std::string in = "-input '" + seq.string() + "' -output '";
  ASSERT_EQ(runOdometry(in + with.string() + "'", log_), 0) << readAll(log_);
  ASSERT_EQ(runOdometry(in + without.string() + "' -no-lookahead -quiet", log_), 0)
      << readAll(log_);
  // -quiet: no progress bar; the skipped scan is still reported.
  EXPECT_EQ(readAll(log_).find("Odometry:"), std::string::npos) << readAll(log_);
  EXPECT_NE(readAll(log_).find("000005.bin"), std::string::npos) << readAll(log_);
  EXPECT_EQ(readAll(with / "poses_kitti.txt"), readAll(without / "poses_kitti.txt"));
  EXPECT_TRUE(nlohmann::json::parse(readAll(with / "summary.json"))["params"]["lookahead"]
                  .get<bool>());
  EXPECT_FALSE(
      nlohmann::json::parse(readAll(without / "summary.json"))["params"]["lookahead"]
          .get<bool>());
  // timing.csv's last column: prepared ahead or not.
  const auto ahead = [](const fs::path& out) {
    std::string flags;
    for (const auto& row : readLines(out / "timing.csv"))
      flags += row.substr(row.rfind(',') + 1);
    return flags;
  };
  // Frame 0 has no frame before it, 5 is unreadable, 6 follows it.
  EXPECT_EQ(ahead(with), "extracted_ahead011110011111");
  EXPECT_EQ(ahead(without), "extracted_ahead000000000000");

  // With no features wanted (-features-every 0), look-ahead or not: the same poses, and
  // summary.json counts the frames tracked without them.
  const fs::path none_with = dir_ / "none_with", none_without = dir_ / "none_without";
  ASSERT_EQ(runOdometry(in + none_with.string() + "' -features-every 0 -quiet", log_), 0)
      << readAll(log_);
  ASSERT_EQ(
      runOdometry(in + none_without.string() + "' -features-every 0 -no-lookahead -quiet",
                  log_),
      0)
      << readAll(log_);
  EXPECT_EQ(readAll(none_with / "poses_kitti.txt"),
            readAll(none_without / "poses_kitti.txt"));
  const auto features = [](const fs::path& out) {
    return nlohmann::json::parse(readAll(out / "summary.json"))["features"];
  };
  EXPECT_EQ(features(with)["every"].get<int>(), 1);
  EXPECT_EQ(features(with)["frames_without"].get<int>(), 0);
  EXPECT_EQ(features(none_with)["every"].get<int>(), 0);
  EXPECT_EQ(features(none_with)["frames_without"].get<int>(),
            features(none_without)["frames_without"].get<int>());
  // The weak dense steps after failed features: on by default, recorded.
  EXPECT_EQ(nlohmann::json::parse(readAll(
                none_with / "summary.json"))["params"]["failed_features_skip_frames"]
                .get<int>(),
            3);
}

TEST_F(OdometryTool, AnErrorMidRunStillWritesTheFramesBeforeItAndExitsThree)
{
  const fs::path seq = sequence();
  const fs::path out = dir_ / "out";
  ::setenv("PCL_RAST_INJECT_FAULT", "tracking:7", 1);
  const int rc = runOdometry("-input '" + seq.string() + "' -output '" + out.string() + "'", log_);
  ::unsetenv("PCL_RAST_INJECT_FAULT");
  ASSERT_EQ(rc, 3) << readAll(log_);
  EXPECT_NE(readAll(log_).find("injected fault"), std::string::npos) << readAll(log_);
  EXPECT_EQ(pcl::rast::readTrajectory((out / "poses_kitti.txt").string()).poses.size(), 7u);
  EXPECT_EQ(pcl::rast::readTrajectory((out / "poses_tum.txt").string()).poses.size(), 7u);
  EXPECT_EQ(readLines(out / "timing.csv").size(), 8u);
  const auto summary = nlohmann::json::parse(readAll(out / "summary.json"));
  EXPECT_EQ(summary["frames"].get<int>(), 7);
  EXPECT_NE(summary["error"].get<std::string>().find("injected fault (PCL_RAST_INJECT_FAULT="
                                                     "tracking:7)"),
            std::string::npos)
      << summary.dump();

  // A malformed fault is refused before any work.
  const fs::path out2 = dir_ / "out2";
  ::setenv("PCL_RAST_INJECT_FAULT", "loop_closing:x", 1);
  EXPECT_EQ(runOdometry("-input '" + seq.string() + "' -output '" + out2.string() + "'", log_), 1);
  ::unsetenv("PCL_RAST_INJECT_FAULT");
  EXPECT_NE(readAll(log_).find("PCL_RAST_INJECT_FAULT"), std::string::npos) << readAll(log_);
}

TEST_F(OdometryTool, FrameSelection)
{
  const fs::path seq = sequence();
  const fs::path out = dir_ / "out";
  ASSERT_EQ(runOdometry("-input '" + seq.string() + "' -output '" + out.string() +
                            "' -first 2 -last 10 -stride 4 -sensor hdl64",
                        log_),
            0)
      << readAll(log_);
  EXPECT_EQ(readLines(out / "poses_kitti.txt").size(), 3u);
  EXPECT_EQ(readLines(out / "timing.csv").size(), 4u);
}

TEST_F(OdometryTool, BadArgumentsExitOneBeforeAnyWork)
{
  const fs::path out = dir_ / "out";
  const std::string io = " -output '" + out.string() + "'";
  EXPECT_EQ(runOdometry("-input /nonexistent/folder" + io, log_), 1);
  EXPECT_EQ(runOdometry(io, log_), 1); // -input missing
  EXPECT_EQ(runOdometry("-input . -output '" + out.string() + "' -bogus 3", log_), 1);
  EXPECT_EQ(runOdometry("-input . -output '" + out.string() + "' -stride 0", log_), 1);
  EXPECT_EQ(runOdometry("-input . -output '" + out.string() + "' -sensor lidar9000", log_), 1);
  EXPECT_EQ(runOdometry("-input . -output '" + out.string() + "' -keyframe-min-frames 0", log_),
            1);
  EXPECT_EQ(runOdometry("-input . -output '" + out.string() + "' -max-features abc", log_), 1);
  EXPECT_EQ(runOdometry("-input . -output '" + out.string() + "' -deskew sometimes", log_), 1);
  EXPECT_EQ(runOdometry("-input . -output '" + out.string() + "' -deskew-reference 400", log_), 1);
  EXPECT_NE(readAll(log_).find("-deskew-reference must be within +-360 deg, got 400"),
            std::string::npos)
      << readAll(log_);
  EXPECT_EQ(runOdometry("-input . -output '" + out.string() + "' -degeneracy-support -1", log_),
            1);
  EXPECT_NE(readAll(log_).find("degeneracy_min_support must be finite and >= 0, got -1"),
            std::string::npos)
      << readAll(log_);
  EXPECT_EQ(runOdometry("-input . -output '" + out.string() + "' -map-nearer -0.1", log_),
            1);
  EXPECT_NE(readAll(log_).find("map_nearer_ratio must be in [0, 1], got -0.1"),
            std::string::npos)
      << readAll(log_);
  EXPECT_EQ(runOdometry("-input . -output '" + out.string() + "' -weak-feature-share 1.5",
                        log_),
            1);
  EXPECT_NE(readAll(log_).find("weak_feature_share must be in [0, 1], got 1.5"),
            std::string::npos)
      << readAll(log_);
  EXPECT_EQ(runOdometry(
                "-input . -output '" + out.string() + "' -failed-features-skip -2", log_),
            1);
  EXPECT_NE(readAll(log_).find("failed_features_skip_frames must be >= 0, got -2"),
            std::string::npos)
      << readAll(log_);
  EXPECT_EQ(
      runOdometry("-input . -output '" + out.string() + "' -features-every -1", log_), 1);
  EXPECT_NE(readAll(log_).find("-features-every -1 (>= 0)"), std::string::npos)
      << readAll(log_);
  EXPECT_FALSE(fs::exists(out)) << "bad arguments must fail before any work";
  EXPECT_EQ(runOdometry("-h", log_), 0);
  EXPECT_NE(readAll(log_).find("-keyframe-min-frames"), std::string::npos);
  EXPECT_NE(readAll(log_).find("-deskew <auto|on|off>"), std::string::npos) << readAll(log_);
}

/// The real HDL-32E scan pair through the CLI with its defaults (-sensor auto): within
/// 5 cm and 0.2 deg of relative.txt, as through the library (the guess used to pick the
/// 16-beam preset: 4.6 cm, 0.36 deg).
TEST_F(OdometryTool, RealScanPairWithTheDefaults)
{
  PCL_RAST_REQUIRE_SHARED_DATA(data);
  const fs::path out = dir_ / "out";
  ASSERT_EQ(runOdometry("-input '" + (data / "scan-pair-pcd").string() + "' -output '" +
                            out.string() + "'",
                        log_),
            0)
      << readAll(log_);
  EXPECT_NE(readAll(log_).find("Sensor preset hdl64"), std::string::npos) << readAll(log_);
  const auto poses = pcl::rast::readTrajectory((out / "poses_kitti.txt").string()).poses;
  ASSERT_EQ(poses.size(), 2u);
  std::ifstream in(data / "scan-pair-pcd" / "relative.txt");
  Eigen::Matrix4d M;
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 4; ++c)
      in >> M(r, c);
  pcl::rast::Pose3d reference(M);
  const pcl::rast::Pose3d error = reference.inverse() * poses[0].inverse() * poses[1];
  const double angle_deg = Eigen::AngleAxisd(error.linear()).angle() * 180.0 / M_PI;
  std::cout << "[ scan-pair-pcd, CLI ] " << 100.0 * error.translation().norm() << " cm, "
            << angle_deg << " deg\n";
  EXPECT_LE(error.translation().norm(), 0.05);
  EXPECT_LE(angle_deg, 0.2);
}

/// -deskew: auto leaves .bin scans (no time field) as they are; on compensates them
/// with times from the azimuth; the choice and the counts are in summary.json and
/// timing.csv. (The last run also turns the elevation self-calibration off.)
TEST_F(OdometryTool, DeskewModeIsChosenAndReported)
{
  const fs::path seq = sequence();
  for (const std::string mode : {"auto", "on", "off"}) {
    const fs::path out = dir_ / ("out_" + mode);
    const bool calibration = mode != "off";
    ASSERT_EQ(runOdometry("-input '" + seq.string() + "' -output '" + out.string() +
                              "' -deskew " + mode +
                              (calibration ? "" : " -no-elevation-calibration"),
                          log_),
              0)
        << readAll(log_);
    const auto summary = nlohmann::json::parse(readAll(out / "summary.json"));
    EXPECT_EQ(summary["elevation_calibration"]["enabled"].get<bool>(), calibration);
    const auto& deskew = summary["deskew"];
    EXPECT_EQ(deskew["mode"].get<std::string>(), mode);
    const auto timing = readLines(out / "timing.csv");
    ASSERT_EQ(timing.size(), 13u);
    EXPECT_NE(timing[0].find(",deskew_ms,deskew,degenerate_directions"), std::string::npos)
        << timing[0];
    EXPECT_EQ(summary["frames_with_degenerate_directions"].get<int>(), 0); // a street
    // The sweep period from times.txt (0.1 s), not the frame interval.
    EXPECT_NE(deskew["timing"].get<std::string>().find("sweep period 0.100000 s (times.txt)"),
              std::string::npos)
        << deskew.dump();
    if (mode == "on") {
      // Every frame gets azimuth times (before two poses there is no motion to apply).
      EXPECT_EQ(deskew["frames_by_time_source"]["azimuth"].get<int>(), 12);
      EXPECT_NE(timing[5].find(",azimuth"), std::string::npos) << timing[5];
    } else {
      EXPECT_TRUE(deskew["frames_by_time_source"].empty()) << deskew.dump();
      EXPECT_NE(timing[5].find(",none"), std::string::npos) << timing[5];
    }
  }
  // Every other frame of a 10 Hz sequence: still a 0.1 s sweep. Without times.txt the
  // timestamps are file indices, taken as 10 Hz sweeps.
  auto deskewTiming = [&](const std::string& name, const std::string& flags) {
    const fs::path out = dir_ / name;
    EXPECT_EQ(runOdometry("-input '" + seq.string() + "' -output '" + out.string() + "' " + flags,
                          log_),
              0)
        << readAll(log_);
    return nlohmann::json::parse(readAll(out / "summary.json"))["deskew"]["timing"]
        .get<std::string>();
  };
  EXPECT_NE(deskewTiming("strided", "-deskew on -stride 2").find("sweep period 0.100000 s (times.txt)"),
            std::string::npos);
  fs::remove(seq / "times.txt");
  EXPECT_NE(deskewTiming("no_times", "-deskew on").find("no times.txt"), std::string::npos);
  const fs::path no_times = dir_ / "no_times";
  EXPECT_EQ(runOdometry("-input '" + seq.string() + "' -output '" + no_times.string() +
                            "' -deskew-period 2",
                        log_),
            1);
}

} // namespace

} // namespace test_odometry_tool
