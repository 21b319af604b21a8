/// \file test_sequence_reader.cpp
/// \brief Tests of the streaming scan-sequence reader: format round trips, ordering,
/// selection, times.txt, bad input and real data.

#include "test_data.h"

#include <cmath>
#include <filesystem>
#include <fstream>
#include <gtest/gtest.h>
#include <limits>
#include <pcl/io/pcd_io.h>
#include <pcl/io/ply_io.h>
#include <pcl/slam/sequence_reader.h>
#include <random>
#include <string>
#include <unistd.h>
#include <vector>

namespace fs = std::filesystem;
using pcl::rast::readScan;
using pcl::rast::ScanFrame;
using pcl::rast::ScanReadError;
using pcl::rast::SequenceReader;
using pcl::rast::SequenceReaderOptions;
using pcl::rast::writeKittiBin;
using Cloud = pcl::PointCloud<pcl::PointXYZI>;

namespace {

/// A seeded random cloud; intensity in [0, 1].
Cloud
randomCloud(std::size_t n, unsigned seed)
{
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> coord(-60.0f, 60.0f);
  std::uniform_real_distribution<float> unit(0.0f, 1.0f);
  Cloud cloud;
  for (std::size_t i = 0; i < n; ++i) {
    pcl::PointXYZI p;
    p.x = coord(rng);
    p.y = coord(rng);
    p.z = coord(rng);
    p.intensity = unit(rng);
    cloud.push_back(p);
  }
  return cloud;
}

/// A cloud whose single point carries \a tag in x and intensity, to identify files.
Cloud
taggedCloud(float tag)
{
  Cloud cloud;
  pcl::PointXYZI p;
  p.x = tag;
  p.y = 1.0f;
  p.z = 2.0f;
  p.intensity = tag;
  cloud.push_back(p);
  return cloud;
}

void
writeText(const fs::path& path, const std::string& text)
{
  std::ofstream out(path, std::ios::binary);
  out << text;
}

void
expectCloudsNear(const Cloud& expected, const Cloud& actual, float tol)
{
  ASSERT_EQ(expected.size(), actual.size());
  for (std::size_t i = 0; i < expected.size(); ++i) {
    EXPECT_NEAR(expected[i].x, actual[i].x, tol) << "point " << i;
    EXPECT_NEAR(expected[i].y, actual[i].y, tol) << "point " << i;
    EXPECT_NEAR(expected[i].z, actual[i].z, tol) << "point " << i;
    EXPECT_NEAR(expected[i].intensity, actual[i].intensity, tol) << "point " << i;
  }
}

/// Expect readScan(path) to throw a ScanReadError naming the path and \a phrase.
void
expectScanReadError(const fs::path& path, const std::string& phrase)
{
  try {
    readScan(path.string());
    ADD_FAILURE() << "no ScanReadError for " << path;
  } catch (const ScanReadError& e) {
    EXPECT_EQ(e.path(), path.string());
    EXPECT_NE(std::string(e.what()).find(path.string()), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find(phrase), std::string::npos)
        << "expected '" << phrase << "' in: " << e.what();
  }
}

/// The message of the exception of type E thrown by constructing a reader.
template <typename E>
std::string
constructorError(const fs::path& folder, const SequenceReaderOptions& options = {})
{
  try {
    SequenceReader reader(folder.string(), options);
  } catch (const E& e) {
    return e.what();
  } catch (const std::exception& e) {
    ADD_FAILURE() << "wrong exception type: " << e.what();
    return "";
  }
  ADD_FAILURE() << "no exception for " << folder;
  return "";
}

/// Tagged .bin files named by \a names, each tagged with its position in \a names.
void
writeTaggedBins(const fs::path& dir, const std::vector<std::string>& names)
{
  for (std::size_t i = 0; i < names.size(); ++i)
    writeKittiBin((dir / names[i]).string(), taggedCloud(static_cast<float>(i)));
}

std::string
kittiName(int i)
{
  char name[32];
  std::snprintf(name, sizeof name, "%06d.bin", i);
  return name;
}

} // namespace

// ---------------------------------------------------------------- options

