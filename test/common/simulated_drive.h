#pragma once
/// \file simulated_drive.h
/// \brief The short simulated drive that the tool tests run on.

#include "temp_cleanup.h"

#include <filesystem>
#include <pcl/simulation/lidar_simulator.h>
#include <string>
#include <unistd.h>

namespace pcl_rast_test {

/// \brief A 40-frame straight HDL-64 drive (seed 5) as KITTI .bin scans with poses.txt
/// and times.txt, simulated into a fresh temporary folder named by \a tag and the
/// process (ctest -j runs a binary's test cases in parallel processes), removed when
/// the process exits.
inline std::filesystem::path
simulateStraightDrive(const std::string& tag)
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
  params.seed = 5;
  params.num_threads = 2;
  pcl::rast::LidarSimulator sim(params, pcl::rast::generatePath(path));
  sim.writeSequence(dir.string(), pcl::rast::ScanFormat::kBin, 0, 39);
  return dir;
}

} // namespace pcl_rast_test
