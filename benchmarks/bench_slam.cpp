/// \file bench_slam.cpp
/// \brief SLAM back-end and whole-pipeline speed:
///  - BM_LocalBundleAdjustment: one local BA window (8 key-frames, their map points);
///  - BM_AppearanceRetrieval: one scan's ORB features ranked by appearance against 900
///    key-frames of simulated HDL-64 scans (KeyFrameDatabase, a placement's retrieval);
///  - BM_PolarDescriptor: one simulated HDL-64 scan described (what indexing a session
///    costs per key-frame, and a placement per scan), and BM_PolarRanking: a scan's
///    descriptor ranked against 1600 key-frames' (a placement's polar candidates);
///  - BM_Pipeline/threads:{0,1}: RastSlam on 120 simulated HDL-64 scans of a loop drive
///    (simulated once, outside the timing), deterministic vs three threads;
///    items_per_second is the throughput in frames per second.

#include "../slam/src/polar_descriptor.h"

#include <benchmark/benchmark.h>

#include <pcl/common/transforms.h>
#include <pcl/simulation/lidar_simulator.h>
#include <pcl/slam/bundle_adjustment.h>
#include <pcl/slam/keyframe_database.h>
#include <pcl/slam/odometry.h>
#include <pcl/slam/rast_slam.h>

#include <cmath>
#include <memory>
#include <random>
#include <string>
#include <vector>

