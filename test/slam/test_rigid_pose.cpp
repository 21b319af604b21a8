/// Poses stay rigid: a chain of 100,000 single-precision steps composed through the
/// map's own code paths stays on SO(3) and is accepted by the pose graph, while the
/// same chain composed naively drifts off; poses from outside are projected within
/// the documented tolerance and rejected beyond it.

#include <pcl/slam/pose_graph.h>
#include <pcl/rast/rigid_pose.h>
#include <pcl/slam/slam_map.h>

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <random>
#include <string>

// This file's names stay its own: a test program compiles several test files as
// one translation unit (test/CMakeLists.txt).
namespace test_rigid_pose {

namespace {

using namespace pcl::rast;

/// A small random motion (about 1 m, 1 deg), rounded to single precision the way a
/// registration result in float arrives: its rotation block is then ~1e-7 off SO(3).
Pose3d
floatStep(std::mt19937& rng)
{
  std::normal_distribution<double> n(0.0, 1.0);
  Pose3d T = Pose3d::Identity();
  const Eigen::Vector3d axis(n(rng), n(rng), n(rng));
  T.linear() = Eigen::AngleAxisd(0.017 * n(rng), axis.normalized()).toRotationMatrix();
  T.translation() = Eigen::Vector3d(1.0 + 0.1 * n(rng), 0.1 * n(rng), 0.01 * n(rng));
  Pose3d rounded = Pose3d::Identity();
  rounded.matrix() = T.matrix().cast<float>().cast<double>();
  return rounded;
}

constexpr int kChainLength = 100000;

TEST(RigidPose, NaiveChainOfFloatStepsDriftsOffTheRotationGroup)
{
  // What the map did before: T_world_k = T_world_k-1 * T_previous_k, unnormalized.
  // This is the drift that tripped the pose graph's check on long drives.
  std::mt19937 rng(7);
  Pose3d T = Pose3d::Identity();
  for (int i = 0; i < kChainLength; ++i)
    T = T * floatStep(rng);
  EXPECT_GT(rotationError(T.linear()), 1e-6);
}

TEST(RigidPose, LongChainThroughTheMapStaysOnSO3AndThePoseGraphAcceptsIt)
{
  std::mt19937 rng(7);
  SlamMap map;
  PoseVector composed; // the same chain through composePoses, as odometry composes
  Pose3d T_world = Pose3d::Identity();
  for (int i = 0; i < kChainLength; ++i) {
    auto kf = std::make_shared<KeyFrame>();
    kf->id = static_cast<KeyFrameId>(i);
    kf->frame_index = static_cast<std::size_t>(i);
    const Pose3d step = i == 0 ? Pose3d::Identity() : floatStep(rng);
    T_world = composePoses(T_world, step);
    composed.push_back(T_world);
    kf->T_previous_keyframe = step;
    kf->T_world_keyframe = T_world;
    map.addKeyFrame(kf);
    FrameRecord frame;
    frame.frame_index = static_cast<std::size_t>(i);
    frame.reference_keyframe = kf->id;
    frame.T_keyframe_lidar = floatStep(rng); // a frame between key-frames
    map.addFrame(frame);
  }
  EXPECT_LE(maxRotationError(composed), 1e-9);
  EXPECT_LE(maxRotationError(map.keyFramePoses()), 1e-9);

  // Loop corrections at ten places, each propagated to every newer key-frame (the
  // map's other composition path), with single-precision corrected poses.
  for (int k = 1; k <= 10; ++k) {
    const auto id = static_cast<KeyFrameId>(k * kChainLength / 11);
    Pose3d corrected = map.keyFramePose(id) * floatStep(rng);
    corrected.matrix() = corrected.matrix().cast<float>().cast<double>();
    map.applyLoopCorrection({{id, corrected}});
  }
  const PoseVector keyframe_poses = map.keyFramePoses();
  ASSERT_EQ(keyframe_poses.size(), static_cast<std::size_t>(kChainLength));
  EXPECT_LE(maxRotationError(keyframe_poses), 1e-9);
  EXPECT_LE(maxRotationError(map.framePoses()), 1e-9);

  // The pose graph takes every stored pose and odometry edge as they are.
  PoseGraph graph;
  const Eigen::Matrix<double, 6, 6> information = Eigen::Matrix<double, 6, 6>::Identity();
  for (int i = 0; i < kChainLength; ++i) {
    ASSERT_NO_THROW(graph.addNode(i, keyframe_poses[i], i == 0)) << "node " << i;
    if (i > 0) {
      ASSERT_NO_THROW(graph.addEdge(i - 1, i, map.odometryEdge(static_cast<KeyFrameId>(i)),
                                    information))
          << "edge " << i;
    }
  }
  double worst_node = 0.0;
  for (const auto& [id, node] : graph.nodes())
    worst_node = std::max(worst_node, rotationError(node.pose().linear()));
  EXPECT_LE(worst_node, 1e-12);
}

TEST(RigidPose, NormalizedPoseKeepsTheTranslationAndFindsTheNearRotation)
{
  std::mt19937 rng(11);
  for (int i = 0; i < 100; ++i) {
    Pose3d T = floatStep(rng);
    Pose3d off = T;
    off.linear() += 1e-6 * Eigen::Matrix3d::Random();
    const Pose3d n = normalizedPose(off);
    EXPECT_LE(rotationError(n.linear()), 1e-14);
    EXPECT_EQ(n.translation(), off.translation());
    EXPECT_LE((n.linear() - T.linear()).cwiseAbs().maxCoeff(), 1e-5);
  }
}

TEST(RigidPose, PosesFromOutsideAreProjectedWithinToleranceAndRejectedBeyond)
{
  Pose3d T = Pose3d::Identity();
  T.linear() = Eigen::AngleAxisd(0.3, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
  T.translation() = Eigen::Vector3d(1, 2, 3);

  // The reported case: 1e-6 off (|R^T R - I| = 0.000001, det = 1.000001) is accepted.
  Pose3d slightly_off = T;
  slightly_off.linear() *= 1.0 + 5e-7;
  Pose3d projected;
  std::string why;
  ASSERT_TRUE(projectToRigid(slightly_off, &projected, &why)) << why;
  EXPECT_LE(rotationError(projected.linear()), 1e-14);
  EXPECT_LE((projected.linear() - T.linear()).cwiseAbs().maxCoeff(), 1e-6);
  EXPECT_EQ(projected.translation(), T.translation());

  // A scaled block (2x), a shear of 1e-2, a reflection, NaN: named and rejected.
  Pose3d scaled = T;
  scaled.linear() *= 2.0;
  Pose3d sheared = T;
  sheared.linear()(0, 1) += 1e-2;
  Pose3d reflected = T;
  reflected.linear().col(0) *= -1.0;
  Pose3d nan = T;
  nan.translation().x() = std::numeric_limits<double>::quiet_NaN();
  for (const Pose3d& bad : {scaled, sheared, reflected}) {
    EXPECT_FALSE(projectToRigid(bad, &projected, &why));
    EXPECT_NE(why.find("not a rotation"), std::string::npos) << why;
    EXPECT_NE(why.find("tolerance 0.001"), std::string::npos) << why;
  }
  EXPECT_FALSE(projectToRigid(nan, &projected, &why));
  EXPECT_NE(why.find("not finite"), std::string::npos) << why;
  try {
    checkedRigidPose(sheared, "PoseGraph::addNode(3)");
    FAIL() << "a sheared pose was accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("PoseGraph::addNode(3): rotation block"),
              std::string::npos)
        << e.what();
  }

  // Through the pose graph's API: accepted and stored as an exact rotation.
  PoseGraph graph;
  ASSERT_NO_THROW(graph.addNode(0, slightly_off, true));
  EXPECT_LE(rotationError(graph.nodes().at(0).pose().linear()), 1e-14);
  EXPECT_THROW(graph.addNode(1, sheared), std::invalid_argument);
}

} // namespace

} // namespace test_rigid_pose