TEST(SequenceReaderOptions, Validation)
{
  std::string why;
  EXPECT_TRUE(SequenceReaderOptions().isValid(&why));

  SequenceReaderOptions o;
  o.stride = 0;
  EXPECT_FALSE(o.isValid(&why));
  EXPECT_NE(why.find("stride"), std::string::npos) << why;

  o = SequenceReaderOptions();
  o.first = 5;
  o.last = 4;
  EXPECT_FALSE(o.isValid(&why));
  EXPECT_NE(why.find("first"), std::string::npos) << why;
  o.last = 5;
  EXPECT_TRUE(o.isValid(nullptr));

  o = SequenceReaderOptions();
  o.last = -2;
  EXPECT_FALSE(o.isValid(nullptr));

  const fs::path dir = pcl_rast_test::makeTempDir("seq");
  writeTaggedBins(dir, {kittiName(0)});
  o.last = -2;
  EXPECT_NE(constructorError<std::invalid_argument>(dir, o).find("last"),
            std::string::npos);
}

// ---------------------------------------------------------------- format round trips

TEST(ReadScan, KittiBinRoundTripIsExact)
{
  const fs::path dir = pcl_rast_test::makeTempDir("seq");
  const Cloud cloud = randomCloud(1000, 1);
  const fs::path path = dir / "000000.bin";
  writeKittiBin(path.string(), cloud);
  EXPECT_EQ(fs::file_size(path), 1000u * 16u);
  EXPECT_FALSE(fs::exists(path.string() + ".tmp")) << "temporary file left behind";

  std::size_t dropped = 99;
  const Cloud::Ptr read = readScan(path.string(), &dropped);
  ASSERT_TRUE(read);
  EXPECT_EQ(dropped, 0u);
  EXPECT_EQ(read->width, 1000u);
  EXPECT_EQ(read->height, 1u);
  EXPECT_TRUE(read->is_dense);
  expectCloudsNear(cloud, *read, 0.0f);

  // Overwriting replaces the file atomically with the new content.
  writeKittiBin(path.string(), randomCloud(10, 2));
  EXPECT_EQ(readScan(path.string())->size(), 10u);
}

TEST(ReadScan, KittiBinLayoutIsFloat32XYZI)
{
  // Hand-written bytes, independent of writeKittiBin.
  const fs::path dir = pcl_rast_test::makeTempDir("seq");
  const float values[8] = {1.5f, -2.0f, 3.25f, 0.5f, 10.0f, 20.0f, 30.0f, 0.0f};
  {
    std::ofstream out(dir / "a.bin", std::ios::binary);
    out.write(reinterpret_cast<const char*>(values), sizeof values);
  }
  const Cloud::Ptr read = readScan((dir / "a.bin").string());
  ASSERT_EQ(read->size(), 2u);
  EXPECT_EQ((*read)[0].x, 1.5f);
  EXPECT_EQ((*read)[0].y, -2.0f);
  EXPECT_EQ((*read)[0].z, 3.25f);
  EXPECT_EQ((*read)[0].intensity, 0.5f);
  EXPECT_EQ((*read)[1].z, 30.0f);
}

TEST(ReadScan, PcdAsciiBinaryCompressedRoundTrip)
{
  const fs::path dir = pcl_rast_test::makeTempDir("seq");
  const Cloud cloud = randomCloud(500, 3);
  ASSERT_EQ(pcl::io::savePCDFileASCII((dir / "ascii.pcd").string(), cloud), 0);
  ASSERT_EQ(pcl::io::savePCDFileBinary((dir / "binary.pcd").string(), cloud), 0);
  ASSERT_EQ(
      pcl::io::savePCDFileBinaryCompressed((dir / "compressed.pcd").string(), cloud), 0);
  expectCloudsNear(cloud, *readScan((dir / "ascii.pcd").string()), 1e-4f);
  expectCloudsNear(cloud, *readScan((dir / "binary.pcd").string()), 0.0f);
  expectCloudsNear(cloud, *readScan((dir / "compressed.pcd").string()), 0.0f);
}