namespace {

using namespace pcl::rast;

void
BM_LocalBundleAdjustment(benchmark::State& state)
{
  std::mt19937 rng(1);
  std::uniform_real_distribution<double> x(-30.0, 70.0), y(-25.0, 25.0), z(-1.5, 3.0);
  std::normal_distribution<double> noise(0.0, 0.02), pose_noise(0.0, 0.05);
  std::vector<Eigen::Vector3d> points;
  for (int i = 0; i < 4000; ++i)
    points.emplace_back(x(rng), y(rng), z(rng));
  BundleAdjustmentProblem base;
  for (KeyFrameId id = 0; id < 10; ++id) {
    Pose3d T = Pose3d::Identity();
    T.translation() = Eigen::Vector3d(5.0 * id, 0.0, 0.0);
    Pose3d T_noisy = T;
    if (id >= 2)
      T_noisy.translation() += Eigen::Vector3d(pose_noise(rng), pose_noise(rng), 0.0);
    base.poses[id] = T_noisy;
    if (id < 2)
      base.fixed.insert(id); // border
    for (std::size_t i = 0; i < points.size(); ++i) {
      const Eigen::Vector3d p = T.inverse() * points[i];
      if (p.head<2>().norm() > 30.0 || (i + id) % 3 != 0)
        continue;
      base.points[static_cast<MapPointId>(i)] = points[i];
      base.observations.push_back({id, static_cast<MapPointId>(i),
                                   p + Eigen::Vector3d(noise(rng), noise(rng), noise(rng))});
    }
  }
  BundleAdjustmentParams params;
  for (auto _ : state) {
    BundleAdjustmentProblem problem = base;
    const BundleAdjustmentSummary s = bundleAdjust(problem, params);
    benchmark::DoNotOptimize(s.final_cost);
    state.counters["residuals"] = s.num_residuals;
  }
}
BENCHMARK(BM_LocalBundleAdjustment)->Unit(benchmark::kMillisecond);

/// The retrieval benchmark's index and query, built once.
struct AppearanceIndex
{
  std::unique_ptr<KeyFrameDatabase> database;
  KeyFrame query;
  std::size_t indexed_features = 0;
  std::string error; ///< why it could not be built
};

constexpr int kPasses = 3, kQueryScan = 150;

const AppearanceIndex&
appearanceIndex()
{
  static const AppearanceIndex index = [] {
    AppearanceIndex out;
    // ORB features of 300 simulated HDL-64 scans along a 300 m drive, each indexed three
    // times as three passes of the place (a few descriptor bits flipped, the ORB angles
    // turned): 900 key-frames, the size of a 2000-scan KITTI session, with the uneven
    // buckets of real raster ORB. Simulated once, outside the timing (about 10 s).
    constexpr int kScans = 300;
    PathParams path;
    path.type = PathType::kStraight;
    path.num_frames = kScans;
    LidarSimulatorParams sim_params;
    sim_params.seed = 3;
    sim_params.num_threads = 2;
    LidarSimulator sim(sim_params, generatePath(path));
    std::mt19937 rng(7);
    std::uniform_int_distribution<int> bit(0, 255);
    const auto perturbed = [&](RasterFeatureSet set, int flips, float turn_deg) {
      for (std::size_t i = 0; i < set.size(); ++i) {
        for (int f = 0; f < flips; ++f) {
          const int k = bit(rng);
          set.descriptors[i][k / 8] ^= static_cast<std::uint8_t>(1u << (k % 8));
        }
        set.points[i].angle_deg = std::fmod(set.points[i].angle_deg + turn_deg, 360.0f);
      }
      return set;
    };
    LoopDetectorParams params;
    params.dense_check = false;
    params.min_keyframe_gap = 1;
    params.min_travel_gap_m = 0.0;
    out.database = std::make_unique<KeyFrameDatabase>(params);
    for (int i = 0; i < kScans; ++i) {
      auto cloud = std::make_shared<pcl::PointCloud<pcl::PointXYZI>>();
      sim.simulateFrame(static_cast<std::size_t>(i), *cloud);
      Odometry odometry; // a fresh front end: each scan's own features
      const OdometryFrameResult r = odometry.processFrame(cloud, 0.0, 0);
      if (!r.features || r.features->empty()) {
        out.error = "a simulated scan gave no features";
        return out;
      }
      for (int pass = 0; pass < kPasses; ++pass) {
        auto kf = std::make_shared<KeyFrame>();
        kf->id = static_cast<KeyFrameId>(kPasses * i + pass);
        kf->T_world_keyframe.translation() = Eigen::Vector3d(i, 0.0, 0.0);
        kf->features = perturbed(*r.features, pass == 0 ? 0 : 8, 40.0f * pass);
        out.indexed_features += kf->features.size();
        out.database->add(kf, kf->T_world_keyframe);
      }
      if (i == kQueryScan) {
        out.query.id = static_cast<KeyFrameId>(kPasses * kScans);
        out.query.features = perturbed(*r.features, 12, 25.0f);
      }
    }
    return out;
  }();
  return index;
}

void
BM_AppearanceRetrieval(benchmark::State& state)
{
  const AppearanceIndex& index = appearanceIndex();
  if (!index.error.empty()) {
    state.SkipWithError(index.error.c_str());
    return;
  }
  for (auto _ : state) {
    const auto ranking =
        index.database->rankByAppearance(index.query, Pose3d::Identity());
    if (ranking.empty() || ranking.front().first / kPasses != kQueryScan) {
      state.SkipWithError("no pass of the query's place is ranked first");
      break;
    }
    benchmark::DoNotOptimize(ranking.data());
  }
  state.counters["indexed_features"] = static_cast<double>(index.indexed_features);
  state.counters["query_features"] = static_cast<double>(index.query.features.size());
}
BENCHMARK(BM_AppearanceRetrieval)->Unit(benchmark::kMillisecond);

const std::vector<pcl::PointCloud<pcl::PointXYZI>::ConstPtr>& scans();

void
BM_PolarDescriptor(benchmark::State& state)
{
  const auto& cloud = *scans().front();
  const slam_detail::PolarDescriptorParams params;
  for (auto _ : state) {
    const slam_detail::PolarDescriptor d(cloud, params);
    benchmark::DoNotOptimize(d.bytes());
  }
  state.counters["points"] = static_cast<double>(cloud.size());
}
BENCHMARK(BM_PolarDescriptor)->Unit(benchmark::kMillisecond);

void
BM_PolarRanking(benchmark::State& state)
{
  // The 120 scans of the loop drive, turned by a different yaw each time round, stand
  // for the 1600 key-frames of a session.
  constexpr std::size_t kKeyFrames = 1600;
  const auto& clouds = scans();
  const slam_detail::PolarDescriptorParams params;
  std::vector<slam_detail::PolarDescriptor> map;
  for (std::size_t i = 0; i < kKeyFrames; ++i) {
    const Eigen::Affine3f turn(Eigen::AngleAxisf(
        0.3f * static_cast<float>(i / clouds.size()), Eigen::Vector3f::UnitZ()));
    pcl::PointCloud<pcl::PointXYZI> turned;
    pcl::transformPointCloud(*clouds[i % clouds.size()], turned, turn);
    map.emplace_back(turned, params);
  }
  const slam_detail::PolarDescriptor query(*clouds[50], params);
  for (auto _ : state) {
    const auto ranked = slam_detail::rankByPolarDescriptor(query, map, 3);
    if (ranked.empty() || ranked.front().index % clouds.size() != 50) {
      state.SkipWithError("the query's own scan is not ranked first");
      break;
    }
    benchmark::DoNotOptimize(ranked.data());
  }
  state.counters["keyframes"] = static_cast<double>(kKeyFrames);
}
BENCHMARK(BM_PolarRanking)->Unit(benchmark::kMillisecond);

const std::vector<pcl::PointCloud<pcl::PointXYZI>::ConstPtr>&
scans()
{
  static const auto clouds = [] {
    PathParams path;
    path.type = PathType::kLoop;
    path.num_frames = 120;
    LidarSimulatorParams params;
    params.seed = 2;
    params.num_threads = 2;
    LidarSimulator sim(params, generatePath(path));
    std::vector<pcl::PointCloud<pcl::PointXYZI>::ConstPtr> out;
    for (std::size_t i = 0; i < sim.numFrames(); ++i) {
      auto c = std::make_shared<pcl::PointCloud<pcl::PointXYZI>>();
      sim.simulateFrame(i, *c);
      out.push_back(c);
    }
    return out;
  }();
  return clouds;
}

void
BM_Pipeline(benchmark::State& state)
{
  const auto& clouds = scans();
  SlamParams params;
  params.deterministic = state.range(0) == 0;
  for (auto _ : state) {
    RastSlam slam(params);
    for (std::size_t i = 0; i < clouds.size(); ++i)
      slam.addScan(clouds[i], 0.1 * i, i);
    slam.finish();
    benchmark::DoNotOptimize(slam.framePoses().size());
  }
  state.SetItemsProcessed(state.iterations() * static_cast<std::int64_t>(clouds.size()));
}
BENCHMARK(BM_Pipeline)->ArgName("threads")->Arg(0)->Arg(1)->Unit(benchmark::kMillisecond)->Iterations(2);

} // namespace

BENCHMARK_MAIN();
