// The headers most test programs include, parsed once per build and reused by every
// test program (test/CMakeLists.txt, PCL_RAST_TEST_PCH): parsing them took a third of a
// test file's compile time. The project headers here make every test program rebuild
// when one of them changes; a test still includes what it uses itself, so it also
// compiles with PCL_RAST_TEST_PCH=OFF.
#pragma once

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <random>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <nlohmann/json.hpp>
#include <pcl/io/pcd_io.h>
#include <pcl/io/pose_io.h>
#include <pcl/io/sequence_reader.h>
#include <pcl/point_cloud.h>
#include <pcl/point_types.h>
#include <pcl/simulation/lidar_simulator.h>
#include <pcl/slam/odometry.h>
#include <pcl/slam/rast_slam.h>
