/// \file test_hostile_inputs.cpp
/// \brief Scan files that lie: headers with impossible counts and sizes, corrupt
/// compressed bodies, words where numbers belong, truncated data. Each must give a
/// ScanReadError that names the file, never a crash, a huge allocation or a silent
/// cloud of zeros (issue 12). The files are mutations, made here, of good PCD, PLY and
/// .bin files; the regression files in test/data/hostile are checked the same way.

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

namespace fs = std::filesystem;
using pcl::rast::readScan;
using pcl::rast::ScanFrame;
using pcl::rast::ScanReadError;
using pcl::rast::SequenceReader;
using Cloud = pcl::PointCloud<pcl::PointXYZI>;

namespace {

using pcl_rast_test::randomCloud;
using pcl_rast_test::readFile;
using pcl_rast_test::writeFile;

/// \a text with the first occurrence of \a from replaced by \a to (which must exist).
std::string
replaced(std::string text, const std::string& from, const std::string& to)
{
  const std::size_t at = text.find(from);
  if (at == std::string::npos)
    throw std::runtime_error("'" + from + "' not in the good file");
  return text.replace(at, from.size(), to);
}

/// The good files the mutations start from, as bytes, by name.
struct GoodFiles
{
  std::string pcd_ascii, pcd_binary, pcd_compressed, ply_ascii, ply_binary;
};

GoodFiles
makeGoodFiles(const fs::path& dir)
{
  const Cloud cloud = randomCloud(200, 7);
  EXPECT_EQ(pcl::io::savePCDFileASCII((dir / "good_a.pcd").string(), cloud), 0);
  EXPECT_EQ(pcl::io::savePCDFileBinary((dir / "good_b.pcd").string(), cloud), 0);
  EXPECT_EQ(pcl::io::savePCDFileBinaryCompressed((dir / "good_c.pcd").string(), cloud),
            0);
  EXPECT_EQ(pcl::io::savePLYFileASCII((dir / "good_a.ply").string(), cloud), 0);
  EXPECT_EQ(pcl::io::savePLYFileBinary((dir / "good_b.ply").string(), cloud), 0);
  return {readFile(dir / "good_a.pcd"),
          readFile(dir / "good_b.pcd"),
          readFile(dir / "good_c.pcd"),
          readFile(dir / "good_a.ply"),
          readFile(dir / "good_b.ply")};
}

/// One hostile file: its name and bytes.
struct Hostile
{
  std::string name;
  std::string bytes;
};

/// Header lies applied to each kind of PCD body.
std::vector<Hostile>
pcdHeaderLies(const GoodFiles& good)
{
  const std::vector<std::pair<std::string, std::string>> kinds = {
      {"ascii", good.pcd_ascii},
      {"binary", good.pcd_binary},
      {"compressed", good.pcd_compressed}};
  const std::vector<std::pair<std::string, std::pair<std::string, std::string>>> lies = {
      {"count_negative", {"COUNT 1 1 1 1", "COUNT -1 1 1 1"}},
      {"count_2p30", {"COUNT 1 1 1 1", "COUNT 1073741824 1 1 1"}},
      {"count_zero", {"COUNT 1 1 1 1", "COUNT 0 1 1 1"}},
      {"size_negative", {"SIZE 4 4 4 4", "SIZE -1 4 4 4"}},
      {"size_3", {"SIZE 4 4 4 4", "SIZE 3 4 4 4"}},
      {"size_float16", {"SIZE 4 4 4 4", "SIZE 2 4 4 4"}},
      {"type_unknown", {"TYPE F F F F", "TYPE X F F F"}},
      {"fields_short", {"SIZE 4 4 4 4", "SIZE 4 4 4"}},
      {"width_2p28", {"WIDTH 200", "WIDTH 268435456"}},
      {"width_negative", {"WIDTH 200", "WIDTH -5"}},
      {"width_above_2p32", {"WIDTH 200", "WIDTH 99999999999"}},
      {"points_mismatch", {"POINTS 200", "POINTS 7"}},
      {"fields_twice", {"SIZE 4 4 4 4", "FIELDS a b c d\nSIZE 4 4 4 4"}},
      {"no_xyz", {"FIELDS x y z intensity", "FIELDS a b c intensity"}},
      {"unknown_key", {"VIEWPOINT", "FROBNICATE 3\nVIEWPOINT"}},
      {"header_line_70k", {"VIEWPOINT", "# " + std::string(70000, 'x') + "\nVIEWPOINT"}},
  };
  std::vector<Hostile> files;
  for (const auto& [kind, bytes] : kinds)
    for (const auto& [lie, edit] : lies)
      files.push_back(
          {"pcd_" + kind + "_" + lie + ".pcd", replaced(bytes, edit.first, edit.second)});
  return files;
}

/// Bodies that do not match a truthful header.
std::vector<Hostile>
pcdBodyLies(const GoodFiles& good)
{
  std::vector<Hostile> files;
  const std::size_t data_c = good.pcd_compressed.find("DATA binary_compressed\n") + 23;
  auto sizes = [&](std::uint32_t compressed, std::uint32_t uncompressed) {
    std::string b = good.pcd_compressed;
    std::memcpy(&b[data_c], &compressed, 4);
    std::memcpy(&b[data_c + 4], &uncompressed, 4);
    return b;
  };
  files.push_back({"pcd_compressed_sizes_zero.pcd", sizes(0, 0)});
  files.push_back({"pcd_compressed_sizes_garbage.pcd", sizes(0xFFFFFFF0u, 0xFFFFFFF0u)});
  files.push_back({"pcd_compressed_uncompressed_lies.pcd", sizes(100, 200 * 16 + 4)});
  std::string scrambled = good.pcd_compressed;
  std::fill(scrambled.begin() + static_cast<long>(data_c) + 8, scrambled.end(), '\xFF');
  files.push_back({"pcd_compressed_scrambled.pcd", scrambled});
  files.push_back(
      {"pcd_compressed_no_sizes.pcd", good.pcd_compressed.substr(0, data_c + 5)});
  files.push_back({"pcd_binary_one_byte_short.pcd",
                   good.pcd_binary.substr(0, good.pcd_binary.size() - 1)});
  files.push_back(
      {"pcd_binary_no_data_line.pcd",
       replaced(good.pcd_binary.substr(0, 200), "DATA binary", "DATUM binary")});
  files.push_back(
      {"pcd_data_kind_unknown.pcd", replaced(good.pcd_ascii, "DATA ascii", "DATA text")});
  // Words where numbers belong: PCL's reader loads these as points at the origin.
  const std::size_t data_a = good.pcd_ascii.find("DATA ascii\n") + 11;
  std::string words = good.pcd_ascii.substr(0, data_a);
  for (int i = 0; i < 200; ++i)
    words += "the quick brown fox\n";
  files.push_back({"pcd_ascii_words.pcd", words});
  files.push_back(
      {"pcd_ascii_missing_value.pcd",
       good.pcd_ascii.substr(0, data_a) + "1 2 3\n" + good.pcd_ascii.substr(data_a)});
  files.push_back({"pcd_ascii_fewer_lines.pcd", good.pcd_ascii.substr(0, data_a + 40)});
  files.push_back({"pcd_ascii_integer_fraction.pcd",
                   replaced(replaced(good.pcd_ascii, "TYPE F F F F", "TYPE F F F U"),
                            "SIZE 4 4 4 4",
                            "SIZE 4 4 4 1")});
  return files;
}

std::vector<Hostile>
plyLies(const GoodFiles& good)
{
  std::vector<Hostile> files;
  const std::vector<std::pair<std::string, std::pair<std::string, std::string>>> lies = {
      {"vertex_2p32", {"element vertex 200", "element vertex 4294967296"}},
      {"vertex_99999999999", {"element vertex 200", "element vertex 99999999999"}},
      {"vertex_negative", {"element vertex 200", "element vertex -1"}},
      {"vertex_more_than_data", {"element vertex 200", "element vertex 3000000"}},
      {"list_on_vertex", {"property float x", "property list uint float x"}},
      {"unknown_type", {"property float x", "property float128 x"}},
      {"no_format", {"format ", "comment "}},
      {"no_end_header", {"end_header", "end_hedder"}},
      {"face_first",
       {"element vertex 200",
        "element face 4294967295\nproperty list uchar int "
        "vertex_indices\nelement vertex 200"}},
      {"no_vertex", {"element vertex 200", "element point 200"}},
      {"magic", {"ply", "plz"}},
  };
  for (const auto& [kind, bytes] : std::vector<std::pair<std::string, std::string>>{
           {"ascii", good.ply_ascii}, {"binary", good.ply_binary}})
    for (const auto& [lie, edit] : lies)
      files.push_back(
          {"ply_" + kind + "_" + lie + ".ply", replaced(bytes, edit.first, edit.second)});
  const std::size_t end = good.ply_ascii.find("end_header\n") + 11;
  files.push_back({"ply_ascii_words.ply",
                   good.ply_ascii.substr(0, end) + std::string(200 * 20, 'w') + "\n"});
  files.push_back(
      {"ply_binary_truncated.ply",
       good.ply_binary.substr(0, good.ply_binary.find("end_header\n") + 11 + 100)});
  files.push_back(
      {"ply_big_endian_truncated.ply",
       replaced(good.ply_binary.substr(0, good.ply_binary.find("end_header\n") + 11 + 30),
                "binary_little_endian",
                "binary_big_endian")});
  return files;
}

std::vector<Hostile>
binLies()
{
  return {{"bin_17_bytes.bin", std::string(17, '\x01')},
          {"bin_15_bytes.bin", std::string(15, '\x01')},
          {"bin_text.bin", "not a float scan at all\n"}};
}

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
  std::vector<Hostile> files = pcdHeaderLies(good);
  for (auto* more : {&pcdBodyLies, &plyLies}) {
    const std::vector<Hostile> extra = more(good);
    files.insert(files.end(), extra.begin(), extra.end());
  }
  for (const Hostile& h : binLies())
    files.push_back(h);
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