TEST(ReadScan, PlyAsciiAndBinaryRoundTrip)
{
  const fs::path dir = pcl_rast_test::makeTempDir("seq");
  const Cloud cloud = randomCloud(300, 4);
  ASSERT_EQ(pcl::io::savePLYFileASCII((dir / "ascii.ply").string(), cloud), 0);
  ASSERT_EQ(pcl::io::savePLYFileBinary((dir / "binary.ply").string(), cloud), 0);
  expectCloudsNear(cloud, *readScan((dir / "ascii.ply").string()), 1e-4f);
  expectCloudsNear(cloud, *readScan((dir / "binary.ply").string()), 0.0f);
}

TEST(ReadScan, NoIntensityGivesZeroAndAliasesAreUsed)
{
  const fs::path dir = pcl_rast_test::makeTempDir("seq");
  pcl::PointCloud<pcl::PointXYZ> xyz;
  xyz.push_back(pcl::PointXYZ(1.0f, 2.0f, 3.0f));
  xyz.push_back(pcl::PointXYZ(4.0f, 5.0f, 6.0f));
  ASSERT_EQ(pcl::io::savePCDFileBinary((dir / "xyz.pcd").string(), xyz), 0);
  ASSERT_EQ(pcl::io::savePLYFileBinary((dir / "xyz.ply").string(), xyz), 0);
  for (const char* name : {"xyz.pcd", "xyz.ply"}) {
    const Cloud::Ptr read = readScan((dir / name).string());
    ASSERT_EQ(read->size(), 2u) << name;
    EXPECT_EQ((*read)[1].x, 4.0f) << name;
    EXPECT_EQ((*read)[1].z, 6.0f) << name;
    EXPECT_EQ((*read)[0].intensity, 0.0f) << name;
    EXPECT_EQ((*read)[1].intensity, 0.0f) << name;
  }

  // CloudCompare-style PLY: double coordinates and a `scalar_intensity` property.
  writeText(dir / "cc.ply",
            "ply\nformat ascii 1.0\nelement vertex 2\n"
            "property double x\nproperty double y\nproperty double z\n"
            "property float scalar_intensity\nend_header\n"
            "1.5 2.5 3.5 0.25\n-1 -2 -3 0.75\n");
  const Cloud::Ptr cc = readScan((dir / "cc.ply").string());
  ASSERT_EQ(cc->size(), 2u);
  EXPECT_FLOAT_EQ((*cc)[0].y, 2.5f);
  EXPECT_FLOAT_EQ((*cc)[0].intensity, 0.25f);
  EXPECT_FLOAT_EQ((*cc)[1].intensity, 0.75f);

  // PCD with a uint8 intensity is converted to float.
  writeText(dir / "u8.pcd",
            "VERSION 0.7\nFIELDS x y z intensity\nSIZE 4 4 4 1\nTYPE F F F U\n"
            "COUNT 1 1 1 1\nWIDTH 2\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 2\n"
            "DATA ascii\n1 2 3 200\n4 5 6 7\n");
  const Cloud::Ptr u8 = readScan((dir / "u8.pcd").string());
  ASSERT_EQ(u8->size(), 2u);
  EXPECT_EQ((*u8)[0].intensity, 200.0f);
  EXPECT_EQ((*u8)[1].intensity, 7.0f);
}

TEST(ReadScan, NonFinitePointsAreDroppedAndCounted)
{
  const fs::path dir = pcl_rast_test::makeTempDir("seq");
  Cloud cloud = randomCloud(10, 5);
  const float nan = std::numeric_limits<float>::quiet_NaN();
  const float inf = std::numeric_limits<float>::infinity();
  cloud[1].x = nan;
  cloud[3].y = inf;
  cloud[4].z = -inf;
  cloud[8].intensity = nan;
  cloud.is_dense = false;
  Cloud finite;
  for (std::size_t i : {0, 2, 5, 6, 7, 9})
    finite.push_back(cloud[i]);

  writeKittiBin((dir / "a.bin").string(), cloud);
  ASSERT_EQ(pcl::io::savePCDFileBinary((dir / "a.pcd").string(), cloud), 0);
  ASSERT_EQ(pcl::io::savePCDFileBinaryCompressed((dir / "b.pcd").string(), cloud), 0);
  for (const char* name : {"a.bin", "a.pcd", "b.pcd"}) {
    std::size_t dropped = 0;
    const Cloud::Ptr read = readScan((dir / name).string(), &dropped);
    EXPECT_EQ(dropped, 4u) << name;
    EXPECT_TRUE(read->is_dense) << name;
    expectCloudsNear(finite, *read, 0.0f);
  }

  // Through the sequence reader the count lands in the frame.
  const fs::path seq = dir / "seq";
  fs::create_directories(seq);
  writeKittiBin((seq / "0.bin").string(), cloud);
  SequenceReader reader(seq.string());
  ScanFrame frame;
  ASSERT_TRUE(reader.next(frame));
  EXPECT_EQ(frame.num_dropped_non_finite, 4u);
  EXPECT_EQ(frame.cloud->size(), 6u);
}

