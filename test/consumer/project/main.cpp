// Uses one symbol of each installed module and prints what it checked.
#include <pcl/features/raster_feature_types.h>
#include <pcl/rast/point_types.h>
#include <pcl/segmentation/sac_ground_removal.h>
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
  // The ground filter through PCL's own base class, on PCL's PointXYZ: a 20 x 20 m
  // floor 1.7 m below the sensor and a 2 m post on it.
  auto cloud = std::make_shared<pcl::PointCloud<pcl::PointXYZ>>();
  for (int i = 0; i < 100; ++i)
    for (int j = 0; j < 100; ++j)
      cloud->push_back(pcl::PointXYZ(0.2f * i - 10.0f, 0.2f * j - 10.0f, -1.7f));
  for (int k = 0; k < 40; ++k)
    cloud->push_back(pcl::PointXYZ(3.0f, 1.0f, -1.675f + 0.05f * k));
  pcl::FilterIndices<pcl::PointXYZ>::Ptr ground(
      new pcl::rast::SACGroundRemoval<pcl::PointXYZ>(true));
  ground->setInputCloud(cloud);
  pcl::PointCloud<pcl::PointXYZ> objects;
  ground->filter(objects);
  if (objects.size() != 36 || ground->getRemovedIndices()->size() != 10004) {
    std::cerr << "consumer: ground filter kept " << objects.size() << " points\n";
    return 1;
  }
  std::cout << "consumer: linked the installed pcl_rast package\n";
  return 0;
}
