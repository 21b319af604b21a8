/// The pcl_rast_localize command line: a simulated drive mapped by pcl_rast_slam
/// -save-session and localized again from a later scan with no initial pose; bad
/// sessions and bad arguments refused before any work.

#include <pcl/io/pose_io.h>

#include <gtest/gtest.h>

#include <nlohmann/json.hpp>

#include "simulated_drive.h"
#include "test_data.h"

#include <filesystem>
#include <fstream>
#include <string>

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
  EXPECT_EQ(summary["placement"]["min_inliers"].get<int>(), 40);
  EXPECT_TRUE(summary["placement"]["track_on_map"].get<bool>());
  EXPECT_TRUE(summary["lookahead"]["on"].get<bool>());

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

  // From a given pose instead: the same place, no retrieval needed.
  const fs::path out2 = dir_ / "out2";
  const auto& T = slam.poses[10];
  const Eigen::Quaterniond q(T.rotation());
  const std::string pose = std::to_string(T.translation().x()) + " " +
                           std::to_string(T.translation().y()) + " " +
                           std::to_string(T.translation().z()) + " " + std::to_string(q.x()) +
                           " " + std::to_string(q.y()) + " " + std::to_string(q.z()) + " " +
                           std::to_string(q.w());
  ASSERT_EQ(run("-session " + quoted(m.session) + " -input " + quoted(m.scans) + " -output " +
                quoted(out2) + " -first 10 -last 19 -software-render -quiet -initial-pose '" +
                pose + "'"),
            0)
      << readFile(log_);
  const auto summary2 = nlohmann::json::parse(readFile(out2 / "summary.json"));
  EXPECT_TRUE(summary2["initial_pose_given"].get<bool>());
  EXPECT_EQ(summary2["frames_localized"].get<int>(), 10);

  // Without the odometry's look-ahead: the same poses (MapLocalization's own test
  // compares them off the map, where the odometry runs on every frame).
  const fs::path out3 = dir_ / "out3";
  ASSERT_EQ(run("-session " + quoted(m.session) + " -input " + quoted(m.scans) +
                " -output " + quoted(out3) +
                " -first 10 -software-render -quiet -no-lookahead"),
            0)
      << readFile(log_);
  EXPECT_EQ(readFile(out3 / "poses_kitti.txt"), readFile(out / "poses_kitti.txt"));
  const auto summary3 = nlohmann::json::parse(readFile(out3 / "summary.json"));
  EXPECT_FALSE(summary3["lookahead"]["on"].get<bool>());
  EXPECT_EQ(summary3["lookahead"]["frames_prepared_ahead"].get<int>(), 0);
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
  EXPECT_EQ(run("-session " + quoted(m.session) + input + " -output " + quoted(out) +
                " -place-min-inliers 2"),
            1);
  EXPECT_NE(readFile(log_).find("-place-min-inliers 2 (>= 3)"), std::string::npos)
      << readFile(log_);
  EXPECT_EQ(run("-session " + quoted(m.session) + input + " -output " + quoted(m.session)), 1);
  EXPECT_FALSE(fs::exists(out / "summary.json"));
  EXPECT_NO_THROW(pcl::rast::readTrajectory((m.slam_out / "poses_kitti.txt").string()));
}

} // namespace

} // namespace test_localize_tool