// ---------------------------------------------------------------- bad scans

TEST(ReadScan, TruncatedBinNamesFileAndSize)
{
  const fs::path dir = pcl_rast_test::makeTempDir("seq");
  writeText(dir / "t.bin", std::string(36, '\0'));
  expectScanReadError(dir / "t.bin", "36");
  expectScanReadError(dir / "t.bin", "multiple of 16");
}

TEST(ReadScan, EmptyFilesAreErrors)
{
  const fs::path dir = pcl_rast_test::makeTempDir("seq");
  for (const char* name : {"e.bin", "e.pcd", "e.ply"}) {
    writeText(dir / name, "");
    expectScanReadError(dir / name, "empty");
  }
}

TEST(ReadScan, UnreadableAndMissingFilesAreErrors)
{
  const fs::path dir = pcl_rast_test::makeTempDir("seq");
  expectScanReadError(dir / "missing.bin", "does not exist");

  // A directory with a scan name cannot be read, even by root.
  fs::create_directories(dir / "x.bin");
  expectScanReadError(dir / "x.bin", "directory");
}

TEST(ReadScan, PermissionDeniedIsAnError)
{
  if (::geteuid() == 0)
    GTEST_SKIP() << "running as root: chmod 000 does not stop reading; the unreadable "
                    "case is covered by a directory named x.bin in "
                    "UnreadableAndMissingFilesAreErrors";
  const fs::path dir = pcl_rast_test::makeTempDir("seq");
  const fs::path locked = dir / "locked.bin";
  writeKittiBin(locked.string(), randomCloud(4, 6));
  fs::permissions(locked, fs::perms::none);
  expectScanReadError(locked, "cannot open");
  fs::permissions(locked, fs::perms::owner_all);
}

TEST(ReadScan, UnparseableFilesAreErrors)
{
  const fs::path dir = pcl_rast_test::makeTempDir("seq");
  writeText(dir / "garbage.pcd", "this is not a point cloud\n");
  expectScanReadError(dir / "garbage.pcd", "cannot parse .pcd");
  writeText(dir / "garbage.ply", "this is not a point cloud\n");
  expectScanReadError(dir / "garbage.ply", "cannot parse .ply");
  // A PCD header that promises more points than the data holds.
  writeText(dir / "short.pcd",
            "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\n"
            "WIDTH 100\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 100\nDATA binary\n"
            "abcdefgh");
  expectScanReadError(dir / "short.pcd", "truncated binary .pcd");
  // An ASCII body with fewer rows than POINTS.
  writeText(dir / "short_ascii.pcd",
            "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\n"
            "WIDTH 3\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 3\nDATA ascii\n1 2 3\n");
  EXPECT_THROW(readScan((dir / "short_ascii.pcd").string()), ScanReadError);
  // A compressed body cut short.
  const fs::path compressed = dir / "cut.pcd";
  ASSERT_EQ(
      pcl::io::savePCDFileBinaryCompressed(compressed.string(), randomCloud(1000, 11)),
      0);
  fs::resize_file(compressed, fs::file_size(compressed) - 2000);
  expectScanReadError(compressed, "truncated binary_compressed");
  // A truncated binary PLY.
  const fs::path ply = dir / "cut.ply";
  ASSERT_EQ(pcl::io::savePLYFileBinary(ply.string(), randomCloud(1000, 12)), 0);
  fs::resize_file(ply, fs::file_size(ply) - 2000);
  EXPECT_THROW(readScan(ply.string()), ScanReadError);
  // Fields without x/y/z.
  writeText(dir / "noxyz.pcd",
            "VERSION 0.7\nFIELDS a b\nSIZE 4 4\nTYPE F F\nCOUNT 1 1\n"
            "WIDTH 1\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 1\nDATA ascii\n1 2\n");
  expectScanReadError(dir / "noxyz.pcd", "x, y and z");
  writeText(dir / "scan.xyz", "1 2 3\n");
  expectScanReadError(dir / "scan.xyz", "unsupported");
}

