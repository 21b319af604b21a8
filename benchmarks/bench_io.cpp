/// \file bench_io.cpp
/// \brief Reading scans as the tools do (SequenceReader::read: the file, its parsing and
/// the point times), one scan per iteration, cycling through the real scans of
/// ../shared/data: kitti-raw-22 (binary PCD, about 118k points, 1.9 MB a file) and
/// kitti-raw-78 (KITTI .bin, about 112k points). The files stay in the page cache, as
/// for a drive read twice; the cost is the copy out of it, the parsing and the cloud's
/// new memory. BM_ReadScan/env reads the folder named by PCL_RAST_BENCH_SCANS (any
/// folder the tools take, a simulated one for instance) and is skipped without it.
///
///   build/benchmarks/bench_io --benchmark_repetitions=5 --benchmark_report_aggregates_only

#include <benchmark/benchmark.h>
#include <cstdlib>
#include <filesystem>
#include <pcl/io/sequence_reader.h>
#include <string>

namespace {

void
BM_ReadScan(benchmark::State& state, const char* folder_name)
{
  const char* env = std::getenv("PCL_RAST_BENCH_SCANS");
  if (!folder_name && !env) {
    state.SkipWithError("PCL_RAST_BENCH_SCANS is not set");
    return;
  }
  const std::string folder =
      folder_name ? std::string(PCL_RAST_SHARED_DATA_DIR) + "/" + folder_name : env;
  if (!std::filesystem::exists(folder)) {
    state.SkipWithError(("no " + folder).c_str());
    return;
  }
  const pcl::rast::SequenceReader reader(folder);
  std::size_t i = 0, points = 0;
  for (auto _ : state) {
    const pcl::rast::ScanFrame frame = reader.read(i);
    benchmark::DoNotOptimize(frame.cloud->points.data());
    points += frame.cloud->size();
    i = (i + 1) % reader.size();
  }
  state.counters["points"] =
      benchmark::Counter(static_cast<double>(points), benchmark::Counter::kAvgIterations);
}

BENCHMARK_CAPTURE(BM_ReadScan, kitti_raw_22_pcd, "kitti-raw-22")
    ->Unit(benchmark::kMillisecond);
BENCHMARK_CAPTURE(BM_ReadScan, kitti_raw_78_bin, "kitti-raw-78")
    ->Unit(benchmark::kMillisecond);
BENCHMARK_CAPTURE(BM_ReadScan, env, nullptr)->Unit(benchmark::kMillisecond);

} // namespace

BENCHMARK_MAIN();
