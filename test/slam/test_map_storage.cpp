/// Storage behind the SLAM map: BlobStore in memory and spilled to disk, the tiled
/// merged map (forEachMapTile / buildMap) against one global voxel grid, and the
/// streaming, atomic PCD writer.

#include "test_data.h"

#include <pcl/io/pcd_io.h>
#include <pcl/io/sequence_reader.h>
#include <pcl/slam/blob_store.h>
#include <pcl/slam/slam_map.h>

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <filesystem>
#include <random>
#include <stdexcept>
#include <thread>
#include <tuple>
#include <vector>

// This file's names stay its own: a test program compiles several test files as
// one translation unit (test/CMakeLists.txt).
namespace test_map_storage {

namespace {

using namespace pcl::rast;
namespace fs = std::filesystem;

using pcl_rast_test::countFiles;

void
roundTrip(BlobStore& store)
{
  std::mt19937 rng(7);
  std::vector<std::vector<std::uint32_t>> blobs;
  std::vector<BlobStore::Handle> handles;
  for (int i = 0; i < 50; ++i) {
    std::vector<std::uint32_t> blob(rng() % 2000);
    for (auto& v : blob)
      v = rng();
    handles.push_back(store.putVector(blob));
    blobs.push_back(std::move(blob));
  }
  for (std::size_t i = blobs.size(); i-- > 0;) // read back out of order
    EXPECT_EQ(store.getVector<std::uint32_t>(handles[i]), blobs[i]) << "blob " << i;
}

TEST(BlobStore, RoundTripsInMemory)
{
  BlobStore store;
  EXPECT_FALSE(store.spilled());
  roundTrip(store);
  EXPECT_GT(store.memoryBytes(), 0u);
  EXPECT_EQ(store.fileBytes(), 0u);
}

TEST(BlobStore, RoundTripsOnDiskAndLeavesNoFileBehind)
{
  const fs::path dir = pcl_rast_test::makeTempDir("blob_store");
  {
    BlobStore store(dir.string());
    EXPECT_TRUE(store.spilled());
    roundTrip(store);
    EXPECT_EQ(store.memoryBytes(), 0u);
    EXPECT_GT(store.fileBytes(), 0u);
    EXPECT_EQ(countFiles(dir), 0u) << "the spill file must be anonymous";
  }
  EXPECT_EQ(countFiles(dir), 0u);
}

TEST(BlobStore, ConcurrentWritersAndReaders)
{
  const fs::path dir = pcl_rast_test::makeTempDir("blob_store");
  BlobStore store(dir.string());
  std::vector<std::vector<BlobStore::Handle>> handles(2);
  std::vector<std::thread> threads;
  for (int t = 0; t < 2; ++t)
    threads.emplace_back([&, t] {
      for (std::uint32_t i = 0; i < 500; ++i) {
        const std::vector<std::uint32_t> blob(1 + i % 37, (t << 16) | i);
        handles[t].push_back(store.putVector(blob));
        EXPECT_EQ(store.getVector<std::uint32_t>(handles[t].back()), blob);
      }
    });
  for (auto& th : threads)
    th.join();
  for (int t = 0; t < 2; ++t)
    for (std::uint32_t i = 0; i < 500; ++i)
      EXPECT_EQ(store.getVector<std::uint32_t>(handles[t][i]),
                std::vector<std::uint32_t>(1 + i % 37, (t << 16) | i));
}

TEST(BlobStore, ReportsBadUse)
{
  try {
    BlobStore store("/nonexistent/pcl_rast_spill_dir");
    FAIL() << "expected std::runtime_error";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("/nonexistent/pcl_rast_spill_dir"), std::string::npos)
        << e.what();
  }
  BlobStore store;
  EXPECT_THROW(store.getVector<int>(BlobStore::Handle{5, 4}), std::runtime_error);
}

/// Three key-frames whose clouds are 1 cm-exact grids spanning several 100 m tiles.
SlamMap::Ptr
makeMap(BlobStore::Ptr store)
{
  auto map = std::make_shared<SlamMap>(0.0, std::move(store));
  std::mt19937 rng(11);
  std::uniform_int_distribution<int> cm(-15000, 15000); // +-150 m, 1 cm steps
  for (KeyFrameId id = 0; id < 3; ++id) {
    auto kf = std::make_shared<KeyFrame>();
    kf->id = id;
    // Steps of whole 3 m and a quarter turn: world coordinates stay on the 1 cm grid,
    // and those not on a 30 cm boundary locally are not on one in the world either.
    kf->T_previous_keyframe = Pose3d::Identity();
    if (id > 0) {
      kf->T_previous_keyframe.translation() = Eigen::Vector3d(36.0, -12.0, 3.0);
      kf->T_previous_keyframe.linear() =
          Eigen::AngleAxisd(0.5 * 3.14159265358979323846, Eigen::Vector3d::UnitZ())
              .toRotationMatrix()
              .array()
              .round()
              .matrix();
    }
    auto cloud = std::make_shared<pcl::PointCloud<pcl::PointXYZI>>();
    // No coordinate on a multiple of 30 cm (the voxel boundaries of the 0.3 m grid
    // below), where float and double rounding could pick different voxels.
    const auto coordinate = [&](int range_cm) {
      int v = 0;
      do
        v = cm(rng) % range_cm;
      while (v % 30 == 0);
      return v * 0.01f;
    };
    for (int i = 0; i < 20000; ++i) {
      pcl::PointXYZI p;
      p.x = coordinate(15001);
      p.y = coordinate(15001);
      p.z = coordinate(500);
      p.intensity = static_cast<float>(rng() % 100);
      cloud->push_back(p);
    }
    kf->cloud = cloud;
    map->addKeyFrame(kf);
  }
  return map;
}

std::vector<std::array<float, 4>>
sortedPoints(const pcl::PointCloud<pcl::PointXYZI>& cloud)
{
  std::vector<std::array<float, 4>> out;
  for (const auto& p : cloud.points)
    out.push_back({p.x, p.y, p.z, p.intensity});
  std::sort(out.begin(), out.end());
  return out;
}

void
expectSamePoints(const pcl::PointCloud<pcl::PointXYZI>& a, const pcl::PointCloud<pcl::PointXYZI>& b)
{
  ASSERT_EQ(a.size(), b.size());
  const auto pa = sortedPoints(a), pb = sortedPoints(b);
  double max_diff = 0.0;
  for (std::size_t i = 0; i < pa.size(); ++i)
    for (int k = 0; k < 4; ++k)
      max_diff = std::max(max_diff, static_cast<double>(std::abs(pa[i][k] - pb[i][k])));
  EXPECT_LT(max_diff, 1e-3);
}

TEST(SlamMapTiles, TiledMapEqualsOneGlobalVoxelGrid)
{
  const fs::path dir = pcl_rast_test::makeTempDir("map_tiles");
  for (const bool spill : {false, true}) {
    SCOPED_TRACE(spill ? "spilled" : "in memory");
    const auto map = makeMap(std::make_shared<BlobStore>(spill ? dir.string() : ""));
    const auto all = map->buildMap(0.0);
    ASSERT_EQ(all->size(), 60000u);
    // Leaf 0.3 m does not divide the 100 m tiles evenly: tiles hold whole voxels anyway.
    const auto global = voxelDownsample(*all, 0.3);
    const auto tiled = map->buildMap(0.3);
    expectSamePoints(*tiled, *global);
    std::size_t tiles = 0, points = 0;
    map->forEachMapTile(0.3, [&](const pcl::PointCloud<pcl::PointXYZI>& tile) {
      ++tiles;
      points += tile.size();
    });
    EXPECT_GT(tiles, 9u) << "the clouds span several tiles";
    EXPECT_EQ(points, tiled->size());
    const SlamMap::MemoryUsage m = map->memoryUsage();
    EXPECT_EQ(spill ? m.map_clouds : m.map_clouds_on_disk, 0u);
    EXPECT_GT(spill ? m.map_clouds_on_disk : m.map_clouds, 0u);
    EXPECT_EQ(map->keyFrameCloud(1)->size(), 20000u);
  }
  EXPECT_THROW(makeMap(nullptr)->forEachMapTile(0.0, [](const auto&) {}), std::invalid_argument);
}

TEST(PcdStreamWriter, WritesWhatBuildMapGivesAtomically)
{
  const fs::path dir = pcl_rast_test::makeTempDir("pcd_stream");
  const auto map = makeMap(nullptr);
  const std::string path = (dir / "map.pcd").string();
  {
    PcdStreamWriter pcd(path);
    map->forEachMapTile(0.5, [&](const pcl::PointCloud<pcl::PointXYZI>& tile) { pcd.append(tile); });
    EXPECT_FALSE(fs::exists(path)) << "nothing may appear before commit";
    EXPECT_EQ(countFiles(dir), 0u);
    pcd.commit();
    EXPECT_THROW(pcd.commit(), std::logic_error);
    EXPECT_THROW(pcd.append(*map->buildMap(0.5)), std::logic_error);
  }
  EXPECT_EQ(countFiles(dir), 1u) << "no temporary file left beside map.pcd";
  pcl::PointCloud<pcl::PointXYZI> loaded;
  ASSERT_EQ(pcl::io::loadPCDFile(path, loaded), 0);
  expectSamePoints(loaded, *map->buildMap(0.5));

  { // destroyed without commit: nothing written
    PcdStreamWriter pcd((dir / "abandoned.pcd").string());
    pcd.append(loaded);
  }
  EXPECT_FALSE(fs::exists(dir / "abandoned.pcd"));
  { // empty: a valid empty PCD
    PcdStreamWriter pcd((dir / "empty.pcd").string());
    pcd.commit();
  }
  // Read as a blob: PCL's typed conversion of an empty cloud takes &points[0] of an
  // empty vector (undefined behaviour that UBSan reports, conversions.h:178).
  pcl::PCLPointCloud2 empty;
  ASSERT_EQ(pcl::io::loadPCDFile((dir / "empty.pcd").string(), empty), 0);
  EXPECT_EQ(empty.width * empty.height, 0u);
  EXPECT_EQ(pcl::rast::readScan((dir / "empty.pcd").string())->size(), 0u);
  EXPECT_THROW(PcdStreamWriter("/nonexistent/dir/map.pcd"), std::runtime_error);
}

} // namespace

} // namespace test_map_storage
