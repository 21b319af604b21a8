#pragma once
/// \file simulated_drive.h
/// \brief The simulated drives the tests run on: a short one on disk for the tool tests,
/// simulators on generated paths, and their scans in memory.

#include "temp_cleanup.h"
#include "test_cache.h"

#include <filesystem>
#include <memory>
#include <pcl/rast/rigid_pose.h>
#include <pcl/simulation/lidar_simulator.h>
#include <string>
#include <unistd.h>
#include <vector>

namespace pcl_rast_test {

/// \brief A 40-frame straight HDL-64 drive (world and noise from \a seed) as KITTI .bin
/// scans with poses.txt and times.txt, in a fresh temporary folder named by \a tag and
/// the process (ctest -j runs a binary's test cases in parallel processes), removed when
/// the process exits. Simulated once per build (test_cache.h) and copied: the tests may
/// change the copy.
inline std::filesystem::path
simulateStraightDrive(const std::string& tag, std::uint64_t seed = 5)
{
  const std::filesystem::path dir = std::filesystem::temp_directory_path() /
                                    "pcl_rast_test" /
                                    (tag + "_" + std::to_string(::getpid()));
  removeAtExit(dir);
  copyCachedFolder("straight_drive_40_seed" + std::to_string(seed),
                   dir,
                   [seed](const std::filesystem::path& out) {
                     pcl::rast::PathParams path;
                     path.type = pcl::rast::PathType::kStraight;
                     path.num_frames = 40;
                     pcl::rast::LidarSimulatorParams params;
                     params.seed = seed;
                     params.num_threads = 2;
                     pcl::rast::LidarSimulator sim(params, pcl::rast::generatePath(path));
                     sim.writeSequence(out.string(), pcl::rast::ScanFormat::kBin, 0, 39);
                   });
  return dir;
}

/// \brief A default simulator (HDL-64, two ray-casting threads) on a generated path of
/// \a frames poses of \a type; \a revisit is PathParams::revisit_fraction; raw sweeps
/// (each column cast from the pose at its firing time) with \a raw_sweep.
inline std::unique_ptr<pcl::rast::LidarSimulator>
pathSimulator(pcl::rast::PathType type,
              int frames,
              double revisit,
              std::uint64_t seed,
              bool raw_sweep = false)
{
  pcl::rast::PathParams path;
  path.type = type;
  path.num_frames = frames;
  path.revisit_fraction = revisit;
  pcl::rast::LidarSimulatorParams params;
  params.seed = seed;
  params.num_threads = 2;
  params.raw_sweep = raw_sweep;
  return std::make_unique<pcl::rast::LidarSimulator>(params, pcl::rast::generatePath(path));
}

/// \brief Raw sweeps of a flawed HDL-64 (sensor imperfections) in realistic traffic on
/// rough ground, two ray-casting threads; the world and noise from \a seed.
inline pcl::rast::LidarSimulatorParams
streetParams(std::uint64_t seed)
{
  pcl::rast::LidarSimulatorParams params;
  params.seed = seed;
  params.num_threads = 2;
  params.raw_sweep = true;
  params.imperfections = true;
  params.world.moving_cars = true;
  params.world.traffic.mode = pcl::rast::TrafficMode::kRealistic;
  params.world.rough_ground = true;
  return params;
}

/// \brief Every scan of a simulator in memory, with its point times and ground truth.
struct SimulatedScans
{
  std::vector<pcl::PointCloud<pcl::PointXYZI>::ConstPtr> clouds;
  std::vector<std::vector<float>> times; ///< per point, relative to the frame time [s]
  std::vector<double> stamps;
  pcl::rast::PoseVector gt; ///< in frame 0's LiDAR frame
};

inline SimulatedScans
simulateScans(const pcl::rast::LidarSimulator& sim)
{
  SimulatedScans d;
  const pcl::rast::Pose3d T0_inv = sim.sensorPose(0).inverse();
  for (std::size_t i = 0; i < sim.numFrames(); ++i) {
    auto cloud = std::make_shared<pcl::PointCloud<pcl::PointXYZI>>();
    std::vector<float> times;
    sim.simulateFrame(i, *cloud, &times);
    d.clouds.push_back(cloud);
    d.times.push_back(std::move(times));
    d.stamps.push_back(sim.timestamp(i));
    d.gt.push_back(T0_inv * sim.sensorPose(i));
  }
  return d;
}

} // namespace pcl_rast_test
