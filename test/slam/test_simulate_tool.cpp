/// \file test_simulate_tool.cpp
/// \brief The command-line contract of pcl_rast_simulate: files written, first pose
/// identity, frame selection, formats, raw sweeps, imperfections, scene types, rough
/// ground and porous vegetation, exit codes on bad arguments.

#include "test_data.h"

#include <cstdlib>
#include <fstream>
#include <pcl/io/pose_io.h>
#include <string>
#include <sys/wait.h>
#include <vector>

// This file's names stay its own: a test program compiles several test files as
// one translation unit (test/CMakeLists.txt).
namespace test_simulate_tool {

namespace {

namespace fs = std::filesystem;

/// Run the tool with \a args (stdout/stderr to a log in \a dir); returns its exit code.
int
runSimulate(const std::string& args, const fs::path& log)
{
  if (!fs::exists(pcl_rast_test::toolPath("pcl_rast_simulate")))
    return -100;
  return pcl_rast_test::runTool("pcl_rast_simulate", args, log);
}

std::size_t
countLines(const fs::path& path)
{
  std::ifstream in(path);
  std::size_t n = 0;
  for (std::string line; std::getline(in, line);)
    n += !line.empty();
  return n;
}

using pcl_rast_test::countFiles;

class SimulateTool : public ::testing::Test
{
protected:
  void SetUp() override
  {
    if (!fs::exists(pcl_rast_test::toolPath("pcl_rast_simulate")))
      FAIL() << "pcl_rast_simulate is not built: build the tools target first";
    dir_ = pcl_rast_test::makeTempDir("simulate_tool");
    log_ = dir_ / "log.txt";
  }
  std::string out(const std::string& name = "seq") const
  {
    return "'" + (dir_ / name).string() + "'";
  }
  /// The bytes of the second scan of the .bin sequence written to \a name.
  std::string bytes(const std::string& name) const
  {
    std::ifstream in(dir_ / name / "velodyne" / "000001.bin", std::ios::binary);
    return std::string((std::istreambuf_iterator<char>(in)), {});
  }
  fs::path dir_, log_;
};

TEST_F(SimulateTool, GeneratedPathWritesKittiLayout)
{
  ASSERT_EQ(runSimulate("-path straight -frames 6 -sensor vlp16 -output " + out(), log_),
            0);
  const fs::path seq = dir_ / "seq";
  EXPECT_EQ(countFiles(seq / "velodyne"), 6u);
  EXPECT_TRUE(fs::exists(seq / "velodyne" / "000000.bin"));
  EXPECT_TRUE(fs::exists(seq / "velodyne" / "000005.bin"));
  EXPECT_GT(fs::file_size(seq / "velodyne" / "000003.bin"), 16u * 5000u);
  EXPECT_EQ(countLines(seq / "times.txt"), 6u);
  const auto traj = pcl::rast::readTrajectory((seq / "poses.txt").string());
  ASSERT_EQ(traj.poses.size(), 6u);
  EXPECT_TRUE(traj.poses[0].isApprox(pcl::rast::Pose3d::Identity(), 1e-9));
  // 10 m/s at 10 Hz along the LiDAR's x axis.
  EXPECT_NEAR(traj.poses[5].translation().x(), 5.0, 0.1);
}

TEST_F(SimulateTool, SelectionFormatAndSeed)
{
  ASSERT_EQ(
      runSimulate("-path loop -frames 40 -sensor os1-64 -first 10 -last 20 -every 5 "
                  "-format pcd -seed 3 -output " +
                      out("a"),
                  log_),
      0);
  EXPECT_EQ(countFiles(dir_ / "a" / "pcd"), 3u);
  EXPECT_TRUE(fs::exists(dir_ / "a" / "pcd" / "000002.pcd"));
  EXPECT_EQ(countLines(dir_ / "a" / "poses.txt"), 3u);
  EXPECT_EQ(countLines(dir_ / "a" / "times.txt"), 3u);

  // Same seed -> same bytes; frame 15 alone equals frame 15 of the run above.
  ASSERT_EQ(
      runSimulate("-path loop -frames 40 -sensor os1-64 -first 15 -last 15 -format pcd "
                  "-seed 3 -output " +
                      out("b"),
                  log_),
      0);
  std::ifstream a(dir_ / "a" / "pcd" / "000001.pcd", std::ios::binary);
  std::ifstream b(dir_ / "b" / "pcd" / "000000.pcd", std::ios::binary);
  const std::string sa((std::istreambuf_iterator<char>(a)), {});
  const std::string sb((std::istreambuf_iterator<char>(b)), {});
  EXPECT_FALSE(sa.empty());
  EXPECT_EQ(sa, sb);
}

TEST_F(SimulateTool, HandheldAndMovingCars)
{
  ASSERT_EQ(
      runSimulate("-path eight -frames 5 -sensor os0-128 -moving-cars -output " + out(),
                  log_),
      0);
  EXPECT_EQ(countFiles(dir_ / "seq" / "velodyne"), 5u);
  EXPECT_EQ(countLines(dir_ / "seq" / "poses.txt"), 5u);
}

TEST_F(SimulateTool, BadArgumentsExitOne)
{
  const std::string o = " -output " + out();
  EXPECT_EQ(runSimulate("-path loop -frames 3 -bogus" + o, log_), 1);
  EXPECT_EQ(runSimulate("-frames 3" + o, log_), 1);              // neither
  EXPECT_EQ(runSimulate("-path loop -traj x.txt" + o, log_), 1); // both
  EXPECT_EQ(runSimulate("-path circle" + o, log_), 1);           // bad choice
  EXPECT_EQ(runSimulate("-path loop -sensor vlp32" + o, log_), 1);
  EXPECT_EQ(runSimulate("-path loop -format ply" + o, log_), 1);
  EXPECT_EQ(runSimulate("-path loop -frames 5 -first 3 -last 1" + o, log_), 1);
  EXPECT_EQ(runSimulate("-path loop -frames 5 -last 5" + o, log_), 1);
  EXPECT_EQ(runSimulate("-path loop -frames abc" + o, log_), 1);
  EXPECT_EQ(runSimulate("-path loop -frames 0" + o, log_), 1);
  EXPECT_EQ(runSimulate("-path loop -every 0" + o, log_), 1);
  EXPECT_EQ(runSimulate("-path loop", log_), 1); // no -output
  EXPECT_EQ(runSimulate("-h", log_), 0);
  EXPECT_EQ(runSimulate("-traj '" + (dir_ / "missing.txt").string() + "'" + o, log_), 2);
  EXPECT_FALSE(fs::exists(dir_ / "seq" / "poses.txt"));
}

std::string
readText(const fs::path& path)
{
  std::ifstream in(path);
  return std::string((std::istreambuf_iterator<char>(in)), {});
}

TEST_F(SimulateTool, RealisticTrafficAndStops)
{
  // The generated path stands from ~16 s to ~24 s: frames 180 and 190 share a pose.
  const std::string run = "-path straight -frames 400 -stops 1 -stop-duration 8 "
                          "-sensor vlp16 -moving-cars -first 180 -last 190 -every 10 ";
  ASSERT_EQ(runSimulate(run + "-traffic realistic -output " + out("real"), log_), 0)
      << readText(log_);
  ASSERT_EQ(runSimulate(run + "-traffic along-path -output " + out("along"), log_), 0);
  const auto real = pcl::rast::readTrajectory((dir_ / "real" / "poses.txt").string());
  ASSERT_EQ(real.poses.size(), 2u);
  EXPECT_TRUE(real.poses[1].isApprox(real.poses[0], 1e-9));
  EXPECT_EQ(countFiles(dir_ / "real" / "velodyne"), 2u);
  // The traffic models differ in what the sensor sees.
  EXPECT_NE(readText(dir_ / "real" / "velodyne" / "000000.bin"),
            readText(dir_ / "along" / "velodyne" / "000000.bin"));
}

TEST_F(SimulateTool, BadTrafficAndStopValuesExitOne)
{
  const std::string o = " -output " + out();
  EXPECT_EQ(runSimulate("-path loop -frames 5 -moving-cars -traffic jam" + o, log_), 1);
  EXPECT_NE(readText(log_).find("jam"), std::string::npos) << readText(log_);
  EXPECT_EQ(runSimulate("-path loop -frames 5 -traffic realistic" + o, log_), 1);
  EXPECT_NE(readText(log_).find("-moving-cars"), std::string::npos) << readText(log_);
  EXPECT_EQ(runSimulate("-path loop -frames 400 -stops -1" + o, log_), 1);
  EXPECT_NE(readText(log_).find("num_stops"), std::string::npos) << readText(log_);
  EXPECT_EQ(runSimulate("-path loop -frames 100 -stops 2" + o, log_), 1);
  EXPECT_NE(readText(log_).find("do not fit"), std::string::npos) << readText(log_);
  EXPECT_EQ(runSimulate("-path loop -frames 400 -stops 1 -accel 0" + o, log_), 1);
  EXPECT_NE(readText(log_).find("acceleration_mps2"), std::string::npos)
      << readText(log_);
  EXPECT_EQ(runSimulate("-traj x.txt -stops 1" + o, log_), 1);
  EXPECT_FALSE(fs::exists(dir_ / "seq" / "poses.txt"));
}

TEST_F(SimulateTool, ImperfectionsSwitch)
{
  // Listed by -h (an unknown flag would exit 1 before the help).
  ASSERT_EQ(runSimulate("-imperfections -h", log_), 0);
  std::ifstream help(log_);
  const std::string usage((std::istreambuf_iterator<char>(help)), {});
  EXPECT_NE(usage.find("-imperfections"), std::string::npos) << usage;

  // It changes the scans, deterministically for the seed.
  const std::string base = "-path straight -frames 2 -sensor vlp16 -seed 5 -output ";
  ASSERT_EQ(runSimulate(base + out("clean"), log_), 0);
  ASSERT_EQ(runSimulate(base + out("a") + " -imperfections", log_), 0);
  ASSERT_EQ(runSimulate(base + out("b") + " -imperfections", log_), 0);
  EXPECT_GT(bytes("clean").size(), 0u);
  EXPECT_NE(bytes("clean"), bytes("a"));
  EXPECT_EQ(bytes("a"), bytes("b"));

  // -elevation-bias sets the per-beam elevation error alone: its default is what
  // -imperfections gives, 0 changes the scans.
  ASSERT_EQ(runSimulate(base + out("d") + " -imperfections -elevation-bias 0.05", log_),
            0);
  ASSERT_EQ(runSimulate(base + out("c") + " -imperfections -elevation-bias 0", log_), 0);
  EXPECT_EQ(bytes("a"), bytes("d"));
  EXPECT_NE(bytes("a"), bytes("c"));
  EXPECT_NE(bytes("clean"), bytes("c"));
  // Without -imperfections, or out of range: exit 1, naming the flag.
  for (const std::string bad : {" -elevation-bias 0.1",
                                " -imperfections -elevation-bias 0.7",
                                " -imperfections -elevation-bias -0.1"}) {
    ASSERT_EQ(runSimulate(base + out("bad") + bad, log_), 1) << bad;
    std::ifstream in(log_);
    const std::string text((std::istreambuf_iterator<char>(in)), {});
    EXPECT_NE(text.find("-elevation-bias"), std::string::npos) << text;
  }
}

TEST_F(SimulateTool, DriveSeedSwitch)
{
  // -drive-seed: another drive through the world of -seed (its library side is pinned
  // in LidarSimulator.DriveSeedIsAnotherDriveThroughTheSameWorld). 0 and the seed
  // itself give the seed's scans; another one other scans.
  const std::string base =
      "-path straight -frames 2 -sensor vlp16 -seed 5 -imperfections -output ";
  ASSERT_EQ(runSimulate(base + out("seed"), log_), 0);
  ASSERT_EQ(runSimulate(base + out("zero") + " -drive-seed 0", log_), 0);
  ASSERT_EQ(runSimulate(base + out("same") + " -drive-seed 5", log_), 0);
  ASSERT_EQ(runSimulate(base + out("other") + " -drive-seed 6", log_), 0);
  EXPECT_GT(bytes("seed").size(), 0u);
  EXPECT_EQ(bytes("seed"), bytes("zero"));
  EXPECT_EQ(bytes("seed"), bytes("same"));
  EXPECT_NE(bytes("seed"), bytes("other"));
  ASSERT_EQ(runSimulate(base + out("bad") + " -drive-seed -3", log_), 1);
  std::ifstream in(log_);
  const std::string text((std::istreambuf_iterator<char>(in)), {});
  EXPECT_NE(text.find("-drive-seed must be >= 0, got -3"), std::string::npos) << text;
  EXPECT_FALSE(fs::exists(dir_ / "bad"));
}

TEST_F(SimulateTool, SceneAndWorldSwitches)
{
  ASSERT_EQ(runSimulate("-h", log_), 0);
  std::ifstream help(log_);
  const std::string usage((std::istreambuf_iterator<char>(help)), {});
  for (const char* flag : {"-scene", "-rough-ground", "-porous-vegetation"})
    EXPECT_NE(usage.find(flag), std::string::npos) << flag << "\n" << usage;

  const std::string base = "-path straight -frames 2 -sensor vlp16 -seed 5 -output ";
  ASSERT_EQ(runSimulate(base + out("suburb"), log_), 0);
  ASSERT_EQ(runSimulate(base + out("tunnel") + " -scene tunnel", log_), 0);
  ASSERT_EQ(
      runSimulate(base + out("all") + " -scene mixed -rough-ground -porous-vegetation",
                  log_),
      0);
  EXPECT_GT(bytes("tunnel").size(), 0u);
  EXPECT_NE(bytes("suburb"), bytes("tunnel"));
  EXPECT_GT(bytes("all").size(), 0u);
  // scenes.txt names the scene of each written frame.
  auto scenes = [&](const std::string& name) {
    std::ifstream in(dir_ / name / "scenes.txt");
    std::vector<std::string> lines;
    for (std::string line; std::getline(in, line);)
      lines.push_back(line);
    return lines;
  };
  EXPECT_EQ(scenes("tunnel"), (std::vector<std::string>{"tunnel", "tunnel"}));
  EXPECT_EQ(scenes("suburb"), (std::vector<std::string>{"suburb", "suburb"}));
  const auto mixed = scenes("all");
  ASSERT_EQ(mixed.size(), 2u);
  EXPECT_TRUE(mixed[0] == "suburb" || mixed[0] == "urban") << mixed[0]; // starts with structure

  EXPECT_EQ(runSimulate(base + out("bad") + " -scene forest", log_), 1);
  std::ifstream err(log_);
  const std::string message((std::istreambuf_iterator<char>(err)), {});
  EXPECT_NE(message.find("forest"), std::string::npos) << message;
}

TEST_F(SimulateTool, RawSweepSwitch)
{
  // Listed by -h (an unknown flag would exit 1 before the help).
  ASSERT_EQ(runSimulate("-raw-sweep -h", log_), 0);
  std::ifstream help(log_);
  const std::string usage((std::istreambuf_iterator<char>(help)), {});
  EXPECT_NE(usage.find("-raw-sweep"), std::string::npos) << usage;

  // Raw sweeps as PCD carry the time field; instantaneous scans do not.
  auto pcdFields = [&](const std::string& name) {
    std::ifstream in(dir_ / name / "pcd" / "000001.pcd", std::ios::binary);
    for (std::string line; std::getline(in, line);)
      if (line.rfind("FIELDS", 0) == 0)
        return line;
    return std::string("no FIELDS line");
  };
  ASSERT_EQ(runSimulate("-path straight -frames 3 -sensor vlp16 -format pcd -raw-sweep "
                        "-output " +
                            out("raw"),
                        log_),
            0);
  EXPECT_EQ(pcdFields("raw"), "FIELDS x y z intensity time");
  ASSERT_EQ(runSimulate("-path straight -frames 3 -sensor vlp16 -format pcd -output " +
                            out("inst"),
                        log_),
            0);
  EXPECT_EQ(pcdFields("inst"), "FIELDS x y z intensity");
}

TEST_F(SimulateTool, KittiGroundTruthTrajectory)
{
  PCL_RAST_REQUIRE_SHARED_DATA(data);
  const std::string gt = "'" + (data / "kitti-gt-poses" / "07.txt").string() + "'";
  ASSERT_EQ(
      runSimulate("-traj " + gt + " -first 100 -last 104 -sensor vlp16 -output " + out(),
                  log_),
      0);
  EXPECT_EQ(countFiles(dir_ / "seq" / "velodyne"), 5u);
  const auto traj = pcl::rast::readTrajectory((dir_ / "seq" / "poses.txt").string());
  ASSERT_EQ(traj.poses.size(), 5u);
  EXPECT_TRUE(traj.poses[0].isApprox(pcl::rast::Pose3d::Identity(), 1e-9));
  // LiDAR frame: the car drives along x (camera frame would be z).
  const Eigen::Vector3d t = traj.poses[4].translation();
  EXPECT_GT(std::abs(t.x()), 2.0 * std::abs(t.z()));
  EXPECT_EQ(countLines(dir_ / "seq" / "times.txt"), 5u);
}

} // namespace

} // namespace test_simulate_tool
