/// Local mapping: bundle adjustment on synthetic problems, map-point association and
/// culling, SlamMap corrections and the merged map export.

#include <pcl/slam/bundle_adjustment.h>
#include <pcl/slam/local_mapping.h>
#include <pcl/slam/slam_map.h>

#include <pcl/io/pcd_io.h>

#include <gtest/gtest.h>

#include "test_data.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <filesystem>
#include <map>
#include <random>
#include <set>
#include <tuple>

// This file's names stay its own: a test program compiles several test files as
// one translation unit (test/CMakeLists.txt).
namespace test_local_mapping {

namespace {

using namespace pcl::rast;

Pose3d
makePose(double x, double y, double z, double yaw_rad, double pitch_rad = 0.0, double roll_rad = 0.0)
{
  Pose3d T = Pose3d::Identity();
  T.linear() = (Eigen::AngleAxisd(yaw_rad, Eigen::Vector3d::UnitZ()) *
                Eigen::AngleAxisd(pitch_rad, Eigen::Vector3d::UnitY()) *
                Eigen::AngleAxisd(roll_rad, Eigen::Vector3d::UnitX()))
                   .toRotationMatrix();
  T.translation() = Eigen::Vector3d(x, y, z);
  return T;
}

/// A small random rigid perturbation.
Pose3d
noisePose(std::mt19937& rng, double sigma_t_m, double sigma_r_rad)
{
  std::normal_distribution<double> t(0.0, sigma_t_m), r(0.0, sigma_r_rad);
  return makePose(t(rng), t(rng), t(rng), r(rng), r(rng), r(rng));
}

double
poseError(const Pose3d& a, const Pose3d& b)
{
  return (a.translation() - b.translation()).norm();
}

/// A corridor of landmarks, each with its own random descriptor.
struct World
{
  std::vector<Eigen::Vector3d> points;
  std::vector<OrbDescriptor> descriptors;
};

World
makeWorld(std::mt19937& rng, double length_m, std::size_t n)
{
  std::uniform_real_distribution<double> x(-30.0, length_m + 30.0), y(-25.0, 25.0), z(-1.5, 3.0);
  std::uniform_int_distribution<int> byte(0, 255);
  World w;
  for (std::size_t i = 0; i < n; ++i) {
    w.points.emplace_back(x(rng), y(rng), z(rng));
    OrbDescriptor d;
    for (auto& b : d)
      b = static_cast<std::uint8_t>(byte(rng));
    w.descriptors.push_back(d);
  }
  return w;
}

/// Key-frame \a id at the true pose: the landmarks within 30 m, 2 cm noise.
KeyFrame::Ptr
makeKeyFrame(std::mt19937& rng, const World& w, KeyFrameId id, const Pose3d& T_world_true)
{
  std::normal_distribution<double> noise(0.0, 0.02);
  auto kf = std::make_shared<KeyFrame>();
  kf->id = id;
  kf->frame_index = id * 5;
  const Pose3d T_kf_world = T_world_true.inverse();
  for (std::size_t i = 0; i < w.points.size(); ++i) {
    const Eigen::Vector3d p = T_kf_world * w.points[i];
    if (p.head<2>().norm() > 30.0)
      continue;
    RasterFeaturePoint fp;
    fp.x = static_cast<float>(p.x() + noise(rng));
    fp.y = static_cast<float>(p.y() + noise(rng));
    fp.z = static_cast<float>(p.z() + noise(rng));
    kf->features.points.push_back(fp);
    kf->features.descriptors.push_back(w.descriptors[i]);
  }
  auto cloud = std::make_shared<pcl::PointCloud<pcl::PointXYZI>>();
  for (const auto& fp : kf->features.points) {
    pcl::PointXYZI q;
    q.x = fp.x;
    q.y = fp.y;
    q.z = fp.z;
    q.intensity = 0.5f;
    cloud->push_back(q);
  }
  kf->cloud = cloud;
  return kf;
}

TEST(BundleAdjustment, ReducesErrorOfNoisyPosesAndPoints)
{
  std::mt19937 rng(7);
  const World w = makeWorld(rng, 40.0, 400);
  BundleAdjustmentProblem problem;
  std::map<KeyFrameId, Pose3d> truth;
  std::normal_distribution<double> point_noise(0.0, 0.15);
  for (KeyFrameId id = 0; id < 6; ++id) {
    truth[id] = makePose(8.0 * id, 0.5 * id, 0.1 * id, 0.05 * id);
    const KeyFrame::Ptr kf = makeKeyFrame(rng, w, id, truth[id]);
    problem.poses[id] = id == 0 ? truth[id] : truth[id] * noisePose(rng, 0.3, 0.02);
    // Observations: which landmark each feature is (features are in landmark order).
    std::size_t f = 0;
    const Pose3d T_kf_world = truth[id].inverse();
    for (std::size_t i = 0; i < w.points.size(); ++i) {
      if ((T_kf_world * w.points[i]).head<2>().norm() > 30.0)
        continue;
      const auto& fp = kf->features.points[f++];
      problem.observations.push_back({id, static_cast<MapPointId>(i),
                                      Eigen::Vector3d(fp.x, fp.y, fp.z)});
      if (!problem.points.count(static_cast<MapPointId>(i)))
        problem.points[static_cast<MapPointId>(i)] =
            w.points[i] + Eigen::Vector3d(point_noise(rng), point_noise(rng), point_noise(rng));
    }
  }
  problem.fixed.insert(0);
  BundleAdjustmentParams params;
  params.max_iterations = 50;
  double before = 0.0;
  for (const auto& [id, T] : problem.poses)
    before += poseError(T, truth[id]);
  const double rms_before = reprojectionRmsPx(problem, params);
  const BundleAdjustmentSummary summary = bundleAdjust(problem, params);
  ASSERT_TRUE(summary.success) << summary.message;
  double after = 0.0;
  for (const auto& [id, T] : problem.poses)
    after += poseError(T, truth[id]);
  EXPECT_LT(summary.final_cost, summary.initial_cost);
  EXPECT_LT(reprojectionRmsPx(problem, params), 0.5 * rms_before);
  EXPECT_LT(after, 0.1 * before) << "before " << before << " after " << after;
  EXPECT_LT(after / 5.0, 0.02); // mean position error of the free poses < 2 cm
  EXPECT_EQ(summary.num_fixed_poses, 1);
  EXPECT_EQ(poseError(problem.poses[0], truth[0]), 0.0); // gauge held
  double point_error = 0.0;
  for (const auto& [id, p] : problem.points)
    point_error += (p - w.points[id]).norm();
  EXPECT_LT(point_error / problem.points.size(), 0.05);
}

TEST(BundleAdjustment, HuberLossResistsOutlierObservations)
{
  std::mt19937 rng(11);
  const World w = makeWorld(rng, 30.0, 300);
  BundleAdjustmentProblem problem;
  std::map<KeyFrameId, Pose3d> truth;
  std::uniform_real_distribution<double> u(0.0, 1.0), far(-5.0, 5.0);
  for (KeyFrameId id = 0; id < 4; ++id) {
    truth[id] = makePose(6.0 * id, 0.0, 0.0, 0.03 * id);
    problem.poses[id] = id == 0 ? truth[id] : truth[id] * noisePose(rng, 0.2, 0.01);
    const Pose3d T_kf_world = truth[id].inverse();
    for (std::size_t i = 0; i < w.points.size(); ++i) {
      Eigen::Vector3d p = T_kf_world * w.points[i];
      if (p.head<2>().norm() > 30.0)
        continue;
      if (u(rng) < 0.1) // 10 % gross outliers (wrong associations)
        p += Eigen::Vector3d(far(rng), far(rng), 0.0);
      problem.observations.push_back({id, static_cast<MapPointId>(i), p});
      problem.points[static_cast<MapPointId>(i)] = w.points[i];
    }
  }
  BundleAdjustmentParams params;
  params.max_iterations = 50;
  const BundleAdjustmentSummary summary = bundleAdjust(problem, params);
  ASSERT_TRUE(summary.success);
  for (KeyFrameId id = 1; id < 4; ++id)
    EXPECT_LT(poseError(problem.poses[id], truth[id]), 0.05) << "key-frame " << id;
}

TEST(BundleAdjustment, PinholeProjectionAlsoConverges)
{
  std::mt19937 rng(5);
  const World w = makeWorld(rng, 30.0, 300);
  BundleAdjustmentProblem problem;
  std::map<KeyFrameId, Pose3d> truth;
  for (KeyFrameId id = 0; id < 4; ++id) {
    truth[id] = makePose(6.0 * id, 1.0 * id, 0.0, 0.02 * id);
    problem.poses[id] = id == 0 ? truth[id] : truth[id] * noisePose(rng, 0.2, 0.01);
    const Pose3d T_kf_world = truth[id].inverse();
    for (std::size_t i = 0; i < w.points.size(); ++i) {
      const Eigen::Vector3d p = T_kf_world * w.points[i];
      if (p.head<2>().norm() > 30.0)
        continue;
      problem.observations.push_back({id, static_cast<MapPointId>(i), p});
      problem.points[static_cast<MapPointId>(i)] = w.points[i];
    }
  }
  BundleAdjustmentParams params;
  params.raster.projection = pcl::rast::RasterProjection::kPinhole;
  params.max_iterations = 50;
  const BundleAdjustmentSummary summary = bundleAdjust(problem, params);
  ASSERT_TRUE(summary.success);
  for (KeyFrameId id = 1; id < 4; ++id)
    EXPECT_LT(poseError(problem.poses[id], truth[id]), 0.02) << "key-frame " << id;
}

TEST(BundleAdjustment, RejectsInvalidInput)
{
  BundleAdjustmentParams params;
  params.huber_delta_px = 0.0;
  std::string why;
  EXPECT_FALSE(params.isValid(&why));
  EXPECT_NE(why.find("huber"), std::string::npos);
  BundleAdjustmentProblem problem;
  EXPECT_THROW(bundleAdjust(problem, params), std::invalid_argument);
  problem.observations.push_back({3, 4, Eigen::Vector3d::Zero()});
  EXPECT_THROW(bundleAdjust(problem, BundleAdjustmentParams()), std::invalid_argument);
  LocalMappingParams lm;
  lm.window_size = 1;
  EXPECT_FALSE(lm.isValid(&why));
  EXPECT_THROW(LocalMapping(lm, std::make_shared<SlamMap>()), std::invalid_argument);
  EXPECT_THROW(LocalMapping(LocalMappingParams(), nullptr), std::invalid_argument);
}

/// Runs \a num_kfs key-frames along a drive with noisy odometry edges through
/// SlamMap + LocalMapping; returns the mean position error of the key-frames.
struct DriveResult
{
  double mean_error_m = 0.0;
  std::size_t max_live_points = 0;
  std::size_t total_matched = 0;
  std::size_t created = 0;
};

DriveResult
runDrive(bool enable_ba, int num_kfs, std::uint32_t seed)
{
  std::mt19937 rng(seed);
  const double step = 5.0;
  const World w = makeWorld(rng, step * num_kfs, 30 * static_cast<std::size_t>(num_kfs));
  auto map = std::make_shared<SlamMap>();
  LocalMappingParams params;
  params.enable_bundle_adjustment = enable_ba;
  params.window_size = 5;
  LocalMapping mapping(params, map);
  PoseVector truth;
  DriveResult result;
  for (int k = 0; k < num_kfs; ++k) {
    truth.push_back(makePose(step * k, 2.0 * std::sin(0.1 * k), 0.0, 0.1 * std::sin(0.2 * k)));
    KeyFrame::Ptr kf = makeKeyFrame(rng, w, static_cast<KeyFrameId>(k), truth.back());
    if (k == 0)
      kf->T_world_keyframe = truth[0];
    else
      kf->T_previous_keyframe = truth[k - 1].inverse() * truth[k] * noisePose(rng, 0.08, 0.004);
    map->addKeyFrame(kf);
    const LocalMappingResult r = mapping.processKeyFrame(kf);
    if (k > 0) {
      EXPECT_GT(r.num_matched, 0) << "key-frame " << k;
    }
    result.total_matched += r.num_matched;
    result.max_live_points = std::max(result.max_live_points, map->numMapPoints());
  }
  const PoseVector est = map->keyFramePoses();
  for (int k = 0; k < num_kfs; ++k)
    result.mean_error_m += poseError(est[k], truth[k]) / num_kfs;
  result.created = map->numMapPointsCreated();
  return result;
}

TEST(LocalMapping, BundleAdjustmentReducesDriftOfNoisyOdometry)
{
  const DriveResult without = runDrive(false, 25, 3);
  const DriveResult with = runDrive(true, 25, 3);
  EXPECT_LT(with.mean_error_m, 0.5 * without.mean_error_m)
      << "without BA " << without.mean_error_m << " m, with " << with.mean_error_m << " m";
}

TEST(LocalMapping, MapPointCullingBoundsTheLocalMap)
{
  const DriveResult short_drive = runDrive(true, 15, 9);
  const DriveResult long_drive = runDrive(true, 45, 9);
  // Three times the key-frames and map points created, the same live local map.
  // (without culling the live map would hold every point ever created)
  EXPECT_GT(long_drive.created, 2.5 * short_drive.created);
  EXPECT_LT(long_drive.max_live_points, 1.6 * short_drive.max_live_points);
  EXPECT_LT(long_drive.max_live_points, 0.3 * long_drive.created);
  // Features of landmarks seen before are associated, not duplicated.
  EXPECT_GT(long_drive.total_matched, long_drive.created);
}

TEST(SlamMap, CorrectionsMoveNewerKeyFramesPointsAndFrames)
{
  auto map = std::make_shared<SlamMap>();
  std::mt19937 rng(1);
  const World w = makeWorld(rng, 20.0, 50);
  for (KeyFrameId id = 0; id < 3; ++id) {
    auto kf = makeKeyFrame(rng, w, id, makePose(5.0 * id, 0, 0, 0));
    kf->T_previous_keyframe = makePose(5.0, 0, 0, 0);
    map->addKeyFrame(kf);
    map->addFrame({kf->frame_index, 0.1 * id, id, Pose3d::Identity(), "features", false, "", ""});
    FrameRecord between{kf->frame_index + 1, 0.1 * id + 0.05, id, makePose(1.0, 0, 0, 0),
                        "features", false, "", ""};
    map->addFrame(between);
  }
  EXPECT_THROW(map->addKeyFrame(std::make_shared<KeyFrame>()), std::invalid_argument);
  const MapPointId pid = map->createMapPoint(2, 0, Eigen::Vector3d(10, 1, 0), OrbDescriptor{});
  // Correct key-frame 1 by +1 m in y: key-frame 2 (newer) follows, so does its point.
  map->applyLoopCorrection({{1, makePose(5.0, 1.0, 0, 0)}});
  EXPECT_EQ(map->correctionEpoch(), 1u);
  EXPECT_NEAR(map->keyFramePose(2).translation().y(), 1.0, 1e-12);
  EXPECT_NEAR(map->mapPoints().front().p_world.y(), 2.0, 1e-12);
  EXPECT_EQ(map->mapPoints().front().id, pid);
  const PoseVector frames = map->framePoses();
  ASSERT_EQ(frames.size(), 6u);
  EXPECT_NEAR(frames[5].translation().x(), 11.0, 1e-12);
  EXPECT_NEAR(frames[5].translation().y(), 1.0, 1e-12);
  // A BA started before the correction is stale and must not be written.
  EXPECT_FALSE(map->applyBundleAdjustment(0, {{2, Pose3d::Identity()}}, {}));
  EXPECT_TRUE(map->applyBundleAdjustment(1, {}, {{pid, Eigen::Vector3d(1, 2, 3)}}));
  EXPECT_NEAR(map->mapPoints().front().p_world.z(), 3.0, 1e-12);
  EXPECT_EQ(map->cullMapPoints({0, 1}), 1u);
  EXPECT_EQ(map->numMapPoints(), 0u);
}

TEST(SlamMap, MergedMapIsVoxelizedAndSavedAsReadablePcd)
{
  auto map = std::make_shared<SlamMap>();
  std::mt19937 rng(2);
  const World w = makeWorld(rng, 20.0, 2000);
  for (KeyFrameId id = 0; id < 3; ++id) {
    auto kf = makeKeyFrame(rng, w, id, makePose(3.0 * id, 0, 0, 0));
    kf->T_previous_keyframe = makePose(3.0, 0, 0, 0);
    map->addKeyFrame(kf);
  }
  const auto full = map->buildMap(0.0);
  const auto coarse = map->buildMap(2.0);
  EXPECT_GT(full->size(), coarse->size());
  EXPECT_GT(coarse->size(), 10u);
  // Every voxel holds at most one point.
  std::set<std::tuple<long, long, long>> voxels;
  for (const auto& p : coarse->points)
    EXPECT_TRUE(voxels.emplace(std::floor(p.x / 2.0), std::floor(p.y / 2.0), std::floor(p.z / 2.0)).second);
  const auto dir = pcl_rast_test::makeTempDir("slam_map_pcd");
  const std::string path = (dir / "map.pcd").string();
  savePcdAtomically(path, *coarse);
  pcl::PointCloud<pcl::PointXYZI> loaded;
  ASSERT_EQ(pcl::io::loadPCDFile(path, loaded), 0);
  EXPECT_EQ(loaded.size(), coarse->size());
  EXPECT_FLOAT_EQ(loaded.points[0].intensity, 0.5f);
  EXPECT_FALSE(std::filesystem::exists(path + ".tmp"));
}

TEST(SlamMap, OftenVisitedTilesAreMergedOnTheWayWithExactMeans)
{
  // 36 key-frames at one place, two alternating scans of 40 k points: 1.44 M samples in
  // one 100 m tile, past the point where the tile's samples are merged on the way.
  auto map = std::make_shared<SlamMap>();
  std::mt19937 rng(9);
  std::uniform_real_distribution<float> xy(10.0f, 50.0f), z(0.0f, 4.0f), intensity(0.0f, 1.0f);
  pcl::PointCloud<pcl::PointXYZI> a, b;
  for (int i = 0; i < 40000; ++i) {
    pcl::PointXYZI p;
    p.x = xy(rng);
    p.y = xy(rng);
    p.z = z(rng);
    p.intensity = intensity(rng);
    a.push_back(p);
    p.x += 0.3f; // often another voxel of the 1 m grid
    p.intensity = intensity(rng);
    b.push_back(p);
  }
  for (KeyFrameId id = 0; id < 36; ++id) {
    auto kf = std::make_shared<KeyFrame>();
    kf->id = id;
    kf->frame_index = id;
    kf->cloud = std::make_shared<const pcl::PointCloud<pcl::PointXYZI>>(id % 2 ? b : a);
    map->addKeyFrame(kf);
  }
  // The expected map: every stored point (buildMap(0) gives them all) into its voxel.
  const double leaf = 1.0;
  std::map<std::tuple<long, long, long>, std::array<double, 5>> sums;
  const auto all_points = map->buildMap(0.0);
  for (const auto& p : all_points->points) {
    auto& acc = sums[{static_cast<long>(std::floor(p.x / leaf)), static_cast<long>(std::floor(p.y / leaf)),
                      static_cast<long>(std::floor(p.z / leaf))}];
    acc[0] += p.x;
    acc[1] += p.y;
    acc[2] += p.z;
    acc[3] += p.intensity;
    acc[4] += 1.0;
  }
  const auto merged = map->buildMap(leaf);
  ASSERT_EQ(merged->size(), sums.size());
  double worst_m = 0.0, worst_intensity = 0.0;
  for (const auto& p : merged->points) {
    const auto it = sums.find({static_cast<long>(std::floor(p.x / leaf)), static_cast<long>(std::floor(p.y / leaf)),
                               static_cast<long>(std::floor(p.z / leaf))});
    ASSERT_NE(it, sums.end());
    const auto& acc = it->second;
    worst_m = std::max({worst_m, std::abs(p.x - acc[0] / acc[4]), std::abs(p.y - acc[1] / acc[4]),
                        std::abs(p.z - acc[2] / acc[4])});
    worst_intensity = std::max(worst_intensity, std::abs(p.intensity - acc[3] / acc[4]));
  }
  EXPECT_LT(worst_m, 1e-4);
  EXPECT_LT(worst_intensity, 1e-4);
}

} // namespace

} // namespace test_local_mapping
