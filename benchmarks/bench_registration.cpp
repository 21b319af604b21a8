/// \file bench_registration.cpp
/// \brief Dense refinement speed (doc/registration.md): target preparation, source
/// preparation and refinement on the real scan pair (scan-pair-pcd, identity guess
/// 0.5 m / 0.7 deg off) and on a consecutive KITTI raw pair (kitti-raw-22 frames 0 and
/// 1, HDL-64, ~120k points, identity guess ~0.8 m off). Report medians:
///   bench_registration --benchmark_repetitions=10 --benchmark_report_aggregates_only=true

#include <pcl/registration/point_to_plane_refinement.h>

#include <benchmark/benchmark.h>
#include <pcl/io/pcd_io.h>

#include <cstdlib>
#include <filesystem>
#include <string>

namespace {

using pcl::rast::PointToPlaneParams;
using pcl::rast::PointToPlaneTarget;
using Cloud = pcl::PointCloud<pcl::PointXYZI>;

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

/// Source and target scans of a pair, loaded once; empty when the data is missing.
struct Pair
{
  Cloud source, target;
};

const Pair&
pair(const std::string& name)
{
  static const Pair scan_pair = [] {
    Pair p;
    const auto dir = sharedDataDir() / "scan-pair-pcd";
    pcl::io::loadPCDFile((dir / "251371071.pcd").string(), p.source);
    pcl::io::loadPCDFile((dir / "251370668.pcd").string(), p.target);
    return p;
  }();
  static const Pair kitti = [] {
    Pair p;
    const auto dir = sharedDataDir() / "kitti-raw-22" / "pcd";
    pcl::io::loadPCDFile((dir / "0000000001.pcd").string(), p.source);
    pcl::io::loadPCDFile((dir / "0000000000.pcd").string(), p.target);
    return p;
  }();
  return name == "kitti" ? kitti : scan_pair;
}

bool
skipWithoutData(benchmark::State& state, const Pair& p)
{
  if (p.source.empty() || p.target.empty()) {
    state.SkipWithError("shared data missing (../shared/data or PCL_RAST_DATA_DIR)");
    return true;
  }
  return false;
}

/// PointToPlaneTarget::build() (on \a threads, PointToPlaneParams::threads). \a sparse:
/// as the VLP-16 preset's map alignment has it (1 m voxels), on every fourth point of
/// the scan: most voxels' planes are then fitted to their 5x5x5 block (found through
/// blocks of 2x2x2 voxels; session 51).
void
BM_PrepareTarget(benchmark::State& state,
                 const std::string& name,
                 int threads,
                 bool sparse)
{
  const Pair& p = pair(name);
  if (skipWithoutData(state, p))
    return;
  Cloud cloud;
  for (std::size_t i = 0; i < p.target.size(); i += sparse ? 4 : 1)
    cloud.push_back(p.target[i]);
  PointToPlaneParams params;
  params.threads = threads;
  if (sparse)
    params.target_voxel_size_m = 1.0;
  for (auto _ : state) {
    PointToPlaneTarget target;
    target.build(cloud, params);
    benchmark::DoNotOptimize(target.size());
  }
  state.counters["points"] = static_cast<double>(cloud.size());
}

/// prepareSource() (on \a threads, PointToPlaneParams::threads).
void
BM_PrepareSource(benchmark::State& state, const std::string& name, int threads)
{
  const Pair& p = pair(name);
  if (skipWithoutData(state, p))
    return;
  PointToPlaneParams params;
  params.threads = threads;
  for (auto _ : state) {
    const PointToPlaneTarget source = pcl::rast::prepareSource(p.source, params);
    benchmark::DoNotOptimize(source.size());
  }
}

/// Refinement only, against a prepared target and a prepared source.
void
BM_Refine(benchmark::State& state, const std::string& name)
{
  const Pair& p = pair(name);
  if (skipWithoutData(state, p))
    return;
  const PointToPlaneParams params;
  PointToPlaneTarget target;
  target.build(p.target, params);
  const PointToPlaneTarget source = pcl::rast::prepareSource(p.source, params);
  pcl::rast::PointToPlaneResult result;
  for (auto _ : state) {
    result = pcl::rast::refinePointToPlane(source, target, Eigen::Isometry3d::Identity(), params);
    benchmark::DoNotOptimize(result.T_target_source);
  }
  state.counters["success"] = result.success;
  state.counters["iterations"] = result.iterations;
  state.counters["source_points"] = result.num_source_points;
}

/// One odometry frame's dense work: prepare the new scan, refine it on the key-frame.
void
BM_PrepareSourceAndRefine(benchmark::State& state, const std::string& name)
{
  const Pair& p = pair(name);
  if (skipWithoutData(state, p))
    return;
  const PointToPlaneParams params;
  PointToPlaneTarget target;
  target.build(p.target, params);
  for (auto _ : state) {
    const auto result =
        pcl::rast::refinePointToPlane(p.source, target, Eigen::Isometry3d::Identity(), params);
    benchmark::DoNotOptimize(result.T_target_source);
  }
}

BENCHMARK_CAPTURE(BM_PrepareTarget, scan_pair, std::string("scan_pair"), 1, false)
    ->Unit(benchmark::kMillisecond);
BENCHMARK_CAPTURE(BM_PrepareTarget, kitti_raw_22, std::string("kitti"), 1, false)
    ->Unit(benchmark::kMillisecond);
BENCHMARK_CAPTURE(
    BM_PrepareTarget, kitti_raw_22_two_threads, std::string("kitti"), 2, false)
    ->Unit(benchmark::kMillisecond);
BENCHMARK_CAPTURE(
    BM_PrepareTarget, kitti_raw_22_quarter_1m, std::string("kitti"), 1, true)
    ->Unit(benchmark::kMillisecond);
BENCHMARK_CAPTURE(
    BM_PrepareTarget, kitti_raw_22_quarter_1m_two_threads, std::string("kitti"), 2, true)
    ->Unit(benchmark::kMillisecond);
BENCHMARK_CAPTURE(BM_PrepareSource, scan_pair, std::string("scan_pair"), 1)
    ->Unit(benchmark::kMillisecond);
BENCHMARK_CAPTURE(BM_PrepareSource, kitti_raw_22, std::string("kitti"), 1)
    ->Unit(benchmark::kMillisecond);
BENCHMARK_CAPTURE(BM_PrepareSource, kitti_raw_22_two_threads, std::string("kitti"), 2)
    ->Unit(benchmark::kMillisecond);
BENCHMARK_CAPTURE(BM_Refine, scan_pair, std::string("scan_pair"))->Unit(benchmark::kMillisecond);
BENCHMARK_CAPTURE(BM_Refine, kitti_raw_22, std::string("kitti"))->Unit(benchmark::kMillisecond);
BENCHMARK_CAPTURE(BM_PrepareSourceAndRefine, scan_pair, std::string("scan_pair"))
    ->Unit(benchmark::kMillisecond);
BENCHMARK_CAPTURE(BM_PrepareSourceAndRefine, kitti_raw_22, std::string("kitti"))
    ->Unit(benchmark::kMillisecond);

} // namespace

BENCHMARK_MAIN();
