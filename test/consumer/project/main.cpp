// Uses one symbol of each installed module and prints what it checked.
#include <pcl/features/raster_feature_types.h>
#include <pcl/slam/pose_io.h>

#include <cmath>
#include <iostream>

int
main()
{
  const pcl::rast::Pose3d T_cam_lidar = pcl::rast::kittiAxisChangeCamLidar();
  // The LiDAR's x (forward) axis is the camera's z axis.
  const Eigen::Vector3d forward = T_cam_lidar.linear() * Eigen::Vector3d::UnitX();
  if ((forward - Eigen::Vector3d::UnitZ()).norm() > 1e-9) {
    std::cerr << "consumer: unexpected axis change\n";
    return 1;
  }
  pcl::rast::OrbDescriptor a{}, b{};
  b[0] = 0xFF;
  if (pcl::rast::hammingDistance(a, b) != 8) {
    std::cerr << "consumer: unexpected Hamming distance\n";
    return 1;
  }
  std::cout << "consumer: linked the installed pcl_rast package\n";
  return 0;
}
