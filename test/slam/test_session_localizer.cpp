/// Cold start on a saved session (issue 13): scans of a second pass over a mapped road
/// are placed on the map with no prior pose, and scans of a world that was never mapped
/// are not placed at all. Simulated (HDL-64 loop, seed 3; the other world seed 9).

#include "simulated_drive.h"
#include "temp_cleanup.h"
#include "test_cache.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <gtest/gtest.h>
#include <limits>
#include <pcl/simulation/lidar_simulator.h>
#include <pcl/slam/rast_slam.h>
#include <pcl/slam/session.h>
#include <pcl/slam/session_localizer.h>
#include <random>
#include <string>
#include <tuple>
#include <utility>
#include <vector>

// This file's names stay its own: a test program compiles several test files as
// one translation unit (test/CMakeLists.txt).
namespace test_session_localizer {

namespace {

using namespace pcl::rast;
namespace fs = std::filesystem;

using CloudPtr = pcl::PointCloud<pcl::PointXYZI>::Ptr;

CloudPtr
simulateFrame(const LidarSimulator& sim, std::size_t i)
{
  auto cloud = std::make_shared<pcl::PointCloud<pcl::PointXYZI>>();
  sim.simulateFrame(i, *cloud);
  return cloud;
}

using pcl_rast_test::pathSimulator;

double
rotationErrorDeg(const Pose3d& a, const Pose3d& b)
{
  const Eigen::AngleAxisd d((a.inverse() * b).rotation());
  return std::abs(d.angle()) * 180.0 / M_PI;
}

/// The map of the tests: frames 0-149 of 1.25 laps of 160 frames (no loop closed
/// yet), or the first `mapped` of them, saved as a session and loaded back; frames
/// 160-199 drive the first 40 m of the lap again.
struct MappedLoop
{
  std::unique_ptr<LidarSimulator> sim;
  std::unique_ptr<SessionLocalizer> localizer;
  OdometryParams odometry;
  Pose3d T0_inv = Pose3d::Identity(); ///< the session's world is frame 0's LiDAR frame
  fs::path dir;                       ///< the saved session

  Pose3d truth(std::size_t i) const { return T0_inv * sim->sensorPose(i); }