// ---------------------------------------------------------------- sequences

TEST(SequenceReader, ConstructorOnlyListsFiles)
{
  const fs::path dir = pcl_rast_test::makeTempDir("seq");
  writeTaggedBins(dir, {kittiName(0)});
  writeText(dir / kittiName(1), std::string(5, 'x')); // truncated, but not read yet
  SequenceReader reader(dir.string());
  EXPECT_EQ(reader.size(), 2u);
  EXPECT_EQ(reader.numFiles(), 2u);
  EXPECT_EQ(reader.position(), 0u);
  EXPECT_THROW(reader.read(1), ScanReadError);
}

TEST(SequenceReader, NumericOrder)
{
  const fs::path dir = pcl_rast_test::makeTempDir("seq");
  // Tag i = expected position: 2 < 9 < 10 < 11 numerically, not lexicographically.
  writeTaggedBins(dir, {"2.bin", "000009.bin", "000010.bin", "11.bin"});
  SequenceReader reader(dir.string());
  ASSERT_EQ(reader.size(), 4u);
  ScanFrame frame;
  for (std::size_t i = 0; i < 4; ++i) {
    ASSERT_TRUE(reader.next(frame));
    EXPECT_EQ(frame.sequence_index, i);
    EXPECT_EQ(frame.file_index, i);
    EXPECT_EQ(frame.cloud->front().intensity, static_cast<float>(i)) << frame.path;
    EXPECT_DOUBLE_EQ(frame.timestamp_s, static_cast<double>(i));
  }
  EXPECT_FALSE(reader.next(frame));
  EXPECT_FALSE(reader.next(frame));

  // Large indices like 251370668.pcd; a shorter number comes first.
  const fs::path big = dir / "big";
  fs::create_directories(big);
  writeTaggedBins(big, {"99999999.bin", "251370668.bin", "251371071.bin"});
  SequenceReader big_reader(big.string());
  for (std::size_t i = 0; i < 3; ++i)
    EXPECT_EQ(big_reader.read(i).cloud->front().intensity, static_cast<float>(i));
}

TEST(SequenceReader, LexicographicOrderForNonNumericNames)
{
  const fs::path dir = pcl_rast_test::makeTempDir("seq");
  writeTaggedBins(dir, {"alpha.bin", "beta.bin", "gamma.bin"});
  writeText(dir / "notes.txt", "not a scan");
  SequenceReader reader(dir.string());
  ASSERT_EQ(reader.size(), 3u);
  for (std::size_t i = 0; i < 3; ++i)
    EXPECT_EQ(reader.read(i).cloud->front().intensity, static_cast<float>(i));
  EXPECT_EQ(fs::path(reader.path(0)).filename(), "alpha.bin");
}

