/// \file bench_front_end.cpp
/// \brief The odometry front end per stage on the real HDL-64 scans of
/// ../shared/data/kitti-raw-22 (single thread): ground removal, rasterization, ORB
/// extraction, matching + RANSAC + pose, and the whole Odometry::processFrame with the
/// median of every stage (refinement included) reported as counters. BM_RawSweep
/// tracks simulated raw sweeps (not real data) without and with motion compensation.
///
///   build/benchmarks/bench_front_end --benchmark_repetitions=3
///
/// Read the CPU column on a shared machine: wall time includes waiting for the core.

#include "../slam/src/elevation_calibration.h"

#include <algorithm>
#include <benchmark/benchmark.h>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <pcl/features/orb_raster_features.h>
#include <pcl/features/range_raster_image.h>
#include <pcl/io/sequence_reader.h>
#include <pcl/registration/hamming_correspondence_estimation.h>
#include <pcl/registration/rigid_ransac.h>
#include <pcl/segmentation/sac_ground_removal.h>
#include <pcl/simulation/lidar_simulator.h>
#include <pcl/slam/odometry.h>
#include <vector>

namespace {

namespace rast = pcl::rast;
using Cloud = pcl::PointCloud<pcl::PointXYZI>;

/// The scans, their non-ground clouds, rasters and features, computed once.
struct Data
{
  std::vector<Cloud::ConstPtr> scans;
  std::vector<Cloud::ConstPtr> non_ground;
  std::vector<rast::RangeRasterImage<pcl::PointXYZI>> rasters;
  std::vector<rast::RasterFeatureSet> features;
  bool ok = false;
};

const Data&
data()
{
  static Data d = [] {
    Data out;
    const std::string folder = std::string(PCL_RAST_SHARED_DATA_DIR) + "/kitti-raw-22";
    if (!std::filesystem::exists(folder))
      return out;
    const rast::OdometryParams params;
    rast::SequenceReader reader(folder);
    for (std::size_t i = 0; i < reader.size(); ++i) {
      const rast::ScanFrame frame = reader.read(i);
      out.scans.push_back(frame.cloud);
      rast::SACGroundRemoval<pcl::PointXYZI> ground(params.ground);
      ground.setInputCloud(frame.cloud);
      rast::GroundRemovalResult<pcl::PointXYZI> g;
      ground.segment(g);
      out.non_ground.push_back(g.non_ground);
      rast::RangeRasterImage<pcl::PointXYZI> raster(params.raster);
      raster.setInputCloud(g.non_ground);
      raster.compute();
      out.rasters.push_back(raster);
      rast::OrbRasterFeatureEstimator<pcl::PointXYZI> orb;
      orb.setParams(params.orb);
      orb.setInputRaster(raster);
      rast::RasterFeatureSet f;
      orb.compute(f);
      out.features.push_back(std::move(f));
    }
    out.ok = !out.scans.empty();
    return out;
  }();
  return d;
}

bool
skipWithoutData(benchmark::State& state)
{
  if (data().ok)
    return false;
  state.SkipWithError("../shared/data/kitti-raw-22 not found");
  return true;
}

/// A simulated HDL-64 making raw sweeps along the rounded-rectangle loop (seed 17),
/// \a frames long.
rast::LidarSimulator
rawSweepSimulator(int frames)
{
  rast::PathParams path;
  path.type = rast::PathType::kLoop;
  path.num_frames = frames;
  rast::LidarSimulatorParams params;
  params.seed = 17;
  params.num_threads = 2; // building the data only, not measured
  params.raw_sweep = true;
  return rast::LidarSimulator(params, rast::generatePath(path));
}

/// Reading one scan file as the tools do (SequenceReader::read): the real HDL-64 PCDs of
/// kitti-raw-22 (binary float32 x y z intensity, about 120 000 points).
void
BM_ReadScan(benchmark::State& state)
{
  if (skipWithoutData(state))
    return;
  const rast::SequenceReader reader(std::string(PCL_RAST_SHARED_DATA_DIR) +
                                    "/kitti-raw-22");
  std::size_t i = 0;
  for (auto _ : state) {
    const rast::ScanFrame frame = reader.read(i++ % reader.size());
    benchmark::DoNotOptimize(frame.cloud->size());
  }
}
BENCHMARK(BM_ReadScan)->Unit(benchmark::kMillisecond);

/// The same for KITTI .bin scans: the real HDL-64 scans of kitti-raw-78 (float32 x y z
/// reflectance, about 112 000 points).
void
BM_ReadScanKittiBin(benchmark::State& state)
{
  const std::string folder = std::string(PCL_RAST_SHARED_DATA_DIR) + "/kitti-raw-78";
  if (!std::filesystem::exists(folder)) {
    state.SkipWithError("../shared/data/kitti-raw-78 not found");
    return;
  }
  const rast::SequenceReader reader(folder);
  std::size_t i = 0;
  for (auto _ : state) {
    const rast::ScanFrame frame = reader.read(i++ % reader.size());
    benchmark::DoNotOptimize(frame.cloud->size());
  }
}
BENCHMARK(BM_ReadScanKittiBin)->Unit(benchmark::kMillisecond);

/// The same for simulated raw sweeps written as the simulator writes them: binary PCD
/// with a float32 time field, read with the points' times.
void
BM_ReadScanWithTimes(benchmark::State& state)
{
  static const std::string folder = [] {
    const rast::LidarSimulator sim = rawSweepSimulator(10);
    const std::string dir =
        (std::filesystem::temp_directory_path() / "pcl_rast_bench_read_scan").string();
    sim.writeSequence(dir, rast::ScanFormat::kPcd, 0, sim.numFrames() - 1);
    return dir;
  }();
  const rast::SequenceReader reader(folder);
  std::size_t i = 0, with_times = 0;
  for (auto _ : state) {
    const rast::ScanFrame frame = reader.read(i++ % reader.size());
    with_times += frame.point_times_s.empty() ? 0 : 1;
    benchmark::DoNotOptimize(frame.cloud->size());
  }
  if (with_times == 0)
    state.SkipWithError("the simulated sweeps were read without their times");
}
BENCHMARK(BM_ReadScanWithTimes)->Unit(benchmark::kMillisecond);

void
BM_GroundRemoval(benchmark::State& state)
{
  if (skipWithoutData(state))
    return;
  const rast::OdometryParams params;
  rast::SACGroundRemoval<pcl::PointXYZI> ground(params.ground);
  std::size_t i = 0;
  for (auto _ : state) {
    ground.setInputCloud(data().scans[i++ % data().scans.size()]);
    rast::GroundRemovalResult<pcl::PointXYZI> g;
    ground.segment(g);
    benchmark::DoNotOptimize(g.ground_found);
  }
}
BENCHMARK(BM_GroundRemoval)->Unit(benchmark::kMillisecond);

void
BM_Rasterization(benchmark::State& state)
{
  if (skipWithoutData(state))
    return;
  const rast::OdometryParams params;
  rast::RangeRasterImage<pcl::PointXYZI> raster(params.raster);
  std::size_t i = 0;
  for (auto _ : state) {
    raster.setInputCloud(data().non_ground[i++ % data().non_ground.size()]);
    raster.compute();
    benchmark::DoNotOptimize(raster.numOccupiedPixels());
  }
}
BENCHMARK(BM_Rasterization)->Unit(benchmark::kMillisecond);

void
BM_OrbExtraction(benchmark::State& state)
{
  if (skipWithoutData(state))
    return;
  const rast::OdometryParams params;
  rast::OrbRasterFeatureEstimator<pcl::PointXYZI> orb;
  orb.setParams(params.orb);
  std::size_t i = 0;
  for (auto _ : state) {
    orb.setInputRaster(data().rasters[i++ % data().rasters.size()]);
    rast::RasterFeatureSet f;
    benchmark::DoNotOptimize(orb.compute(f).num_features);
  }
}
BENCHMARK(BM_OrbExtraction)->Unit(benchmark::kMillisecond);

void
BM_MatchRansacPose(benchmark::State& state)
{
  if (skipWithoutData(state))
    return;
  const rast::OdometryParams params;
  const auto& f = data().features;
  std::size_t i = 0;
  for (auto _ : state) {
    const std::size_t k = i++ % (f.size() - 1);
    const pcl::Correspondences matches =
        rast::matchHamming(f[k + 1], f[k], params.registration.matching);
    const rast::RigidRansacResult r = rast::estimateRigidRansac(
        f[k + 1].points, f[k].points, matches, params.registration.ransac);
    benchmark::DoNotOptimize(r.success);
  }
}
BENCHMARK(BM_MatchRansacPose)->Unit(benchmark::kMillisecond);

/// A drive to track: scans, optional per-point times (as a PCD time field gives
/// them), timestamps.
struct Drive
{
  std::vector<Cloud::ConstPtr> scans;
  std::vector<std::vector<float>> times; ///< empty: none
  std::vector<double> stamps;
};

const Drive&
realDrive()
{
  static const Drive d = [] {
    Drive out;
    out.scans = data().scans;
    for (std::size_t i = 0; i < out.scans.size(); ++i)
      out.stamps.push_back(0.1 * static_cast<double>(i));
    return out;
  }();
  return d;
}

/// Simulated, not real data: 100 raw HDL-64 sweeps at 10 m/s around the generated
/// loop (its corners turn at up to ~0.5 rad/s; seed 17), each column cast from the
/// pose at its firing time, with the point times the simulator writes as a PCD field.
const Drive&
rawSweepDrive()
{
  static const Drive d = [] {
    const rast::LidarSimulator sim = rawSweepSimulator(100);
    Drive out;
    for (std::size_t i = 0; i < sim.numFrames(); ++i) {
      auto cloud = std::make_shared<Cloud>();
      std::vector<float> times;
      sim.simulateFrame(i, *cloud, &times);
      out.scans.push_back(cloud);
      out.times.push_back(std::move(times));
      out.stamps.push_back(sim.timestamp(i));
    }
    return out;
  }();
  return d;
}

/// The whole front end frame by frame over \a drive (restarted at its end), with its
/// point times when \a with_times; counters give the median of every stage as the
/// odometry measured it.
void
processFrames(benchmark::State& state,
              const rast::OdometryParams& params,
              const Drive& drive,
              bool with_times = false,
              bool lookahead = false)
{
  auto odometry = std::make_unique<rast::Odometry>(params);
  std::vector<rast::OdometryTimings> timings;
  const std::vector<float> no_times;
  std::size_t i = 0, index = 0;
  for (auto _ : state) {
    if (i == drive.scans.size()) {
      state.PauseTiming();
      odometry = std::make_unique<rast::Odometry>(params);
      i = 0;
      state.ResumeTiming();
    }
    const auto& times = with_times ? drive.times[i] : no_times;
    const auto r =
        lookahead && i + 1 < drive.scans.size()
            ? odometry->processFrame(drive.scans[i],
                                     drive.stamps[i],
                                     index,
                                     times,
                                     {drive.scans[i + 1],
                                      drive.stamps[i + 1],
                                      index + 1,
                                      with_times ? drive.times[i + 1] : no_times})
            : odometry->processFrame(drive.scans[i], drive.stamps[i], index, times);
    ++i;
    ++index;
    if (i > 1) // the first frame of a run only builds the map
      timings.push_back(r.timings);
  }
  auto median = [&timings](double rast::OdometryTimings::*member) {
    std::vector<double> v;
    for (const auto& t : timings)
      v.push_back(t.*member);
    if (v.empty())
      return 0.0;
    std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
    return v[v.size() / 2];
  };
  state.counters["ground_ms"] = median(&rast::OdometryTimings::ground_ms);
  state.counters["raster_ms"] = median(&rast::OdometryTimings::raster_ms);
  state.counters["orb_ms"] = median(&rast::OdometryTimings::orb_ms);
  state.counters["match_ms"] = median(&rast::OdometryTimings::match_ms);
  state.counters["refine_ms"] = median(&rast::OdometryTimings::refine_ms);
  state.counters["keyframe_ms"] = median(&rast::OdometryTimings::keyframe_ms);
  state.counters["deskew_ms"] = median(&rast::OdometryTimings::deskew_ms);
  state.counters["elevation_ms"] = median(&rast::OdometryTimings::elevation_ms);
  state.counters["total_ms"] = median(&rast::OdometryTimings::total_ms);
}

/// processFrames on the real scans of kitti-raw-22.
void
processFrames(benchmark::State& state, const rast::OdometryParams& params)
{
  if (skipWithoutData(state))
    return;
  processFrames(state, params, realDrive());
}

void
BM_ProcessFrame(benchmark::State& state)
{
  processFrames(state, rast::OdometryParams());
}
BENCHMARK(BM_ProcessFrame)->Unit(benchmark::kMillisecond)->Iterations(210);

/// BM_ProcessFrame with the look-ahead: the next scan's ground removal, raster and ORB
/// on a second thread (these scans have no times: the whole of it). Compare the wall
/// time ("Time"), not the main thread's CPU time.
void
BM_ProcessFrameLookahead(benchmark::State& state)
{
  if (skipWithoutData(state))
    return;
  processFrames(state, rast::OdometryParams(), realDrive(), false, true);
}
BENCHMARK(BM_ProcessFrameLookahead)->Unit(benchmark::kMillisecond)->Iterations(210);

/// Without the nearest-neighbour re-match of weak features (its cost, side by side).
void
BM_ProcessFrameRatioTestOnly(benchmark::State& state)
{
  rast::OdometryParams params;
  params.loose_rematch = false;
  processFrames(state, params);
}
BENCHMARK(BM_ProcessFrameRatioTestOnly)->Unit(benchmark::kMillisecond)->Iterations(210);

void
BM_ProcessFrameNoRefinement(benchmark::State& state)
{
  rast::OdometryParams params;
  params.registration.refine = false;
  processFrames(state, params);
}
BENCHMARK(BM_ProcessFrameNoRefinement)->Unit(benchmark::kMillisecond)->Iterations(210);

/// With at most range(0) source points in the dense step (-dense-points; 2000 is the
/// default): what more points cost, side by side (doc/odometry.md, "Dense source
/// points").
void
BM_ProcessFrameDensePoints(benchmark::State& state)
{
  rast::OdometryParams params;
  params.dense.max_source_points = static_cast<int>(state.range(0));
  processFrames(state, params);
}
BENCHMARK(BM_ProcessFrameDensePoints)
    ->Arg(1000)
    ->Arg(2000)
    ->Arg(3000)
    ->Unit(benchmark::kMillisecond)
    ->Iterations(210);

/// With nearer points replacing the farthest of a full local-map voxel (-map-nearer
/// 0.5) instead of the first points kept (0, KISS-ICP's rule, the default): the
/// replacement's cost, side by side.
void
BM_ProcessFrameMapNearerPoints(benchmark::State& state)
{
  rast::OdometryParams params;
  params.dense.map_nearer_ratio = 0.5;
  processFrames(state, params);
}
BENCHMARK(BM_ProcessFrameMapNearerPoints)->Unit(benchmark::kMillisecond)->Iterations(210);

/// Without the beams' elevation self-calibration (-no-elevation-calibration): its cost,
/// side by side (its table is in use from the 51st tracked frame on).
void
BM_ProcessFrameNoElevationCalibration(benchmark::State& state)
{
  rast::OdometryParams params;
  params.elevation_calibration.enabled = false;
  processFrames(state, params);
}
BENCHMARK(BM_ProcessFrameNoElevationCalibration)
    ->Unit(benchmark::kMillisecond)
    ->Iterations(210);

/// The correction of one scan by a table that turns every bin (what each frame pays
/// once the calibration has a table).
void
BM_ElevationCorrection(benchmark::State& state)
{
  if (skipWithoutData(state))
    return;
  const Cloud& scan = *data().scans.front();
  rast::odometry_detail::ElevationTable table;
  for (int b = 0; b < table.bins(); ++b)
    table.set(b, (b % 2 ? 1.0 : -1.0) * 0.001);
  for (auto _ : state)
    benchmark::DoNotOptimize(rast::odometry_detail::applyElevationTable(table, scan));
  state.counters["points"] = static_cast<double>(scan.size());
}
BENCHMARK(BM_ElevationCorrection)->Unit(benchmark::kMillisecond);

/// Without the vehicle-dynamics prior (-no-vehicle-prior): its cost, side by side.
void
BM_ProcessFrameNoVehiclePrior(benchmark::State& state)
{
  rast::OdometryParams params;
  rast::disableVehiclePrior(params);
  processFrames(state, params);
}
BENCHMARK(BM_ProcessFrameNoVehiclePrior)->Unit(benchmark::kMillisecond)->Iterations(210);

/// With the moving-object tests (-visibility-margin 1, off by default): their cost,
/// side by side.
void
BM_ProcessFrameVisibility(benchmark::State& state)
{
  rast::OdometryParams params;
  params.visibility_margin_m = 1.0;
  processFrames(state, params);
}
BENCHMARK(BM_ProcessFrameVisibility)->Unit(benchmark::kMillisecond)->Iterations(210);

/// With motion compensation from the azimuth (-deskew on) on every frame: its cost side
/// by side with BM_ProcessFrame (deskew_ms: both passes, the second one's dense
/// refinement included).
void
BM_ProcessFrameDeskewAzimuth(benchmark::State& state)
{
  rast::OdometryParams params;
  params.deskew.mode = rast::DeskewMode::kOn;
  processFrames(state, params);
}
BENCHMARK(BM_ProcessFrameDeskewAzimuth)->Unit(benchmark::kMillisecond)->Iterations(210);

/// ... with the look-ahead: a compensated scan's raster and ORB wait for its own call,
/// only the ground removal and the dense source's choice run ahead.
void
BM_ProcessFrameDeskewAzimuthLookahead(benchmark::State& state)
{
  if (skipWithoutData(state))
    return;
  rast::OdometryParams params;
  params.deskew.mode = rast::DeskewMode::kOn;
  processFrames(state, params, realDrive(), false, true);
}
BENCHMARK(BM_ProcessFrameDeskewAzimuthLookahead)
    ->Unit(benchmark::kMillisecond)
    ->Iterations(210);

/// The same without the second pass (compensation with the prior's motion only): the
/// second pass's cost, side by side.
void
BM_ProcessFrameDeskewFirstPassOnly(benchmark::State& state)
{
  rast::OdometryParams params;
  params.deskew.mode = rast::DeskewMode::kOn;
  params.deskew.second_pass_translation_m = 1e9;
  params.deskew.second_pass_rotation_deg = 1e9;
  processFrames(state, params);
}
BENCHMARK(BM_ProcessFrameDeskewFirstPassOnly)
    ->Unit(benchmark::kMillisecond)
    ->Iterations(210);

/// The first pass alone on one real HDL-64 scan (~117k points): times from the azimuth
/// and the compensation (eq. 1 of deskew.h) at 0.8 m and 1 deg a frame.
void
BM_DeskewScan(benchmark::State& state)
{
  if (skipWithoutData(state))
    return;
  const Cloud& scan = *data().scans.front();
  rast::Twist xi;
  xi << 8.0, 0.0, 0.0, 0.0, 0.0, 0.17; // m/s, rad/s
  for (auto _ : state) {
    const std::vector<float> times = rast::azimuthTimes(scan, 0.1);
    benchmark::DoNotOptimize(rast::deskewCloud(scan, times, xi));
  }
  state.counters["points"] = static_cast<double>(scan.size());
}
BENCHMARK(BM_DeskewScan)->Unit(benchmark::kMillisecond);

/// Its two parts: the per-point times from the azimuth ...
void
BM_AzimuthTimes(benchmark::State& state)
{
  if (skipWithoutData(state))
    return;
  const Cloud& scan = *data().scans.front();
  for (auto _ : state)
    benchmark::DoNotOptimize(rast::azimuthTimes(scan, 0.1));
}
BENCHMARK(BM_AzimuthTimes)->Unit(benchmark::kMillisecond);

/// ... and the compensation itself.
void
BM_DeskewCloud(benchmark::State& state)
{
  if (skipWithoutData(state))
    return;
  const Cloud& scan = *data().scans.front();
  const std::vector<float> times = rast::azimuthTimes(scan, 0.1);
  rast::Twist xi;
  xi << 8.0, 0.0, 0.0, 0.0, 0.0, 0.17;
  for (auto _ : state)
    benchmark::DoNotOptimize(rast::deskewCloud(scan, times, xi));
}
BENCHMARK(BM_DeskewCloud)->Unit(benchmark::kMillisecond);

/// What compensation costs where it is needed (simulated raw sweeps, rawSweepDrive):
/// the same scans tracked uncompensated (-deskew off), with their time field (-deskew
/// auto on a PCD with times) and with times from the azimuth (-deskew on, .bin).
/// Unlike KITTI's scans, compensated already, these need it. The frame difference is
/// still not the compensation alone: the tracking differs with and without it (the
/// loop's corners make the dense step run from the prior too on some frames);
/// deskew_ms is the compensation's own time.
void
BM_RawSweep(benchmark::State& state)
{
  rast::OdometryParams params;
  const int mode = static_cast<int>(state.range(0));
  params.deskew.mode = mode == 2   ? rast::DeskewMode::kOn
                       : mode == 1 ? rast::DeskewMode::kAuto
                                   : rast::DeskewMode::kOff;
  processFrames(state, params, rawSweepDrive(), mode == 1);
  state.SetLabel(mode == 2   ? "deskew on (azimuth)"
                 : mode == 1 ? "deskew auto (time field)"
                             : "deskew off");
}
BENCHMARK(BM_RawSweep)
    ->Arg(0)
    ->Arg(1)
    ->Arg(2)
    ->Unit(benchmark::kMillisecond)
    ->Iterations(200);

} // namespace

BENCHMARK_MAIN();
