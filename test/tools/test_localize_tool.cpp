/// The pcl_rast_localize command line: a simulated drive mapped by pcl_rast_slam
/// -save-session and localized again from a later scan with no initial pose; bad
/// sessions and bad arguments refused before any work.

#include "simulated_drive.h"
#include "test_data.h"

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>
#include <pcl/io/pose_io.h>
#include <string>
#include <vector>

// This file's names stay its own: a test program compiles several test files as
// one translation unit (test/CMakeLists.txt).
namespace test_localize_tool {

namespace {

namespace fs = std::filesystem;
using pcl_rast_test::readFile;

std::string
quoted(const fs::path& p)
{
  return "'" + p.string() + "'";
}

/// The 40-frame straight drive and a session of it, made once per process.
struct Mapped
{
  fs::path scans, slam_out, session;
};

const Mapped&
mapped()
{
  static const Mapped m = [] {
    Mapped r;
    r.scans = pcl_rast_test::simulateStraightDrive("localize_tool_sequence");
    const fs::path dir = pcl_rast_test::makeTempDir("localize_tool_map");
    r.slam_out = dir / "slam";
    r.session = dir / "session";
    const int rc = pcl_rast_test::runTool(
        "pcl_rast_slam",
        "-input " + quoted(r.scans) + " -output " + quoted(r.slam_out) + " -save-session " +
            quoted(r.session) + " -software-render -quiet",
        dir / "slam_log.txt");
    if (rc != 0)
      ADD_FAILURE() << "pcl_rast_slam: " << readFile(dir / "slam_log.txt");
    return r;
  }();
  return m;
}

class LocalizeTool : public ::testing::Test
{
protected:
  void SetUp() override
  {
    if (!fs::exists(pcl_rast_test::toolPath("pcl_rast_localize")))
      FAIL() << "pcl_rast_localize is not built";
    dir_ = pcl_rast_test::makeTempDir("localize_tool");
    log_ = dir_ / "log.txt";
  }
  int run(const std::string& args)
  {
    return pcl_rast_test::runTool("pcl_rast_localize", args, log_);
  }
  fs::path dir_, log_;
};

TEST_F(LocalizeTool, LocalizesALaterStartWithNoInitialPose)
{
  const Mapped& m = mapped();
  const fs::path out = dir_ / "out";
  ASSERT_EQ(run("-session " + quoted(m.session) + " -input " + quoted(m.scans) + " -output " +
                quoted(out) + " -first 10 -software-render -quiet"),
            0)
      << readFile(log_);
  for (const char* f : {"poses_kitti.txt", "poses_tum.txt", "status.csv", "render.png",
                        "summary.json"})
    EXPECT_TRUE(fs::exists(out / f)) << f;
  const auto summary = nlohmann::json::parse(readFile(out / "summary.json"));
  EXPECT_EQ(summary["frames"].get<int>(), 30);
  EXPECT_EQ(summary["first_localized_frame"].get<int>(), 0) << "placed at the first scan";
  EXPECT_GE(summary["frames_localized"].get<int>(), 29);
  EXPECT_FALSE(summary["initial_pose_given"].get<bool>());
  EXPECT_TRUE(summary["jumps"].empty());
  EXPECT_EQ(summary["placement"]["min_inliers"].get<int>(), 40); // the hdl64 preset's
  EXPECT_EQ(summary["placement"]["min_initial_inliers"].get<int>(), 12);
  EXPECT_EQ(summary["placement"]["neighbourhood_keyframes"].get<int>(), 0);
  EXPECT_EQ(summary["placement"]["first_attempts"].get<int>(), 5);
  EXPECT_EQ(summary["placement"]["first_attempts_neighbourhood_keyframes"].get<int>(), 2);
  EXPECT_EQ(summary["placement"]["polar_candidates"].get<int>(), 3);
  EXPECT_EQ(summary["placement"]["backoff_after"].get<int>(), 20);
  EXPECT_TRUE(summary["placement"]["track_on_map"].get<bool>());
  EXPECT_TRUE(summary["lookahead"]["on"].get<bool>());
  EXPECT_TRUE(summary["odometry_features"]["on_demand"].get<bool>());
  EXPECT_EQ(summary["map_alignment"]["merged_keyframes_within_m"].get<double>(), 10.0);
  EXPECT_TRUE(summary["map_alignment"]["tracked_together"].get<bool>());
  EXPECT_EQ(summary["map_alignment"]["tracked_together_min_overlap_ratio"].get<double>(),
            0.5);
  EXPECT_TRUE(summary["map_alignment"]["degenerate_needs_tracked_odometry"].get<bool>());
  EXPECT_TRUE(summary["elevation_calibration"]["enabled"].get<bool>())
      << "hdl64's default";

  // In the map's frame: where the SLAM run put the same scans.
  const auto slam = pcl::rast::readTrajectory((m.slam_out / "poses_kitti.txt").string());
  const auto loc = pcl::rast::readTrajectory((out / "poses_kitti.txt").string());
  ASSERT_EQ(loc.poses.size(), 30u);
  for (std::size_t k = 0; k < loc.poses.size(); ++k)
    EXPECT_LT((loc.poses[k].translation() - slam.poses[10 + k].translation()).norm(), 0.15)
        << "frame " << 10 + k;

  // status.csv: a header and one row per frame.
  std::ifstream csv(out / "status.csv");
  std::size_t rows = 0;
  for (std::string line; std::getline(csv, line);)
    ++rows;
  EXPECT_EQ(rows, 31u);

  // From a given pose instead: the same place, no retrieval needed (and the key-frames
  // one by one only, which suffice here).
  const fs::path out2 = dir_ / "out2";
  const auto& T = slam.poses[10];
  const Eigen::Quaterniond q(T.rotation());
  const std::string pose = std::to_string(T.translation().x()) + " " +
                           std::to_string(T.translation().y()) + " " +
                           std::to_string(T.translation().z()) + " " + std::to_string(q.x()) +
                           " " + std::to_string(q.y()) + " " + std::to_string(q.z()) + " " +
                           std::to_string(q.w());
  ASSERT_EQ(run("-session " + quoted(m.session) + " -input " + quoted(m.scans) +
                " -output " + quoted(out2) +
                " -first 10 -last 19 -software-render -quiet -no-merged-keyframes "
                "-no-tracked-together -place-backoff 7 -place-min-initial 11 "
                "-no-elevation-calibration "
                "-place-min-inliers 38 -place-neighbours 3 "
                "-place-polar 1 -initial-pose '" +
                pose + "'"),
            0)
      << readFile(log_);
  const auto summary2 = nlohmann::json::parse(readFile(out2 / "summary.json"));
  EXPECT_TRUE(summary2["initial_pose_given"].get<bool>());
  EXPECT_EQ(summary2["frames_localized"].get<int>(), 10);
  EXPECT_EQ(summary2["map_alignment"]["merged_keyframes_within_m"].get<double>(), 0.0);
  EXPECT_FALSE(summary2["map_alignment"]["tracked_together"].get<bool>());
  EXPECT_FALSE(summary2["elevation_calibration"]["enabled"].get<bool>());
  // Given thresholds replace the sensor preset's.
  EXPECT_EQ(summary2["placement"]["min_initial_inliers"].get<int>(), 11);
  EXPECT_EQ(summary2["placement"]["min_inliers"].get<int>(), 38);
  EXPECT_EQ(summary2["placement"]["neighbourhood_keyframes"].get<int>(), 3);
  EXPECT_EQ(summary2["placement"]["first_attempts_neighbourhood_keyframes"].get<int>(), 3)
      << "-place-neighbours sets the first attempts' too";
  EXPECT_EQ(summary2["placement"]["polar_candidates"].get<int>(), 1);
  EXPECT_EQ(summary2["placement"]["backoff_after"].get<int>(), 7);

  // Without the odometry's look-ahead, and with every scan's features: the same poses
  // (MapLocalization's own test compares them off the map, where the odometry runs on
  // every frame; on the map no placement backs off, so every frame wants its features).
  const fs::path out3 = dir_ / "out3";
  ASSERT_EQ(run("-session " + quoted(m.session) + " -input " + quoted(m.scans) +
                " -output " + quoted(out3) +
                " -first 10 -software-render -quiet -no-lookahead -all-features"
                " -trust-degraded-odometry"),
            0)
      << readFile(log_);
  EXPECT_EQ(readFile(out3 / "poses_kitti.txt"), readFile(out / "poses_kitti.txt"));
  const auto summary3 = nlohmann::json::parse(readFile(out3 / "summary.json"));
  EXPECT_FALSE(summary3["lookahead"]["on"].get<bool>());
  EXPECT_EQ(summary3["lookahead"]["frames_prepared_ahead"].get<int>(), 0);
  EXPECT_FALSE(summary3["odometry_features"]["on_demand"].get<bool>());
  // The HDL-64 preset keeps no direction at the prediction: trusting a degraded
  // odometry there changes nothing (the poses above).
  EXPECT_FALSE(
      summary3["map_alignment"]["degenerate_needs_tracked_odometry"].get<bool>());
  EXPECT_EQ(summary["odometry_features"]["frames_without"].get<int>(), 0);
  EXPECT_EQ(summary3["odometry_features"]["frames_without"].get<int>(), 0);
}

/// A drive that enters the map from a road the map lacks: 24 scans of another world,
/// then the mapped drive's scans 10-39. Placements back off after 20 failures (one
/// every 9 frames with -place-every 9), so the map's first scans are placed late; the
/// frames before the placement are then revised in status.csv and the poses
/// (backtracked 1), and with -backtrack 0 they are not.
TEST_F(LocalizeTool, FramesBeforeALatePlacementAreRevisedBackwards)
{
  const Mapped& m = mapped();
  const fs::path other = pcl_rast_test::simulateStraightDrive("localize_tool_other", 9);
  const fs::path input = dir_ / "entering";
  fs::create_directories(input / "velodyne");
  std::ifstream other_times(other / "times.txt"), map_times(m.scans / "times.txt");
  std::vector<std::string> stamps;
  for (std::string t; std::getline(other_times, t);)
    stamps.push_back(t);
  ASSERT_GE(stamps.size(), 24u);
  stamps.resize(24);
  const double last_other = std::stod(stamps.back());
  const auto bin = [](int i) {
    char name[32];
    std::snprintf(name, sizeof name, "%06d.bin", i);
    return std::string(name);
  };
  for (int i = 0; i < 24; ++i)
    fs::copy_file(other / "velodyne" / bin(i), input / "velodyne" / bin(i));
  for (int j = 0; j < 30; ++j) {
    fs::copy_file(m.scans / "velodyne" / bin(10 + j), input / "velodyne" / bin(24 + j));
    stamps.push_back(std::to_string(last_other + 0.1 * (j + 1)));
  }
  std::ofstream(input / "times.txt") << [&] {
    std::string all;
    for (const std::string& t : stamps)
      all += t + "\n";
    return all;
  }();

  const auto localize = [&](const fs::path& out, const std::string& extra) {
    EXPECT_EQ(run("-session " + quoted(m.session) + " -input " + quoted(input) +
                  " -output " + quoted(out) + " -place-every 9 -software-render -quiet" +
                  extra),
              0)
        << readFile(log_);
    return nlohmann::json::parse(readFile(out / "summary.json"));
  };
  const auto rows = [](const fs::path& csv_path) {
    std::ifstream csv(csv_path);
    std::vector<std::string> lines;
    for (std::string line; std::getline(csv, line);)
      lines.push_back(line);
    return lines;
  };
  const fs::path out = dir_ / "out", plain = dir_ / "plain";
  const auto summary = localize(out, "");
  const auto summary_plain = localize(plain, " -backtrack 0");
  const int first = summary["first_localized_frame"].get<int>();
  // As the run went: placed late, the same frame with and without backtracking.
  EXPECT_GT(first, 24) << "placed at the map's first scan: the test needs it late";
  EXPECT_EQ(summary_plain["first_localized_frame"].get<int>(), first);
  EXPECT_EQ(summary["placement"]["backtrack_frames"].get<int>(), 20);
  EXPECT_EQ(summary_plain["frames_backtracked"].get<int>(), 0);
  const int backtracked = summary["frames_backtracked"].get<int>();
  EXPECT_GE(backtracked, 1);
  EXPECT_EQ(summary["frames_localized"].get<int>(),
            summary_plain["frames_localized"].get<int>() + backtracked);
  // Backed off, off the map, the odometry made the features of the attempts' scans only.
  EXPECT_GT(summary["odometry_features"]["frames_without"].get<int>(), 0);

  const std::vector<std::string> lines = rows(out / "status.csv");
  ASSERT_EQ(lines.size(), 55u);
  EXPECT_EQ(lines[0].substr(lines[0].rfind(',')), ",backtracked");
  const auto slam = pcl::rast::readTrajectory((m.slam_out / "poses_kitti.txt").string());
  const auto loc = pcl::rast::readTrajectory((out / "poses_kitti.txt").string());
  const auto loc_plain = pcl::rast::readTrajectory((plain / "poses_kitti.txt").string());
  ASSERT_EQ(loc.poses.size(), 54u);
  int revised = 0, lowest = first;
  for (int k = 0; k < 54; ++k) {
    const std::string& row = lines[k + 1];
    const bool is_backtracked = row.substr(row.rfind(',')) == ",1";
    if (is_backtracked)
      lowest = std::min(lowest, k);
    if (!is_backtracked) {
      EXPECT_TRUE(loc.poses[k].matrix() == loc_plain.poses[k].matrix()) << "frame " << k;
      continue;
    }
    ++revised;
    EXPECT_GE(k, 24) << "a frame of the other world: " << row;
    EXPECT_LT(k, first);
    EXPECT_NE(row.find(",localized,"), std::string::npos) << row;
    EXPECT_NE(row.find("backwards from the placement of frame " + std::to_string(first)),
              std::string::npos)
        << row;
    // In the map's frame: where the SLAM run put the same scan.
    EXPECT_LT((loc.poses[k].translation() - slam.poses[10 + k - 24].translation()).norm(),
              0.15)
        << "frame " << k;
  }
  EXPECT_EQ(revised, backtracked);
  EXPECT_EQ(lowest, first - backtracked) << "not the frames just before the placement";
  std::printf("simulated: the map from input frame 24, placed at frame %d, %d frames "
              "before it revised backwards\n",
              first,
              backtracked);
}

TEST_F(LocalizeTool, BadSessionsAndArgumentsAreRefusedBeforeAnyWork)
{
  const Mapped& m = mapped();
  const std::string input = " -input " + quoted(m.scans);
  const fs::path out = dir_ / "out";

  // A corrupted key-frame cloud: exit 2 naming it, no output.
  const fs::path broken = dir_ / "broken";
  fs::copy(m.session, broken, fs::copy_options::recursive);
  const fs::path cloud = broken / "keyframes" / "000001.pcd";
  std::string bytes = readFile(cloud);
  bytes[bytes.size() / 2] ^= 0x11;
  pcl_rast_test::writeFile(cloud, bytes);
  EXPECT_EQ(run("-session " + quoted(broken) + input + " -output " + quoted(out)), 2);
  EXPECT_NE(readFile(log_).find(cloud.string()), std::string::npos) << readFile(log_);
  EXPECT_NE(readFile(log_).find("checksum"), std::string::npos) << readFile(log_);
  EXPECT_FALSE(fs::exists(out / "summary.json"));

  // Another sensor preset than the session's.
  EXPECT_EQ(run("-session " + quoted(m.session) + input + " -output " + quoted(out) +
                " -sensor vlp16"),
            2);
  EXPECT_NE(readFile(log_).find("'vlp16'"), std::string::npos) << readFile(log_);

  // No session there; a malformed initial pose; the output is the session.
  EXPECT_EQ(run("-session " + quoted(dir_ / "none") + input + " -output " + quoted(out)), 2);
  EXPECT_NE(readFile(log_).find("none"), std::string::npos) << readFile(log_);
  EXPECT_EQ(run("-session " + quoted(m.session) + input + " -output " + quoted(out) +
                " -initial-pose '1 2 3'"),
            1);
  EXPECT_NE(readFile(log_).find("need 7 finite numbers"), std::string::npos) << readFile(log_);
  // Flags out of range: exit 1, the value named.
  for (const auto& [flag, said] :
       {std::pair{"-place-min-inliers 2", "-place-min-inliers 2 (>= 3)"},
        std::pair{"-place-neighbours -1", "-place-neighbours -1 (>= 0)"},
        std::pair{"-place-polar -2", "-place-polar -2 (>= 0)"},
        std::pair{"-place-backoff -1", "placement_backoff_after must be >= 0"},
        std::pair{"-leaving-corridor -1",
                  "leaving_map_corridor_m must be finite and >= 0"},
        std::pair{"-dense-points 5", "-dense-points 5 (>= 10)"}}) {
    EXPECT_EQ(run("-session " + quoted(m.session) + input + " -output " + quoted(out) +
                  " " + flag),
              1)
        << flag;
    EXPECT_NE(readFile(log_).find(said), std::string::npos) << readFile(log_);
  }
  EXPECT_EQ(run("-session " + quoted(m.session) + input + " -output " + quoted(m.session)), 1);
  EXPECT_FALSE(fs::exists(out / "summary.json"));
  EXPECT_NO_THROW(pcl::rast::readTrajectory((m.slam_out / "poses_kitti.txt").string()));
}

} // namespace

} // namespace test_localize_tool
