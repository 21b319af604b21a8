/// Multi-session mapping (issue 13): a second drive that overlaps a saved session is
/// joined to it by inter-session loops and optimized with its graph; a drive through a
/// world that was never mapped stays a separate, reported component. Simulated (HDL-64
/// loop, seed 3: the session maps frames 0-79, the drive covers 50-139; the other world
/// seed 9).

#include "simulated_drive.h"
#include "temp_cleanup.h"

#include <cstdio>
#include <filesystem>
#include <gtest/gtest.h>
#include <memory>
#include <pcl/evaluation/trajectory_evaluation.h>
#include <pcl/simulation/lidar_simulator.h>
#include <pcl/slam/rast_slam.h>
#include <pcl/slam/session.h>
#include <pcl/slam/session_localizer.h>
#include <pcl/slam/session_merge.h>
#include <string>

// This file's names stay its own: a test program compiles several test files as
// one translation unit (test/CMakeLists.txt).
namespace test_session_merge {

namespace {

using namespace pcl::rast;
namespace fs = std::filesystem;

using pcl_rast_test::pathSimulator;

/// SLAM over frames [first, last) of \a sim.
std::unique_ptr<RastSlam>
runDrive(const LidarSimulator& sim, std::size_t first, std::size_t last)
{
  SlamParams params;
  params.deterministic = true;
  auto slam = std::make_unique<RastSlam>(params);
  for (std::size_t i = first; i < last; ++i) {
    auto cloud = std::make_shared<pcl::PointCloud<pcl::PointXYZI>>();
    sim.simulateFrame(i, *cloud);
    slam->addScan(cloud, sim.timestamp(i), i - first);
  }
  slam->finish();
  return slam;
}

SessionInfo
hdl64Info()
{
  SessionInfo info;
  info.sensor_preset = toString(SensorPreset::kHdl64);
  info.created_by = "test_session_merge";
  return info;
}

/// SLAM over frames [first, last) of \a sim, as an in-memory session.
Session
mapDrive(const LidarSimulator& sim, std::size_t first, std::size_t last)
{
  return sessionFromSlam(*runDrive(sim, first, last), hdl64Info());
}

/// ATE (SE(3)-aligned RMSE) of key-frame poses against the simulator's truth.
double
keyFrameAte(const std::vector<KeyFrame::Ptr>& keyframes,
            const LidarSimulator& sim,
            std::size_t first_frame)
{
  PoseVector estimate, truth;
  for (const KeyFrame::Ptr& kf : keyframes) {
    estimate.push_back(kf->T_world_keyframe);
    truth.push_back(sim.sensorPose(first_frame + kf->frame_index));
  }
  return evaluateTrajectory(estimate, truth).ate_rmse_m;
}

SessionLocalizer
localizerOn(Session session)
{
  SessionLocalizerParams params;
  applySensorPreset(SensorPreset::kHdl64, params.odometry);
  return SessionLocalizer(std::move(session), params);
}

TEST(SessionMerge, AnOverlappingDriveIsJoinedAndOptimizedWithTheSession)
{
  const auto sim = pathSimulator(PathType::kLoop, 200, 0.25, 3);
  constexpr std::size_t kDriveFirst = 50;
  const Session prior = mapDrive(*sim, 0, 80);
  std::unique_ptr<RastSlam> drive_run = runDrive(*sim, kDriveFirst, 140);
  const Session drive = sessionFromSlam(*drive_run, hdl64Info());
  ASSERT_GT(prior.keyframes.size(), 5u);
  ASSERT_GT(drive.keyframes.size(), 5u);
  const double prior_ate = keyFrameAte(prior.keyframes, *sim, 0);
  const double drive_ate = keyFrameAte(drive.keyframes, *sim, kDriveFirst);

  const SessionLocalizer localizer = localizerOn(prior);
  const SessionMergeResult r = mergeSessions(localizer, drive);
  std::printf("simulated merge: %s; %.0f ms\n", r.message.c_str(), r.time_ms);
  ASSERT_TRUE(r.connected) << r.message;
  EXPECT_EQ(r.component, 0);
  EXPECT_GE(r.loops_agreeing, 2);
  EXPECT_GE(r.loops_used, 2);
  EXPECT_TRUE(r.optimization.success) << r.optimization.message;
  EXPECT_EQ(r.drive_first_keyframe, prior.keyframes.size());
  ASSERT_EQ(r.merged.keyframes.size(), prior.keyframes.size() + drive.keyframes.size());
  ASSERT_EQ(r.drive_keyframe_poses.size(), drive.keyframes.size());
  ASSERT_EQ(r.merged.drives.size(), 2u);
  EXPECT_EQ(r.merged.drives[1].first_keyframe, prior.keyframes.size());
  EXPECT_EQ(r.merged.drives[1].component, 0);
  EXPECT_EQ(r.merged.graph.numNodes(), r.merged.keyframes.size());
  // Every inter-session loop used is an edge of the graph, prior -> drive.
  int inter_session_edges = 0;
  for (const PoseGraphEdge& e : r.merged.graph.edges())
    if (e.from < static_cast<int>(r.drive_first_keyframe) &&
        e.to >= static_cast<int>(r.drive_first_keyframe))
      ++inter_session_edges;
  EXPECT_EQ(inter_session_edges, r.loops_used);

  // The drive lands where it drove, in the session's world (frame 0's LiDAR frame).
  const Pose3d T0_inv = sim->sensorPose(0).inverse();
  double max_error_m = 0.0;
  for (std::size_t k = 0; k < drive.keyframes.size(); ++k) {
    const Pose3d truth = T0_inv * sim->sensorPose(kDriveFirst + drive.keyframes[k]->frame_index);
    max_error_m = std::max(
        max_error_m, (r.drive_keyframe_poses[k].translation() - truth.translation()).norm());
  }
  EXPECT_LT(max_error_m, 0.5) << "drive key-frames in the session's frame";

  // Joint ATE over both drives' key-frames: at most each session alone + 0.05 m.
  PoseVector estimate, truth;
  for (const KeyFrame::Ptr& kf : r.merged.keyframes) {
    const bool of_drive = kf->id >= r.drive_first_keyframe;
    estimate.push_back(kf->T_world_keyframe);
    truth.push_back(sim->sensorPose(kf->frame_index + (of_drive ? kDriveFirst : 0)));
  }
  const double joint_ate = evaluateTrajectory(estimate, truth).ate_rmse_m;
  std::printf("simulated ATE: session %.3f m, drive alone %.3f m, joint %.3f m, drive "
              "key-frames at most %.3f m off in the session's frame\n",
              prior_ate, drive_ate, joint_ate, max_error_m);
  EXPECT_LE(joint_ate, std::max(prior_ate, drive_ate) + 0.05);

  // Saved and loaded back: the drives, the graph and the inter-session loops survive,
  // and the merged map localizes.
  const fs::path dir = fs::temp_directory_path() / "pcl_rast_test" /
                       ("session_merge_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  pcl_rast_test::removeAtExit(dir);
  saveSession(r.merged, dir.string());
  const Session loaded = loadSession(dir.string());
  ASSERT_EQ(loaded.drives.size(), 2u);
  EXPECT_EQ(loaded.drives[1].first_keyframe, r.drive_first_keyframe);
  EXPECT_EQ(loaded.keyframes.size(), r.merged.keyframes.size());
  EXPECT_EQ(loaded.graph.numEdges(), r.merged.graph.numEdges());
  EXPECT_EQ(loaded.loops.size(), r.merged.loops.size());
  EXPECT_EQ(localizerOn(loaded).numIndexed(), localizer.numIndexed() + [&] {
    std::size_t n = 0;
    for (const KeyFrame::Ptr& kf : drive.keyframes)
      n += !kf->features.empty() && kf->cloud ? 1 : 0;
    return n;
  }());

  // The same drive with its clouds read from the run's map when needed
  // (pcl_rast_slam -session): the same merge, and the same saved clouds once the run
  // itself is gone.
  Session lazy = sessionFromSlam(*drive_run, hdl64Info(), /*clouds_on_demand=*/true);
  drive_run.reset();
  ASSERT_EQ(lazy.keyframes.size(), drive.keyframes.size());
  EXPECT_FALSE(lazy.keyframes.front()->cloud);
  ASSERT_TRUE(sessionHasCloud(lazy, 0));
  ASSERT_TRUE(sessionCloud(lazy, 0));
  EXPECT_EQ(sessionCloud(lazy, 0)->size(), drive.keyframes.front()->cloud->size());
  const SessionMergeResult lazy_r = mergeSessions(localizer, lazy);
  EXPECT_EQ(lazy_r.keyframes_tried, r.keyframes_tried);
  EXPECT_EQ(lazy_r.loops_used, r.loops_used);
  ASSERT_EQ(lazy_r.drive_keyframe_poses.size(), r.drive_keyframe_poses.size());
  for (std::size_t k = 0; k < r.drive_keyframe_poses.size(); ++k)
    EXPECT_LT((lazy_r.drive_keyframe_poses[k].translation() -
               r.drive_keyframe_poses[k].translation())
                  .norm(),
              1e-9)
        << "key-frame " << k;
  lazy = Session(); // the merged session keeps what it needs to read the drive's clouds
  const fs::path lazy_dir = dir.string() + "_lazy";
  pcl_rast_test::removeAtExit(lazy_dir);
  saveSession(lazy_r.merged, lazy_dir.string());
  const Session lazy_loaded = loadSession(lazy_dir.string());
  ASSERT_EQ(lazy_loaded.keyframes.size(), loaded.keyframes.size());
  for (std::size_t k = 0; k < loaded.keyframes.size(); ++k) {
    ASSERT_EQ(static_cast<bool>(lazy_loaded.keyframes[k]->cloud),
              static_cast<bool>(loaded.keyframes[k]->cloud))
        << "key-frame " << k;
    if (loaded.keyframes[k]->cloud) {
      EXPECT_EQ(lazy_loaded.keyframes[k]->cloud->size(),
                loaded.keyframes[k]->cloud->size())
          << "key-frame " << k;
    }
  }
}

TEST(SessionMerge, ADriveThatNeverMeetsTheMapStaysASeparateComponent)
{
  const auto sim = pathSimulator(PathType::kLoop, 200, 0.25, 3);
  const Session prior = mapDrive(*sim, 0, 60);
  const auto elsewhere = pathSimulator(PathType::kStraight, 40, 0.0, 9);
  const Session drive = mapDrive(*elsewhere, 0, 40);
  const SessionLocalizer localizer = localizerOn(prior);
  const SessionMergeResult r = mergeSessions(localizer, drive);
  EXPECT_FALSE(r.connected) << r.message;
  EXPECT_EQ(r.component, 1);
  EXPECT_EQ(r.loops_used, 0);
  EXPECT_NE(r.message.find("not joined"), std::string::npos) << r.message;
  ASSERT_EQ(r.merged.drives.size(), 2u);
  EXPECT_EQ(r.merged.drives[1].component, 1);
  // The drive keeps its own frame: its first key-frame where its own SLAM put it.
  EXPECT_LT((r.drive_keyframe_poses.front().translation() -
             drive.keyframes.front()->T_world_keyframe.translation())
                .norm(),
            1e-9);
  EXPECT_EQ(sessionComponentOf(r.merged, r.drive_first_keyframe), 1);
  EXPECT_EQ(sessionComponentOf(r.merged, 0), 0);
  // Localization on the merged session ignores the separate component.
  EXPECT_EQ(localizerOn(r.merged).numIndexed(), localizer.numIndexed());
  // Merged again with the same drive: a third component, not the second.
  const SessionLocalizer merged_localizer = localizerOn(r.merged);
  const SessionMergeResult again = mergeSessions(merged_localizer, drive);
  EXPECT_FALSE(again.connected);
  EXPECT_EQ(again.component, 2);
}

TEST(SessionMerge, RefusesBadParametersAndAnEmptyDrive)
{
  SessionMergeParams p;
  std::string why;
  EXPECT_TRUE(p.isValid(&why)) << why;
  p.min_anchor_loops = 0;
  EXPECT_FALSE(p.isValid(&why));
  EXPECT_NE(why.find("min_anchor_loops"), std::string::npos) << why;
  p = SessionMergeParams();
  p.agreement_m = -1.0;
  EXPECT_FALSE(p.isValid(&why));
  EXPECT_NE(why.find("agreement_m"), std::string::npos) << why;
  p = SessionMergeParams();
  p.keyframe_stride = 0;
  EXPECT_FALSE(p.isValid(&why));
  EXPECT_NE(why.find("keyframe_stride"), std::string::npos) << why;

  const auto sim = pathSimulator(PathType::kStraight, 20, 0.0, 3);
  const SessionLocalizer localizer = localizerOn(mapDrive(*sim, 0, 12));
  EXPECT_THROW(mergeSessions(localizer, Session()), std::invalid_argument);
  Session drive = mapDrive(*sim, 8, 20);
  p = SessionMergeParams();
  p.num_threads = 0;
  EXPECT_THROW(mergeSessions(localizer, drive, p), std::invalid_argument);
  drive.keyframes.front()->id = 7; // ids must be 0..n-1
  EXPECT_THROW(mergeSessions(localizer, drive), std::invalid_argument);
}

} // namespace

} // namespace test_session_merge
