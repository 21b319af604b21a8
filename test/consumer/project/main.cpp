// Calls every installed library target through real work and checks the results.
// Built without OpenCV's include path (run_consumer_test.sh checks the flags).
#include <pcl/common/transforms.h>
#include <pcl/evaluation/trajectory_evaluation.h>
#include <pcl/features/orb_raster_features.h>
#include <pcl/io/pose_io.h>
#include <pcl/rast/point_types.h>
#include <pcl/rast/rigid_pose.h>
#include <pcl/registration/raster_orb_registration.h>
#include <pcl/segmentation/sac_ground_removal.h>
#include <pcl/simulation/lidar_simulator.h>
#include <pcl/slam/odometry.h>
#include <pcl/visualization/map_render.h>

#include <cmath>
#include <iostream>
#include <random>

namespace {

/// A floor 1.7 m below the sensor and boxes of random size and height on it.
pcl::PointCloud<pcl::PointXYZI>::Ptr
makeScene()
{
  auto cloud = std::make_shared<pcl::PointCloud<pcl::PointXYZI>>();
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> position(-30.0f, 30.0f), size(0.8f, 3.0f),
      height(0.5f, 4.0f);
  pcl::PointXYZI p;
  p.intensity = 0.5f;
  for (float x = -40.0f; x <= 40.0f; x += 0.25f)
    for (float y = -40.0f; y <= 40.0f; y += 0.25f) {
      p.x = x;
      p.y = y;
      p.z = -1.7f;
      cloud->push_back(p);
    }
  for (int box = 0; box < 70; ++box) {
    const float cx = position(rng), cy = position(rng), sx = size(rng), sy = size(rng);
    const float top = -1.7f + height(rng);
    for (float dx = 0.0f; dx <= sx; dx += 0.05f)
      for (float dy = 0.0f; dy <= sy; dy += 0.05f) {
        p.x = cx + dx;
        p.y = cy + dy;
        p.z = top + 0.1f * dy;
        cloud->push_back(p);
      }
  }
  return cloud;
}

} // namespace

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

  // features: ORB through PCL's keypoint interface.
  const auto scene = makeScene();
  pcl::Keypoint<pcl::PointXYZI, pcl::rast::ORBSignature256>::Ptr orb(
      new pcl::rast::OrbRasterFeatureEstimator<pcl::PointXYZI>);
  orb->setInputCloud(scene);
  pcl::PointCloud<pcl::rast::ORBSignature256> features;
  orb->compute(features);
  if (features.size() < 100) {
    std::cerr << "consumer: only " << features.size() << " ORB features\n";
    return 1;
  }

  // registration: the scene moved by 1 m and 10 deg, recovered through pcl::Registration.
  Eigen::Affine3f motion = Eigen::Affine3f::Identity();
  motion.translate(Eigen::Vector3f(1.0f, 0.3f, 0.0f));
  motion.rotate(Eigen::AngleAxisf(10.0f * float(M_PI) / 180.0f, Eigen::Vector3f::UnitZ()));
  auto moved = std::make_shared<pcl::PointCloud<pcl::PointXYZI>>();
  pcl::transformPointCloud(*scene, *moved, motion.inverse());
  pcl::Registration<pcl::PointXYZI, pcl::PointXYZI>::Ptr reg(
      new pcl::rast::RasterORBRegistration<pcl::PointXYZI, pcl::PointXYZI>);
  reg->setInputSource(moved);
  reg->setInputTarget(scene);
  pcl::PointCloud<pcl::PointXYZI> aligned;
  reg->align(aligned);
  const Eigen::Matrix4f error = motion.matrix().inverse() * reg->getFinalTransformation();
  if (!reg->hasConverged() || error.topRightCorner<3, 1>().norm() > 0.05f) {
    std::cerr << "consumer: registration off by " << error.topRightCorner<3, 1>().norm()
              << " m\n";
    return 1;
  }

  // slam: two frames of odometry; simulation: a generated path; evaluation: its ATE
  // against itself; common: pose helpers.
  pcl::rast::Odometry odometry;
  odometry.processFrame(scene, 0.0, 0);
  const auto second = odometry.processFrame(moved, 0.1, 1);
  if ((second.T_world_lidar.translation() - Eigen::Vector3d(1.0, 0.3, 0.0)).norm() > 0.05) {
    std::cerr << "consumer: odometry at " << second.T_world_lidar.translation().transpose()
              << "\n";
    return 1;
  }
  pcl::rast::PathParams path_params;
  path_params.num_frames = 50;
  const pcl::rast::PoseVector path = pcl::rast::generatePath(path_params);
  const pcl::rast::EvaluationResult self = pcl::rast::evaluateTrajectory(path, path);
  if (path.size() != 50 || self.ate_rmse_m > 1e-9 ||
      pcl::rast::maxRotationError(path) > 1e-6) {
    std::cerr << "consumer: path of " << path.size() << " poses, ATE " << self.ate_rmse_m
              << "\n";
    return 1;
  }

  // visualization: the scene and the path, drawn top-down into a PNG.
  pcl::rast::MapRenderInput picture;
  picture.map = scene.get();
  for (const auto& T : path)
    picture.trajectory.push_back(T.translation());
  picture.title = "consumer";
  pcl::rast::MapRenderParams look;
  look.width_px = 400;
  look.height_px = 300;
  const pcl::rast::MapRenderResult drawn =
      pcl::rast::renderMapTopDown(picture, look, "consumer_render.png");
  if (!drawn.success) {
    std::cerr << "consumer: render failed: " << drawn.message << "\n";
    return 1;
  }
  std::cout << "consumer: linked the installed pcl_rast package (render: " << drawn.backend
            << ")\n";
  return 0;
}
