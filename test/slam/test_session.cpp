/// Sessions (issue 13): a finished run saved and loaded back as it was; damaged,
/// future or foreign sessions refused naming the file before any work; saves that
/// replace a session whole or leave it as it was.

#include "temp_cleanup.h"

#include <boost/crc.hpp>
#include <filesystem>
#include <fstream>
#include <gtest/gtest.h>
#include <iterator>
#include <pcl/rast/file_checksum.h>
#include <pcl/simulation/lidar_simulator.h>
#include <pcl/slam/rast_slam.h>
#include <pcl/slam/session.h>
#include <random>
#include <string>
#include <vector>

// This file's names stay its own: a test program compiles several test files as
// one translation unit (test/CMakeLists.txt).
namespace test_session {

namespace {

using namespace pcl::rast;
namespace fs = std::filesystem;

/// A fresh folder for one test, removed when the process exits.
fs::path
tempDir(const std::string& tag)
{
  const fs::path dir = fs::temp_directory_path() / "pcl_rast_test" /
                       ("session_" + tag + "_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  pcl_rast_test::removeAtExit(dir);
  return dir;
}

/// One finished SLAM run on a simulated 60-frame HDL-64 drive (seed 5), shared by the
/// tests of this file.
const RastSlam&
finishedRun()
{
  static const std::unique_ptr<RastSlam> slam = [] {
    PathParams path;
    path.type = PathType::kStraight;
    path.num_frames = 60;
    LidarSimulatorParams params;
    params.seed = 5;
    params.num_threads = 2;
    LidarSimulator sim(params, generatePath(path));
    SlamParams slam_params;
    slam_params.deterministic = true;
    auto run = std::make_unique<RastSlam>(slam_params);
    for (std::size_t i = 0; i < sim.numFrames(); ++i) {
      auto cloud = std::make_shared<pcl::PointCloud<pcl::PointXYZI>>();
      sim.simulateFrame(i, *cloud);
      run->addScan(cloud, sim.timestamp(i), i);
    }
    run->finish();
    return run;
  }();
  return *slam;
}

SessionInfo
hdl64Info()
{
  SessionInfo info;
  info.sensor_preset = "hdl64";
  info.created_by = "test_session";
  info.parameters_json = R"({"threads": "off"})";
  return info;
}

/// A saved session of the shared run, made once per process.
const fs::path&
savedSession()
{
  static const fs::path dir = [] {
    const fs::path d = tempDir("saved") / "session";
    saveSession(finishedRun(), d.string(), hdl64Info());
    return d;
  }();
  return dir;
}

fs::path
copyOfSession(const std::string& tag)
{
  const fs::path copy = tempDir(tag) / "session";
  fs::copy(savedSession(), copy, fs::copy_options::recursive);
  return copy;
}

std::string
readText(const fs::path& path)
{
  std::ifstream in(path, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

void
writeText(const fs::path& path, const std::string& text)
{
  std::ofstream(path, std::ios::binary | std::ios::trunc) << text;
}

/// The SessionError loadSession throws for \a dir, or a failure.
SessionError
loadError(const fs::path& dir, const SessionLoadOptions& options = SessionLoadOptions())
{
  try {
    loadSession(dir.string(), options);
  } catch (const SessionError& e) {
    return e;
  }
  ADD_FAILURE() << "loadSession(" << dir << ") did not throw";
  return SessionError("", "");
}

// The checksums of saved sessions and output sets are CRC-32 (IEEE), the check value
// of the CRC catalogue and Boost.CRC's, which computed them before zlib did: sessions
// saved before still load. The second file crosses the 1 MiB read blocks.
TEST(FileChecksum, IsTheStandardCrc32AcrossReadBlocks)
{
  const fs::path dir = tempDir("crc");
  const fs::path check = dir / "check.txt";
  std::ofstream(check, std::ios::binary) << "123456789";
  EXPECT_EQ(fileCrc32(check.string()), "cbf43926");

  std::vector<char> bytes((5u << 19) + 7); // 2.5 MiB and a few bytes
  std::mt19937 rng(42);
  for (char& b : bytes)
    b = static_cast<char>(rng());
  const fs::path big = dir / "big.bin";
  std::ofstream(big, std::ios::binary)
      .write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
  boost::crc_32_type reference;
  reference.process_bytes(bytes.data(), bytes.size());
  char hex[9];
  std::snprintf(hex, sizeof hex, "%08x", reference.checksum());
  EXPECT_EQ(fileCrc32(big.string()), hex);

  const fs::path empty = dir / "empty.bin";
  std::ofstream(empty, std::ios::binary).close();
  EXPECT_EQ(fileCrc32(empty.string()), "00000000");
  try {
    fileCrc32((dir / "missing.bin").string());
    FAIL() << "a missing file was checksummed";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("missing.bin"), std::string::npos) << e.what();
  }
}

TEST(Session, ASavedRunLoadsBackAsItWas)
{
  const RastSlam& slam = finishedRun();
  const fs::path dir = savedSession();
  const Session session = loadSession(dir.string());

  const std::vector<KeyFrame::Ptr> keyframes = slam.keyFrames();
  const PoseVector poses = slam.keyFramePoses();
  ASSERT_GE(keyframes.size(), 3u);
  ASSERT_EQ(session.keyframes.size(), keyframes.size());
  EXPECT_EQ(session.version, kSessionFormatVersion);
  EXPECT_EQ(session.info.sensor_preset, "hdl64");
  EXPECT_EQ(session.info.created_by, "test_session");
  EXPECT_EQ(session.info.num_frames, 60u);
  EXPECT_NE(session.info.parameters_json.find("threads"), std::string::npos);
  EXPECT_EQ(session.graph.numNodes(), keyframes.size());
  EXPECT_EQ(session.graph.numEdges(), keyframes.size() - 1); // odometry only: no loop
  EXPECT_TRUE(fs::exists(dir / "session.json"));
  EXPECT_TRUE(fs::exists(dir / "graph.g2o"));

  for (std::size_t i = 0; i < keyframes.size(); ++i) {
    SCOPED_TRACE("key-frame " + std::to_string(i));
    const KeyFrame& saved = *keyframes[i];
    const KeyFrame& loaded = *session.keyframes[i];
    EXPECT_EQ(loaded.id, saved.id);
    EXPECT_EQ(loaded.frame_index, saved.frame_index);
    EXPECT_DOUBLE_EQ(loaded.timestamp_s, saved.timestamp_s);
    EXPECT_EQ(loaded.odometry_map_scans, saved.odometry_map_scans);
    EXPECT_LT((loaded.T_world_keyframe.matrix() - poses[i].matrix()).cwiseAbs().maxCoeff(), 1e-9);
    EXPECT_LT((loaded.T_previous_keyframe.matrix() -
               slam.map()->odometryEdge(saved.id).matrix())
                  .cwiseAbs()
                  .maxCoeff(),
              1e-9);
    // The graph's nodes are the same poses (g2o keeps fewer digits).
    EXPECT_LT((session.graph.node(static_cast<int>(i)).pose().translation() -
               poses[i].translation())
                  .norm(),
              1e-4);
    // Features: every point and every descriptor bit.
    ASSERT_EQ(loaded.features.size(), saved.features.size());
    for (std::size_t k = 0; k < saved.features.size(); ++k) {
      ASSERT_EQ(loaded.features.descriptors[k], saved.features.descriptors[k]) << k;
      EXPECT_EQ(loaded.features.points[k].x, saved.features.points[k].x);
      EXPECT_EQ(loaded.features.points[k].octave, saved.features.points[k].octave);
    }
    // The cloud is the map's compact copy, point for point.
    const auto compact = slam.map()->keyFrameCloud(saved.id);
    ASSERT_TRUE(loaded.cloud);
    ASSERT_EQ(loaded.cloud->size(), compact->size());
    ASSERT_GT(compact->size(), 1000u);
    for (std::size_t k = 0; k < compact->size(); k += 97) {
      EXPECT_EQ(loaded.cloud->points[k].x, compact->points[k].x);
      EXPECT_EQ(loaded.cloud->points[k].intensity, compact->points[k].intensity);
    }
  }
  // Features were kept for the key-frames the loop database holds.
  EXPECT_FALSE(session.keyframes.back()->features.empty());

  // Without clouds: the same key-frames, no cloud read.
  SessionLoadOptions no_clouds;
  no_clouds.load_clouds = false;
  const Session light = loadSession(dir.string(), no_clouds);
  ASSERT_EQ(light.keyframes.size(), keyframes.size());
  EXPECT_FALSE(light.keyframes.front()->cloud);
}

// A session loaded without its clouds still gives the whole map: the clouds are read
// from its files tile by tile (pcl_rast_slam -session holds no prior cloud), the same
// voxels as from the clouds in memory.
TEST(Session, TheMapOfASessionLoadedWithoutCloudsIsReadFromItsFiles)
{
  const Session full = loadSession(savedSession().string());
  SessionLoadOptions no_clouds;
  no_clouds.load_clouds = false;
  const Session light = loadSession(savedSession().string(), no_clouds);
  ASSERT_FALSE(light.keyframes.front()->cloud);
  struct MapSum
  {
    std::size_t points = 0, tiles = 0;
    double x = 0.0, z = 0.0, intensity = 0.0;
  };
  const auto mapOf = [](const auto& build) {
    MapSum sum;
    build([&](const pcl::PointCloud<pcl::PointXYZI>& tile) {
      ++sum.tiles;
      for (const auto& p : tile.points) {
        ++sum.points;
        sum.x += p.x;
        sum.z += p.z;
        sum.intensity += p.intensity;
      }
    });
    return sum;
  };
  const MapSum in_memory = mapOf([&](const SlamMap::MapTileSink& sink) {
    forEachSessionMapTile(full.keyframes, 0.5, sink);
  });
  const MapSum from_files = mapOf([&](const SlamMap::MapTileSink& sink) {
    forEachSessionMapTile(light, light.keyframes, 0.5, sink);
  });
  ASSERT_GT(in_memory.points, 1000u);
  EXPECT_EQ(from_files.points, in_memory.points);
  EXPECT_EQ(from_files.tiles, in_memory.tiles);
  EXPECT_DOUBLE_EQ(from_files.x, in_memory.x);
  EXPECT_DOUBLE_EQ(from_files.z, in_memory.z);
  EXPECT_DOUBLE_EQ(from_files.intensity, in_memory.intensity);
  // Without the session, key-frames with no cloud in memory add nothing.
  const MapSum without_session = mapOf([&](const SlamMap::MapTileSink& sink) {
    forEachSessionMapTile(light.keyframes, 0.5, sink);
  });
  EXPECT_EQ(without_session.points, 0u);
  EXPECT_THROW(forEachSessionMapTile(light, light.keyframes, 0.0, [](const auto&) {}),
               std::invalid_argument);
}

TEST(Session, LoopsAndASessionInMemoryRoundTrip)
{
  Session session = loadSession(savedSession().string());
  ASSERT_GE(session.keyframes.size(), 3u);
  LoopEdge loop;
  loop.query = static_cast<KeyFrameId>(session.keyframes.size() - 1);
  loop.candidate = 0;
  loop.num_inliers = 77;
  loop.T_candidate_query = session.keyframes.front()->T_world_keyframe.inverse() *
                           session.keyframes.back()->T_world_keyframe;
  session.loops.push_back(loop);
  session.graph.addEdge(0, static_cast<int>(loop.query), loop.T_candidate_query,
                        Eigen::Matrix<double, 6, 6>::Identity(), PoseGraphEdgeType::kLoop);
  session.info.sensor_preset = "vlp16";

  const fs::path dir = tempDir("loops") / "merged";
  saveSession(session, dir.string());
  const Session loaded = loadSession(dir.string());
  ASSERT_EQ(loaded.loops.size(), 1u);
  EXPECT_EQ(loaded.loops[0].query, loop.query);
  EXPECT_EQ(loaded.loops[0].candidate, 0u);
  EXPECT_EQ(loaded.loops[0].num_inliers, 77);
  EXPECT_LT((loaded.loops[0].T_candidate_query.matrix() - loop.T_candidate_query.matrix())
                .cwiseAbs()
                .maxCoeff(),
            1e-9);
  EXPECT_EQ(loaded.graph.numEdges(), session.graph.numEdges());
  EXPECT_EQ(loaded.info.sensor_preset, "vlp16");
  ASSERT_EQ(loaded.keyframes.size(), session.keyframes.size());
  EXPECT_EQ(loaded.keyframes[1]->cloud->size(), session.keyframes[1]->cloud->size());
}

TEST(Session, DamagedFutureOrForeignSessionsAreNamedBeforeAnyWork)
{
  {
    const fs::path dir = copyOfSession("flip");
    const fs::path file = dir / "features" / "000001.pcd";
    std::string bytes = readText(file);
    bytes[bytes.size() - 5] ^= 0x40;
    writeText(file, bytes);
    const SessionError e = loadError(dir);
    EXPECT_EQ(e.path(), file.string());
    EXPECT_NE(std::string(e.what()).find("checksum"), std::string::npos) << e.what();
  }
  {
    const fs::path dir = copyOfSession("truncate");
    const fs::path file = dir / "keyframes" / "000002.pcd";
    fs::resize_file(file, fs::file_size(file) / 2);
    const SessionError e = loadError(dir);
    EXPECT_EQ(e.path(), file.string());
    EXPECT_NE(std::string(e.what()).find("truncated"), std::string::npos) << e.what();
  }
  {
    const fs::path dir = copyOfSession("missing");
    fs::remove(dir / "graph.g2o");
    const SessionError e = loadError(dir);
    EXPECT_EQ(e.path(), (dir / "graph.g2o").string());
    EXPECT_NE(std::string(e.what()).find("missing"), std::string::npos) << e.what();
  }
  {
    const fs::path dir = copyOfSession("future");
    std::string json = readText(dir / "session.json");
    const std::string version = "\"version\": " + std::to_string(kSessionFormatVersion);
    ASSERT_NE(json.find(version), std::string::npos);
    json.replace(json.find(version), version.size(), "\"version\": 99");
    writeText(dir / "session.json", json);
    const SessionError e = loadError(dir);
    EXPECT_EQ(e.path(), (dir / "session.json").string());
    EXPECT_NE(std::string(e.what()).find("version 99"), std::string::npos) << e.what();
  }
  {
    const fs::path dir = copyOfSession("garbage");
    writeText(dir / "session.json", "{\"format\": \"pcl_rast_session\", \"vers");
    EXPECT_NE(std::string(loadError(dir).what()).find("not valid JSON"), std::string::npos);
    fs::remove(dir / "session.json");
    EXPECT_NE(std::string(loadError(dir).what()).find("missing"), std::string::npos);
  }
  {
    SessionLoadOptions ouster;
    ouster.expected_sensor_preset = "ouster64";
    const std::string what = loadError(savedSession(), ouster).what();
    EXPECT_NE(what.find("'hdl64'"), std::string::npos) << what;
    EXPECT_NE(what.find("'ouster64'"), std::string::npos) << what;
  }
  {
    const fs::path none = tempDir("none") / "no_such_session";
    EXPECT_EQ(loadError(none).path(), none.string());
  }
  // The right preset loads.
  SessionLoadOptions hdl64;
  hdl64.expected_sensor_preset = "hdl64";
  EXPECT_NO_THROW(loadSession(savedSession().string(), hdl64));
}

TEST(Session, ASaveReplacesASessionWholeOrLeavesItAsItWas)
{
  const fs::path parent = tempDir("replace");
  const fs::path dir = parent / "session";
  Session first = loadSession(savedSession().string());
  saveSession(first, dir.string());
  const std::string first_json = readText(dir / "session.json");

  // A save that fails half way (its graph does not match its key-frames) changes nothing.
  Session broken = first;
  broken.graph = PoseGraph();
  broken.graph.addNode(0, Pose3d::Identity());
  EXPECT_THROW(saveSession(broken, dir.string()), std::invalid_argument);
  EXPECT_EQ(readText(dir / "session.json"), first_json);
  EXPECT_NO_THROW(loadSession(dir.string()));
  std::size_t entries = 0;
  for ([[maybe_unused]] const auto& e : fs::directory_iterator(parent))
    ++entries;
  EXPECT_EQ(entries, 1u) << "a staging folder was left behind";

  // A smaller session replaces it whole: no file of the earlier one is left.
  Session second = first;
  second.keyframes.resize(2);
  // Its drives no longer match its key-frames: an error naming them ...
  try {
    saveSession(second, dir.string());
    ADD_FAILURE() << "drives that cover other key-frames were saved";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("drives cover"), std::string::npos) << e.what();
  }
  second.drives.clear(); // ... until they are left out (all key-frames: one drive)
  PoseGraph graph;
  graph.addNode(0, second.keyframes[0]->T_world_keyframe, true);
  graph.addNode(1, second.keyframes[1]->T_world_keyframe);
  graph.addEdge(0, 1, second.keyframes[1]->T_previous_keyframe,
                Eigen::Matrix<double, 6, 6>::Identity(), PoseGraphEdgeType::kOdometry);
  second.graph = graph;
  saveSession(second, dir.string());
  EXPECT_EQ(loadSession(dir.string()).keyframes.size(), 2u);
  EXPECT_FALSE(fs::exists(dir / "keyframes" / "000002.pcd"));

  // A folder that is not a session is never replaced.
  const fs::path scans = parent / "scans";
  fs::create_directories(scans);
  writeText(scans / "000000.bin", "not a session");
  try {
    checkSessionDestination(scans.string());
    ADD_FAILURE() << "a folder of other files was accepted";
  } catch (const SessionError& e) {
    EXPECT_EQ(e.path(), scans.string());
  }
  EXPECT_THROW(saveSession(second, scans.string()), SessionError);
  EXPECT_EQ(readText(scans / "000000.bin"), "not a session");
  EXPECT_NO_THROW(checkSessionDestination((parent / "new").string()));
  // A folder that cannot be created, below a file: refused before any work.
  try {
    checkSessionDestination((scans / "000000.bin" / "deeper" / "session").string());
    ADD_FAILURE() << "a session below a file was accepted";
  } catch (const SessionError& e) {
    EXPECT_NE(std::string(e.what()).find("is not a folder"), std::string::npos) << e.what();
  }
}

} // namespace

} // namespace test_session
