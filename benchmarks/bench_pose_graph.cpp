/// \file bench_pose_graph.cpp
/// \brief Pose-graph optimization speed: the parking-garage g2o graph (1661 nodes,
/// 6275 edges) and a synthetic 500-keyframe loop with drift.

#include <benchmark/benchmark.h>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <pcl/slam/g2o_io.h>
#include <pcl/slam/pose_graph.h>
#include <random>
#include <string>

namespace {

using pcl::rast::Pose3d;
using pcl::rast::PoseGraph;
using pcl::rast::PoseGraphEdgeType;
using pcl::rast::PoseGraphOptions;

std::filesystem::path
sharedDataDir()
{
  if (const char* env = std::getenv("PCL_RAST_DATA_DIR"))
    return env;
#ifdef PCL_RAST_SHARED_DATA_DIR
  return PCL_RAST_SHARED_DATA_DIR;
#else
  return std::filesystem::path(__FILE__).parent_path() / ".." / ".." / "shared" / "data";
#endif
}

Pose3d
expSmall(const Eigen::Vector3d& t, const Eigen::Vector3d& rotation_vector)
{
  Pose3d T = Pose3d::Identity();
  if (rotation_vector.norm() > 0)
    T.linear() = Eigen::AngleAxisd(rotation_vector.norm(), rotation_vector.normalized())
                     .toRotationMatrix();
  T.translation() = t;
  return T;
}

/// n key-frames on a circle (1.25 m apart), initialized by chaining noisy odometry
/// with a yaw drift, closed by three loop edges between the last and first frames.
PoseGraph
makeCircleLoop(int n, unsigned seed)
{
  const double kPi = 3.14159265358979323846;
  const double sigma_t_m = 0.05, sigma_r_rad = 0.005;
  const double radius_m = 1.25 * n / (2.0 * kPi);
  std::mt19937 rng(seed);
  std::normal_distribution<double> normal(0.0, 1.0);
  auto noise3 = [&](double sigma) {
    return Eigen::Vector3d(sigma * normal(rng), sigma * normal(rng), sigma * normal(rng));
  };
  Eigen::Matrix<double, 6, 6> information = Eigen::Matrix<double, 6, 6>::Zero();
  information.diagonal() << Eigen::Vector3d::Constant(1.0 / (sigma_t_m * sigma_t_m)),
      Eigen::Vector3d::Constant(1.0 / (sigma_r_rad * sigma_r_rad));

  pcl::rast::PoseVector truth;
  for (int i = 0; i < n; ++i) {
    const double theta = 2.0 * kPi * i / n;
    Pose3d T = Pose3d::Identity();
    T.linear() =
        Eigen::AngleAxisd(theta + kPi / 2, Eigen::Vector3d::UnitZ()).toRotationMatrix();
    T.translation() << radius_m * std::cos(theta), radius_m * std::sin(theta),
        std::sin(2 * theta);
    truth.push_back(T);
  }
  PoseGraph graph;
  Pose3d T_world_node = truth[0];
  graph.addNode(0, T_world_node);
  for (int i = 0; i + 1 < n; ++i) {
    const Pose3d T_measured =
        truth[i].inverse() * truth[i + 1] *
        expSmall(noise3(0.01), noise3(0.0005) + Eigen::Vector3d(0, 0, 0.001));
    T_world_node = T_world_node * T_measured;
    graph.addNode(i + 1, T_world_node);
    graph.addEdge(i, i + 1, T_measured, information, PoseGraphEdgeType::kOdometry);
  }
  for (const auto& [from, to] : {std::pair<int, int>{n - 1, 0}, {n - 1, 1}, {n - 2, 0}})
    graph.addEdge(from,
                  to,
                  truth[from].inverse() * truth[to],
                  information,
                  PoseGraphEdgeType::kLoop);
  return graph;
}

void
reportSummary(benchmark::State& state, const pcl::rast::PoseGraphSummary& summary)
{
  state.counters["initial_cost"] = summary.initial_cost;
  state.counters["final_cost"] = summary.final_cost;
  state.counters["iterations"] = summary.iterations;
  state.counters["nodes"] = summary.num_nodes;
  state.counters["edges"] = summary.num_edges;
  if (!summary.success)
    state.SkipWithError(summary.BriefReport().c_str());
}

void
BM_OptimizeParkingGarage(benchmark::State& state)
{
  const auto path = sharedDataDir() / "pose-graph-g2o" / "parking-garage.g2o";
  if (!std::filesystem::exists(path)) {
    state.SkipWithError(
        ("missing " + path.string() + " (set PCL_RAST_DATA_DIR)").c_str());
    return;
  }
  const PoseGraph initial = pcl::rast::readG2o(path.string());
  PoseGraphOptions options; // plain least squares, as the Ceres pose_graph_3d example
  options.loop_loss.type = pcl::rast::RobustLossType::kNone;
  pcl::rast::PoseGraphSummary summary;
  for (auto _ : state) {
    state.PauseTiming();
    PoseGraph graph = initial;
    state.ResumeTiming();
    summary = pcl::rast::optimizePoseGraph(graph, options);
    benchmark::ClobberMemory();
  }
  reportSummary(state, summary);
}
BENCHMARK(BM_OptimizeParkingGarage)->Unit(benchmark::kMillisecond);

void
BM_OptimizeSyntheticLoop(benchmark::State& state)
{
  const PoseGraph initial = makeCircleLoop(static_cast<int>(state.range(0)), 42);
  const PoseGraphOptions options; // default: Cauchy on loops
  pcl::rast::PoseGraphSummary summary;
  for (auto _ : state) {
    state.PauseTiming();
    PoseGraph graph = initial;
    state.ResumeTiming();
    summary = pcl::rast::optimizePoseGraph(graph, options);
    benchmark::ClobberMemory();
  }
  reportSummary(state, summary);
}
BENCHMARK(BM_OptimizeSyntheticLoop)->Arg(500)->Unit(benchmark::kMillisecond);

void
BM_ReadParkingGarage(benchmark::State& state)
{
  const auto path = sharedDataDir() / "pose-graph-g2o" / "parking-garage.g2o";
  if (!std::filesystem::exists(path)) {
    state.SkipWithError(("missing " + path.string()).c_str());
    return;
  }
  for (auto _ : state) {
    const PoseGraph graph = pcl::rast::readG2o(path.string());
    benchmark::DoNotOptimize(graph.numEdges());
  }
}
BENCHMARK(BM_ReadParkingGarage)->Unit(benchmark::kMillisecond);

} // namespace

BENCHMARK_MAIN();