TEST(SequenceReader, FirstLastStride)
{
  const fs::path dir = pcl_rast_test::makeTempDir("seq");
  std::vector<std::string> names;
  for (int i = 0; i < 10; ++i)
    names.push_back(kittiName(i));
  writeTaggedBins(dir, names);

  SequenceReaderOptions o;
  o.first = 2;
  o.last = 8;
  o.stride = 3;
  SequenceReader reader(dir.string(), o);
  ASSERT_EQ(reader.size(), 3u);
  EXPECT_EQ(reader.numFiles(), 10u);
  const std::size_t expected[] = {2, 5, 8};
  ScanFrame frame;
  for (std::size_t i = 0; i < 3; ++i) {
    ASSERT_TRUE(reader.next(frame));
    EXPECT_EQ(frame.sequence_index, i);
    EXPECT_EQ(frame.file_index, expected[i]);
    EXPECT_EQ(frame.cloud->front().intensity, static_cast<float>(expected[i]));
    EXPECT_DOUBLE_EQ(frame.timestamp_s, static_cast<double>(expected[i]));
    EXPECT_DOUBLE_EQ(reader.timestamp(i), static_cast<double>(expected[i]));
  }
  EXPECT_FALSE(reader.next(frame));

  // last = -1 runs to the end, inclusive.
  o = SequenceReaderOptions();
  o.stride = 4;
  SequenceReader to_end(dir.string(), o);
  ASSERT_EQ(to_end.size(), 3u);
  EXPECT_EQ(to_end.read(2).file_index, 8u);
  o.stride = 1;
  o.first = 9;
  EXPECT_EQ(SequenceReader(dir.string(), o).size(), 1u);

  // first / last beyond the folder.
  o = SequenceReaderOptions();
  o.first = 10;
  EXPECT_NE(constructorError<std::invalid_argument>(dir, o).find("10"),
            std::string::npos);
  o.first = 0;
  o.last = 10;
  EXPECT_NE(constructorError<std::invalid_argument>(dir, o).find("last"),
            std::string::npos);

  // Random access and seek.
  EXPECT_THROW(reader.read(3), std::out_of_range);
  EXPECT_THROW(reader.path(3), std::out_of_range);
  reader.seek(1);
  ASSERT_TRUE(reader.next(frame));
  EXPECT_EQ(frame.file_index, 5u);
  EXPECT_EQ(reader.position(), 2u);
  EXPECT_THROW(reader.seek(4), std::out_of_range);
}

TEST(SequenceReader, TimesTxt)
{
  const fs::path dir = pcl_rast_test::makeTempDir("seq");
  std::vector<std::string> names;
  std::string times;
  for (int i = 0; i < 5; ++i) {
    names.push_back(kittiName(i));
    times += std::to_string(100.5 + 0.25 * i) + "\n";
  }
  writeTaggedBins(dir, names);
  writeText(dir / "times.txt", times);

  SequenceReaderOptions o;
  o.first = 1;
  o.stride = 2;
  SequenceReader reader(dir.string(), o);
  EXPECT_EQ(reader.timesPath(), (dir / "times.txt").string());
  ASSERT_EQ(reader.size(), 2u);
  EXPECT_DOUBLE_EQ(reader.read(0).timestamp_s, 100.75);
  EXPECT_DOUBLE_EQ(reader.read(1).timestamp_s, 101.25);

  // KITTI odometry layout: sequence/times.txt beside sequence/velodyne/.
  const fs::path seq = dir / "seq";
  fs::create_directories(seq / "velodyne");
  writeTaggedBins(seq / "velodyne", {kittiName(0), kittiName(1)});
  writeText(seq / "times.txt", "0.000000e+00\n1.036600e-01\n");
  SequenceReader kitti(seq.string());
  EXPECT_EQ(kitti.timesPath(), (seq / "times.txt").string());
  EXPECT_DOUBLE_EQ(kitti.timestamp(1), 0.10366);

  // Wrong length: an error naming the file and both counts.
  writeText(seq / "times.txt", "0\n1\n2\n");
  const std::string msg = constructorError<std::runtime_error>(seq);
  EXPECT_NE(msg.find((seq / "times.txt").string()), std::string::npos) << msg;
  EXPECT_NE(msg.find("3"), std::string::npos) << msg;
  EXPECT_NE(msg.find("2 scans"), std::string::npos) << msg;

  // Malformed line.
  writeText(seq / "times.txt", "0\nabc\n");
  EXPECT_NE(constructorError<std::runtime_error>(seq).find("line 2"), std::string::npos);
}

