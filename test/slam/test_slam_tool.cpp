/// The pcl_rast_slam command-line contract: output files, line counts, summary keys,
/// corrupt scans skipped and listed, and clear errors (exit codes) on bad arguments.

#include "simulated_drive.h"
#include "test_data.h"

#include <filesystem>
#include <fstream>
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>
#include <pcl/io/pcd_io.h>
#include <pcl/io/pose_io.h>
#include <pcl/simulation/lidar_simulator.h>
#include <pcl/slam/session.h>
#include <pcl/slam/session_localizer.h>
#include <sys/wait.h>
#include <unistd.h>

// This file's names stay its own: a test program compiles several test files as
// one translation unit (test/CMakeLists.txt).
namespace test_slam_tool {

namespace {

namespace fs = std::filesystem;

int
runTool(const std::string& args, const fs::path& log)
{
  return pcl_rast_test::runTool("pcl_rast_slam", args, log);
}

std::size_t
countLines(const fs::path& path)
{
  std::ifstream in(path);
  std::size_t n = 0;
  for (std::string line; std::getline(in, line);)
    n += !line.empty() && line[0] != '#';
  return n;
}

using pcl_rast_test::readFile;

/// A 40-frame straight HDL-64 drive written once, frame 12 truncated (corrupt).
const fs::path&
sequenceDir()
{
  static const fs::path dir = [] {
    const fs::path d = pcl_rast_test::simulateStraightDrive("slam_tool_sequence");
    fs::resize_file(d / "velodyne" / "000012.bin", 10); // not a multiple of 16 bytes
    return d;
  }();
  return dir;
}

class SlamTool : public ::testing::Test
{
protected:
  void SetUp() override
  {
    if (!fs::exists(pcl_rast_test::toolPath("pcl_rast_slam")))
      FAIL() << "pcl_rast_slam is not built";
    dir_ = pcl_rast_test::makeTempDir("slam_tool");
    log_ = dir_ / "log.txt";
  }
  fs::path dir_, log_;
};

TEST_F(SlamTool, WritesEveryOutputWithTheContractedContent)
{
  const fs::path out = dir_ / "out";
  const fs::path seq = sequenceDir();
  const int rc = runTool("-input '" + seq.string() + "' -output '" + out.string() + "' -gt '" +
                             (seq / "poses.txt").string() + "' -software-render",
                         log_);
  ASSERT_EQ(rc, 0) << readFile(log_);
  for (const char* f : {"poses_kitti.txt", "poses_tum.txt", "map.pcd", "render.png", "summary.json"})
    EXPECT_TRUE(fs::exists(out / f)) << f;
  EXPECT_EQ(countLines(out / "poses_kitti.txt"), 40u);
  EXPECT_EQ(countLines(out / "poses_tum.txt"), 40u);
  const pcl::rast::Trajectory kitti = pcl::rast::readTrajectory((out / "poses_kitti.txt").string());
  EXPECT_TRUE(kitti.poses.front().isApprox(pcl::rast::Pose3d::Identity(), 1e-6));
  const pcl::rast::Trajectory tum = pcl::rast::readTrajectory((out / "poses_tum.txt").string());
  EXPECT_NEAR(tum.timestamps_s[1] - tum.timestamps_s[0], 0.1, 1e-6); // from times.txt

  pcl::PointCloud<pcl::PointXYZI> map;
  ASSERT_EQ(pcl::io::loadPCDFile((out / "map.pcd").string(), map), 0);
  EXPECT_GT(map.size(), 1000u);

  const auto summary = nlohmann::json::parse(readFile(out / "summary.json"));
  for (const char* key : {"frames",
                          "skipped_frames",
                          "keyframes",
                          "loops_accepted",
                          "loops_rejected",
                          "timing_ms",
                          "wall_s",
                          "fps",
                          "peak_rss_mb",
                          "ate_rmse_m",
                          "kitti_t_err_pct",
                          "kitti_r_err_deg_per_100m",
                          "degraded_frames",
                          "longest_degraded_stretch"})
    EXPECT_TRUE(summary.contains(key)) << key;
  EXPECT_LE(summary["longest_degraded_stretch"]["frames"].get<int>(),
            summary["degraded_frames"].get<int>());
  EXPECT_EQ(summary["frames"].get<int>(), 40);
  ASSERT_EQ(summary["skipped_frames"].size(), 1u);
  EXPECT_EQ(summary["skipped_frames"][0]["frame"].get<int>(), 12);
  EXPECT_NE(summary["skipped_frames"][0]["path"].get<std::string>().find("000012.bin"),
            std::string::npos);
  EXPECT_FALSE(summary["skipped_frames"][0]["reason"].get<std::string>().empty());
  for (const char* stage : {"tracking", "local_mapping", "loop_detection"})
    for (const char* stat : {"mean", "median", "max"})
      EXPECT_TRUE(summary["timing_ms"][stage].contains(stat)) << stage << " " << stat;
  EXPECT_TRUE(summary["kitti_t_err_pct"].is_null()); // 39 m: no 100 m segment
  EXPECT_LT(summary["ate_rmse_m"].get<double>(), 1.0);
  // No temporary files left behind.
  for (const auto& entry : fs::directory_iterator(out))
    EXPECT_EQ(entry.path().string().find(".tmp"), std::string::npos) << entry.path();
}

TEST_F(SlamTool, GroundTruthOfWrongLengthIsAnErrorBeforeAnyWork)
{
  const fs::path seq = sequenceDir();
  const pcl::rast::Trajectory gt = pcl::rast::readTrajectory((seq / "poses.txt").string());
  pcl::rast::PoseVector shorter(gt.poses.begin(), gt.poses.end() - 3);
  pcl::rast::writeKittiPoses((dir_ / "short.txt").string(), shorter);
  const fs::path out = dir_ / "out";
  EXPECT_EQ(runTool("-input '" + seq.string() + "' -output '" + out.string() + "' -gt '" +
                        (dir_ / "short.txt").string() + "'",
                    log_),
            1);
  EXPECT_NE(readFile(log_).find("37"), std::string::npos) << readFile(log_);
  EXPECT_FALSE(fs::exists(out / "summary.json"));
}

TEST_F(SlamTool, UnwritableOutputIsAnIoError)
{
  std::ofstream(dir_ / "a_file") << "x";
  const fs::path out = dir_ / "a_file" / "out"; // a folder below a regular file
  EXPECT_EQ(runTool("-input '" + sequenceDir().string() + "' -output '" + out.string() + "'",
                    log_),
            2);
  EXPECT_NE(readFile(log_).find("out"), std::string::npos);
}

TEST_F(SlamTool, UnknownFlagAndMissingOutputAreArgumentErrors)
{
  EXPECT_EQ(runTool("-input '" + sequenceDir().string() + "' -output '" + dir_.string() +
                        "/o' -no-such-flag",
                    log_),
            1);
  EXPECT_NE(readFile(log_).find("no-such-flag"), std::string::npos);
  EXPECT_EQ(runTool("-input '" + sequenceDir().string() + "'", log_), 1);
  EXPECT_EQ(runTool("-input '" + sequenceDir().string() + "' -output '" + dir_.string() +
                        "/o' -stride 0",
                    log_),
            1);
  // A flag's bad value: exit 1, naming the flag and the value.
  const auto rejects = [&](const std::string& flag, const std::string& message) {
    EXPECT_EQ(runTool("-input '" + sequenceDir().string() + "' -output '" +
                          dir_.string() + "/o' " + flag,
                      log_),
              1)
        << flag;
    EXPECT_NE(readFile(log_).find(message), std::string::npos) << readFile(log_);
  };
  rejects("-young-map-scans 0", "-young-map-scans must be >= 1, got 0");
  rejects("-degeneracy-support -2",
          "-degeneracy-support must be finite and >= 0, got -2");
  rejects("-map-nearer 1.5", "-map-nearer must be in [0, 1], got 1.5");
  rejects("-weak-feature-share 2", "-weak-feature-share must be in [0, 1], got 2");
  rejects("-visibility-margin -0.5",
          "-visibility-margin must be finite and >= 0, got -0.5");
  EXPECT_FALSE(std::filesystem::exists(dir_ / "o" / "summary.json")) << "no work before the check";
  EXPECT_EQ(runTool("-h", log_), 0);
  EXPECT_NE(readFile(log_).find("-map-leaf"), std::string::npos);
  EXPECT_NE(readFile(log_).find("-no-revisit-culling"), std::string::npos);
}

/// -visibility-margin (issue 10, off by default) and -no-elevation-calibration are handed
/// to the SLAM's odometry as to pcl_rast_odometry's: the summary records the odometry
/// parameters the run was made with.
TEST_F(SlamTool, TheVisibilityMarginIsHandedToTheOdometry)
{
  const fs::path out = dir_ / "out";
  const fs::path seq = sequenceDir();
  ASSERT_EQ(runTool("-input '" + seq.string() + "' -output '" + out.string() + "' -gt '" +
                        (seq / "poses.txt").string() +
                        "' -software-render -visibility-margin 1",
                    log_),
            0)
      << readFile(log_);
  const auto summary = nlohmann::json::parse(readFile(out / "summary.json"));
  EXPECT_EQ(summary["params"]["visibility_margin_m"].get<double>(), 1.0);
  EXPECT_EQ(summary["frames"].get<int>(), 40);
  EXPECT_LT(summary["ate_rmse_m"].get<double>(), 1.0);
  // The calibration is on (the hdl64 preset), but 40 frames are fewer than its first
  // window of 50: nothing corrected yet.
  EXPECT_TRUE(summary["elevation_calibration"]["enabled"].get<bool>());
  EXPECT_EQ(summary["elevation_calibration"]["updates"].get<int>(), 0);
  EXPECT_TRUE(summary["elevation_calibration"]["corrections"].empty());
  ASSERT_EQ(runTool("-input '" + seq.string() + "' -output '" + out.string() +
                        "' -software-render -last 3 -no-elevation-calibration",
                    log_),
            0)
      << readFile(log_);
  const auto summary2 = nlohmann::json::parse(readFile(out / "summary.json"));
  EXPECT_EQ(summary2["params"]["visibility_margin_m"].get<double>(), 0.0)
      << "off by default";
  EXPECT_FALSE(summary2["elevation_calibration"]["enabled"].get<bool>());
}

/// -features-on-demand: recorded in the summary with the frames that skipped their
/// features; off by default, where no frame skips them.
TEST_F(SlamTool, FeaturesOnDemandAreCountedInTheSummary)
{
  const fs::path seq = sequenceDir();
  const std::string in = "-input '" + seq.string() + "' -gt '" +
                         (seq / "poses.txt").string() + "' -software-render -output '";
  const fs::path on = dir_ / "on", off = dir_ / "off";
  ASSERT_EQ(runTool(in + on.string() + "' -features-on-demand", log_), 0)
      << readFile(log_);
  ASSERT_EQ(runTool(in + off.string() + "'", log_), 0) << readFile(log_);
  const auto with = nlohmann::json::parse(readFile(on / "summary.json"));
  const auto without = nlohmann::json::parse(readFile(off / "summary.json"));
  EXPECT_TRUE(with["params"]["features_on_demand"].get<bool>());
  EXPECT_FALSE(without["params"]["features_on_demand"].get<bool>());
  EXPECT_GT(with["frames_without_features"].get<int>(), 0);
  EXPECT_LT(with["frames_without_features"].get<int>(), with["frames"].get<int>());
  EXPECT_EQ(without["frames_without_features"].get<int>(), 0);
  EXPECT_LT(with["ate_rmse_m"].get<double>(), 1.0);
}

/// The next scan prepared on a second thread (the default): in deterministic mode the
/// run is the same without it, file for file; the sequence's corrupt frame 12 is not
/// prepared ahead.
TEST_F(SlamTool, TheLookAheadChangesNoPose)
{
  const fs::path seq = sequenceDir();
  const std::string in =
      "-input '" + seq.string() + "' -threads off -software-render -output '";
  const fs::path with = dir_ / "with", without = dir_ / "without";
  ASSERT_EQ(runTool(in + with.string() + "'", log_), 0) << readFile(log_);
  ASSERT_EQ(runTool(in + without.string() + "' -no-lookahead", log_), 0)
      << readFile(log_);
  EXPECT_EQ(readFile(with / "poses_kitti.txt"), readFile(without / "poses_kitti.txt"));
  EXPECT_FALSE(readFile(with / "poses_kitti.txt").empty());
  EXPECT_TRUE(
      nlohmann::json::parse(readFile(with / "summary.json"))["params"]["lookahead"]
          .get<bool>());
  EXPECT_FALSE(
      nlohmann::json::parse(readFile(without / "summary.json"))["params"]["lookahead"]
          .get<bool>());
}

/// -save-session: the run's map saved as a session that loads back with the run's
/// key-frames and sensor preset; a folder that is not a session is refused before any
/// work, and a session folder is replaced by the next run.
TEST_F(SlamTool, SavesASessionAndRefusesAFolderThatIsNotOne)
{
  const fs::path out = dir_ / "out";
  const fs::path session = dir_ / "session";
  const std::string common =
      "-input '" + sequenceDir().string() + "' -output '" + out.string() + "' -software-render";
  ASSERT_EQ(runTool(common + " -save-session '" + session.string() + "'", log_), 0)
      << readFile(log_);
  const nlohmann::json summary = nlohmann::json::parse(readFile(out / "summary.json"));
  ASSERT_TRUE(summary.contains("session")) << summary.dump(1);
  EXPECT_TRUE(summary["session"]["saved"].get<bool>());
  const pcl::rast::Session loaded = pcl::rast::loadSession(session.string());
  EXPECT_EQ(loaded.keyframes.size(), summary["keyframes"].get<std::size_t>());
  EXPECT_EQ(loaded.info.sensor_preset, summary["params"]["sensor"].get<std::string>());
  EXPECT_EQ(loaded.info.created_by, "pcl_rast_slam");
  EXPECT_EQ(loaded.info.num_frames, 40u);
  const std::string first_json = readFile(session / "session.json");

  // A folder of other files: exit 2 naming it, before any work, the folder untouched.
  const fs::path scans = dir_ / "scans";
  fs::create_directories(scans);
  std::ofstream(scans / "keep.txt") << "mine";
  const fs::path out2 = dir_ / "out2";
  EXPECT_EQ(runTool("-input '" + sequenceDir().string() + "' -output '" + out2.string() +
                        "' -save-session '" + scans.string() + "'",
                    log_),
            2);
  EXPECT_NE(readFile(log_).find(scans.string()), std::string::npos) << readFile(log_);
  EXPECT_EQ(readFile(scans / "keep.txt"), "mine");
  EXPECT_FALSE(fs::exists(out2 / "summary.json"));

  // The same session folder again: replaced by a complete session of the new run.
  ASSERT_EQ(runTool(common + " -last 19 -save-session '" + session.string() + "'", log_), 0)
      << readFile(log_);
  EXPECT_NE(readFile(session / "session.json"), first_json);
  EXPECT_EQ(pcl::rast::loadSession(session.string()).info.num_frames, 20u);
}

/// An exception in the loop-closing thread mid-run (injected at its second key-frame)
/// ends the run but does not lose it: every output is written for the frames processed,
/// summary.json names the error, and the exit code is 3.
/// A session's sensor preset sets the merge's placement thresholds: a VLP-16 session
/// places the drive's key-frames with its 8 / 30 inliers, not the HDL-64's 12 / 40.
/// (And -weak-feature-share reaches the odometry over the preset's.)
TEST_F(SlamTool, AMergePlacesWithTheSessionSensorsThresholds)
{
  const fs::path seq = sequenceDir();
  const fs::path first = dir_ / "first", second = dir_ / "second";
  const fs::path session = dir_ / "session";
  const std::string input = "-input '" + seq.string() + "' -software-render -quiet";
  ASSERT_EQ(runTool(input + " -last 14 -sensor vlp16 -output '" + first.string() +
                        "' -save-session '" + session.string() + "'",
                    log_),
            0)
      << readFile(log_);
  ASSERT_EQ(runTool(input + " -first 10 -last 19 -weak-feature-share 0.5 -output '" +
                        second.string() + "' -session '" + session.string() + "'",
                    log_),
            0)
      << readFile(log_);
  // The preset's odometry in the first run; a flag wins over it in the second.
  const auto first_summary = nlohmann::json::parse(readFile(first / "summary.json"));
  pcl::rast::OdometryParams vlp16_odometry;
  pcl::rast::applySensorPreset(pcl::rast::SensorPreset::kVlp16, vlp16_odometry);
  EXPECT_EQ(first_summary["params"]["weak_feature_share"],
            vlp16_odometry.weak_feature_share);
  const auto summary = nlohmann::json::parse(readFile(second / "summary.json"));
  EXPECT_EQ(summary["params"]["sensor"], "vlp16") << summary["params"].dump(1);
  EXPECT_EQ(summary["params"]["weak_feature_share"], 0.5);
  const auto& placement = summary["multi_session"]["placement"];
  pcl::rast::SessionLocalizerParams vlp16;
  pcl::rast::applySensorPreset(pcl::rast::SensorPreset::kVlp16, vlp16);
  const pcl::rast::SessionLocalizerParams defaults;
  ASSERT_NE(vlp16.verification.min_inliers, defaults.verification.min_inliers);
  EXPECT_EQ(placement["min_initial_inliers"], vlp16.verification.min_initial_inliers)
      << placement.dump(1);
  EXPECT_EQ(placement["min_inliers"], vlp16.verification.min_inliers)
      << placement.dump(1);
}

/// Multi-session mapping through the command line: frames 0-24 saved as a session, then
/// frames 15-39 extend it (-session); a drive of another world stays separate.
TEST_F(SlamTool, ExtendsASessionWithASecondDriveAndKeepsAStrangerSeparate)
{
  const fs::path seq = sequenceDir();
  const fs::path first = dir_ / "first", second = dir_ / "second", third = dir_ / "third";
  const fs::path session = dir_ / "session", merged = dir_ / "merged", apart = dir_ / "apart";
  const std::string input = "-input '" + seq.string() + "' -software-render -quiet";
  ASSERT_EQ(runTool(input + " -last 24 -output '" + first.string() + "' -save-session '" +
                        session.string() + "'",
                    log_),
            0)
      << readFile(log_);
  ASSERT_EQ(runTool(input + " -first 15 -output '" + second.string() + "' -session '" +
                        session.string() + "' -save-session '" + merged.string() + "'",
                    log_),
            0)
      << readFile(log_);
  const auto summary = nlohmann::json::parse(readFile(second / "summary.json"));
  ASSERT_TRUE(summary.contains("multi_session")) << summary.dump(1);
  const auto& ms = summary["multi_session"];
  EXPECT_TRUE(ms["connected"].get<bool>()) << ms.dump(1);
  EXPECT_GE(ms["loops_used"].get<int>(), 2) << ms.dump(1);
  EXPECT_EQ(summary["poses_frame"], "session");
  EXPECT_EQ(summary["params"]["sensor_choice"], "the session's");
  // The overlap, frames 15-24, lands where the first drive put it.
  const pcl::rast::PoseVector a =
      pcl::rast::readTrajectory((first / "poses_kitti.txt").string()).poses;
  const pcl::rast::PoseVector b =
      pcl::rast::readTrajectory((second / "poses_kitti.txt").string()).poses;
  ASSERT_EQ(a.size(), 25u); // frame 12 is corrupt: skipped, carried by the odometry
  ASSERT_EQ(b.size(), 25u);
  double worst_m = 0.0;
  for (std::size_t i = 15; i < 24; ++i)
    worst_m = std::max(worst_m, (a[i].translation() - b[i - 15].translation()).norm());
  EXPECT_LT(worst_m, 0.3) << "frames 15-23 of the two drives";
  // The merged session: both drives, one component; the map covers both.
  const pcl::rast::Session m = pcl::rast::loadSession(merged.string());
  ASSERT_EQ(m.drives.size(), 2u);
  EXPECT_EQ(m.drives[1].component, 0);
  EXPECT_EQ(m.keyframes.size(), ms["merged_keyframes"].get<std::size_t>());
  pcl::PointCloud<pcl::PointXYZI> map;
  ASSERT_EQ(pcl::io::loadPCDFile((second / "map.pcd").string(), map), 0);
  float max_x = -1e9f;
  for (const auto& p : map.points)
    max_x = std::max(max_x, p.x);
  EXPECT_GT(max_x, b.back().translation().x()) << "the map reaches the second drive's end";

  // A drive through another world: not joined, reported, poses in its own frame.
  const fs::path stranger = pcl_rast_test::simulateStraightDrive("slam_tool_stranger", 11);
  ASSERT_EQ(runTool("-input '" + stranger.string() + "' -software-render -quiet -output '" +
                        third.string() + "' -session '" + merged.string() +
                        "' -save-session '" + apart.string() + "'",
                    log_),
            0)
      << readFile(log_);
  const auto s3 = nlohmann::json::parse(readFile(third / "summary.json"));
  EXPECT_FALSE(s3["multi_session"]["connected"].get<bool>()) << s3["multi_session"].dump(1);
  EXPECT_EQ(s3["multi_session"]["component"], 1);
  EXPECT_EQ(s3["poses_frame"], "first_scan");
  EXPECT_NE(readFile(log_).find("not joined"), std::string::npos) << readFile(log_);
  const pcl::rast::Session m3 = pcl::rast::loadSession(apart.string());
  ASSERT_EQ(m3.drives.size(), 3u);
  EXPECT_EQ(m3.drives[2].component, 1);

  // Bad use, before any work: another sensor than the session's, the session as output.
  const fs::path bad = dir_ / "bad";
  EXPECT_EQ(runTool(input + " -output '" + bad.string() + "' -session '" + session.string() +
                        "' -sensor vlp16",
                    log_),
            2);
  EXPECT_NE(readFile(log_).find("hdl64"), std::string::npos) << readFile(log_);
  EXPECT_EQ(runTool(input + " -output '" + session.string() + "' -session '" +
                        session.string() + "'",
                    log_),
            1);
  EXPECT_EQ(runTool(input + " -output '" + bad.string() + "' -session '" + seq.string() + "'",
                    log_),
            2);
  EXPECT_NE(readFile(log_).find("session.json"), std::string::npos) << readFile(log_);
  EXPECT_FALSE(fs::exists(bad / "summary.json"));
}

TEST_F(SlamTool, AnErrorInTheLoopClosingThreadStillWritesEveryOutputAndExitsThree)
{
  const fs::path out = dir_ / "out";
  const fs::path seq = sequenceDir();
  ::setenv("PCL_RAST_INJECT_FAULT", "loop_closing:1", 1);
  const int rc = runTool("-input '" + seq.string() + "' -output '" + out.string() + "' -gt '" +
                             (seq / "poses.txt").string() + "' -software-render -quiet",
                         log_);
  ::unsetenv("PCL_RAST_INJECT_FAULT");
  ASSERT_EQ(rc, 3) << readFile(log_);
  for (const char* f : {"poses_kitti.txt", "poses_tum.txt", "map.pcd", "render.png", "summary.json"})
    EXPECT_TRUE(fs::exists(out / f)) << f;
  const auto summary = nlohmann::json::parse(readFile(out / "summary.json"));
  ASSERT_TRUE(summary["error"].is_string()) << summary.dump();
  EXPECT_NE(summary["error"].get<std::string>().find("injected fault (PCL_RAST_INJECT_FAULT="
                                                     "loop_closing:1)"),
            std::string::npos);
  const auto frames = summary["frames"].get<std::size_t>();
  EXPECT_GE(frames, 2u);
  EXPECT_LE(frames, 40u);
  EXPECT_GE(summary["keyframes"].get<int>(), 2);
  EXPECT_EQ(countLines(out / "poses_kitti.txt"), frames);
  EXPECT_EQ(countLines(out / "poses_tum.txt"), frames);
  EXPECT_LE(summary["max_rotation_error"].get<double>(), 1e-9);
  pcl::PointCloud<pcl::PointXYZI> map;
  ASSERT_EQ(pcl::io::loadPCDFile((out / "map.pcd").string(), map), 0);
  EXPECT_GT(map.size(), 1000u);
  EXPECT_NE(readFile(log_).find("injected fault"), std::string::npos);

  // The same run without the fault: exit 0 and a null error.
  ASSERT_EQ(runTool("-input '" + seq.string() + "' -output '" + out.string() +
                        "' -software-render -quiet",
                    log_),
            0)
      << readFile(log_);
  EXPECT_TRUE(nlohmann::json::parse(readFile(out / "summary.json"))["error"].is_null());
}

} // namespace

} // namespace test_slam_tool
