/// \file bench_slam.cpp
/// \brief SLAM back-end and whole-pipeline speed:
///  - BM_LocalBundleAdjustment: one local BA window (8 key-frames, their map points);
///  - BM_Pipeline/threads:{0,1}: RastSlam on 120 simulated HDL-64 scans of a loop drive
///    (simulated once, outside the timing), deterministic vs three threads;
///    items_per_second is the throughput in frames per second.

#include <benchmark/benchmark.h>

#include <pcl/slam/bundle_adjustment.h>
#include <pcl/simulation/lidar_simulator.h>
#include <pcl/slam/rast_slam.h>

#include <memory>
#include <random>
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