TEST(SequenceReader, FindsScanSubfolder)
{
  const fs::path dir = pcl_rast_test::makeTempDir("seq");
  for (const char* sub : {"velodyne", "pcd", "ply"}) {
    const fs::path root = dir / (std::string("root_") + sub);
    fs::create_directories(root / sub);
    writeText(root / "README.txt", "not a scan");
    const Cloud cloud = randomCloud(20, 7);
    const std::string name =
        std::string("000000.") + (sub == std::string("velodyne") ? "bin" : sub);
    if (sub == std::string("velodyne"))
      writeKittiBin((root / sub / name).string(), cloud);
    else if (sub == std::string("pcd"))
      ASSERT_EQ(pcl::io::savePCDFileBinary((root / sub / name).string(), cloud), 0);
    else
      ASSERT_EQ(pcl::io::savePLYFileBinary((root / sub / name).string(), cloud), 0);
    SequenceReader reader(root.string());
    EXPECT_EQ(fs::path(reader.scanFolder()).filename(), sub);
    ASSERT_EQ(reader.size(), 1u);
    expectCloudsNear(cloud, *reader.read(0).cloud, 0.0f);
  }
}

TEST(SequenceReader, FolderErrors)
{
  const fs::path dir = pcl_rast_test::makeTempDir("seq");
  std::string msg = constructorError<std::invalid_argument>(dir / "nope");
  EXPECT_NE(msg.find((dir / "nope").string()), std::string::npos) << msg;
  EXPECT_NE(msg.find("does not exist"), std::string::npos) << msg;

  fs::create_directories(dir / "empty");
  writeText(dir / "empty" / "notes.txt", "x");
  fs::create_directories(dir / "empty" / "velodyne");
  msg = constructorError<std::invalid_argument>(dir / "empty");
  EXPECT_NE(msg.find((dir / "empty").string()), std::string::npos) << msg;
  EXPECT_NE(msg.find("no scans"), std::string::npos) << msg;

  fs::create_directories(dir / "mixed");
  writeKittiBin((dir / "mixed" / "000000.bin").string(), randomCloud(3, 8));
  ASSERT_EQ(pcl::io::savePCDFileBinary((dir / "mixed" / "000001.pcd").string(),
                                       randomCloud(3, 9)),
            0);
  msg = constructorError<std::invalid_argument>(dir / "mixed");
  EXPECT_NE(msg.find((dir / "mixed").string()), std::string::npos) << msg;
  EXPECT_NE(msg.find(".bin"), std::string::npos) << msg;
  EXPECT_NE(msg.find(".pcd"), std::string::npos) << msg;

  writeKittiBin((dir / "file.bin").string(), randomCloud(3, 10));
  EXPECT_NE(
      constructorError<std::invalid_argument>(dir / "file.bin").find("not a folder"),
      std::string::npos);
}

TEST(SequenceReader, ContinuesAfterBadFrames)
{
  const fs::path dir = pcl_rast_test::makeTempDir("seq");
  writeTaggedBins(dir, {kittiName(0)});
  writeText(dir / kittiName(1), std::string(20, '\0')); // truncated
  writeText(dir / kittiName(2), "");                    // empty
  fs::create_directories(dir / kittiName(3));           // unreadable
  writeKittiBin((dir / kittiName(4)).string(), taggedCloud(4.0f));

  SequenceReader reader(dir.string());
  ASSERT_EQ(reader.size(), 5u);
  std::vector<std::size_t> good;
  std::vector<std::string> bad_paths;
  ScanFrame frame;
  for (int guard = 0; guard < 20; ++guard) {
    try {
      if (!reader.next(frame))
        break;
      good.push_back(frame.file_index);
    } catch (const ScanReadError& e) {
      bad_paths.push_back(e.path());
    }
  }
  EXPECT_EQ(good, (std::vector<std::size_t>{0, 4}));
  ASSERT_EQ(bad_paths.size(), 3u);
  EXPECT_EQ(fs::path(bad_paths[0]).filename(), kittiName(1));
  EXPECT_EQ(fs::path(bad_paths[1]).filename(), kittiName(2));
  EXPECT_EQ(fs::path(bad_paths[2]).filename(), kittiName(3));
  EXPECT_EQ(frame.cloud->front().intensity, 4.0f);
}

// ---------------------------------------------------------------- real data

