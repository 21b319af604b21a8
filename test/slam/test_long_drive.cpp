/// Long drives in both thread modes: a simulated loop driven five times with a key-frame
/// forced at every tracked scan gives more than 3000 key-frames, a pose graph of that
/// size re-optimized on every revisit, and thousands of composed poses. The run must
/// finish, every stored pose must stay on SO(3), and an error in the loop-closing
/// thread must end the run without losing what was processed.

#include <pcl/simulation/lidar_simulator.h>
#include <pcl/slam/rast_slam.h>
#include <pcl/evaluation/trajectory_evaluation.h>

#include <gtest/gtest.h>

#include <atomic>
#include <iostream>
#include <memory>
#include <stdexcept>
#include <string>

// This file's names stay its own: a test program compiles several test files as
// one translation unit (test/CMakeLists.txt).
namespace test_long_drive {

namespace {

using namespace pcl::rast;

constexpr int kFrames = 3100;
constexpr double kLaps = 5.0;
#if defined(__SANITIZE_ADDRESS__) || defined(__SANITIZE_THREAD__)
/// Under the sanitizers the threaded run drives 2.1 laps (1300 scans, loops closed on
/// the second lap): the same stages, spills and releases, in 40 % of the time (it took
/// 3.6 minutes under ASan, the longest test there). The full drive runs without them.
constexpr int kThreadedFrames = 1300;
#else
constexpr int kThreadedFrames = kFrames;
#endif

/// VLP-16 (cheap to simulate and track) around a 620 m loop at 1 m per scan.
std::unique_ptr<LidarSimulator>
makeSimulator()
{
  PathParams path;
  path.type = PathType::kLoop;
  path.num_frames = kFrames;
  path.revisit_fraction = kLaps - 1.0;
  LidarSimulatorParams params;
  params.sensor = SensorModel::kVlp16;
  params.seed = 23;
  params.num_threads = 2;
  return std::make_unique<LidarSimulator>(params, generatePath(path));
}

/// Key-frames at every tracked scan (0.5 m apart at 1 m a scan); loop search cooled
/// down for 50 key-frames after a loop, so the graph of thousands of nodes is solved
/// about once every 50 m of a revisit.
SlamParams
longDriveParams(bool deterministic)
{
  SlamParams params;
  params.deterministic = deterministic;
  applySensorPreset(SensorPreset::kVlp16, params.odometry);
  params.odometry.keyframe_max_distance_m = 0.5;
  params.odometry.keyframe_min_frames = 1;
  params.loop_closing.cooldown_keyframes = 50;
  return params;
}

struct DriveResult
{
  SlamStatistics stats;
  PoseVector frame_poses, keyframe_poses, gt;
  std::vector<LoopEdge> loops;
  std::string error;
  std::size_t frames_added = 0;
};

/// Drive \a frames scans through RastSlam; an exception from addScan or finish ends
/// the run and is returned in DriveResult::error (the results so far are still read).
DriveResult
drive(const SlamParams& params, int frames, const RastSlam::KeyFrameObserver& observer = {})
{
  const std::unique_ptr<LidarSimulator> sim = makeSimulator();
  RastSlam slam(params);
  if (observer)
    slam.setKeyFrameObserver(observer);
  DriveResult r;
  const Pose3d T0_inv = sim->sensorPose(0).inverse();
  try {
    for (int i = 0; i < frames; ++i) {
      auto cloud = std::make_shared<pcl::PointCloud<pcl::PointXYZI>>();
      sim->simulateFrame(static_cast<std::size_t>(i), *cloud);
      r.gt.push_back(T0_inv * sim->sensorPose(static_cast<std::size_t>(i)));
      slam.addScan(cloud, sim->timestamp(static_cast<std::size_t>(i)),
                   static_cast<std::size_t>(i));
      ++r.frames_added;
    }
    slam.finish();
  } catch (const std::exception& e) {
    r.error = e.what();
    try {
      slam.finish(); // joins the stages; the error was reported already
    } catch (const std::exception&) {
    }
  }
  r.stats = slam.statistics();
  r.frame_poses = slam.framePoses();
  r.keyframe_poses = slam.keyFramePoses();
  r.loops = slam.loops();
  return r;
}

void
expectLongDriveFinishesOnSO3(bool deterministic, int frames)
{
  const DriveResult r = drive(longDriveParams(deterministic), frames);
  ASSERT_TRUE(r.error.empty()) << r.error;
  ASSERT_EQ(r.frame_poses.size(), static_cast<std::size_t>(frames));
  // A key-frame at nearly every scan; loops on every lap after the first.
  EXPECT_GE(r.stats.keyframes, static_cast<std::size_t>(frames - 100));
  const std::size_t min_loops = frames >= kFrames ? 3 : 1;
  EXPECT_GE(r.stats.pose_graph_runs, min_loops) << "the revisits must close loops";
  std::size_t active = 0;
  for (const auto& e : r.loops)
    active += e.active;
  EXPECT_GE(active, min_loops);
  EXPECT_LE(maxRotationError(r.keyframe_poses), 1e-9);
  EXPECT_LE(maxRotationError(r.frame_poses), 1e-9);
  const EvaluationResult ev = evaluateTrajectory(r.frame_poses, r.gt);
  // Simulated VLP-16, 3.1 km: odometry alone drifts metres here; loops bound it.
  EXPECT_LT(ev.ate_rmse_m, 1.0);
  std::cout << (deterministic ? "deterministic" : "threaded") << ": " << r.stats.keyframes
            << " key-frames, " << active << " loops, " << r.stats.pose_graph_runs
            << " pose-graph runs, ATE " << ev.ate_rmse_m << " m, max rotation error "
            << maxRotationError(r.keyframe_poses) << "\n";
}

TEST(LongDrive, ThreadedRunOfThousandsOfKeyFramesFinishesOnSO3)
{
  expectLongDriveFinishesOnSO3(false, kThreadedFrames);
}

TEST(LongDrive, DeterministicRunOfThousandsOfKeyFramesFinishesOnSO3)
{
#if defined(__SANITIZE_ADDRESS__) || defined(__SANITIZE_THREAD__)
  // 3.7 minutes under ASan, the longest test of the sanitizer suite: the threaded run
  // above drives the same stages, and RastSlam.DeterministicModeIsReproducible the
  // deterministic mode, under the sanitizers too.
  GTEST_SKIP() << "the deterministic long drive runs without sanitizers only";
#endif
  expectLongDriveFinishesOnSO3(true, kFrames);
}

/// An exception in the loop-closing thread (injected through the key-frame observer)
/// ends the threaded run: addScan or finish reports it, and every frame processed
/// before it keeps its pose.
TEST(LongDrive, LoopClosingErrorEndsTheRunWithoutLosingIt)
{
  const int frames = 120;
  std::atomic<int> loop_closing_seen{0};
  const DriveResult r =
      drive(longDriveParams(false), frames, [&](SlamStage stage, const KeyFrame& kf) {
        if (stage == SlamStage::kLoopClosing && ++loop_closing_seen == 30)
          throw std::runtime_error("injected: loop closing fails at key-frame " +
                                   std::to_string(kf.id));
      });
  ASSERT_NE(r.error.find("injected: loop closing fails"), std::string::npos) << r.error;
  EXPECT_LT(r.frames_added, static_cast<std::size_t>(frames)) << "the run went on";
  EXPECT_EQ(r.frame_poses.size(), r.frames_added);
  EXPECT_GE(r.keyframe_poses.size(), 30u);
  EXPECT_LE(maxRotationError(r.frame_poses), 1e-9);
  const PoseVector gt(r.gt.begin(), r.gt.begin() + static_cast<long>(r.frame_poses.size()));
  EXPECT_LT(evaluateTrajectory(r.frame_poses, gt).ate_rmse_m, 0.5);
}

/// In deterministic mode every stage runs on the caller's thread: a stage's error is
/// thrown by addScan and ends the run (later scans are refused with it, finish reports
/// it), and what was processed stays readable.
TEST(LongDrive, DeterministicStageErrorEndsTheRun)
{
  SlamParams params = longDriveParams(true);
  const std::unique_ptr<LidarSimulator> sim = makeSimulator();
  RastSlam slam(params);
  slam.setKeyFrameObserver([](SlamStage stage, const KeyFrame& kf) {
    if (stage == SlamStage::kLocalMapping && kf.id == 5)
      throw std::runtime_error("injected: local mapping fails");
  });
  std::size_t added = 0;
  bool thrown = false;
  for (std::size_t i = 0; i < 20 && !thrown; ++i) {
    auto cloud = std::make_shared<pcl::PointCloud<pcl::PointXYZI>>();
    sim->simulateFrame(i, *cloud);
    try {
      slam.addScan(cloud, sim->timestamp(i), i);
      ++added;
    } catch (const std::runtime_error& e) {
      EXPECT_NE(std::string(e.what()).find("injected"), std::string::npos);
      thrown = true;
    }
  }
  ASSERT_TRUE(thrown);
  auto next = std::make_shared<pcl::PointCloud<pcl::PointXYZI>>();
  sim->simulateFrame(30, *next);
  EXPECT_ANY_THROW(slam.addScan(next, sim->timestamp(30), 30)) << "the run must have ended";
  EXPECT_NO_THROW(slam.finish()); // reported already
  EXPECT_EQ(slam.framePoses().size(), added + 1); // the failing frame was tracked
  EXPECT_GE(slam.keyFramePoses().size(), 6u);
}

} // namespace

} // namespace test_long_drive
