/// \file test_hostile_inputs.cpp
/// \brief Scan files that lie: headers with impossible counts and sizes, corrupt
/// compressed bodies, words where numbers belong, truncated data. Each must give a
/// ScanReadError that names the file, never a crash, a huge allocation or a silent
/// cloud of zeros (issue 12). The files are mutations, made here, of good PCD, PLY and
/// .bin files; the regression files in test/data/hostile are checked the same way.

#include "hostile_files.h"
#include "random_cloud.h"
#include "test_data.h"

#include <algorithm>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <gtest/gtest.h>
#include <pcl/io/pcd_io.h>
#include <pcl/io/ply_io.h>
#include <pcl/io/pose_io.h>
#include <pcl/io/sequence_reader.h>
#include <pcl/slam/g2o_io.h>
#include <random>
#include <sstream>
#include <string>
#include <vector>

// This file's names stay its own: a test program compiles several test files as
// one translation unit (test/CMakeLists.txt).
namespace test_hostile_inputs {

namespace fs = std::filesystem;
using pcl::rast::readScan;
using pcl::rast::ScanFrame;
using pcl::rast::ScanReadError;
using pcl::rast::SequenceReader;
using Cloud = pcl::PointCloud<pcl::PointXYZI>;

namespace {

using pcl_rast_test::allScanLies;
using pcl_rast_test::GoodFiles;
using pcl_rast_test::Hostile;
using pcl_rast_test::makeGoodFiles;
using pcl_rast_test::pcdHeaderLies;
using pcl_rast_test::randomCloud;
using pcl_rast_test::replaced;
using pcl_rast_test::readFile;
using pcl_rast_test::writeFile;

/// readScan on \a path must throw a ScanReadError that names it.
::testing::AssertionResult
rejected(const fs::path& path)
{
  try {
    const Cloud::Ptr cloud = readScan(path.string());
    return ::testing::AssertionFailure()
           << path.filename() << " was read as " << cloud->size() << " points";
  } catch (const ScanReadError& e) {
    if (e.path() != path.string() ||
        std::string(e.what()).find(path.string()) == std::string::npos)
      return ::testing::AssertionFailure()
             << "error does not name the file: " << e.what();
    return ::testing::AssertionSuccess();
  } catch (const std::exception& e) {
    return ::testing::AssertionFailure() << "not a ScanReadError: " << e.what();
  }
}

std::string
errorOf(const fs::path& path)
{
  try {
    readScan(path.string());
  } catch (const ScanReadError& e) {
    return e.what();
  }
  return "";
}

} // namespace

TEST(HostileScans, GoodFilesStillRead)
{
  const fs::path dir = pcl_rast_test::makeTempDir("hostile");
  makeGoodFiles(dir);
  for (const char* name :
       {"good_a.pcd", "good_b.pcd", "good_c.pcd", "good_a.ply", "good_b.ply"})
    EXPECT_EQ(readScan((dir / name).string())->size(), 200u) << name;
}

TEST(HostileScans, EveryLyingFileIsAClearError)
{
  const fs::path dir = pcl_rast_test::makeTempDir("hostile");
  const GoodFiles good = makeGoodFiles(dir);
  const std::vector<Hostile> files = allScanLies(good);
  EXPECT_GE(files.size(), 50u);
  for (const Hostile& h : files) {
    writeFile(dir / h.name, h.bytes);
    EXPECT_TRUE(rejected(dir / h.name)) << h.name;
  }
}

TEST(HostileScans, ErrorsSayWhatIsWrong)
{
  const fs::path dir = pcl_rast_test::makeTempDir("hostile");
  const GoodFiles good = makeGoodFiles(dir);
  const std::vector<std::pair<Hostile, std::string>> cases = {
      {{"count.pcd", replaced(good.pcd_binary, "COUNT 1 1 1 1", "COUNT -1 1 1 1")},
       "COUNT value '-1'"},
      {{"width.pcd",
        replaced(replaced(good.pcd_binary, "WIDTH 200", "WIDTH 268435456"),
                 "POINTS 200",
                 "POINTS 268435456")},
       "268435456 points of 16 bytes exceed the limit"},
      {{"short.pcd",
        replaced(replaced(good.pcd_binary, "WIDTH 200", "WIDTH 1000"),
                 "POINTS 200",
                 "POINTS 1000")},
       "truncated data: the header declares 1000 points but only 3200 bytes follow"},
      {{"size.pcd", replaced(good.pcd_binary, "SIZE 4 4 4 4", "SIZE 3 4 4 4")},
       "field 'x' has TYPE 'F' with SIZE 3"},
      {{"words.pcd",
        replaced(
            replaced(good.pcd_ascii.substr(0, good.pcd_ascii.find("DATA ascii\n") + 11),
                     "WIDTH 200",
                     "WIDTH 1"),
            "POINTS 200",
            "POINTS 1") +
            "one two three four\n"},
       "'one' is not a number"},
      {{"vertex.ply",
        replaced(good.ply_binary, "element vertex 200", "element vertex 4294967296")},
       "count from 0 to 4294967295"},
      {{"list.ply",
        replaced(good.ply_binary, "property float x", "property list uint float x")},
       "is a list"},
  };
  for (const auto& [file, phrase] : cases) {
    writeFile(dir / file.name, file.bytes);
    const std::string what = errorOf(dir / file.name);
    EXPECT_NE(what.find(phrase), std::string::npos)
        << file.name << ": expected '" << phrase << "' in: " << what;
  }
}

TEST(HostileScans, BigEndianPlyIsRead)
{
  const fs::path dir = pcl_rast_test::makeTempDir("hostile");
  std::string ply =
      "ply\nformat binary_big_endian 1.0\nelement vertex 2\nproperty float x\n"
      "property float y\nproperty float z\nproperty uchar intensity\nend_header\n";
  for (float v : {1.5f, -2.0f, 3.25f, 4.0f, 5.0f, -6.5f}) {
    char b[4];
    std::memcpy(b, &v, 4);
    std::reverse(b, b + 4);
    ply.append(b, 4);
    if (v == 3.25f || v == -6.5f)
      ply.push_back(static_cast<char>(v == 3.25f ? 7 : 9));
  }
  writeFile(dir / "be.ply", ply);
  const Cloud::Ptr cloud = readScan((dir / "be.ply").string());
  ASSERT_EQ(cloud->size(), 2u);
  EXPECT_EQ((*cloud)[0].x, 1.5f);
  EXPECT_EQ((*cloud)[0].y, -2.0f);
  EXPECT_EQ((*cloud)[0].z, 3.25f);
  EXPECT_EQ((*cloud)[0].intensity, 7.0f);
  EXPECT_EQ((*cloud)[1].z, -6.5f);
  EXPECT_EQ((*cloud)[1].intensity, 9.0f);
}

TEST(HostileScans, RegressionFilesAreClearErrors)
{
  const fs::path dir = fs::path(PCL_RAST_SOURCE_DIR) / "test" / "data" / "hostile";
  ASSERT_TRUE(fs::is_directory(dir)) << dir;
  std::size_t n = 0;
  for (const fs::directory_entry& e : fs::directory_iterator(dir)) {
    if (e.path().extension() == ".md" || e.is_directory())
      continue;
    ++n;
    if (e.path().filename().string().rfind("fuzz-", 0) == 0) {
      // A fuzzer's finding crashed once; it may be a valid (say, empty) scan: it must
      // now read or be a ScanReadError, and nothing else.
      try {
        readScan(e.path().string());
      } catch (const ScanReadError&) {
      }
      continue;
    }
    EXPECT_TRUE(rejected(e.path())) << e.path().filename();
  }
  EXPECT_GE(n, 10u);
}

TEST(HostileScans, SequenceWithLyingFilesGoesOn)
{
  const fs::path dir = pcl_rast_test::makeTempDir("hostile");
  const GoodFiles good = makeGoodFiles(dir);
  const fs::path seq = dir / "seq";
  fs::create_directories(seq);
  const std::vector<Hostile> lies = pcdHeaderLies(good);
  for (int i = 0; i < 6; ++i) {
    writeFile(seq / (std::to_string(2 * i) + ".pcd"), good.pcd_binary);
    writeFile(seq / (std::to_string(2 * i + 1) + ".pcd"),
              lies[static_cast<std::size_t>(3 * i)].bytes);
  }
  SequenceReader reader(seq.string());
  std::size_t good_frames = 0, bad_frames = 0;
  for (;;) {
    ScanFrame frame;
    try {
      if (!reader.next(frame))
        break;
      EXPECT_EQ(frame.cloud->size(), 200u);
      ++good_frames;
    } catch (const ScanReadError&) {
      ++bad_frames;
    }
  }
  EXPECT_EQ(good_frames, 6u);
  EXPECT_EQ(bad_frames, 6u);
}

// ---------------------------------------------------------------- text files

TEST(HostileTextFiles, LinesWithoutEndAreBoundedErrors)
{
  const fs::path dir = pcl_rast_test::makeTempDir("hostile");
  // 2 MiB of zeros and no newline, as /dev/zero gives: an error, not unbounded memory.
  const std::string zeros(2 * pcl::rast::kMaxTextLineBytes, '\0');
  writeFile(dir / "poses.txt", zeros);
  writeFile(dir / "times.txt", zeros);
  writeFile(dir / "calib.txt", zeros);
  writeFile(dir / "graph.g2o", zeros);
  const auto expectLineError = [](const std::function<void()>& read,
                                  const fs::path& path) {
    try {
      read();
      ADD_FAILURE() << "no error for " << path;
    } catch (const std::runtime_error& e) {
      EXPECT_NE(std::string(e.what()).find(path.string()), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find("longer than"), std::string::npos) << e.what();
    }
  };
  expectLineError([&] { pcl::rast::readTrajectory((dir / "poses.txt").string()); },
                  dir / "poses.txt");
  expectLineError([&] { pcl::rast::readKittiCalibTr((dir / "calib.txt").string()); },
                  dir / "calib.txt");
  expectLineError([&] { pcl::rast::readG2o((dir / "graph.g2o").string()); },
                  dir / "graph.g2o");
  // times.txt is read when a sequence folder holds one.
  const fs::path seq = dir / "seq";
  fs::create_directories(seq);
  fs::copy_file(dir / "times.txt", seq / "times.txt");
  pcl::rast::writeKittiBin((seq / "000000.bin").string(), randomCloud(10, 3));
  expectLineError([&] { SequenceReader reader(seq.string()); }, seq / "times.txt");
}

TEST(HostileTextFiles, ReadBoundedLineSplitsLikeGetline)
{
  std::istringstream in("a b\r\n\nlast");
  std::string line;
  std::vector<std::string> lines;
  for (std::size_t n = 1; pcl::rast::readBoundedLine(in, line, "mem", n); ++n)
    lines.push_back(line);
  EXPECT_EQ(lines, (std::vector<std::string>{"a b", "", "last"}));
}

TEST(HostileTextFiles, RegressionFilesAreClearErrors)
{
  // Named <case>.<reader>.txt: each must give the reader's documented error (a
  // std::runtime_error or std::invalid_argument), never a crash or another exception.
  const fs::path dir =
      fs::path(PCL_RAST_SOURCE_DIR) / "test" / "data" / "hostile" / "text";
  ASSERT_TRUE(fs::is_directory(dir)) << dir;
  std::size_t n = 0;
  for (const fs::directory_entry& e : fs::directory_iterator(dir)) {
    const std::string name = e.path().filename().string();
    const std::string reader = fs::path(e.path().stem()).extension().string();
    std::function<void()> read;
    if (reader == ".poses")
      read = [&] { pcl::rast::readTrajectory(e.path().string()); };
    else if (reader == ".calib")
      read = [&] { pcl::rast::readKittiCalibTr(e.path().string()); };
    else if (reader == ".g2o")
      read = [&] { pcl::rast::readG2o(e.path().string()); };
    else if (reader == ".times")
      read = [&] {
        const fs::path seq = pcl_rast_test::makeTempDir("hostile_times");
        fs::copy_file(e.path(), seq / "times.txt");
        pcl::rast::writeKittiBin((seq / "000000.bin").string(), randomCloud(4, 1));
        pcl::rast::writeKittiBin((seq / "000001.bin").string(), randomCloud(4, 2));
        SequenceReader reader_of_times(seq.string());
      };
    else
      continue;
    ++n;
    try {
      read();
      ADD_FAILURE() << name << " was read without an error";
    } catch (const std::runtime_error& err) {
      const std::string file = reader == ".times" ? "times.txt" : name;
      EXPECT_NE(std::string(err.what()).find(file), std::string::npos)
          << name << ": the error does not name the file: " << err.what();
    } catch (const std::invalid_argument&) {
    }
  }
  EXPECT_GE(n, 10u);
}

} // namespace test_hostile_inputs
