/// \file test_hostile_tools.cpp
/// \brief The lying-file corpus through every tool (issue 12): each lying scan is a
/// clear error in pcl_rast_features, and a sequence holding all of them between good
/// scans finishes with exit 0 in pcl_rast_slam, pcl_rast_odometry and
/// pcl_rast_localize, every one of them skipped with its reason; each lying pose file is a clear error, before any work, in
/// pcl_rast_eval, pcl_rast_slam -gt and pcl_rast_simulate -traj. "Clear" means: the
/// tool exits with its documented code (it is not killed by a signal), the message
/// names the file, and nothing is written.

#include "hostile_files.h"
#include "simulated_drive.h"
#include "test_data.h"

#include <cstdio>
#include <filesystem>
#include <gtest/gtest.h>
#include <map>
#include <nlohmann/json.hpp>
#include <pcl/io/pcd_io.h>
#include <pcl/io/ply_io.h>
#include <pcl/io/sequence_reader.h>
#include <set>
#include <string>
#include <vector>

// This file's names stay its own: a test program compiles several test files as
// one translation unit (test/CMakeLists.txt).
namespace test_hostile_tools {

namespace {

namespace fs = std::filesystem;
using pcl_rast_test::Hostile;
using pcl_rast_test::readFile;
using pcl_rast_test::runTool;
using pcl_rast_test::writeFile;

std::string
quoted(const fs::path& p)
{
  return "'" + p.string() + "'";
}

/// The 40-frame simulated drive, written once per process.
const fs::path&
driveDir()
{
  static const fs::path dir = pcl_rast_test::simulateStraightDrive("hostile_tools_drive");
  return dir;
}

/// The generated lying scans and the regression files of test/data/hostile (not the
/// fuzzer's findings, which may be valid scans), written into \a dir.
std::vector<fs::path>
writeLyingScans(const fs::path& dir)
{
  fs::create_directories(dir);
  const pcl_rast_test::GoodFiles good = pcl_rast_test::makeGoodFiles(dir);
  std::vector<fs::path> files;
  for (const Hostile& h : pcl_rast_test::allScanLies(good)) {
    writeFile(dir / h.name, h.bytes);
    files.push_back(dir / h.name);
  }
  const fs::path regression = fs::path(PCL_RAST_SOURCE_DIR) / "test" / "data" / "hostile";
  for (const fs::directory_entry& e : fs::directory_iterator(regression))
    if (e.is_regular_file() && e.path().extension() != ".md" &&
        e.path().filename().string().rfind("fuzz-", 0) != 0)
      files.push_back(e.path());
  return files;
}

/// The tool's log says "error" and names \a file.
::testing::AssertionResult
namesFile(const std::string& log, const fs::path& file)
{
  if (log.find("error") == std::string::npos)
    return ::testing::AssertionFailure() << "no error message: " << log;
  if (log.find(file.string()) == std::string::npos)
    return ::testing::AssertionFailure() << "the message does not name the file: " << log;
  return ::testing::AssertionSuccess();
}

} // namespace

TEST(HostileTools, FeaturesGivesAClearErrorOnEveryLyingScan)
{
  const fs::path dir = pcl_rast_test::makeTempDir("hostile_tools");
  const std::vector<fs::path> files = writeLyingScans(dir / "in");
  ASSERT_GE(files.size(), 50u);
  const fs::path png = dir / "features.png";
  const fs::path log = dir / "log.txt";
  for (const fs::path& file : files) {
    // Exit 2: the documented code of an unreadable input.
    EXPECT_EQ(runTool("pcl_rast_features", quoted(file) + " -output " + quoted(png), log),
              2)
        << file.filename() << ": " << readFile(log);
    EXPECT_TRUE(namesFile(readFile(log), file)) << file.filename();
    EXPECT_FALSE(fs::exists(png)) << file.filename();
  }
}

/// A sequence of one scan format: the 40 good scans of the drive with the lying files
/// of that format spread between them, all named by their frame number.
struct MixedSequence
{
  fs::path dir;
  std::set<std::string> lying; ///< file names of the lying frames
};

MixedSequence
makeMixedSequence(const fs::path& dir,
                  const std::string& ext,
                  const std::vector<fs::path>& lies)
{
  std::vector<fs::path> bad;
  for (const fs::path& f : lies)
    if (f.extension() == ext)
      bad.push_back(f);
  MixedSequence seq{dir, {}};
  fs::create_directories(dir);
  pcl::rast::SequenceReader drive(driveDir().string());
  std::size_t frame = 0, next_bad = 0;
  const auto name = [&](std::size_t i) {
    char buf[32];
    std::snprintf(buf, sizeof buf, "%06zu", i);
    return std::string(buf) + ext;
  };
  for (std::size_t good = 0; good < 40; ++good) {
    pcl::rast::ScanFrame scan;
    if (!drive.next(scan))
      throw std::runtime_error("the simulated drive has fewer than 40 scans");
    const fs::path out = dir / name(frame++);
    if (ext == ".pcd")
      pcl::io::savePCDFileBinary(out.string(), *scan.cloud);
    else if (ext == ".ply")
      pcl::io::savePLYFileBinary(out.string(), *scan.cloud);
    else
      pcl::rast::writeKittiBin(out.string(), *scan.cloud);
    // The lying files spread over the drive after its first five scans.
    for (; good >= 5 && next_bad < bad.size() && next_bad * 34 <= (good - 5) * bad.size();
         ++next_bad) {
      const std::string n = name(frame++);
      fs::copy_file(bad[next_bad], dir / n);
      seq.lying.insert(n);
    }
  }
  if (next_bad != bad.size())
    throw std::runtime_error("not every lying file was placed");
  return seq;
}

class HostileSequence
    : public ::testing::TestWithParam<std::pair<std::string, std::string>>
{
};

TEST_P(HostileSequence, FinishesWithEveryLyingScanSkippedAndNamed)
{
  const auto& [tool, ext] = GetParam();
  const fs::path dir = pcl_rast_test::makeTempDir("hostile_tools");
  const std::vector<fs::path> lies = writeLyingScans(dir / "lies");
  const MixedSequence seq = makeMixedSequence(dir / "seq", ext, lies);
  ASSERT_GE(seq.lying.size(), ext == ".bin" ? 3u : 20u);
  const fs::path out = dir / "out";
  const fs::path log = dir / "log.txt";
  std::string extra = " -quiet";
  if (tool == "pcl_rast_slam")
    extra += " -threads off";
  if (tool == "pcl_rast_localize") {
    // Localization needs a map: a session of the same sequence (its lying files are
    // skipped there as well).
    const fs::path session = dir / "session";
    ASSERT_EQ(runTool("pcl_rast_slam",
                      "-input " + quoted(seq.dir) + " -output " + quoted(dir / "slam") +
                          " -quiet -threads off -software-render -save-session " +
                          quoted(session),
                      log),
              0)
        << readFile(log);
    extra += " -software-render -session " + quoted(session);
  }
  ASSERT_EQ(
      runTool(tool, "-input " + quoted(seq.dir) + " -output " + quoted(out) + extra, log),
      0)
      << readFile(log);
  const auto summary = nlohmann::json::parse(readFile(out / "summary.json"));
  ASSERT_EQ(summary["skipped_frames"].size(), seq.lying.size());
  std::set<std::string> skipped;
  for (const auto& s : summary["skipped_frames"]) {
    const fs::path path = s["path"].get<std::string>();
    skipped.insert(path.filename().string());
    EXPECT_NE(s["reason"].get<std::string>().find(path.string()), std::string::npos)
        << "the reason does not name the file: " << s["reason"];
  }
  EXPECT_EQ(skipped, seq.lying);
  // Each skipped file is also reported when it is met.
  const std::string text = readFile(log);
  for (const std::string& name : seq.lying)
    EXPECT_NE(text.find(name), std::string::npos) << name << " is not reported";
}

INSTANTIATE_TEST_SUITE_P(
    EveryScanTool,
    HostileSequence,
    ::testing::Values(
        std::make_pair(std::string("pcl_rast_slam"), std::string(".pcd")),
        std::make_pair(std::string("pcl_rast_slam"), std::string(".ply")),
        std::make_pair(std::string("pcl_rast_slam"), std::string(".bin")),
        std::make_pair(std::string("pcl_rast_odometry"), std::string(".pcd")),
        std::make_pair(std::string("pcl_rast_odometry"), std::string(".ply")),
        std::make_pair(std::string("pcl_rast_odometry"), std::string(".bin")),
        std::make_pair(std::string("pcl_rast_localize"), std::string(".pcd"))),
    [](const auto& info) {
      return info.param.first.substr(9) + "_" + info.param.second.substr(1);
    });

TEST(HostileTools, EveryLyingPoseFileIsAClearErrorBeforeAnyWork)
{
  const fs::path dir = pcl_rast_test::makeTempDir("hostile_tools");
  std::vector<fs::path> files;
  for (const Hostile& h : pcl_rast_test::poseLies()) {
    writeFile(dir / h.name, h.bytes);
    files.push_back(dir / h.name);
  }
  const fs::path text =
      fs::path(PCL_RAST_SOURCE_DIR) / "test" / "data" / "hostile" / "text";
  for (const fs::directory_entry& e : fs::directory_iterator(text))
    if (e.path().stem().extension() == ".poses")
      files.push_back(e.path());
  ASSERT_GE(files.size(), 20u);
  const fs::path good = driveDir() / "poses.txt";
  const fs::path log = dir / "log.txt";
  for (const fs::path& file : files) {
    const std::string name = file.filename().string();
    // pcl_rast_eval, the lying file as the estimate and as the ground truth.
    for (const std::string& args :
         {quoted(file) + " " + quoted(good), quoted(good) + " " + quoted(file)}) {
      const int code = runTool("pcl_rast_eval", args, log);
      EXPECT_TRUE(code == 1 || code == 2)
          << name << ": exit " << code << ": " << readFile(log);
      EXPECT_TRUE(namesFile(readFile(log), file)) << name;
    }
    // pcl_rast_slam -gt: refused before the first scan, nothing written.
    const fs::path out = dir / ("slam_" + name);
    int code = runTool("pcl_rast_slam",
                       "-input " + quoted(driveDir()) + " -gt " + quoted(file) +
                           " -output " + quoted(out) + " -quiet",
                       log);
    EXPECT_TRUE(code == 1 || code == 2)
        << name << ": exit " << code << ": " << readFile(log);
    EXPECT_TRUE(namesFile(readFile(log), file)) << name;
    EXPECT_EQ(pcl_rast_test::countFiles(out), 0u) << name;
    // pcl_rast_simulate -traj: refused before the first scan is cast.
    const fs::path sim = dir / ("sim_" + name);
    code = runTool("pcl_rast_simulate",
                   "-traj " + quoted(file) + " -output " + quoted(sim) + " -last 3",
                   log);
    EXPECT_TRUE(code == 1 || code == 2)
        << name << ": exit " << code << ": " << readFile(log);
    EXPECT_TRUE(namesFile(readFile(log), file)) << name;
    EXPECT_EQ(pcl_rast_test::countFiles(sim), 0u) << name;
  }
}

} // namespace test_hostile_tools