  /// Another localizer on the saved session (loaded again, without its clouds).
  std::unique_ptr<SessionLocalizer>
  localizerWith(const SessionLocalizerParams& params) const
  {
    SessionLoadOptions options;
    options.load_clouds = false;
    return std::make_unique<SessionLocalizer>(loadSession(dir.string(), options), params);
  }
};

MappedLoop
mapLoop(bool load_clouds = true,
        std::size_t mapped = 150,
        SensorModel sensor = SensorModel::kHdl64,
        SensorPreset preset = SensorPreset::kHdl64)
{
  MappedLoop m;
  if (sensor == SensorModel::kHdl64) {
    m.sim = pathSimulator(PathType::kLoop, 200, 0.25, 3);
  } else { // another sensor, in a harder world: sensor imperfections, rough ground,
           // porous vegetation
    LidarSimulatorParams sim_params;
    sim_params.sensor = sensor;
    sim_params.seed = 3;
    sim_params.num_threads = 2;
    sim_params.imperfections = true;
    sim_params.world.rough_ground = true;
    sim_params.world.porous_vegetation = true;
    PathParams path;
    path.type = PathType::kLoop;
    path.num_frames = 200;
    path.revisit_fraction = 0.25;
    m.sim = std::make_unique<LidarSimulator>(sim_params, generatePath(path));
  }
  const fs::path dir = fs::temp_directory_path() / "pcl_rast_test" /
                       ("session_localizer_" + std::to_string(::getpid()));
  pcl_rast_test::removeAtExit(dir);
  // Mapped once per build and copied (test_cache.h): the map is the same in every test
  // that asks for it (a deterministic run), and making it took 5-10 s each time.
  const std::string key = std::string("session_localizer_map_") + toString(preset) + "_" +
                          std::to_string(static_cast<int>(sensor)) + "_" +
                          std::to_string(mapped);
  pcl_rast_test::copyCachedFolder(key, dir, [&](const fs::path& out) {
    SlamParams slam_params;
    slam_params.deterministic = true;
    applySensorPreset(preset, slam_params.odometry);
    RastSlam slam(slam_params);
    for (std::size_t i = 0; i < mapped; ++i)
      slam.addScan(simulateFrame(*m.sim, i), m.sim->timestamp(i), i);
    slam.finish();
    SessionInfo info;
    info.sensor_preset = toString(preset);
    saveSession(slam, out.string(), info);
  });

  SessionLoadOptions options;
  options.load_clouds = load_clouds;
  Session session = loadSession(dir.string(), options);
  m.dir = dir;
  SessionLocalizerParams params;
  applySensorPreset(sensorPresetFromName(session.info.sensor_preset), params);
  m.odometry = params.odometry;
  m.localizer = std::make_unique<SessionLocalizer>(std::move(session), params);
  m.T0_inv = m.sim->sensorPose(0).inverse();
  return m;
}

/// A drive onto the map from a world the map never saw: frames 0 to off - 1 of
/// \a elsewhere, then `on` frames from frame 160 of the map's own simulator (the lap's
/// first metres again), timed on from the other world's last frame at 10 Hz.
std::vector<OdometryInput>
enteringDrive(const MappedLoop& m,
              const LidarSimulator& elsewhere,
              std::size_t off,
              std::size_t on)
{
  std::vector<OdometryInput> drive;
  for (std::size_t i = 0; i < off; ++i)
    drive.push_back({simulateFrame(elsewhere, i), elsewhere.timestamp(i), i, {}});
  for (std::size_t j = 0; j < on; ++j)
    drive.push_back({simulateFrame(*m.sim, 160 + j),
                     elsewhere.timestamp(off - 1) + 0.1 * (j + 1),
                     off + j,
                     {}});
  return drive;
}

TEST(SessionLocalizer, PlacesASecondPassWithNoPriorAndNothingOffTheMap)
{
  const MappedLoop m = mapLoop();
  const auto& sim = m.sim;
  const SessionLocalizer& localizer = *m.localizer;
  ASSERT_GT(localizer.numIndexed(), 5u);

  // The session's world is the LiDAR frame of frame 0.
  int placed = 0, wrong = 0;
  double max_error_m = 0.0, max_error_deg = 0.0, total_ms = 0.0;
  for (std::size_t i = 160; i < 200; i += 2) {
    const Placement p = localizer.place(simulateFrame(*sim, i));
    total_ms += p.time_ms;
    if (!p.success)
      continue;
    const Pose3d gt = m.truth(i);
    const double error_m = (p.T_world_lidar.translation() - gt.translation()).norm();
    const double error_deg = rotationErrorDeg(p.T_world_lidar, gt);
    ++placed;
    max_error_m = std::max(max_error_m, error_m);
    max_error_deg = std::max(max_error_deg, error_deg);
    // The map itself drifts a little over 150 m: 0.5 m / 1 deg is a right placement.
    if (error_m > 0.5 || error_deg > 1.0) {
      ++wrong;
      ADD_FAILURE() << "frame " << i << " placed " << error_m << " m, " << error_deg
                    << " deg off: " << p.message;
    }
  }
  std::printf("simulated second pass: %d of 20 scans placed, largest error %.3f m / %.3f deg, "
              "%.0f ms per scan\n",
              placed, max_error_m, max_error_deg, total_ms / 20.0);
  EXPECT_GE(placed, 19) << "of 20 second-pass scans";
  EXPECT_EQ(wrong, 0);

  // A world that was never mapped: nothing placed.
  const auto elsewhere = pathSimulator(PathType::kStraight, 40, 0.0, 9);
  for (std::size_t i = 0; i < 40; i += 4) {
    const Placement p = localizer.place(simulateFrame(*elsewhere, i));
    EXPECT_FALSE(p.success) << "frame " << i << " of another world: " << p.message;
    EXPECT_FALSE(p.message.empty());
  }

  // No scan at all: a failure that says so.
  const Placement none = localizer.place(std::make_shared<pcl::PointCloud<pcl::PointXYZI>>());
  EXPECT_FALSE(none.success);
  EXPECT_EQ(none.message, "empty scan");
}

/// A session loaded without its clouds (what pcl_rast_localize does, to hold less
/// memory) places scans exactly as one loaded with them: the index keeps the dense
/// targets, and the clouds are read from their files when needed, also to save it.
TEST(SessionLocalizer, ASessionLoadedWithoutCloudsPlacesTheSameScans)
{
  const MappedLoop full = mapLoop(true);
  const MappedLoop lazy = mapLoop(false);
  const Session& session = lazy.localizer->session();
  EXPECT_EQ(lazy.localizer->numIndexed(), full.localizer->numIndexed());
  for (const KeyFrame::Ptr& kf : session.keyframes)
    EXPECT_FALSE(kf->cloud) << "key-frame " << kf->id << " holds its cloud after indexing";
  const KeyFrameId last = static_cast<KeyFrameId>(session.keyframes.size() - 1);
  ASSERT_TRUE(sessionHasCloud(session, last));
  ASSERT_TRUE(sessionCloud(session, last));
  EXPECT_EQ(sessionCloud(session, last)->size(),
            sessionCloud(full.localizer->session(), last)->size());

  int placed = 0;
  for (std::size_t i = 160; i < 200; i += 8) {
    const Placement a = full.localizer->place(simulateFrame(*full.sim, i));
    const Placement b = lazy.localizer->place(simulateFrame(*lazy.sim, i));
    ASSERT_EQ(a.success, b.success) << "frame " << i << ": " << a.message << " / " << b.message;
    if (!a.success)
      continue;
    ++placed;
    EXPECT_EQ(a.keyframe, b.keyframe) << "frame " << i;
    EXPECT_EQ(a.num_inliers, b.num_inliers) << "frame " << i;
    EXPECT_LT((a.T_world_lidar.translation() - b.T_world_lidar.translation()).norm(), 1e-6)
        << "frame " << i;
  }
  EXPECT_GE(placed, 4) << "of 5 second-pass scans";

  // Saved again, the clouds come from the files they were loaded from.
  const fs::path copy = lazy.dir.string() + "_copy";
  fs::remove_all(copy);
  pcl_rast_test::removeAtExit(copy);
  saveSession(session, copy.string());
  const Session again = loadSession(copy.string());
  ASSERT_EQ(again.keyframes.size(), session.keyframes.size());
  ASSERT_TRUE(again.keyframes[last]->cloud);
  EXPECT_EQ(again.keyframes[last]->cloud->size(), sessionCloud(session, last)->size());

  // A cloud file that changed since the load is an error naming it.
  fs::resize_file(session.cloud_files[last].path, 200);
  EXPECT_THROW(sessionCloud(session, last), SessionError);
}

/// A second pass localized scan after scan (cold start, then tracking on the map), with
/// the odometry resting while the map confirms the frames and with it tracking every
/// frame, on demand (features only where a placement may use them: not after a frame
/// the map confirmed) or with every frame's features; and a kidnapping: 100 frames
/// dropped from the input are reported as a jump and the pose is right again within 5
/// frames.
TEST(MapLocalization, TracksASecondPassAndRecoversFromAKidnapping)
{
  const MappedLoop m = mapLoop();
  std::vector<std::vector<Pose3d>> poses;
  for (const auto& [track_on_map, on_demand] :
       {std::pair{true, true}, std::pair{false, true}, std::pair{false, false}}) {
    MapLocalizationParams params;
    params.track_on_map = track_on_map;
    params.features_on_demand = on_demand;
    MapLocalization localization(*m.localizer, m.odometry, params);
    int localized = 0, odometry_frames = 0, skipped = 0;
    double sum_sq = 0.0, max_error_m = 0.0;
    poses.emplace_back();
    bool previous_localized = false;
    for (std::size_t i = 160; i < 200; ++i) {
      const LocalizationFrame f = localization.addScan(simulateFrame(*m.sim, i),
                                                       m.sim->timestamp(i), i);
      poses.back().push_back(f.T_world_lidar);
      odometry_frames += f.odometry_ran ? 1 : 0;
      skipped += f.odometry_features_skipped ? 1 : 0;
      // Only after a frame the map confirmed: a placement is unlikely then.
      if (f.odometry_features_skipped) {
        EXPECT_TRUE(previous_localized) << "frame " << i << ": " << f.message;
      }
      previous_localized = f.status == LocalizationStatus::kLocalized;
      const double error_m = (f.T_world_lidar.translation() - m.truth(i).translation()).norm();
      if (f.status == LocalizationStatus::kLocalized) {
        ++localized;
        sum_sq += error_m * error_m;
        max_error_m = std::max(max_error_m, error_m);
      }
      EXPECT_LT(error_m, 2.0) << "frame " << i << " (" << toString(f.status) << "): " << f.message;
      if (i == 160)
        EXPECT_TRUE(f.placed) << "the first scan is placed by retrieval: " << f.message;
      else
        EXPECT_FALSE(f.jump) << "frame " << i << ": " << f.message;
    }
    const double rmse = std::sqrt(sum_sq / std::max(1, localized));
    std::printf(
        "simulated second pass, 40 frames, track_on_map %d, features on demand %d: "
        "%d localized, the odometry on %d (%d without features), map-frame RMSE "
        "%.3f m, largest %.3f m\n",
        track_on_map ? 1 : 0,
        on_demand ? 1 : 0,
        localized,
        odometry_frames,
        skipped,
        rmse,
        max_error_m);
    EXPECT_GE(localized, 38);
    EXPECT_LT(rmse, 0.10);
    if (track_on_map) {
      EXPECT_LE(odometry_frames, 4) << "the map tracks once two frames are confirmed";
    } else {
      EXPECT_EQ(odometry_frames, 40);
    }
    if (!track_on_map && on_demand) {
      EXPECT_GE(skipped, 25) << "the frames after a confirmed one need no features"; // 29
    }
    if (!on_demand) {
      EXPECT_EQ(skipped, 0);
    }
  }
  // Predicting by the map's velocity instead of the odometry, or with the features of
  // every frame, lands on the same poses.
  for (std::size_t k = 1; k < poses.size(); ++k)
    for (std::size_t j = 0; j < poses[0].size(); ++j)
      EXPECT_LT((poses[0][j].translation() - poses[k][j].translation()).norm(), 0.05)
          << "run " << k << ", frame " << 160 + j;
  {
    // Frames 20-39, then 140-149: the input jumps 100 m ahead.
    MapLocalization localization(*m.localizer, m.odometry);
    int first_right_after_jump = -1;
    bool jump_reported = false;
    for (std::size_t i = 20; i < 150; i = (i == 39 ? 140 : i + 1)) {
      const LocalizationFrame f = localization.addScan(simulateFrame(*m.sim, i),
                                                       m.sim->timestamp(i), i);
      const double error_m = (f.T_world_lidar.translation() - m.truth(i).translation()).norm();
      if (i < 40) {
        EXPECT_EQ(f.status, LocalizationStatus::kLocalized) << "frame " << i << ": " << f.message;
        EXPECT_LT(error_m, 0.2) << "frame " << i;
        continue;
      }
      jump_reported = jump_reported || f.jump;
      // A placement says why the map did not confirm the stale prediction.
      if (f.placed) {
        EXPECT_NE(f.message.find("; the prediction was not confirmed ("),
                  std::string::npos)
            << "frame " << i << ": " << f.message;
      }
      // Never localized at the stale place the odometry carries on from.
      if (f.status == LocalizationStatus::kLocalized) {
        EXPECT_LT(error_m, 2.0) << "frame " << i << " localized off: " << f.message;
      }
      if (first_right_after_jump < 0 && f.status == LocalizationStatus::kLocalized &&
          error_m < 0.2)
        first_right_after_jump = static_cast<int>(i - 140);
      if (first_right_after_jump >= 0) {
        EXPECT_LT(error_m, 0.3) << "frame " << i << " after the recovery: " << f.message;
      }
    }
    EXPECT_TRUE(jump_reported);
    EXPECT_GE(first_right_after_jump, 0) << "never recovered";
    EXPECT_LT(first_right_after_jump, 5);
  }
}

/// An alignment that keeps a direction at the prediction confirms a frame only where the
/// odometry that predicted it tracked that frame. Every alignment here keeps at least
/// one direction (degeneracy_min_ratio 0.5); an odometry that makes every frame's
/// features and never passes them (a threshold beyond any scan) tracks every frame by
/// its dense fallback, degraded. Then no frame is localized by such an alignment, and
/// the frames say why (a placement, a measurement of its own, still localizes them);
/// with the odometry tracking, or with the rule off, the map's alignments confirm them.
TEST(MapLocalization, AKeptDirectionConfirmsAFrameOnlyWhereTheOdometryTrackedIt)
{
  const MappedLoop m = mapLoop();
  OdometryParams failing = m.odometry;
  failing.min_feature_inliers = 100000;
  failing.strong_feature_inliers = 100000;
  struct Run
  {
    const char* name;
    const OdometryParams* odometry;
    bool rule;
    int kept = 0, refused = 0;
  };
  Run runs[] = {{"tracking odometry", &m.odometry, true},
                {"odometry falling back", &failing, true},
                {"odometry falling back, rule off", &failing, false}};
  for (Run& run : runs) {
    MapLocalizationParams params;
    params.track_on_map = false;       // the odometry predicts every frame
    params.features_on_demand = false; // ... with its features
    params.alignment.degeneracy_min_ratio = 0.5;
    params.degenerate_needs_tracked_odometry = run.rule;
    MapLocalization localization(*m.localizer, *run.odometry, params);
    for (std::size_t i = 160; i < 200; ++i) {
      const LocalizationFrame f =
          localization.addScan(simulateFrame(*m.sim, i), m.sim->timestamp(i), i);
      if (f.status == LocalizationStatus::kLocalized &&
          f.message.find("kept at the prediction") != std::string::npos)
        ++run.kept;
      if (f.message.find("direction(s) the scan does not constrain and the odometry's "
                         "step there was degraded (dense_fallback)") != std::string::npos)
        ++run.refused;
    }
    std::printf("simulated second pass, 40 frames, every alignment keeping a direction, "
                "%s: %d localized by such alignments, %d refused\n",
                run.name,
                run.kept,
                run.refused);
  }
  EXPECT_GE(runs[0].kept, 35);
  EXPECT_EQ(runs[0].refused, 0);
  EXPECT_EQ(runs[1].kept, 0);
  EXPECT_GE(runs[1].refused, 10);
  EXPECT_GE(runs[2].kept, 35);
  EXPECT_EQ(runs[2].refused, 0);
}

/// After a jump the odometry starts afresh. It tracks the scan the jump was found on
/// first, so that the next frame's step is measured: a fresh odometry's first frame has
/// no step, and an alignment that keeps a direction at the prediction would hold it
/// there, one frame's motion behind, and carry that offset on (a simulated VLP-16 at 3
/// m a frame stayed 2-3 m behind along the street for 50 frames). Here every alignment
/// keeps a direction (degeneracy_min_ratio 0.5), and after frames 20-39 the input jumps
/// to frame 100 and goes on at every third frame (3 m a frame).
TEST(MapLocalization, TheFrameAfterAJumpMovesByTheRestartedOdometry)
{
  const MappedLoop m = mapLoop();
  MapLocalizationParams params;
  params.track_on_map = false;
  params.features_on_demand = false;
  params.alignment.degeneracy_min_ratio = 0.5;
  MapLocalization localization(*m.localizer, m.odometry, params);
  int jumps = 0, kept_after_jump = 0, right_after = 0, off_after = 0;
  bool jumped = false;
  for (std::size_t i = 20; i < 150; i = (i == 39 ? 100 : i < 39 ? i + 1 : i + 3)) {
    const LocalizationFrame f =
        localization.addScan(simulateFrame(*m.sim, i), m.sim->timestamp(i), i);
    const double error_m =
        (f.T_world_lidar.translation() - m.truth(i).translation()).norm();
    if (f.jump) {
      ++jumps;
      jumped = true;
      EXPECT_LT(error_m, 0.3) << "frame " << i << ": " << f.message;
      continue;
    }
    if (!jumped || f.status != LocalizationStatus::kLocalized)
      continue;
    if (f.message.find("kept at the prediction") != std::string::npos)
      ++kept_after_jump;
    (error_m < 0.3 ? right_after : off_after) += 1;
    EXPECT_LT(error_m, 0.3) << "frame " << i << " after the jump: " << f.message;
  }
  std::printf("simulated jump, then 3 m a frame, every alignment keeping a direction: %d "
              "jump(s), then %d frames localized within 0.3 m and %d farther (%d of them "
              "by alignments keeping a direction)\n",
              jumps,
              right_after,
              off_after,
              kept_after_jump);
  EXPECT_EQ(jumps, 1);
  EXPECT_GE(kept_after_jump, 10);
  EXPECT_GE(right_after, 12);
  EXPECT_EQ(off_after, 0);
}

/// Raw sweeps with their point times (10 m/s, so half a sweep is 0.5 m) on a map of
/// instantaneous scans: each scan's source for the map alignment is prepared from its
/// raw points and then moved by the frame's motion; with a look-ahead scan it is
/// prepared while the frame before is aligned, which changes no pose. Tracked on the
/// map within centimetres once placed; with the times left out, several times farther
/// off.
TEST(MapLocalization, ASixteenBeamMapIsAlignedToInCoarserPlanes)
{
  // A VLP-16 map: away from the sensor a key-frame's cloud holds few points per 0.3 m
  // voxel (rings 2 deg apart), too few for the alignment's planes, and the map confirms
  // no frame: each is placed anew by retrieval. The preset's 1 m voxels hold several
  // rings (and its odometry runs on every frame, for the directions they leave open).
  const MappedLoop m = mapLoop(true, 150, SensorModel::kVlp16, SensorPreset::kVlp16);
  int localized[2] = {0, 0}, aligned[2] = {0, 0};
  double rmse[2] = {0.0, 0.0};
  for (const bool preset : {false, true}) {
    MapLocalizationParams params;
    if (preset) {
      applySensorPreset(SensorPreset::kVlp16, params);
    } else {
      // One key-frame at a time: three key-frames' clouds together hold points enough
      // even in 0.3 m voxels (39 of the 40 frames aligned there).
      params.tracked_together = false;
    }
    MapLocalization localization(*m.localizer, m.odometry, params);
    double sum_sq = 0.0;
    for (std::size_t i = 160; i < 200; ++i) {
      const LocalizationFrame f =
          localization.addScan(simulateFrame(*m.sim, i), m.sim->timestamp(i), i);
      const double error_m =
          (f.T_world_lidar.translation() - m.truth(i).translation()).norm();
      EXPECT_LT(error_m, 2.0) << "frame " << i << " (" << toString(f.status)
                              << "): " << f.message;
      if (f.status == LocalizationStatus::kLocalized) {
        ++localized[preset];
        aligned[preset] += f.placed ? 0 : 1; // the map confirmed the prediction
        sum_sq += error_m * error_m;
      }
    }
    rmse[preset] = std::sqrt(sum_sq / std::max(1, localized[preset]));
  }
  MapLocalizationParams vlp16;
  applySensorPreset(SensorPreset::kVlp16, vlp16);
  std::printf("simulated VLP-16 second pass, 40 frames: %d localized, %d of them aligned "
              "to the map (RMSE %.3f m, the map's error included) with 0.3 m alignment "
              "voxels; %d and %d (RMSE %.3f m) with the preset's %.1f m\n",
              localized[0],
              aligned[0],
              rmse[0],
              localized[1],
              aligned[1],
              rmse[1],
              vlp16.alignment.target_voxel_size_m);
  EXPECT_GE(localized[1], 38);
  EXPECT_GE(aligned[1], 35) << "the map confirms the frames it tracks";
  EXPECT_LT(aligned[0], aligned[1] - 10);
  EXPECT_LT(rmse[1], rmse[0] + 0.05);
  // Only the preset keeps unconstrained directions at the prediction (where the
  // odometry carries them); the other presets keep the alignment as it is, with plain
  // steps: predicted by the map's velocity, a kept direction lagged behind an HDL-64
  // on a street (doc/session.md, "Session 44").
  EXPECT_GT(vlp16.alignment.degeneracy_min_ratio, 0.0);
  EXPECT_FALSE(vlp16.track_on_map);
  for (const SensorPreset other :
       {SensorPreset::kHdl64, SensorPreset::kOs1_64, SensorPreset::kOs0_128}) {
    MapLocalizationParams p;
    applySensorPreset(other, p);
    EXPECT_EQ(p.alignment.target_voxel_size_m,
              MapLocalizationParams().alignment.target_voxel_size_m);
    EXPECT_EQ(p.alignment.degeneracy_min_ratio, 0.0) << toString(other);
    EXPECT_TRUE(p.track_on_map) << toString(other);
  }
}

TEST(MapLocalization, RawSweepsAreAlignedWithTheirSourcesPreparedAhead)
{
  const MappedLoop m = mapLoop(true, 40);
  const auto raw = pathSimulator(PathType::kLoop, 200, 0.25, 3, true);
  std::vector<OdometryInput> drive;
  for (std::size_t i = 160; i < 172; ++i) {
    OdometryInput s;
    auto cloud = std::make_shared<pcl::PointCloud<pcl::PointXYZI>>();
    raw->simulateFrame(i, *cloud, &s.point_times_s);
    s.cloud = cloud;
    s.timestamp_s = raw->timestamp(i);
    s.frame_index = i;
    drive.push_back(std::move(s));
  }
  const auto run = [&](bool lookahead, bool times) {
    MapLocalization localization(*m.localizer, m.odometry);
    std::vector<LocalizationFrame> frames;
    for (std::size_t k = 0; k < drive.size(); ++k) {
      const OdometryInput& s = drive[k];
      const std::vector<float> none;
      const std::vector<float>& t = times ? s.point_times_s : none;
      if (lookahead && k + 1 < drive.size()) {
        OdometryInput next = drive[k + 1];
        if (!times)
          next.point_times_s.clear();
        frames.push_back(
            localization.addScan(s.cloud, s.timestamp_s, s.frame_index, t, next));
      } else {
        frames.push_back(localization.addScan(s.cloud, s.timestamp_s, s.frame_index, t));
      }
    }
    return frames;
  };
  const auto worstError = [&](const std::vector<LocalizationFrame>& frames,
                              int& localized) {
    double worst = 0.0;
    localized = 0;
    for (const LocalizationFrame& f : frames) {
      if (f.status != LocalizationStatus::kLocalized)
        continue;
      ++localized;
      if (f.placed)
        continue; // the first scan, placed with no motion to compensate it by
      worst = std::max(
          worst,
          (f.T_world_lidar.translation() - m.truth(f.frame_index).translation()).norm());
    }
    return worst;
  };
  const std::vector<LocalizationFrame> ahead = run(true, true);
  const std::vector<LocalizationFrame> alone = run(false, true);
  const std::vector<LocalizationFrame> untimed = run(true, false);
  int prepared_ahead = 0;
  for (std::size_t k = 0; k < ahead.size(); ++k) {
    prepared_ahead += ahead[k].alignment_prepared_ahead ? 1 : 0;
    EXPECT_FALSE(alone[k].alignment_prepared_ahead);
    EXPECT_TRUE(ahead[k].T_world_lidar.matrix() == alone[k].T_world_lidar.matrix())
        << "frame " << k << ": " << ahead[k].message;
    EXPECT_EQ(ahead[k].status, alone[k].status) << "frame " << k;
  }
  int localized = 0, localized_untimed = 0;
  const double worst = worstError(ahead, localized);
  const double worst_untimed = worstError(untimed, localized_untimed);
  std::printf(
      "simulated raw sweeps on the map, 12 frames: %d localized (%d sources prepared "
      "ahead), largest error after the placement %.3f m; times left out: %d, %.3f m\n",
      localized,
      prepared_ahead,
      worst,
      localized_untimed,
      worst_untimed);
  EXPECT_GE(localized, 11);
  EXPECT_GE(prepared_ahead, 9);          // from the third frame on, once the map tracks
  EXPECT_LT(worst, 0.04);                // 0.016 m when written
  EXPECT_GT(worst_untimed, 2.0 * worst); // 0.075 m
}

/// A placement short of the full inlier threshold is tentative: never taken alone,
/// taken when the next scan's placement, moved by the odometry, agrees with it, or
/// when the next scan's alignment to the map from it confirms it. Here no
/// placement can reach the full threshold (1000 inliers), so every one is tentative.
TEST(MapLocalization, TentativePlacementsAreTakenWhenTwoScansAgree)
{
  const MappedLoop m = mapLoop();
  SessionLocalizerParams params;
  params.odometry = m.odometry;
  params.verification.min_inliers = 1000;
  ASSERT_EQ(params.tentative_min_inliers, 20);
  const SessionLocalizer strict(loadSession(m.dir.string()), params);

  const Placement p = strict.place(simulateFrame(*m.sim, 160));
  EXPECT_FALSE(p.success);
  ASSERT_TRUE(p.tentative) << p.message;
  EXPECT_LT((p.T_world_lidar.translation() - m.truth(160).translation()).norm(), 0.5);
  EXPECT_NE(p.message.find("tentatively on key-frame"), std::string::npos) << p.message;

  for (const auto& [window, by_alignment] :
       std::vector<std::pair<int, bool>>{{3, false}, {3, true}, {0, true}}) {
    MapLocalizationParams loc_params;
    loc_params.tentative_window_frames = window;
    loc_params.confirm_tentative_by_alignment = by_alignment;
    MapLocalization localization(strict, m.odometry, loc_params);
    for (std::size_t i = 160; i < 166; ++i) {
      const LocalizationFrame f =
          localization.addScan(simulateFrame(*m.sim, i), m.sim->timestamp(i), i);
      if (window == 0 || i == 160) {
        EXPECT_NE(f.status, LocalizationStatus::kLocalized)
            << "window " << window << ", frame " << i << ": " << f.message;
        continue;
      }
      ASSERT_EQ(f.status, LocalizationStatus::kLocalized) << "frame " << i << ": " << f.message;
      EXPECT_LT((f.T_world_lidar.translation() - m.truth(i).translation()).norm(), 0.5)
          << "frame " << i;
      if (i == 161) {
        // Confirmed by this scan's alignment to the map, else by its own placement.
        EXPECT_TRUE(f.placed);
        EXPECT_NE(f.message.find(by_alignment ? "from the tentative placement 1 frames before"
                                              : "agrees with the placement 1 frames before"),
                  std::string::npos)
            << f.message;
      }
    }
  }

  // Placements that cannot agree, and a map alignment that cannot confirm: nothing is
  // taken, and each frame says why the confirmation failed. Either every source point
  // must pair, or the alignment keeps a direction at its prediction: there the
  // prediction is the tentative placement moved by the odometry, which is what wants
  // confirming. A share of half the weight leaves at least one translation direction
  // under it in any scene (the three share the weight between them).
  for (const bool degenerate : {false, true}) {
    MapLocalizationParams loc_params;
    loc_params.agree_m = 1e-6;
    if (degenerate)
      loc_params.alignment.degeneracy_min_ratio = 0.5;
    else
      loc_params.alignment.min_overlap_ratio = 1.0;
    const std::string why = degenerate ? "direction(s) the scan does not constrain)"
                                       : "of the source points paired";
    MapLocalization localization(strict, m.odometry, loc_params);
    for (std::size_t i = 160; i < 164; ++i) {
      const LocalizationFrame f =
          localization.addScan(simulateFrame(*m.sim, i), m.sim->timestamp(i), i);
      EXPECT_NE(f.status, LocalizationStatus::kLocalized)
          << "frame " << i << ": " << f.message;
      if (i == 160)
        continue;
      EXPECT_NE(f.message.find(
                    "the tentative placement 1 frame before not confirmed (key-frame"),
                std::string::npos)
          << "frame " << i << ": " << f.message;
      EXPECT_NE(f.message.find(why), std::string::npos)
          << "frame " << i << ": " << f.message;
    }
  }

  // A world that was never mapped: not even tentative.
  const auto elsewhere = pathSimulator(PathType::kStraight, 40, 0.0, 9);
  for (std::size_t i = 0; i < 40; i += 4) {
    const Placement q = strict.place(simulateFrame(*elsewhere, i));
    EXPECT_FALSE(q.success || q.tentative) << "frame " << i << ": " << q.message;
  }
}

/// A tentative placement whose next scan pairs too little with each nearest key-frame
/// alone is confirmed by their clouds together (MapLocalizationParams::
/// merged_keyframes_within_m). The map alignment reads each key-frame's cloud cut to a
/// quarter of the view (key-frame k keeps the 90 degrees around azimuth k * 90 in its
/// own frame), so one key-frame pairs at most about a quarter of a whole scan, under
/// the 30 % asked, and three neighbours together three quarters; the placements were
/// indexed on the whole clouds. No full placement (1000 inliers asked) and no two
/// placements agreeing (within 1 um) can localize here: only a tentative placement
/// confirmed by the next scan's alignment.
TEST(MapLocalization, ATentativePlacementIsConfirmedByTheNearestKeyFramesTogether)
{
  const MappedLoop m = mapLoop();
  Session session = loadSession(m.dir.string());
  using CloudConstPtr = pcl::PointCloud<pcl::PointXYZI>::ConstPtr;
  std::vector<CloudConstPtr> whole, quarter;
  for (KeyFrame::Ptr& kf : session.keyframes) {
    ASSERT_EQ(kf->id, whole.size());
    ASSERT_TRUE(kf->cloud);
    auto cut = std::make_shared<pcl::PointCloud<pcl::PointXYZI>>();
    const double centre = 0.5 * M_PI * static_cast<double>(kf->id % 4);
    for (const auto& p : kf->cloud->points) {
      const double off = std::remainder(std::atan2(p.y, p.x) - centre, 2.0 * M_PI);
      if (std::abs(off) < 0.25 * M_PI)
        cut->push_back(p);
    }
    whole.push_back(kf->cloud);
    quarter.push_back(cut);
    kf->cloud = nullptr; // from cloud_source, when needed
  }
  session.cloud_files.clear(); // not read from the files either
  auto cut_clouds = std::make_shared<bool>(false);
  session.cloud_source = [whole, quarter, cut_clouds](KeyFrameId id) {
    return *cut_clouds ? quarter.at(id) : whole.at(id);
  };
  SessionLocalizerParams params;
  params.odometry = m.odometry;
  params.verification.min_inliers = 1000;
  const SessionLocalizer quarters(std::move(session), params);
  *cut_clouds = true; // the index holds its own targets from the whole clouds

  // Together: none, only for confirming a placement, and for tracked frames too.
  for (const int together : {0, 1, 2}) {
    MapLocalizationParams loc_params;
    loc_params.agree_m = 1e-6;
    ASSERT_DOUBLE_EQ(loc_params.alignment.min_overlap_ratio, 0.3);
    if (together == 0)
      loc_params.merged_keyframes_within_m = 0.0;
    loc_params.tracked_together = together == 2;
    MapLocalization localization(quarters, m.odometry, loc_params);
    int confirmed = 0, tracked = 0;
    for (std::size_t i = 160; i < 170; ++i) {
      const LocalizationFrame f =
          localization.addScan(simulateFrame(*m.sim, i), m.sim->timestamp(i), i);
      if (f.status != LocalizationStatus::kLocalized)
        continue;
      EXPECT_GT(together, 0) << "frame " << i << ": " << f.message;
      EXPECT_LT((f.T_world_lidar.translation() - m.truth(i).translation()).norm(), 0.1)
          << "frame " << i << ": " << f.message;
      EXPECT_LT(rotationErrorDeg(f.T_world_lidar, m.truth(i)), 0.5) << "frame " << i;
      if (f.placed) {
        ++confirmed;
        EXPECT_NE(f.message.find(" together from the tentative placement"),
                  std::string::npos)
            << f.message;
      } else if (f.message.find(" together") != std::string::npos) {
        ++tracked; // aligned together from the frame before
      }
    }
    std::printf("simulated quarter clouds, together %d: %d placements confirmed, %d "
                "frames tracked together\n",
                together,
                confirmed,
                tracked);
    if (together == 0) {
      EXPECT_EQ(confirmed, 0);
    }
    // Only a placement's confirmation: a confirmed frame's successor is tracked, which
    // one key-frame at a time cannot confirm, and is placed tentatively anew.
    if (together == 1) {
      EXPECT_GE(confirmed, 3);
      EXPECT_EQ(tracked, 0);
    }
    // Tracked frames too: once placed, the map confirms the frames that follow.
    if (together == 2) {
      EXPECT_GE(confirmed, 1);
      EXPECT_GE(tracked, 7);
    }
  }
}

/// Off the map every placement fails: after placement_backoff_after of them in a row a
/// placement is tried only every placement_every frames, and the first one tried on the
/// map places the scan. Here 18 frames of a world that was never mapped, then the
/// mapped loop's second pass.
TEST(MapLocalization, PlacementsBackOffOffTheMapAndResumeOnIt)
{
  // The drive comes back to frames 0-7 of the map: the first 40 frames are map enough,
  // and the test, which CI runs under TSan, builds it in a quarter of the time.
  const MappedLoop m = mapLoop(true, 40);
  const auto elsewhere = pathSimulator(PathType::kStraight, 18, 0.0, 9);
  // The drive: 18 frames off the map, then 8 on it.
  const std::vector<OdometryInput> drive = enteringDrive(m, *elsewhere, 18, 8);
  const auto addScan = [&](MapLocalization& localization, std::size_t k, bool lookahead) {
    const OdometryInput& s = drive[k];
    return lookahead && k + 1 < drive.size()
               ? localization.addScan(
                     s.cloud, s.timestamp_s, s.frame_index, {}, drive[k + 1])
               : localization.addScan(s.cloud, s.timestamp_s, s.frame_index);
  };
  // every 1: each frame tries at once (the lag needs placement_every above it); every
  // 3: backed off, at once (lag 0) or in the background and taken a frame later; the
  // last again with the odometry's look-ahead (the next scan prepared on a thread of its
  // own), which changes no pose.
  std::vector<LocalizationFrame> without_lookahead;
  for (const auto& [every, lag, lookahead] : {std::tuple{1, 1, false},
                                              std::tuple{3, 0, false},
                                              std::tuple{3, 1, false},
                                              std::tuple{3, 1, true}}) {
    MapLocalizationParams params;
    params.placement_backoff_after = 6;
    params.placement_every = every;
    params.background_placement_lag = lag;
    const bool background = every > lag && lag > 0;
    MapLocalization localization(*m.localizer, m.odometry, params);
    std::vector<LocalizationFrame> frames;
    int tried_off = 0, first_localized = -1, collected = 0, failed = 0, no_features = 0;
    for (std::size_t i = 0; i < 18; ++i) {
      const LocalizationFrame f = addScan(localization, i, lookahead);
      frames.push_back(f);
      EXPECT_NE(f.status, LocalizationStatus::kLocalized) << "frame " << i << ": " << f.message;
      tried_off += f.placement_tried ? 1 : 0;
      // Backed off, the odometry makes the features of the frames that try a placement
      // (features_on_demand) and may skip the others'; before, every frame tries.
      no_features += f.odometry_features_skipped ? 1 : 0;
      if (f.placement_tried || i < 6) {
        EXPECT_FALSE(f.odometry_features_skipped) << "frame " << i << ": " << f.message;
      }
      const bool started =
          f.message.find("started in the background") != std::string::npos;
      if (f.placement_tried && i >= 6) {
        EXPECT_EQ(started, background) << f.message;
      }
      // A run that starts off the map has no prediction to call far from it: every
      // attempt may verify the candidates' neighbourhoods.
      if (f.placement_tried) {
        EXPECT_TRUE(f.placement_with_neighbourhoods) << "frame " << i;
      }
      if (f.placement_tried && !started)
        ++failed; // at once
      if (!f.placement_tried) {
        const bool taken =
            f.message.find("in the background from the scan 1 frame before: ") !=
            std::string::npos;
        collected += taken ? 1 : 0;
        failed += taken ? 1 : 0;
        const std::size_t at = f.message.find("not tried: ");
        EXPECT_TRUE(taken || at != std::string::npos) << f.message;
        // Each attempt counts once among the failures in a row, when its result is known.
        if (at != std::string::npos) {
          EXPECT_EQ(std::atoi(f.message.c_str() + at + 11), failed) << f.message;
        }
      }
    }
    for (std::size_t j = 0; j < 8; ++j) {
      const std::size_t i = 160 + j;
      const LocalizationFrame f = addScan(localization, 18 + j, lookahead);
      frames.push_back(f);
      if (f.status != LocalizationStatus::kLocalized)
        continue;
      if (first_localized < 0) {
        first_localized = static_cast<int>(j);
        EXPECT_EQ(f.message.find("in the background from the scan 1 frame before") !=
                      std::string::npos,
                  background)
            << f.message;
      }
      EXPECT_LT((f.T_world_lidar.translation() - m.truth(i).translation()).norm(), 0.5)
          << "frame " << i << ": " << f.message;
    }
    std::printf(
        "simulated: every %d, lag %d: %d of 18 off-map frames tried a placement (%d "
        "taken from the background); the map's first localized frame %d\n",
        every,
        lag,
        tried_off,
        collected,
        first_localized);
    // 6 failures, then frames 9, 12, 15 and 18 of the run; the last one's result is
    // taken on the map.
    EXPECT_EQ(tried_off, every == 1 ? 18 : 10);
    EXPECT_EQ(collected, background ? 3 : 0);
    if (every == 1) {
      EXPECT_EQ(no_features, 0);
    } else {
      EXPECT_GT(no_features, 0) << "frames between the attempts";
    }
    ASSERT_GE(first_localized, 0) << "never localized on the map";
    // The first placement tried on the map places it: at once, or a frame later.
    EXPECT_LT(first_localized, every + (background ? lag : 0));
    if (!lookahead && every == 3 && lag == 1)
      without_lookahead = frames;
    if (lookahead) {
      int prepared_ahead = 0;
      for (const auto& f : frames)
        prepared_ahead += f.odometry_prepared_ahead ? 1 : 0;
      // Off the map the odometry runs on every frame: all but the first take theirs.
      EXPECT_GE(prepared_ahead, 17);
      ASSERT_EQ(frames.size(), without_lookahead.size());
      for (std::size_t k = 0; k < frames.size(); ++k) {
        EXPECT_TRUE(frames[k].T_world_lidar.matrix() ==
                    without_lookahead[k].T_world_lidar.matrix())
            << "frame " << k << ": " << frames[k].message;
        EXPECT_EQ(frames[k].status, without_lookahead[k].status) << "frame " << k;
      }
    }
  }
}

/// A tracked frame that no key-frame alone confirms is aligned to the nearest
/// key-frames' clouds together (MapLocalizationParams::tracked_together), right after
/// a frame the map confirmed. Here the input jumps from the mapped loop onto a straight
/// street of another world, whose ground and generic facades pair with three
/// key-frames' clouds together as well as a true place seen from elsewhere does
/// (doc/session.md, "Session 42"): four jumps, from four places of the loop onto four
/// stretches of the street. Asked 30 % paired, as of one key-frame, the clouds together
/// "localize" it, and each frame so confirmed lets the next one try them too; asked the
/// default share (tracked_together_min_overlap_ratio), none of its frames is localized.
TEST(MapLocalization, AJumpOntoAnotherWorldsStreetIsNotTrackedTogether)
{
  const MappedLoop m = mapLoop(true, 40);
  const auto elsewhere = pathSimulator(PathType::kStraight, 24, 0.0, 9);
  // Without the residual check (max_rmse_ratio), which refuses some of them too: the
  // key-frames one by one, together asking 30 %, and together asking the default.
  const MapLocalizationParams defaults;
  for (const double min_ratio : {0.0, 0.3, defaults.tracked_together_min_overlap_ratio}) {
    int on_map = 0, wrong = 0;
    std::string first_wrong;
    for (std::size_t jump = 0; jump < 4; ++jump) {
      MapLocalizationParams params;
      params.tracked_together = min_ratio > 0.0;
      if (min_ratio > 0.0)
        params.tracked_together_min_overlap_ratio = min_ratio;
      params.max_rmse_ratio = 0.0;
      MapLocalization localization(*m.localizer, m.odometry, params);
      const std::size_t first = 10 * jump; // the loop's frames first..first+7
      localization.setInitialPose(m.truth(first));
      for (std::size_t i = first; i < first + 8; ++i) {
        const LocalizationFrame f =
            localization.addScan(simulateFrame(*m.sim, i), m.sim->timestamp(i), i);
        on_map += f.status == LocalizationStatus::kLocalized ? 1 : 0;
      }
      for (std::size_t k = 6 * jump; k < 6 * jump + 6; ++k) {
        const double t =
            m.sim->timestamp(first + 7) + 0.1 * static_cast<double>(k - 6 * jump + 1);
        const LocalizationFrame f =
            localization.addScan(simulateFrame(*elsewhere, k), t, first + 8 + k);
        if (f.status == LocalizationStatus::kLocalized && wrong++ == 0)
          first_wrong = f.message;
      }
    }
    std::printf(
        "simulated jumps onto another world's street, together from %.0f %% "
        "(0: off): %d of 32 map frames localized, %d of 24 other-world frames%s%s\n",
        100.0 * min_ratio,
        on_map,
        wrong,
        wrong > 0 ? ", the first " : "",
        first_wrong.c_str());
    EXPECT_GE(on_map, 28);
    if (min_ratio == 0.3) {
      EXPECT_GT(wrong, 0) << "the street no longer pairs with the clouds together";
    } else {
      EXPECT_EQ(wrong, 0) << first_wrong;
    }
  }
}

/// Once placed, a run whose dead reckoning lies far from every key-frame of the map
/// backs off further: an attempt every far_placement_every frames, taken
/// far_placement_lag frames later. Here a world that was never mapped is driven from
/// a given pose 1 km from the map, or from the map's own first pose (near it); with
/// far_radius_m 0 the far schedule is off.
TEST(MapLocalization, AttemptsFarFromTheMapAreFewerAndLater)
{
  const MappedLoop m = mapLoop(true, 40);
  const auto elsewhere = pathSimulator(PathType::kStraight, 24, 0.0, 9);
  const Pose3d far_away(Eigen::Translation3d(1000.0, 0.0, 0.0));
  // Backed off after 6 attempts: every 2 frames, taken 1 frame later; far: every 5,
  // taken 3 frames later.
  const auto schedule = [](double far_radius_m, double far_drift_ratio) {
    MapLocalizationParams params;
    params.placement_backoff_after = 6;
    params.placement_every = 2;
    params.background_placement_lag = 1;
    params.far_radius_m = far_radius_m;
    params.far_drift_ratio = far_drift_ratio;
    params.far_placement_every = 5;
    params.far_placement_lag = 3;
    return params;
  };
  for (const auto& [start, far_radius_m, far_expected] :
       {std::tuple{far_away, 30.0, true},
        std::tuple{m.truth(0), 30.0, false},
        std::tuple{far_away, 0.0, false}}) {
    MapLocalization localization(*m.localizer, m.odometry, schedule(far_radius_m, 0.2));
    localization.setInitialPose(start);
    std::vector<std::size_t> started;
    int far_notes = 0, no_features = 0;
    for (std::size_t i = 0; i < 24; ++i) {
      const LocalizationFrame f =
          localization.addScan(simulateFrame(*elsewhere, i), elsewhere->timestamp(i), i);
      EXPECT_NE(f.status, LocalizationStatus::kLocalized)
          << "frame " << i << ": " << f.message;
      if (f.message.find("started in the background") != std::string::npos)
        started.push_back(i);
      far_notes += f.message.find("far from the map: ") != std::string::npos ? 1 : 0;
      // Its features were made for the attempt: the schedule, far or near, was known.
      if (f.placement_tried) {
        EXPECT_FALSE(f.odometry_features_skipped) << "frame " << i << ": " << f.message;
      }
      no_features += f.odometry_features_skipped ? 1 : 0;
      // Far from the map the attempts leave the candidates' neighbourhoods out.
      if (f.placement_tried) {
        EXPECT_EQ(f.placement_with_neighbourhoods,
                  f.message.find("far from the map: ") == std::string::npos)
            << "frame " << i << ": " << f.message;
      }
      // An attempt is taken after its lag: 3 frames far from the map, 1 near it.
      const std::string taken =
          far_expected ? "from the scan 3 frames before" : "from the scan 1 frame before";
      if (!started.empty() && i == started.front() + (far_expected ? 3 : 1)) {
        EXPECT_NE(f.message.find(taken), std::string::npos)
            << "frame " << i << ": " << f.message;
      }
    }
    ASSERT_GE(started.size(), 2u) << "no attempt in the background";
    for (std::size_t k = 1; k < started.size(); ++k)
      EXPECT_EQ(started[k] - started[k - 1], far_expected ? 5u : 2u)
          << "attempts at frames " << started[k - 1] << " and " << started[k];
    std::printf(
        "simulated: start %.0f m from the map, far_radius_m %.0f: %zu attempts in "
        "the background after the back-off, %d frames said far from the map\n",
        (start.translation() - m.truth(0).translation()).norm(),
        far_radius_m,
        started.size(),
        far_notes);
    EXPECT_EQ(far_notes > 0, far_expected);
    EXPECT_GT(no_features, 0) << "the frames between the attempts make no features";
  }
  // The drift allowance grows with the distance driven, so the same drive turns from
  // far to near: an attempt started far (taken 3 frames later) may still run when the
  // near schedule (every 2 frames) is due. Nothing else is tried while it runs. The
  // drive goes on away from the map at 1 m a frame from 1 km, and 30 m plus 80 or 120
  // times the distance driven reaches it at frame 12 or 8, after far attempts started
  // at frames 11 or 6.
  int exercised = 0;
  for (const double ratio : {80.0, 120.0}) {
    MapLocalization localization(*m.localizer, m.odometry, schedule(30.0, ratio));
    localization.setInitialPose(far_away);
    bool running = false;
    std::size_t started_at = 0; // the frame the running attempt started on
    for (std::size_t i = 0; i < 24; ++i) {
      const LocalizationFrame f =
          localization.addScan(simulateFrame(*elsewhere, i), elsewhere->timestamp(i), i);
      if (f.message.find("in the background from the scan") != std::string::npos)
        running = false;
      if (running) {
        EXPECT_FALSE(f.placement_tried)
            << "ratio " << ratio << ", frame " << i << ", attempt of frame " << started_at
            << " still running: " << f.message;
        exercised += f.message.find("far from the map") == std::string::npos ? 1 : 0;
      }
      if (f.message.find("started in the background") != std::string::npos) {
        running = true;
        started_at = i;
      }
    }
  }
  std::printf(
      "simulated: %d frames near the map while an attempt started far from it ran\n",
      exercised);
  EXPECT_GT(exercised, 0)
      << "no drift allowance turned the drive near the map mid-attempt";
}

/// A drive enters the map from a road the map lacks and is placed only some frames
/// after it is on the map (the back-off's schedule here). The frames before the
/// placement are then localized backwards (MapLocalizationParams::backtrack_frames):
/// returned with the placing frame, nearest first, at their true poses, none of the
/// other world's frames before them, at most backtrack_frames, none with 0.
TEST(MapLocalization, FramesBeforeAPlacementAreLocalizedBackwards)
{
  const MappedLoop m = mapLoop(true, 40);
  const auto elsewhere = pathSimulator(PathType::kStraight, 18, 0.0, 9);
  const std::vector<OdometryInput> drive = enteringDrive(m, *elsewhere, 18, 10);
  // The same drive with the map's part as raw sweeps with point times: the kept scans
  // are motion-compensated when aligned backwards.
  const auto raw = pathSimulator(PathType::kLoop, 200, 0.25, 3, true);
  std::vector<OdometryInput> raw_drive = drive;
  for (std::size_t j = 0; j < 10; ++j) {
    auto cloud = std::make_shared<pcl::PointCloud<pcl::PointXYZI>>();
    raw->simulateFrame(160 + j, *cloud, &raw_drive[18 + j].point_times_s);
    raw_drive[18 + j].cloud = cloud;
  }
  std::vector<LocalizationFrame> as_returned_without; // backtrack_frames 0
  std::vector<std::vector<LocalizationFrame>> as_returned_with;
  for (const auto& [backtrack, timed] : {std::pair{20, false},
                                         std::pair{3, false},
                                         std::pair{0, false},
                                         std::pair{20, true}}) {
    MapLocalizationParams params;
    params.placement_backoff_after = 6;
    params.placement_every = 9; // after frame 5: frames 14 and 23 try, at once
    params.background_placement_lag = 0;
    params.backtrack_frames = backtrack;
    MapLocalization localization(*m.localizer, m.odometry, params);
    std::vector<LocalizationFrame> frames, as_returned;
    int placed_at = -1;
    for (const OdometryInput& s : timed ? raw_drive : drive) {
      LocalizationFrame f =
          localization.addScan(s.cloud, s.timestamp_s, s.frame_index, s.point_times_s);
      frames.push_back(f);
      as_returned.push_back(f);
      for (const LocalizationFrame& b : f.backtracked_frames) {
        ASSERT_LT(b.frame_index, frames.size());
        frames[b.frame_index] = b;
      }
      if (f.placed && placed_at < 0) {
        placed_at = static_cast<int>(s.frame_index);
        // Nearest first, each the frame before the last.
        for (std::size_t k = 0; k < f.backtracked_frames.size(); ++k)
          EXPECT_EQ(f.backtracked_frames[k].frame_index, s.frame_index - 1 - k);
        EXPECT_LE(f.backtracked_frames.size(), static_cast<std::size_t>(backtrack));
        if (backtrack > 0) {
          EXPECT_NE(f.message.find("localized backwards"), std::string::npos)
              << f.message;
        }
      }
    }
    ASSERT_EQ(placed_at, 23) << "the schedule changed: the test needs the placement late";
    int backtracked = 0;
    for (std::size_t k = 0; k < frames.size(); ++k) {
      const LocalizationFrame& f = frames[k];
      if (k < 18) {
        EXPECT_NE(f.status, LocalizationStatus::kLocalized)
            << "frame " << k << " of the other world: " << f.message;
        continue;
      }
      const Pose3d truth = m.truth(160 + (k - 18));
      if (f.backtracked) {
        ++backtracked;
        EXPECT_EQ(f.status, LocalizationStatus::kLocalized);
        EXPECT_LT((f.T_world_lidar.translation() - truth.translation()).norm(), 0.3)
            << "frame " << k << ": " << f.message;
        EXPECT_LT(rotationErrorDeg(f.T_world_lidar, truth), 1.0) << "frame " << k;
      }
    }
    std::printf(
        "simulated%s: backtrack_frames %d: placed at frame 23, %d of the 5 frames on "
        "the map before it localized backwards: %s\n",
        timed ? " raw sweeps" : "",
        backtrack,
        backtracked,
        frames[23].message.c_str());
    // Frames 18-22 are on the map. The odometry has not found its feet yet on the
    // first of them (it still holds the other world's local map): the placement of 23
    // reaches the frames after, or as many as backtrack_frames keeps.
    if (backtrack >= 5) {
      EXPECT_GE(backtracked, 3);
      EXPECT_NE(frames[23].message.find(
                    timed ? "(stopped at " : "the odometry's motion from it is unknown"),
                std::string::npos)
          << frames[23].message;
    } else {
      EXPECT_EQ(backtracked, backtrack);
    }
    if (!timed)
      (backtrack == 0 ? as_returned_without : as_returned_with.emplace_back()) =
          as_returned;
  }
  // An alignment that keeps a direction at its prediction does not localize a frame
  // backwards: there the prediction is the placement moved back by the odometry. The
  // placement and the frames after it are as before (the tracked frames take such
  // alignments); the backtracking stops at the first frame and says why.
  {
    MapLocalizationParams params;
    params.placement_backoff_after = 6;
    params.placement_every = 9;
    params.background_placement_lag = 0;
    params.backtrack_frames = 20;
    params.alignment.degeneracy_min_ratio = 0.5; // at least one direction, see above
    MapLocalization localization(*m.localizer, m.odometry, params);
    int placed_at = -1;
    for (const OdometryInput& s : drive) {
      const LocalizationFrame f =
          localization.addScan(s.cloud, s.timestamp_s, s.frame_index, s.point_times_s);
      if (!f.placed || placed_at >= 0)
        continue;
      placed_at = static_cast<int>(s.frame_index);
      EXPECT_TRUE(f.backtracked_frames.empty()) << f.message;
      EXPECT_NE(
          f.message.find("(stopped at frame " + std::to_string(placed_at - 1) + ": "),
          std::string::npos)
          << f.message;
      EXPECT_NE(f.message.find("direction(s) the scan does not constrain)"),
                std::string::npos)
          << f.message;
    }
    EXPECT_EQ(placed_at, 23);
  }

  // As the frames came, backtracking or not: the same poses (its alignment targets
  // stay out of the cache the frames after the placement use).
  ASSERT_EQ(as_returned_with.size(), 2u);
  for (const auto& with : as_returned_with) {
    ASSERT_EQ(with.size(), as_returned_without.size());
    for (std::size_t k = 0; k < with.size(); ++k) {
      EXPECT_TRUE(with[k].T_world_lidar.matrix() ==
                  as_returned_without[k].T_world_lidar.matrix())
          << "frame " << k << ": " << with[k].message;
      EXPECT_EQ(with[k].status, as_returned_without[k].status) << "frame " << k;
    }
  }
}

/// A prior pose (MapLocalization's dead reckoning) makes the key-frames near it
/// candidates whatever their appearance: with retrieval switched off (an appearance
/// score no key-frame reaches), second-pass scans are placed from a prior 3 m and 5 deg
/// off, and not from one 60 m off along the loop, where every nearby key-frame is of
/// another place.
/// A placement of frame \a i within 0.5 m and 1 degree of \a truth, by what \a by
/// names in its message; its error raises \a max_error_m.
void
expectPlacedRight(const Placement& p,
                  const Pose3d& truth,
                  std::size_t i,
                  const char* by,
                  double& max_error_m)
{
  const double error_m = (p.T_world_lidar.translation() - truth.translation()).norm();
  max_error_m = std::max(max_error_m, error_m);
  EXPECT_LT(error_m, 0.5) << "frame " << i << ": " << p.message;
  EXPECT_LT(rotationErrorDeg(p.T_world_lidar, truth), 1.0) << "frame " << i;
  EXPECT_NE(p.message.find(by), std::string::npos) << p.message;
}

TEST(SessionLocalizer, APriorPlacesScansThatAppearanceDoesNotRetrieve)
{
  const MappedLoop m = mapLoop();
  SessionLocalizerParams params;
  applySensorPreset(SensorPreset::kHdl64, params.odometry);
  params.verification.min_appearance_score = 1000000;
  params.polar_candidates = 0; // the prior alone (PolarDescriptorPlaces... below)
  SessionLocalizer localizer(loadSession(m.dir.string()), params);
  SessionLocalizerParams no_short_params = params; // every short overlap refused
  no_short_params.verification.tentative_dense_overlap = -1.0;
  SessionLocalizer no_short(loadSession(m.dir.string()), no_short_params);
  params.max_prior_candidates = 0;
  SessionLocalizer no_prior(loadSession(m.dir.string()), params);

  const Pose3d nudge =
      Pose3d(Eigen::Translation3d(2.0, -2.0, 0.5) *
             Eigen::AngleAxisd(5.0 * M_PI / 180.0, Eigen::Vector3d::UnitZ()));
  int placed = 0, tentative = 0, tried = 0;
  double max_error_m = 0.0;
  for (std::size_t i = 160; i < 200; i += 4) {
    const CloudPtr scan = simulateFrame(*m.sim, i);
    const Placement alone = localizer.place(scan);
    EXPECT_FALSE(alone.success || alone.tentative)
        << "frame " << i << ": " << alone.message;
    PlacementPrior prior;
    prior.T_world_lidar = m.truth(i) * nudge;
    prior.radius_m = 10.0;
    EXPECT_FALSE(no_prior.place(scan, prior).success) << "max_prior_candidates 0";
    const Placement p = localizer.place(scan, prior);
    ++tried;
    if (p.success || p.tentative) {
      expectPlacedRight(p, m.truth(i), i, "from the prior", max_error_m);
      placed += p.success ? 1 : 0;
      tentative += p.tentative ? 1 : 0;
    }
    // 60 frames (60 m) back along the loop: nothing there verifies within 10 m of it.
    PlacementPrior wrong = prior;
    wrong.T_world_lidar = m.truth(i - 60) * nudge;
    const Placement w = localizer.place(scan, wrong);
    EXPECT_FALSE(w.success || w.tentative)
        << "frame " << i << " from a prior 60 m off: " << w.message;
    // The prior's overlap threshold reaches the dense check: short of it, the
    // placement is tentative (verification.tentative_dense_overlap), or refused where
    // short overlaps are.
    if (p.success) {
      PlacementPrior strict = prior;
      strict.min_dense_overlap = 1.0;
      const Placement s = localizer.place(scan, strict);
      EXPECT_FALSE(s.success) << s.message;
      EXPECT_TRUE(s.tentative) << s.message;
      EXPECT_DOUBLE_EQ(s.dense_overlap, p.dense_overlap) << s.message;
      const Placement refused = no_short.place(scan, strict);
      EXPECT_FALSE(refused.success || refused.tentative) << refused.message;
      EXPECT_NE(refused.message.find("< 1.00"), std::string::npos) << refused.message;
    }
  }
  std::printf(
      "simulated second pass with retrieval off: %d of %d scans placed from a prior "
      "3 m and 5 deg off (%d more tentatively), largest error %.3f m\n",
      placed,
      tried,
      tentative,
      max_error_m);
  EXPECT_GE(placed, tried - 2);

  PlacementPrior bad;
  bad.radius_m = 0.0;
  EXPECT_THROW(localizer.place(simulateFrame(*m.sim, 160), bad), std::invalid_argument);
  bad.radius_m = 5.0;
  bad.T_world_lidar.translation().x() = std::nan("");
  EXPECT_THROW(localizer.place(simulateFrame(*m.sim, 160), bad), std::invalid_argument);
}

/// Where the raster features retrieve no key-frame (here: none reaches the appearance
/// score), the polar max-height descriptor finds the place and the yaw, and the
/// verification under that guess places the scan tentatively (a second scan must
/// agree); another world is not placed, and with polar_candidates 0 or
/// PlacementOptions::polar_candidates false nothing is.
TEST(SessionLocalizer, APolarDescriptorPlacesScansThatAppearanceDoesNotRetrieve)
{
  const MappedLoop m = mapLoop();
  SessionLocalizerParams params;
  applySensorPreset(SensorPreset::kHdl64, params.odometry);
  params.verification.min_appearance_score = 1000000;
  ASSERT_GT(params.polar_candidates, 0);
  SessionLocalizer localizer(loadSession(m.dir.string()), params);
  params.polar_candidates = 0;
  SessionLocalizer no_polar(loadSession(m.dir.string()), params);
  PlacementOptions off;
  off.polar_candidates = false;

  int tentative = 0, tried = 0;
  double max_error_m = 0.0;
  for (std::size_t i = 160; i < 200; i += 4) {
    const CloudPtr scan = simulateFrame(*m.sim, i);
    ++tried;
    const Placement p = localizer.place(scan);
    EXPECT_GT(p.polar_verified, 0) << "frame " << i << ": " << p.message;
    if (p.success || p.tentative) {
      expectPlacedRight(p, m.truth(i), i, "polar descriptor", max_error_m);
      EXPECT_FALSE(p.success) << "a polar candidate places tentatively: " << p.message;
      tentative += p.tentative ? 1 : 0;
    }
    const Placement none = no_polar.place(scan);
    EXPECT_FALSE(none.success || none.tentative)
        << "polar_candidates 0: " << none.message;
    EXPECT_EQ(none.polar_verified, 0);
    const Placement not_asked = localizer.place(scan, nullptr, off);
    EXPECT_FALSE(not_asked.success || not_asked.tentative) << not_asked.message;
    EXPECT_EQ(not_asked.polar_verified, 0);
  }
  std::printf(
      "simulated second pass with appearance retrieval off: %d of %d scans placed "
      "tentatively by the polar descriptor, largest error %.3f m\n",
      tentative,
      tried,
      max_error_m);
  EXPECT_GE(tentative, tried - 2);

  // A sensor turned far from the map's heading: the descriptors' yaw turns the guess.
  // The cloud turned by R is seen from a LiDAR frame turned by R's inverse.
  for (const double yaw_deg : {100.0, -150.0}) {
    const Pose3d R(Eigen::AngleAxisd(yaw_deg * M_PI / 180.0, Eigen::Vector3d::UnitZ()));
    auto turned =
        std::make_shared<pcl::PointCloud<pcl::PointXYZI>>(*simulateFrame(*m.sim, 172));
    for (pcl::PointXYZI& q : turned->points)
      q.getVector3fMap() = (R * q.getVector3fMap().cast<double>()).cast<float>();
    const Placement p = localizer.place(turned);
    ASSERT_TRUE(p.tentative) << "turned by " << yaw_deg << " deg: " << p.message;
    expectPlacedRight(
        p, m.truth(172) * R.inverse(), 172, "polar descriptor", max_error_m);
  }

  // Where tentative placements are switched off, polar candidates are too.
  params.polar_candidates = 3;
  params.tentative_min_inliers = 0;
  SessionLocalizer no_tentative(loadSession(m.dir.string()), params);
  const Placement none = no_tentative.place(simulateFrame(*m.sim, 172));
  EXPECT_FALSE(none.success || none.tentative) << none.message;
  EXPECT_EQ(none.polar_verified, 0);

  // A world that was never mapped: its nearest descriptors are verified and fail.
  const auto elsewhere = pathSimulator(PathType::kStraight, 40, 0.0, 9);
  for (std::size_t i = 0; i < 40; i += 4) {
    const Placement p = localizer.place(simulateFrame(*elsewhere, i));
    EXPECT_FALSE(p.success || p.tentative)
        << "frame " << i << " of another world: " << p.message;
    EXPECT_GT(p.polar_verified, 0);
  }
}

/// MapLocalization hands the odometry's dead reckoning to its placements: a second pass
/// started from a given pose, with the map alignment failing (it asks for more points
/// than a scan has) and retrieval switched off, only the prior can place the scans; with
/// prior_radius_m 0 none is.
TEST(MapLocalization, PlacesFromItsDeadReckoningWhenRetrievalCannot)
{
  const MappedLoop m = mapLoop();
  SessionLocalizerParams params;
  applySensorPreset(SensorPreset::kHdl64, params.odometry);
  params.verification.min_appearance_score = 1000000; // retrieval finds nothing
  params.polar_candidates = 0; // nor the polar descriptor (ColdStartsBy... below)
  const SessionLocalizer localizer(loadSession(m.dir.string()), params);
  for (const double radius : {10.0, 0.0}) {
    MapLocalizationParams lp;
    lp.prior_radius_m = radius;
    lp.alignment.min_correspondences = 1000000; // never aligned: the odometry carries on
    MapLocalization localization(localizer, m.odometry, lp);
    localization.setInitialPose(m.truth(160));
    int placed = 0;
    double max_error_m = 0.0;
    for (std::size_t i = 160; i < 190; ++i) {
      const LocalizationFrame f =
          localization.addScan(simulateFrame(*m.sim, i), m.sim->timestamp(i), i);
      const double error_m =
          (f.T_world_lidar.translation() - m.truth(i).translation()).norm();
      if (f.status == LocalizationStatus::kLocalized) {
        EXPECT_TRUE(f.placed) << "frame " << i << ": " << f.message;
        EXPECT_LT(error_m, 0.5) << "frame " << i << ": " << f.message;
        EXPECT_NE(f.message.find("from the prior"), std::string::npos) << f.message;
        max_error_m = std::max(max_error_m, error_m);
        ++placed;
      }
    }
    std::printf(
        "simulated, no map alignment and no retrieval, prior radius %.0f m: %d of 30 "
        "frames placed, largest error %.3f m\n",
        radius,
        placed,
        max_error_m);
    if (radius > 0.0)
      EXPECT_GE(placed, 20);
    else
      EXPECT_EQ(placed, 0) << "no prior and no retrieval: nothing places the scans";
  }
}

/// Scans that could not be read (MapLocalization::addSkippedScan) are carried by the
/// last confirmed motion: on the straight start of the second pass, four skipped frames
/// stay within centimetres of the truth and the next scan is aligned to the map again.
/// Before any scan, a skipped one has no pose and says why.
/// A cold start where appearance retrieval finds nothing: the polar descriptor's
/// candidates place the first scans tentatively, a second scan agrees (by its own
/// placement or its alignment), and the run is localized within 3 scans at the right
/// pose. Without them (polar_candidates 0) it stays lost.
TEST(MapLocalization, ColdStartsByThePolarDescriptorWhenRetrievalFindsNothing)
{
  const MappedLoop m = mapLoop();
  SessionLocalizerParams params;
  applySensorPreset(SensorPreset::kHdl64, params.odometry);
  params.verification.min_appearance_score = 1000000; // retrieval finds nothing
  const SessionLocalizer localizer(loadSession(m.dir.string()), params);
  params.polar_candidates = 0;
  const SessionLocalizer no_polar(loadSession(m.dir.string()), params);
  for (const std::size_t start : {162u, 176u}) {
    SCOPED_TRACE(start);
    MapLocalization localization(localizer, m.odometry);
    MapLocalization without(no_polar, m.odometry);
    int first_localized = -1;
    for (std::size_t i = start; i < start + 6; ++i) {
      const CloudPtr scan = simulateFrame(*m.sim, i);
      const LocalizationFrame f = localization.addScan(scan, m.sim->timestamp(i), i);
      if (f.status == LocalizationStatus::kLocalized) {
        if (first_localized < 0)
          first_localized = static_cast<int>(i - start);
        EXPECT_LT((f.T_world_lidar.translation() - m.truth(i).translation()).norm(), 0.5)
            << "frame " << i << ": " << f.message;
        EXPECT_LT(rotationErrorDeg(f.T_world_lidar, m.truth(i)), 1.0) << "frame " << i;
      }
      const LocalizationFrame g = without.addScan(scan, m.sim->timestamp(i), i);
      EXPECT_EQ(g.status, LocalizationStatus::kLost)
          << "frame " << i << ": " << g.message;
    }
    EXPECT_GE(first_localized, 1) << "a polar placement alone is only tentative";
    EXPECT_LE(first_localized, 2) << "localized within 3 scans";
  }
}

TEST(MapLocalization, SkippedScansAreCarriedByTheLastMotion)
{
  const MappedLoop m = mapLoop();
  MapLocalization localization(*m.localizer, m.odometry);
  const LocalizationFrame none =
      localization.addSkippedScan(m.sim->timestamp(159), 159, "unreadable");
  EXPECT_EQ(none.status, LocalizationStatus::kLost);
  EXPECT_EQ(none.message, "skipped: unreadable");
  double max_skipped_m = 0.0;
  for (std::size_t i = 160; i < 175; ++i) {
    const bool skip = i >= 166 && i < 170;
    const LocalizationFrame f =
        skip ? localization.addSkippedScan(m.sim->timestamp(i), i, "unreadable")
             : localization.addScan(simulateFrame(*m.sim, i), m.sim->timestamp(i), i);
    const double error_m =
        (f.T_world_lidar.translation() - m.truth(i).translation()).norm();
    if (skip) {
      EXPECT_EQ(f.status, LocalizationStatus::kTrackingOnly) << "frame " << i;
      EXPECT_EQ(f.message, "skipped: unreadable");
      max_skipped_m = std::max(max_skipped_m, error_m);
    } else if (i > 161) {
      EXPECT_EQ(f.status, LocalizationStatus::kLocalized)
          << "frame " << i << ": " << f.message;
      EXPECT_LT(error_m, 0.1) << "frame " << i << ": " << f.message;
    }
  }
  std::printf("simulated, 4 scans skipped on a straight: carried within %.3f m\n",
              max_skipped_m);
  EXPECT_LT(max_skipped_m, 0.3);
}

/// A drive that leaves the map where it ends (MapLocalizationParams::
/// leaving_map_corridor_m): frames 20-79 of the lap, of which the map holds 0-39. Once
/// the map stops confirming the pose, no key-frame lies ahead, and the attempts back off
/// at once, in the background; with the corridor 0 the first ones try every frame on the
/// tracking thread, as after a jump.
TEST(MapLocalization, ADriveLeavingTheMapWhereItEndsBacksOffAtOnce)
{
  const MappedLoop m = mapLoop(true, 40);
  std::vector<OdometryInput> drive;
  for (std::size_t i = 20; i < 80; ++i)
    drive.push_back({simulateFrame(*m.sim, i), m.sim->timestamp(i), i - 20, {}});
  for (const double corridor : {10.0, 0.0}) {
    MapLocalizationParams params;
    params.leaving_map_corridor_m = corridor;
    MapLocalization localization(*m.localizer, m.odometry, params);
    int localized = 0, exit_frame = -1, at_once_after_exit = 0, in_background = 0;
    bool said_leaving = false;
    for (std::size_t k = 0; k < drive.size(); ++k) {
      const OdometryInput& s = drive[k];
      const LocalizationFrame f =
          k + 1 < drive.size()
              ? localization.addScan(
                    s.cloud, s.timestamp_s, s.frame_index, {}, drive[k + 1])
              : localization.addScan(s.cloud, s.timestamp_s, s.frame_index);
      if (f.status == LocalizationStatus::kLocalized) {
        ++localized;
        EXPECT_LT((f.T_world_lidar.translation() - m.truth(20 + k).translation()).norm(),
                  0.5)
            << "frame " << 20 + k << ": " << f.message;
        continue;
      }
      if (localized == 0)
        continue; // the cold start
      if (exit_frame < 0)
        exit_frame = static_cast<int>(20 + k);
      said_leaving |=
          f.message.find("leaving it, attempts backed off") != std::string::npos;
      const bool started =
          f.message.find("started in the background") != std::string::npos;
      at_once_after_exit += f.placement_tried && !started ? 1 : 0;
      in_background += started ? 1 : 0;
    }
    std::printf("simulated: corridor %.0f m: %d frames localized, the map stopped "
                "confirming at frame %d; %d attempts on the tracking thread after it, "
                "%d in the background\n",
                corridor,
                localized,
                exit_frame,
                at_once_after_exit,
                in_background);
    ASSERT_GT(localized, 10) << "the drive was not tracked on the map";
    ASSERT_GE(exit_frame, 40) << "the map stopped confirming before its end";
    if (corridor > 0.0) {
      EXPECT_TRUE(said_leaving);
      EXPECT_EQ(at_once_after_exit, 0);
      EXPECT_GT(in_background, 0);
    } else {
      EXPECT_FALSE(said_leaving);
      EXPECT_GT(at_once_after_exit, 0);
    }
  }
  MapLocalizationParams bad;
  bad.leaving_map_corridor_m = -1.0;
  EXPECT_THROW(MapLocalization(*m.localizer, m.odometry, bad), std::invalid_argument);
}

/// A VLP-16 scan pairs few corners with any one key-frame of the map. Verified with the
/// key-frames around a candidate as well, where each one alone fails, more scans are
/// placed, none wrong, and another world still places nothing.
TEST(MapLocalization, TheFirstAttemptsVerifyNeighbourhoods)
{
  // A localizer set to verify no neighbourhoods (the HDL-64 preset's setting): cold
  // starts on sparse scans, whose first attempts verify two neighbours by default
  // (MapLocalizationParams::first_attempts), and without them.
  const MappedLoop m = mapLoop(true, 150, SensorModel::kVlp16, SensorPreset::kVlp16);
  SessionLocalizerParams none;
  applySensorPreset(SensorPreset::kVlp16, none);
  none.neighbourhood_keyframes = 0;
  const SessionLocalizer localizer(loadSession(m.dir.string()), none);
  MapLocalizationParams with_first, without;
  without.first_attempts = 0;
  int placed[2] = {0, 0}, by_neighbours = 0;
  std::mt19937 rng(11);
  for (std::size_t i = 160; i < 200; i += 2) {
    const auto full = simulateFrame(*m.sim, i);
    auto scan = std::make_shared<pcl::PointCloud<pcl::PointXYZI>>();
    for (const pcl::PointXYZI& q : full->points)
      if (rng() % 100 < 20)
        scan->push_back(q);
    for (const bool first : {false, true}) {
      MapLocalization localization(localizer, m.odometry, first ? with_first : without);
      const LocalizationFrame f = localization.addScan(scan, m.sim->timestamp(i), 0);
      EXPECT_TRUE(f.placement_tried) << "frame " << i;
      if (!f.placed)
        continue;
      ++placed[first];
      EXPECT_LT((f.T_world_lidar.translation() - m.truth(i).translation()).norm(), 0.5)
          << "frame " << i << ": " << f.message;
      if (f.message.find("with its neighbours") != std::string::npos) {
        EXPECT_TRUE(first) << "frame " << i << ": " << f.message;
        ++by_neighbours;
      }
    }
  }
  std::printf("cold starts on 20 sparse scans: %d placed without neighbourhoods, %d with "
              "them in the first attempts (%d by them)\n",
              placed[0],
              placed[1],
              by_neighbours);
  EXPECT_GT(by_neighbours, 0);
  EXPECT_EQ(placed[1], placed[0] + by_neighbours);

  MapLocalizationParams bad;
  bad.first_attempts = -1;
  EXPECT_THROW(MapLocalization(localizer, m.odometry, bad), std::invalid_argument);
}

TEST(SessionLocalizer, ACandidatesNeighboursPlaceSparseScansThatItAloneCannot)
{
  const MappedLoop m = mapLoop(false, 150, SensorModel::kVlp16, SensorPreset::kVlp16);
  const auto localizerWith = [&](int neighbours) {
    SessionLocalizerParams params;
    applySensorPreset(SensorPreset::kVlp16, params);
    params.neighbourhood_keyframes = neighbours;
    return m.localizerWith(params);
  };
  const auto alone = localizerWith(0);
  const auto together = localizerWith(2);
  const auto elsewhere = pathSimulator(PathType::kStraight, 40, 0.0, 9);
  int placed[2] = {0, 0}, by_neighbours = 0;
  // The second pass thinned to a fifth of its points (a fixed draw), a sparser view of
  // the place: fewer of its corners pair with any one key-frame.
  std::mt19937 rng(7);
  for (std::size_t i = 160; i < 200; ++i) {
    const auto full = simulateFrame(*m.sim, i);
    auto scan = std::make_shared<pcl::PointCloud<pcl::PointXYZI>>();
    for (const pcl::PointXYZI& q : full->points)
      if (rng() % 100 < 20)
        scan->push_back(q);
    // At least two neighbours asked by the caller, on a localizer set to none, are
    // the same as the localizer's two.
    PlacementOptions at_least_two;
    at_least_two.min_neighbourhood_keyframes = 2;
    const Placement asked = alone->place(scan, nullptr, at_least_two);
    const Placement set = together->place(scan);
    EXPECT_EQ(asked.success, set.success) << "frame " << i;
    EXPECT_EQ(asked.neighbourhoods_verified, set.neighbourhoods_verified)
        << "frame " << i;
    if (asked.success && set.success) {
      EXPECT_TRUE(asked.T_world_lidar.isApprox(set.T_world_lidar, 1e-9)) << "frame " << i;
    }
    for (const bool with : {false, true}) {
      const Placement p = (with ? *together : *alone).place(scan);
      if (!p.success)
        continue;
      ++placed[with];
      const Pose3d gt = m.truth(i);
      const double error_m = (p.T_world_lidar.translation() - gt.translation()).norm();
      EXPECT_LT(error_m, 0.5) << "frame " << i << (with ? " with" : " without")
                              << " neighbours: " << p.message;
      EXPECT_LT(rotationErrorDeg(p.T_world_lidar, gt), 2.0) << "frame " << i;
      if (with && p.message.find("with its neighbours") != std::string::npos)
        ++by_neighbours;
    }
  }
  int neighbourhoods = 0;
  for (std::size_t i = 0; i < 40; i += 2) {
    const auto scan = simulateFrame(*elsewhere, i);
    const Placement p = together->place(scan);
    EXPECT_FALSE(p.success) << "frame " << i << " of another world: " << p.message;
    EXPECT_LE(p.neighbourhoods_verified, p.candidates_verified);
    neighbourhoods += p.neighbourhoods_verified;
    // A caller can leave the second pass out.
    PlacementOptions alone_only;
    alone_only.neighbourhoods = false;
    EXPECT_EQ(together->place(scan, nullptr, alone_only).neighbourhoods_verified, 0);
  }
  EXPECT_GT(neighbourhoods, 0)
      << "another world's scans were verified with neighbourhoods";
  std::printf("simulated VLP-16 second pass: %d of 40 scans placed alone, %d with two "
              "neighbours (%d by them)\n",
              placed[0],
              placed[1],
              by_neighbours);
  EXPECT_GT(by_neighbours, 0);
  EXPECT_EQ(placed[1], placed[0] + by_neighbours) << "the first pass is the plain one";
}

/// Frame \a i's key-frame (features and cloud) as SessionLocalizer::place makes it from
/// the whole scan: a fresh front end's first frame.
KeyFrame::Ptr
placementQuery(const MappedLoop& m, std::size_t i)
{
  Odometry front_end(m.odometry);
  return front_end.processFrame(simulateFrame(*m.sim, i), 0.0, 0).keyframe;
}

/// A scan whose features place it but which holds too little structure for the dense
/// check (an open highway's: a guard rail, an embankment) is placed tentatively: another
/// scan has to agree (MapLocalization). Without tentative placements it is not placed.
TEST(SessionLocalizer, AScanWithTooLittleStructurePlacesTentatively)
{
  const MappedLoop m = mapLoop(false);
  const auto localizerWith = [&](int tentative_min_inliers) {
    SessionLocalizerParams params;
    params.tentative_min_inliers = tentative_min_inliers;
    return m.localizerWith(params);
  };
  const auto with_tentative = localizerWith(20);
  const auto without = localizerWith(0);
  int full_placed = 0, tentative = 0;
  for (std::size_t i = 160; i < 200; i += 4) {
    // The scan's features as the localizer makes them, from the whole scan ...
    const KeyFrame::Ptr query = placementQuery(m, i);
    ASSERT_TRUE(query) << "frame " << i;
    const Placement full = with_tentative->place(*query);
    full_placed += full.success ? 1 : 0;
    // ... and a cloud for the dense check with nothing more than 0.1 m above the road
    // (1.73 m below the sensor): no walls to pair.
    KeyFrame bare = *query;
    auto low = std::make_shared<pcl::PointCloud<pcl::PointXYZI>>();
    for (const pcl::PointXYZI& q : bare.cloud->points)
      if (q.z < -1.63f)
        low->push_back(q);
    bare.cloud = low;
    const Placement p = with_tentative->place(bare);
    EXPECT_FALSE(p.success) << "frame " << i << ": " << p.message;
    if (p.tentative) {
      ++tentative;
      EXPECT_NE(p.message.find("too little structure"), std::string::npos) << p.message;
      const Pose3d gt = m.truth(i);
      EXPECT_LT((p.T_world_lidar.translation() - gt.translation()).norm(), 0.5)
          << "frame " << i << ": " << p.message;
      EXPECT_LT(rotationErrorDeg(p.T_world_lidar, gt), 1.0) << "frame " << i;
    }
    const Placement refused = without->place(bare);
    EXPECT_FALSE(refused.success) << "frame " << i;
    EXPECT_FALSE(refused.tentative) << "frame " << i << ": " << refused.message;
  }
  std::printf("simulated second pass: %d of 10 scans placed whole, %d tentatively with "
              "their walls cut away\n",
              full_placed,
              tentative);
  EXPECT_GE(full_placed, 9);
  EXPECT_GE(tentative, 7);
}

/// A candidate whose features place the scan but of whose structure too small a share
/// pairs with the map (the scan sees roads the map never drove: a crossing, the map's
/// edge) places the scan tentatively where the share reaches
/// verification.tentative_dense_overlap, and not at all below it. Here the full
/// threshold is raised above the shares a right placement reaches on this loop, so
/// that every right candidate falls short of it.
TEST(SessionLocalizer, AShortDenseOverlapPlacesTentatively)
{
  const MappedLoop m = mapLoop(false);
  const auto localizerWith = [&](double tentative_overlap, int tentative_min_inliers) {
    SessionLocalizerParams params;
    params.verification.min_dense_overlap = 0.99;
    params.verification.tentative_dense_overlap = tentative_overlap;
    params.tentative_min_inliers = tentative_min_inliers;
    return m.localizerWith(params);
  };
  const auto tentative_at_25 = localizerWith(0.25, 20);
  const auto tentative_at_99 = localizerWith(-1.0, 20);
  const auto no_tentatives = localizerWith(0.25, 0);
  int tentative = 0;
  for (std::size_t i = 160; i < 200; i += 8) {
    const KeyFrame::Ptr query = placementQuery(m, i);
    ASSERT_TRUE(query) << "frame " << i;
    const Placement p = tentative_at_25->place(*query);
    EXPECT_FALSE(p.success) << "frame " << i << ": " << p.message;
    if (p.tentative) {
      ++tentative;
      EXPECT_GE(p.dense_overlap, 0.25) << p.message;
      EXPECT_LT(p.dense_overlap, 0.99) << p.message;
      const Pose3d gt = m.truth(i);
      EXPECT_LT((p.T_world_lidar.translation() - gt.translation()).norm(), 0.5)
          << "frame " << i << ": " << p.message;
      EXPECT_LT(rotationErrorDeg(p.T_world_lidar, gt), 1.0) << "frame " << i;
    }
    for (const auto* refusing : {tentative_at_99.get(), no_tentatives.get()}) {
      const Placement refused = refusing->place(*query);
      EXPECT_FALSE(refused.success) << "frame " << i;
      EXPECT_FALSE(refused.tentative) << "frame " << i << ": " << refused.message;
    }
  }
  std::printf("simulated second pass: %d of 5 scans placed tentatively under a full "
              "threshold of 0.99\n",
              tentative);
  EXPECT_GE(tentative, 4);
}

TEST(SessionLocalizer, RefusesBadParametersAndAnEmptySession)
{
  SessionLocalizerParams params;
  params.max_candidates = 0;
  Session session;
  session.keyframes.push_back(std::make_shared<KeyFrame>());
  try {
    SessionLocalizer localizer(session, params);
    ADD_FAILURE() << "max_candidates 0 accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("max_candidates must be >= 1, got 0"),
              std::string::npos)
        << e.what();
  }
  EXPECT_THROW(SessionLocalizer(Session(), SessionLocalizerParams()), std::invalid_argument);
  // Each invalid value is refused with a message that names it.
  const auto expectInvalid = [](const auto& params, const std::string& message) {
    std::string why;
    EXPECT_FALSE(params.isValid(&why)) << message;
    EXPECT_NE(why.find(message), std::string::npos) << why;
  };
  const auto mapParams = [](const auto& change) {
    MapLocalizationParams p;
    change(p);
    return p;
  };
  expectInvalid(mapParams([](auto& p) { p.map_keyframes = 0; }),
                "map_keyframes must be >= 1, got 0");
  expectInvalid(mapParams([](auto& p) { p.max_realign_frames = 0; }),
                "max_realign_frames must be >= 1, got 0");
  expectInvalid(mapParams([](auto& p) { p.agree_m = 0.0; }), "agree_m and agree_deg must be > 0");
  expectInvalid(mapParams([](auto& p) { p.reuse_target_m = -1.0; }),
                "reuse_target_m must be >= 0");
  expectInvalid(mapParams([](auto& p) { p.merged_keyframes_within_m = NAN; }),
                "merged_keyframes_within_m must be >= 0");
  expectInvalid(mapParams([](auto& p) { p.tracked_together_min_overlap_ratio = 0.0; }),
                "tracked_together_min_overlap_ratio must be in (0, 1], got 0");
  expectInvalid(mapParams([](auto& p) { p.tracked_together_min_overlap_ratio = NAN; }),
                "tracked_together_min_overlap_ratio must be in (0, 1], got nan");
  expectInvalid(mapParams([](auto& p) { p.max_rmse_ratio = 0.5; }),
                "max_rmse_ratio must be 0 or >= 1");
  expectInvalid(mapParams([](auto& p) { p.placement_every = 0; }),
                "placement_backoff_after must be >= 0 and placement_every >= 1, got 20 and 0");
  expectInvalid(mapParams([](auto& p) { p.placement_backoff_after = -1; }),
                "placement_backoff_after must be >= 0");
  expectInvalid(
      mapParams([](auto& p) { p.background_placement_lag = 4; }),
      "background_placement_lag must be >= 0 and at most tentative_window_frames, "
      "got 4 (tentative_window_frames 3)");
  expectInvalid(mapParams([](auto& p) { p.background_placement_lag = -1; }),
                "background_placement_lag must be >= 0");
  expectInvalid(mapParams([](auto& p) { p.far_radius_m = -1.0; }),
                "far_radius_m and far_drift_ratio must be finite and >= 0, got -1");
  expectInvalid(mapParams([](auto& p) { p.far_drift_ratio = std::nan(""); }),
                "far_radius_m and far_drift_ratio must be finite and >= 0");
  expectInvalid(mapParams([](auto& p) {
                  p.far_drift_ratio = std::numeric_limits<double>::infinity();
                }),
                "far_radius_m and far_drift_ratio must be finite and >= 0, got 30");
  expectInvalid(mapParams([](auto& p) { p.far_placement_every = 0; }),
                "far_placement_every must be >= 1");
  expectInvalid(mapParams([](auto& p) { p.far_placement_lag = 4; }),
                "far_placement_lag >= 0 and at most tentative_window_frames, got 8 and 4 "
                "(tentative_window_frames 3)");
  expectInvalid(mapParams([](auto& p) { p.backtrack_frames = -1; }),
                "backtrack_frames must be >= 0, got -1");
  expectInvalid(
      mapParams([](auto& p) { p.prior_max_radius_m = 5.0; }),
      "prior_max_radius_m >= prior_radius_m, got 10.000000, 0.020000 and 5.000000");
  expectInvalid(mapParams([](auto& p) { p.lost_prior_min_dense_overlap = 1.5; }),
                "lost_prior_min_dense_overlap must be at most 1, got 1.5");
  SessionLocalizerParams prior_candidates;
  prior_candidates.max_prior_candidates = -1;
  expectInvalid(prior_candidates, "max_prior_candidates must be >= 0, got -1");
  SessionLocalizerParams tentative_two;
  tentative_two.tentative_min_inliers = 2;
  expectInvalid(tentative_two, "tentative_min_inliers must be 0 or >= 3, got 2");
  SessionLocalizerParams neighbours;
  neighbours.neighbourhood_keyframes = -1;
  expectInvalid(neighbours, "neighbourhood_keyframes must be >= 0, got -1");
  neighbours.neighbourhood_keyframes = 2;
  neighbours.neighbourhood_radius_m = 0.0;
  expectInvalid(neighbours, "neighbourhood_radius_m must be > 0, got 0");
}

} // namespace

} // namespace test_session_localizer
