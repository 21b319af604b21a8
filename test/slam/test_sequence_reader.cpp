/// \file test_sequence_reader.cpp
/// \brief Tests of the streaming scan-sequence reader: format round trips, ordering,
/// selection, times.txt, per-point times, bad input and real data.

#include "random_cloud.h"
#include "test_data.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <gtest/gtest.h>
#include <limits>
#include <pcl/PCLPointCloud2.h>
#include <pcl/io/pcd_io.h>
#include <pcl/io/ply_io.h>
#include <pcl/io/sequence_reader.h>
#include <random>
#include <string>
#include <unistd.h>
#include <vector>

// This file's names stay its own: a test program compiles several test files as
// one translation unit (test/CMakeLists.txt).
namespace test_sequence_reader {

namespace fs = std::filesystem;
using pcl::rast::readScan;
using pcl::rast::ScanFrame;
using pcl::rast::ScanReadError;
using pcl::rast::SequenceReader;
using pcl::rast::SequenceReaderOptions;
using pcl::rast::writeKittiBin;
using Cloud = pcl::PointCloud<pcl::PointXYZI>;

namespace {

using pcl_rast_test::randomCloud;

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

/// A per-point field of a hand-built scan: name, PCL type and one value per point.
struct ExtraField
{
  std::string name;
  std::uint8_t datatype;
  std::vector<double> values;
};

/// Store \a v as the PCL type \a datatype (FLOAT32, FLOAT64 or UINT32) at \a p.
void
storeAs(std::uint8_t datatype, double v, std::uint8_t* p)
{
  if (datatype == pcl::PCLPointField::FLOAT32) {
    const float f = static_cast<float>(v);
    std::memcpy(p, &f, sizeof f);
  } else if (datatype == pcl::PCLPointField::FLOAT64) {
    std::memcpy(p, &v, sizeof v);
  } else if (datatype == pcl::PCLPointField::UINT32) {
    const std::uint32_t u = static_cast<std::uint32_t>(v);
    std::memcpy(p, &u, sizeof u);
  } else {
    ADD_FAILURE() << "storeAs: unsupported datatype " << int(datatype);
  }
}

/// Write \a points (float x y z intensity) with \a extra fields as a binary PCD of
/// \a height rows (row-major; height 1 = unorganized), the way a driver would save a
/// sweep with its per-point times.
void
writePcdWithFields(const fs::path& path,
                   const Cloud& points,
                   const std::vector<ExtraField>& extra,
                   std::uint32_t height = 1)
{
  pcl::PCLPointCloud2 blob;
  std::uint32_t offset = 0;
  auto addField = [&](const std::string& name, std::uint8_t datatype) {
    pcl::PCLPointField f;
    f.name = name;
    f.offset = offset;
    f.datatype = datatype;
    f.count = 1;
    blob.fields.push_back(f);
    offset += static_cast<std::uint32_t>(pcl::getFieldSize(datatype));
  };
  for (const char* name : {"x", "y", "z", "intensity"})
    addField(name, pcl::PCLPointField::FLOAT32);
  for (const ExtraField& e : extra) {
    ASSERT_EQ(e.values.size(), points.size()) << e.name;
    addField(e.name, e.datatype);
  }
  ASSERT_EQ(points.size() % height, 0u);
  blob.height = height;
  blob.width = static_cast<std::uint32_t>(points.size() / height);
  blob.point_step = offset;
  blob.row_step = blob.point_step * blob.width;
  blob.is_dense = false;
  blob.data.resize(static_cast<std::size_t>(blob.row_step) * height);
  for (std::size_t i = 0; i < points.size(); ++i) {
    std::uint8_t* pt = blob.data.data() + i * blob.point_step;
    const float xyzi[4] = {points[i].x, points[i].y, points[i].z, points[i].intensity};
    std::memcpy(pt, xyzi, sizeof xyzi);
    for (std::size_t e = 0; e < extra.size(); ++e)
      storeAs(extra[e].datatype, extra[e].values[i], pt + blob.fields[4 + e].offset);
  }
  ASSERT_EQ(pcl::PCDWriter().writeBinary(path.string(), blob), 0) << path;
}

/// \a n times from \a start, \a step apart.
std::vector<double>
rampTimes(std::size_t n, double start, double step)
{
  std::vector<double> times(n);
  for (std::size_t i = 0; i < n; ++i)
    times[i] = start + step * static_cast<double>(i);
  return times;
}

/// Write one scan with a single time field into a fresh folder \a dir and read it
/// back through the sequence reader.
ScanFrame
readTimedScan(const fs::path& dir,
              const Cloud& points,
              const ExtraField& time_field,
              std::uint32_t height = 1)
{
  fs::create_directories(dir);
  writePcdWithFields(dir / "000000.pcd", points, {time_field}, height);
  return SequenceReader(dir.string()).read(0);
}

/// Expect \a frame to carry no times and a warning naming \a field and \a phrase,
/// with its cloud still read (\a num_points points).
void
expectTimesRejected(const ScanFrame& frame,
                    const std::string& field,
                    const std::string& phrase,
                    std::size_t num_points)
{
  EXPECT_TRUE(frame.point_times_s.empty());
  EXPECT_TRUE(frame.time_field.empty()) << frame.time_field;
  EXPECT_NE(frame.time_warning.find("'" + field + "'"), std::string::npos)
      << frame.time_warning;
  EXPECT_NE(frame.time_warning.find(phrase), std::string::npos)
      << "expected '" << phrase << "' in: " << frame.time_warning;
  ASSERT_TRUE(frame.cloud);
  EXPECT_EQ(frame.cloud->size(), num_points) << "the scan itself must still be read";
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
  for (const auto& entry : fs::directory_iterator(dir))
    EXPECT_EQ(entry.path().filename(), "000000.bin") << "temporary file left behind";

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
  cloud[8].intensity = nan; // intensity is optional: kept as 0
  cloud.is_dense = false;
  Cloud finite;
  for (std::size_t i : {0, 2, 5, 6, 7, 8, 9})
    finite.push_back(cloud[i]);
  finite[5].intensity = 0.0f;

  writeKittiBin((dir / "a.bin").string(), cloud);
  ASSERT_EQ(pcl::io::savePCDFileBinary((dir / "a.pcd").string(), cloud), 0);
  ASSERT_EQ(pcl::io::savePCDFileBinaryCompressed((dir / "b.pcd").string(), cloud), 0);
  for (const char* name : {"a.bin", "a.pcd", "b.pcd"}) {
    std::size_t dropped = 0;
    const Cloud::Ptr read = readScan((dir / name).string(), &dropped);
    EXPECT_EQ(dropped, 3u) << name;
    EXPECT_TRUE(read->is_dense) << name;
    EXPECT_EQ(read->width, 7u) << name;
    EXPECT_EQ(read->height, 1u) << name;
    expectCloudsNear(finite, *read, 0.0f);
  }

  // Through the sequence reader the count lands in the frame.
  const fs::path seq = dir / "seq";
  fs::create_directories(seq);
  writeKittiBin((seq / "0.bin").string(), cloud);
  SequenceReader reader(seq.string());
  ScanFrame frame;
  ASSERT_TRUE(reader.next(frame));
  EXPECT_EQ(frame.num_dropped_non_finite, 3u);
  EXPECT_EQ(frame.cloud->size(), 7u);
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
  expectScanReadError(dir / "short.pcd", "truncated data");
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
  expectScanReadError(compressed, "truncated binary_compressed data");
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

// ---------------------------------------------------------------- per-point times

TEST(SequenceReaderPointTimes, FloatSecondsAreCentredOnTheSweep)
{
  const fs::path dir = pcl_rast_test::makeTempDir("seq");
  const Cloud points = randomCloud(1001, 21);
  // Velodyne-like `time` in s from 0 to 0.1, and a `timestamp` field that must lose
  // against it (priority: time first).
  fs::create_directories(dir / "scan");
  writePcdWithFields(
      dir / "scan" / "000000.pcd",
      points,
      {{"timestamp", pcl::PCLPointField::FLOAT64, std::vector<double>(1001, 42.0)},
       {"time", pcl::PCLPointField::FLOAT32, rampTimes(1001, 0.0, 1e-4)}});
  const ScanFrame frame = SequenceReader((dir / "scan").string()).read(0);
  EXPECT_EQ(frame.time_field, "time");
  EXPECT_TRUE(frame.time_warning.empty()) << frame.time_warning;
  ASSERT_EQ(frame.point_times_s.size(), frame.cloud->size());
  ASSERT_EQ(frame.point_times_s.size(), 1001u);
  EXPECT_NEAR(frame.point_times_s.front(), -0.05, 1e-6);
  EXPECT_NEAR(frame.point_times_s[500], 0.0, 1e-6);
  EXPECT_NEAR(frame.point_times_s.back(), 0.05, 1e-6);
  EXPECT_NEAR(frame.point_times_s[100], 0.01 - 0.05, 1e-6);

  // readScan alone gives the same cloud.
  expectCloudsNear(*frame.cloud, *readScan(frame.path), 0.0f);
}

TEST(SequenceReaderPointTimes, OrganizedOusterNanosecondsRestartEachRow)
{
  // Ouster-like: 16 beams (rows) x 64 columns, uint32 `t` in ns since the sweep start,
  // increasing along each row and starting again on the next one (with a 100 ns
  // offset per beam). Read as one list, the 15 restarts would be 15 of 1023 steps
  // backwards (1.5 % > 1 %): only the per-row check accepts it.
  const std::uint32_t rows = 16, cols = 64;
  const double column_ns = 1562500.0; // 64 columns in 0.1 s
  const Cloud points = randomCloud(rows * cols, 22);
  ExtraField t{"t", pcl::PCLPointField::UINT32, {}};
  for (std::uint32_t r = 0; r < rows; ++r)
    for (std::uint32_t c = 0; c < cols; ++c)
      t.values.push_back(c * column_ns + r * 100.0);
  const ScanFrame frame =
      readTimedScan(pcl_rast_test::makeTempDir("seq") / "os", points, t, rows);
  EXPECT_EQ(frame.time_field, "t");
  EXPECT_TRUE(frame.time_warning.empty()) << frame.time_warning;
  ASSERT_EQ(frame.point_times_s.size(), rows * cols);

  const double mid_ns = 0.5 * (0.0 + (63 * column_ns + 15 * 100.0));
  auto expected_s = [&](std::uint32_t r, std::uint32_t c) {
    return (c * column_ns + r * 100.0 - mid_ns) * 1e-9;
  };
  EXPECT_NEAR(frame.point_times_s[5 * cols + 10], expected_s(5, 10), 1e-7);
  EXPECT_NEAR(frame.point_times_s[0], expected_s(0, 0), 1e-7);
  EXPECT_NEAR(frame.point_times_s[rows * cols - 1], expected_s(15, 63), 1e-7);
  // Every row starts near -span/2 again.
  for (std::uint32_t r = 0; r < rows; ++r)
    EXPECT_NEAR(frame.point_times_s[r * cols], -0.0492, 1e-4) << "row " << r;
}

TEST(SequenceReaderPointTimes, AbsoluteDoubleTimestampKeepsMicroseconds)
{
  // Hesai-like absolute times around 1.7e9 s: a float has a 128 s step there, so only
  // reading them as double and subtracting in double keeps the 0.1 ms steps.
  const Cloud points = randomCloud(1000, 23);
  const double t0 = 1.7e9 + 0.123456;
  const ScanFrame frame = readTimedScan(
      pcl_rast_test::makeTempDir("seq") / "hesai",
      points,
      {"timestamp", pcl::PCLPointField::FLOAT64, rampTimes(1000, t0, 1e-4)});
  EXPECT_EQ(frame.time_field, "timestamp");
  EXPECT_TRUE(frame.time_warning.empty()) << frame.time_warning;
  ASSERT_EQ(frame.point_times_s.size(), 1000u);
  const double mid = 0.5 * 999 * 1e-4;
  for (std::size_t i : {0u, 1u, 2u, 377u, 998u, 999u})
    EXPECT_NEAR(frame.point_times_s[i], i * 1e-4 - mid, 1e-6) << "point " << i;
}

TEST(SequenceReaderPointTimes, NonFiniteTimeIsRejected)
{
  const fs::path dir = pcl_rast_test::makeTempDir("seq");
  const Cloud points = randomCloud(200, 24);
  struct Case
  {
    const char* field;
    std::uint8_t datatype;
    std::size_t index;
    double bad_value;
    const char* phrase;
  };
  for (const Case& c : {Case{"time",
                             pcl::PCLPointField::FLOAT32,
                             7,
                             std::numeric_limits<double>::quiet_NaN(),
                             "NaN"},
                        Case{"ts",
                             pcl::PCLPointField::FLOAT64,
                             150,
                             std::numeric_limits<double>::infinity(),
                             "infinite"}}) {
    std::vector<double> times = rampTimes(200, 0.0, 5e-4);
    times[c.index] = c.bad_value;
    expectTimesRejected(
        readTimedScan(dir / c.field, points, {c.field, c.datatype, times}),
        c.field,
        c.phrase,
        200);
  }
}

TEST(SequenceReaderPointTimes, EqualTimesAreRejected)
{
  const Cloud points = randomCloud(100, 25);
  expectTimesRejected(
      readTimedScan(
          pcl_rast_test::makeTempDir("seq") / "eq",
          points,
          {"time", pcl::PCLPointField::FLOAT32, std::vector<double>(100, 0.05)}),
      "time",
      "equal",
      100);
}

TEST(SequenceReaderPointTimes, ShuffledOrderIsNotMonotonic)
{
  const fs::path dir = pcl_rast_test::makeTempDir("seq");
  const Cloud sweep = randomCloud(1000, 26);
  const std::vector<double> times = rampTimes(1000, 0.0, 1e-4);

  // The same points and times, stored in a shuffled order (fixed seed).
  std::vector<std::size_t> order(1000);
  for (std::size_t i = 0; i < order.size(); ++i)
    order[i] = i;
  std::shuffle(order.begin(), order.end(), std::mt19937(26));
  Cloud shuffled;
  std::vector<double> shuffled_times;
  for (std::size_t i : order) {
    shuffled.push_back(sweep[i]);
    shuffled_times.push_back(times[i]);
  }
  expectTimesRejected(
      readTimedScan(dir / "shuffled",
                    shuffled,
                    {"time", pcl::PCLPointField::FLOAT32, shuffled_times}),
      "time",
      "not monotonic",
      1000);

  // A few restarts (4 rows of 250 stored as one list: 3 of 999 steps back, 0.3 %)
  // are within the 1 % allowed.
  std::vector<double> rows_times;
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 250; ++c)
      rows_times.push_back(c * 4e-4);
  const ScanFrame rows = readTimedScan(
      dir / "rows", sweep, {"offset_time", pcl::PCLPointField::FLOAT64, rows_times});
  EXPECT_TRUE(rows.time_warning.empty()) << rows.time_warning;
  EXPECT_EQ(rows.time_field, "offset_time");
  EXPECT_EQ(rows.point_times_s.size(), 1000u);
}

TEST(SequenceReaderPointTimes, UnitFollowsTheSpan)
{
  const fs::path dir = pcl_rast_test::makeTempDir("seq");
  const Cloud points = randomCloud(101, 27);
  // A 0.1 s sweep in s, ms, us and ns: the first unit that makes the span lie in
  // [0.005, 0.5] s is taken, so all four give -0.05 ... +0.05 s.
  int k = 0;
  for (double span : {0.1, 100.0, 1e5, 1e8}) {
    const ScanFrame frame = readTimedScan(
        dir / ("ok" + std::to_string(k++)),
        points,
        {"time", pcl::PCLPointField::FLOAT64, rampTimes(101, 0.0, span / 100)});
    EXPECT_TRUE(frame.time_warning.empty()) << span << ": " << frame.time_warning;
    ASSERT_EQ(frame.point_times_s.size(), 101u) << span;
    EXPECT_NEAR(frame.point_times_s.front(), -0.05, 1e-6) << span;
    EXPECT_NEAR(frame.point_times_s.back(), 0.05, 1e-6) << span;
  }

  // Spans that are no sweep in any unit: 2 (2 s or 2 ms), 1000 (1 s or 1 ms),
  // 1e6 (1 s or 1 ms).
  for (double span : {2.0, 1000.0, 1e6})
    expectTimesRejected(
        readTimedScan(
            dir / ("bad" + std::to_string(k++)),
            points,
            {"time", pcl::PCLPointField::FLOAT64, rampTimes(101, 0.0, span / 100)}),
        "time",
        "fits no unit",
        101);

  // A span of 50 cannot be told from a 50 ms sweep: the rule reads it as ms.
  const ScanFrame fifty =
      readTimedScan(dir / "fifty",
                    points,
                    {"time", pcl::PCLPointField::FLOAT64, rampTimes(101, 0.0, 0.5)});
  EXPECT_TRUE(fifty.time_warning.empty()) << fifty.time_warning;
  ASSERT_EQ(fifty.point_times_s.size(), 101u);
  EXPECT_NEAR(fifty.point_times_s.back(), 0.025, 1e-6);
}

TEST(SequenceReaderPointTimes, PlyTimeProperty)
{
  const fs::path dir = pcl_rast_test::makeTempDir("seq");
  fs::create_directories(dir / "ascii");
  writeText(dir / "ascii" / "000000.ply",
            "ply\nformat ascii 1.0\nelement vertex 5\n"
            "property float x\nproperty float y\nproperty float z\n"
            "property float intensity\nproperty float time\nend_header\n"
            "1 0 0 0.1 0\n0 1 0 0.2 0.025\n-1 0 0 0.3 0.05\n0 -1 0 0.4 0.075\n"
            "1 1 0 0.5 0.1\n");
  const ScanFrame frame = SequenceReader((dir / "ascii").string()).read(0);
  EXPECT_EQ(frame.time_field, "time");
  EXPECT_TRUE(frame.time_warning.empty()) << frame.time_warning;
  ASSERT_EQ(frame.cloud->size(), 5u);
  ASSERT_EQ(frame.point_times_s.size(), 5u);
  const float expected[5] = {-0.05f, -0.025f, 0.0f, 0.025f, 0.05f};
  for (std::size_t i = 0; i < 5; ++i)
    EXPECT_NEAR(frame.point_times_s[i], expected[i], 1e-6) << "point " << i;

  // Binary little-endian PLY with an absolute double `timestamp`.
  fs::create_directories(dir / "binary");
  {
    std::ofstream out(dir / "binary" / "000000.ply", std::ios::binary);
    out << "ply\nformat binary_little_endian 1.0\nelement vertex 3\n"
           "property float x\nproperty float y\nproperty float z\n"
           "property double timestamp\nend_header\n";
    for (int i = 0; i < 3; ++i) {
      const float xyz[3] = {1.0f + i, 2.0f, 3.0f};
      const double t = 1.7e9 + 0.04 * i;
      out.write(reinterpret_cast<const char*>(xyz), sizeof xyz);
      out.write(reinterpret_cast<const char*>(&t), sizeof t);
    }
  }
  const ScanFrame binary = SequenceReader((dir / "binary").string()).read(0);
  EXPECT_EQ(binary.time_field, "timestamp");
  EXPECT_TRUE(binary.time_warning.empty()) << binary.time_warning;
  ASSERT_EQ(binary.point_times_s.size(), 3u);
  EXPECT_NEAR(binary.point_times_s[0], -0.04, 1e-6);
  EXPECT_NEAR(binary.point_times_s[1], 0.0, 1e-6);
  EXPECT_NEAR(binary.point_times_s[2], 0.04, 1e-6);
}

TEST(SequenceReaderPointTimes, DroppedPointsKeepTimesAligned)
{
  Cloud points = randomCloud(100, 28);
  std::vector<double> times = rampTimes(100, 0.0, 1e-3); // 0 ... 0.099 s
  const float nan = std::numeric_limits<float>::quiet_NaN();
  points[10].x = nan;
  points[50].y = nan;
  points[70].z = std::numeric_limits<float>::infinity();
  // The time of a dropped point does not count, even when it is NaN itself.
  times[10] = std::numeric_limits<double>::quiet_NaN();
  const ScanFrame frame = readTimedScan(pcl_rast_test::makeTempDir("seq") / "drop",
                                        points,
                                        {"time", pcl::PCLPointField::FLOAT32, times});
  EXPECT_EQ(frame.num_dropped_non_finite, 3u);
  EXPECT_TRUE(frame.time_warning.empty()) << frame.time_warning;
  ASSERT_EQ(frame.cloud->size(), 97u);
  ASSERT_EQ(frame.point_times_s.size(), 97u);

  // Output point 60 is input point 62 (10 and 50 dropped before it).
  const double mid = 0.5 * 0.099;
  EXPECT_EQ((*frame.cloud)[60].x, points[62].x);
  EXPECT_NEAR(frame.point_times_s[60], 0.062 - mid, 1e-6);
  // And every kept point has its own time.
  std::size_t k = 0;
  for (std::size_t i = 0; i < 100; ++i) {
    if (i == 10 || i == 50 || i == 70)
      continue;
    EXPECT_NEAR(frame.point_times_s[k], times[i] - mid, 1e-6) << "input point " << i;
    ++k;
  }
}

TEST(SequenceReaderPointTimes, ScansWithoutTimeFieldHaveNoTimesAndNoWarning)
{
  const fs::path dir = pcl_rast_test::makeTempDir("seq");
  const Cloud cloud = randomCloud(50, 29);
  fs::create_directories(dir / "bin");
  writeKittiBin((dir / "bin" / "000000.bin").string(), cloud);
  fs::create_directories(dir / "pcd");
  ASSERT_EQ(pcl::io::savePCDFileBinary((dir / "pcd" / "000000.pcd").string(), cloud), 0);
  for (const char* sub : {"bin", "pcd"}) {
    const ScanFrame frame = SequenceReader((dir / sub).string()).read(0);
    EXPECT_EQ(frame.cloud->size(), 50u) << sub;
    EXPECT_TRUE(frame.point_times_s.empty()) << sub;
    EXPECT_TRUE(frame.time_field.empty()) << sub;
    EXPECT_TRUE(frame.time_warning.empty()) << sub << ": " << frame.time_warning;
  }
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

} // namespace test_sequence_reader
