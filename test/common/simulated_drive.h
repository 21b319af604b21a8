#pragma once
/// \file simulated_drive.h
/// \brief The short simulated drive that the tool tests run on.

#include "temp_cleanup.h"

#include <filesystem>
#include <memory>
#include <pcl/simulation/lidar_simulator.h>
#include <string>
#include <unistd.h>

namespace pcl_rast_test {

/// \brief A 40-frame straight HDL-64 drive (world and noise from \a seed) as KITTI .bin scans with poses.txt
/// and times.txt, simulated into a fresh temporary folder named by \a tag and the
/// process (ctest -j runs a binary's test cases in parallel processes), removed when
/// the process exits.
inline std::filesystem::path
simulateStraightDrive(const std::string& tag, std::uint64_t seed = 5)
{
  const std::filesystem::path dir = std::filesystem::temp_directory_path() /
                                    "pcl_rast_test" /
                                    (tag + "_" + std::to_string(::getpid()));
  std::filesystem::remove_all(dir);
  removeAtExit(dir);
  pcl::rast::PathParams path;
  path.type = pcl::rast::PathType::kStraight;
  path.num_frames = 40;
  pcl::rast::LidarSimulatorParams params;
  params.seed = seed;
  params.num_threads = 2;
  pcl::rast::LidarSimulator sim(params, pcl::rast::generatePath(path));
  sim.writeSequence(dir.string(), pcl::rast::ScanFormat::kBin, 0, 39);
  return dir;
}

/// \brief A default simulator (HDL-64, two ray-casting threads) on a generated path of
/// \a frames poses of \a type; \a revisit is PathParams::revisit_fraction.
inline std::unique_ptr<pcl::rast::LidarSimulator>
pathSimulator(pcl::rast::PathType type, int frames, double revisit, std::uint64_t seed)
{
  pcl::rast::PathParams path;
  path.type = type;
  path.num_frames = frames;
  path.revisit_fraction = revisit;
  pcl::rast::LidarSimulatorParams params;
  params.seed = seed;
  params.num_threads = 2;
  return std::make_unique<pcl::rast::LidarSimulator>(params, pcl::rast::generatePath(path));
}

} // namespace pcl_rast_test