TEST(SequenceReaderRealData, KittiRaw22PcdSubfolder)
{
  PCL_RAST_REQUIRE_SHARED_DATA(data);
  SequenceReader reader((data / "kitti-raw-22").string());
  EXPECT_EQ(fs::path(reader.scanFolder()).filename(), "pcd");
  ASSERT_EQ(reader.size(), 22u);
  std::size_t total = 0;
  ScanFrame frame;
  float max_intensity = 0.0f;
  while (reader.next(frame)) {
    EXPECT_EQ(fs::path(frame.path).stem().string().size(), 10u);
    EXPECT_GT(frame.cloud->size(), 100000u) << frame.path;
    EXPECT_LT(frame.cloud->size(), 130000u) << frame.path;
    total += frame.cloud->size();
    for (const auto& p : *frame.cloud)
      max_intensity = std::max(max_intensity, p.intensity);
  }
  const double mean = static_cast<double>(total) / 22.0;
  EXPECT_NEAR(mean, 117000.0, 5000.0);
  EXPECT_GT(max_intensity, 0.1f) << "intensity field not read";

  // Cross-check the first frame against PCL's own loader.
  Cloud reference;
  ASSERT_EQ(pcl::io::loadPCDFile(reader.path(0), reference), 0);
  std::size_t dropped = 0;
  const Cloud::Ptr first = readScan(reader.path(0), &dropped);
  EXPECT_EQ(first->size() + dropped, reference.size());
  std::size_t j = 0;
  for (const auto& p : reference) {
    if (!std::isfinite(p.x) || !std::isfinite(p.y) || !std::isfinite(p.z))
      continue;
    ASSERT_LT(j, first->size());
    EXPECT_EQ((*first)[j].x, p.x);
    EXPECT_EQ((*first)[j].intensity, p.intensity);
    ++j;
  }
}

TEST(SequenceReaderRealData, KittiRaw78VelodyneSubfolder)
{
  PCL_RAST_REQUIRE_SHARED_DATA(data);
  SequenceReader reader((data / "kitti-raw-78").string());
  EXPECT_EQ(fs::path(reader.scanFolder()).filename(), "velodyne");
  ASSERT_EQ(reader.size(), 78u);
  EXPECT_TRUE(reader.timesPath().empty());
  ScanFrame frame;
  std::size_t count = 0;
  while (reader.next(frame)) {
    EXPECT_EQ(frame.file_index, count);
    EXPECT_DOUBLE_EQ(frame.timestamp_s, static_cast<double>(count));
    EXPECT_EQ(frame.cloud->size() + frame.num_dropped_non_finite,
              fs::file_size(frame.path) / 16)
        << frame.path;
    EXPECT_GT(frame.cloud->size(), 50000u) << frame.path;
    ++count;
  }
  EXPECT_EQ(count, 78u);

  // Stride over real data.
  SequenceReaderOptions o;
  o.first = 10;
  o.last = 70;
  o.stride = 20;
  SequenceReader strided((data / "kitti-raw-78").string(), o);
  ASSERT_EQ(strided.size(), 4u);
  EXPECT_EQ(fs::path(strided.path(3)).filename(), "0000000070.bin");
}

TEST(SequenceReaderRealData, ScanPairPlyAndPcd)
{
  PCL_RAST_REQUIRE_SHARED_DATA(data);
  SequenceReader ply((data / "scan-pair-ply").string());
  ASSERT_EQ(ply.size(), 2u);
  EXPECT_EQ(fs::path(ply.path(0)).filename(), "source.ply");
  EXPECT_EQ(fs::path(ply.path(1)).filename(), "target.ply");
  for (std::size_t i = 0; i < 2; ++i) {
    const ScanFrame frame = ply.read(i);
    EXPECT_GT(frame.cloud->size(), 60000u);
    EXPECT_LT(frame.cloud->size(), 80000u);
    float max_intensity = 0.0f;
    for (const auto& p : *frame.cloud)
      max_intensity = std::max(max_intensity, p.intensity);
    EXPECT_GT(max_intensity, 0.0f) << "scalar_intensity not read from " << frame.path;
  }

  SequenceReader pcd((data / "scan-pair-pcd").string());
  ASSERT_EQ(pcd.size(), 2u);
  EXPECT_EQ(fs::path(pcd.path(0)).filename(), "251370668.pcd");
  const ScanFrame first = pcd.read(0);
  EXPECT_EQ(first.cloud->size() + first.num_dropped_non_finite,
            69088u); // POINTS in header
}
