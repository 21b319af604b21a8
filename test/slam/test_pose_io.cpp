// KITTI / TUM pose files: round trips, detection, malformed input, frame changes.
#include "test_data.h"

#include <cmath>
#include <filesystem>
#include <fstream>
#include <gtest/gtest.h>
#include <pcl/io/pose_io.h>
#include <random>
#include <string>

// This file's names stay its own: a test program compiles several test files as
// one translation unit (test/CMakeLists.txt).
namespace test_pose_io {

namespace {

namespace fs = std::filesystem;
using namespace pcl::rast;

/// Random poses with a fixed seed.
PoseVector
randomPoses(std::size_t n, unsigned seed)
{
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  PoseVector poses;
  for (std::size_t i = 0; i < n; ++i) {
    Pose3d T = Pose3d::Identity();
    T.linear() = Eigen::Quaterniond(u(rng), u(rng), u(rng), u(rng))
                     .normalized()
                     .toRotationMatrix();
    T.translation() = 100.0 * Eigen::Vector3d(u(rng), u(rng), u(rng));
    poses.push_back(T);
  }
  return poses;
}

void
writeText(const fs::path& path, const std::string& text)
{
  std::ofstream(path) << text;
}

/// The message of the runtime_error thrown by \a f, or "" when none is thrown.
template <typename F>
std::string
errorOf(F f)
{
  try {
    f();
  } catch (const std::runtime_error& e) {
    return e.what();
  }
  return "";
}

void
expectPosesNear(const PoseVector& a, const PoseVector& b, double tol)
{
  ASSERT_EQ(a.size(), b.size());
  for (std::size_t i = 0; i < a.size(); ++i)
    EXPECT_TRUE(a[i].matrix().isApprox(b[i].matrix(), tol)) << "pose " << i;
}

const std::string kIdentityKitti = "1 0 0 0 0 1 0 0 0 0 1 0\n";

TEST(PoseIo, KittiRoundTrip)
{
  const auto dir = pcl_rast_test::makeTempDir("pose_io");
  const auto poses = randomPoses(50, 1);
  const auto path = (dir / "poses.txt").string();
  writeKittiPoses(path, poses);
  const Trajectory read = readTrajectory(path);
  EXPECT_EQ(read.format, PoseFormat::kKitti);
  expectPosesNear(read.poses, poses, 1e-12);
  ASSERT_EQ(read.timestamps_s.size(), poses.size());
  EXPECT_EQ(read.timestamps_s[7], 7.0);
}

TEST(PoseIo, TumRoundTrip)
{
  const auto dir = pcl_rast_test::makeTempDir("pose_io");
  const auto poses = randomPoses(50, 2);
  std::vector<double> stamps;
  for (std::size_t i = 0; i < poses.size(); ++i)
    stamps.push_back(1317384506.123456 + 0.1 * i);
  const auto path = (dir / "poses.tum").string();
  writeTumPoses(path, poses, stamps);
  const Trajectory read = readTrajectory(path);
  EXPECT_EQ(read.format, PoseFormat::kTum);
  expectPosesNear(read.poses, poses, 1e-12);
  ASSERT_EQ(read.timestamps_s.size(), stamps.size());
  for (std::size_t i = 0; i < stamps.size(); ++i)
    EXPECT_DOUBLE_EQ(read.timestamps_s[i], stamps[i]);

  // Without timestamps the frame index is used.
  writeTumPoses(path, poses);
  EXPECT_EQ(readTrajectory(path).timestamps_s[3], 3.0);
  EXPECT_THROW(writeTumPoses(path, poses, {1.0, 2.0}), std::invalid_argument);
}

TEST(PoseIo, DetectsFormatSkippingCommentsAndBlankLines)
{
  const auto dir = pcl_rast_test::makeTempDir("pose_io");
  writeText(dir / "k.txt", "\n# comment\n" + kIdentityKitti);
  writeText(dir / "t.txt", "# timestamp tx ty tz qx qy qz qw\n\n0.5 1 2 3 0 0 0 1\n");
  writeText(dir / "bad.txt", "1 2 3\n");
  writeText(dir / "empty.txt", "# nothing\n");
  EXPECT_EQ(detectPoseFormat((dir / "k.txt").string()), PoseFormat::kKitti);
  EXPECT_EQ(detectPoseFormat((dir / "t.txt").string()), PoseFormat::kTum);
  const auto t = readTrajectory((dir / "t.txt").string());
  ASSERT_EQ(t.poses.size(), 1u);
  EXPECT_DOUBLE_EQ(t.timestamps_s[0], 0.5);
  EXPECT_TRUE(t.poses[0].translation().isApprox(Eigen::Vector3d(1, 2, 3)));

  const auto bad = (dir / "bad.txt").string();
  const std::string why = errorOf([&] { detectPoseFormat(bad); });
  EXPECT_NE(why.find(bad + ":1"), std::string::npos) << why;
  EXPECT_NE(errorOf([&] { detectPoseFormat((dir / "empty.txt").string()); }), "");
  EXPECT_NE(errorOf([&] {
              readTrajectory((dir / "missing.txt").string());
            }).find("missing.txt"),
            std::string::npos);
}

TEST(PoseIo, MalformedLinesNameFileAndLine)
{
  const auto dir = pcl_rast_test::makeTempDir("pose_io");
  struct Case
  {
    std::string third_line, expected_words;
  };
  const std::vector<Case> cases = {
      {"1 0 0 0 0 1 0 0 0 0 1\n", "11 fields"},
      {"1 0 0 0 0 1 0 x 0 0 1 0\n", "'x' is not a number"},
      {"1 0 0 0 0 1 0 0 0 0 1 nan\n", "not a finite number"},
      {"1 0 0 0 0 1 0 0 0 0 1 1e999\n", "not a finite number"},
      {"1 0 0 0 0 1 0 0 0 0 1 2abc\n", "'2abc' is not a number"},
      {"2 0 0 0 0 1 0 0 0 0 1 0\n", "not a rotation"},    // det 2
      {"-1 0 0 0 0 1 0 0 0 0 1 0\n", "not a rotation"},   // reflection, det -1
      {"1 0.01 0 0 0 1 0 0 0 0 1 0\n", "not a rotation"}, // not orthonormal
  };
  for (const auto& c : cases) {
    const auto path = (dir / "poses.txt").string();
    writeText(path, kIdentityKitti + "# comment\n" + c.third_line);
    const std::string why = errorOf([&] { readTrajectory(path); });
    EXPECT_NE(why.find(path + ":3:"), std::string::npos) << c.third_line << " -> " << why;
    EXPECT_NE(why.find(c.expected_words), std::string::npos)
        << c.third_line << " -> " << why;
  }
  // TUM: a non-unit quaternion and a wrong field count.
  const auto tum = (dir / "poses.tum").string();
  writeText(tum, "0 0 0 0 0 0 0 1\n1 0 0 0 0 0 0 2\n");
  EXPECT_NE(errorOf([&] { readTrajectory(tum); }).find(tum + ":2: quaternion"),
            std::string::npos);
  writeText(tum, "0 0 0 0 0 0 0 1\n1 0 0 0 0 0 1\n");
  EXPECT_NE(errorOf([&] { readTrajectory(tum); }).find(tum + ":2: has 7 fields"),
            std::string::npos);
  // A KITTI file read explicitly as TUM fails on its first line.
  writeText(tum, kIdentityKitti);
  EXPECT_NE(errorOf([&] { readTrajectory(tum, PoseFormat::kTum); }).find(tum + ":1:"),
            std::string::npos);
}

TEST(PoseIo, ReorthonormalizesSmallNoise)
{
  const auto dir = pcl_rast_test::makeTempDir("pose_io");
  const auto path = (dir / "poses.txt").string();
  // A rotation written with 4 decimals: off by ~1e-4, accepted and cleaned.
  writeText(path, "0.7071 -0.7071 0 1 0.7071 0.7071 0 2 0 0 1 3\n");
  const auto t = readTrajectory(path);
  ASSERT_EQ(t.poses.size(), 1u);
  const Eigen::Matrix3d R = t.poses[0].linear();
  EXPECT_NEAR((R.transpose() * R - Eigen::Matrix3d::Identity()).norm(), 0.0, 1e-12);
  EXPECT_NEAR(R.determinant(), 1.0, 1e-12);
  EXPECT_NEAR(std::atan2(R(1, 0), R(0, 0)), M_PI / 4, 1e-9);
  EXPECT_TRUE(t.poses[0].translation().isApprox(Eigen::Vector3d(1, 2, 3)));
}

TEST(PoseIo, AtomicWriteLeavesNoTemporary)
{
  const auto dir = pcl_rast_test::makeTempDir("pose_io");
  const auto path = dir / "poses.txt";
  writeText(path, "old content\n");
  writeKittiPoses(path.string(), randomPoses(3, 3));
  EXPECT_EQ(readTrajectory(path.string()).poses.size(), 3u);
  std::size_t files = 0;
  for (const auto& entry : fs::directory_iterator(dir)) {
    (void)entry;
    ++files;
  }
  EXPECT_EQ(files, 1u);

  // A file of the user's named like a temporary one is neither used nor removed.
  writeText(dir / "x.json.tmp", "mine\n");
  writeFileAtomically((dir / "x.json").string(), "{}\n");
  files = 0;
  for (const auto& entry : fs::directory_iterator(dir)) {
    EXPECT_TRUE(entry.path().filename() == "poses.txt" ||
                entry.path().filename() == "x.json" ||
                entry.path().filename() == "x.json.tmp")
        << entry.path();
    ++files;
  }
  EXPECT_EQ(files, 3u);
  EXPECT_EQ(pcl_rast_test::readFile(dir / "x.json.tmp"), "mine\n");
  // A folder that does not exist: error naming the path, nothing left behind.
  const auto bad = (dir / "no_such_dir" / "poses.txt").string();
  EXPECT_NE(errorOf([&] { writeKittiPoses(bad, randomPoses(1, 4)); }).find("no_such_dir"),
            std::string::npos);
  EXPECT_FALSE(fs::exists(dir / "no_such_dir"));
}

TEST(PoseIo, KittiAxisChange)
{
  const Pose3d T_cam_lidar = kittiAxisChangeCamLidar();
  EXPECT_NEAR(T_cam_lidar.linear().determinant(), 1.0, 1e-15);
  EXPECT_TRUE(T_cam_lidar.translation().isZero());
  // LiDAR forward (x) is camera forward (z); LiDAR left (y) is camera -x (x right);
  // LiDAR up (z) is camera -y (y down).
  EXPECT_TRUE(
      (T_cam_lidar * Eigen::Vector3d(1, 0, 0)).isApprox(Eigen::Vector3d(0, 0, 1)));
  EXPECT_TRUE(
      (T_cam_lidar * Eigen::Vector3d(0, 1, 0)).isApprox(Eigen::Vector3d(-1, 0, 0)));
  EXPECT_TRUE(
      (T_cam_lidar * Eigen::Vector3d(0, 0, 1)).isApprox(Eigen::Vector3d(0, -1, 0)));
  const Eigen::Vector3d p_lidar(2.0, 3.0, 5.0);
  const Eigen::Vector3d p_cam = T_cam_lidar * p_lidar;
  EXPECT_DOUBLE_EQ(p_cam.x(), -p_lidar.y());
  EXPECT_DOUBLE_EQ(p_cam.y(), -p_lidar.z());
  EXPECT_DOUBLE_EQ(p_cam.z(), p_lidar.x());
}

TEST(PoseIo, CameraToLidarPoses)
{
  // A camera moving 10 m forward (camera z) then turning left; in the LiDAR frame
  // that is 10 m along x and a positive yaw about z.
  PoseVector T_cam0_cami(3, Pose3d::Identity());
  T_cam0_cami[0].translation() << 0.3, -0.2, 0.1; // first pose is not the identity
  T_cam0_cami[1] = T_cam0_cami[0] * Eigen::Translation3d(0, 0, 10);
  // A left turn of a camera (y down) is a negative rotation about y.
  T_cam0_cami[2] = T_cam0_cami[1] * Eigen::AngleAxisd(-0.5, Eigen::Vector3d::UnitY());
  const auto T_lidar0 = cameraToLidarPoses(T_cam0_cami, kittiAxisChangeCamLidar());
  ASSERT_EQ(T_lidar0.size(), 3u);
  EXPECT_TRUE(T_lidar0[0].matrix().isIdentity(1e-12));
  EXPECT_TRUE(T_lidar0[1].translation().isApprox(Eigen::Vector3d(10, 0, 0), 1e-12));
  const Eigen::Matrix3d R2 = T_lidar0[2].linear();
  EXPECT_NEAR(std::atan2(R2(1, 0), R2(0, 0)), 0.5, 1e-12);
  EXPECT_TRUE(cameraToLidarPoses({}, kittiAxisChangeCamLidar()).empty());

  // With a general extrinsic the first pose is still the identity and relative
  // motions are conjugated: T_l_a^-1 T_l_b = Tr^-1 (T_c_a^-1 T_c_b) Tr.
  const Pose3d Tr = randomPoses(1, 5)[0];
  const auto cams = randomPoses(4, 6);
  const auto lidars = cameraToLidarPoses(cams, Tr);
  EXPECT_TRUE(lidars[0].matrix().isIdentity(1e-12));
  const Pose3d expected = Tr.inverse() * (cams[1].inverse() * cams[3]) * Tr;
  EXPECT_TRUE(
      (lidars[1].inverse() * lidars[3]).matrix().isApprox(expected.matrix(), 1e-9));
}

TEST(PoseIo, ReadKittiCalibTr)
{
  const auto dir = pcl_rast_test::makeTempDir("pose_io");
  const std::string tr =
      "-1.857739385241e-03 -9.999659513510e-01 -8.039975204516e-03 -4.784029760483e-03 "
      "-6.481465826011e-03 8.051860151134e-03 -9.999466081774e-01 -7.337429464231e-02 "
      "9.999773098287e-01 -1.805528627661e-03 -6.496203536139e-03 -3.339968064433e-01";
  const std::string p = "7.188560000000e+02 0 6.071928000000e+02 0 0 7.188560000000e+02 "
                        "1.852157000000e+02 0 0 0 1 0";
  writeText(dir / "calib.txt", "P0: " + p + "\nP1: " + p + "\nTr: " + tr + "\n");
  const Pose3d T = readKittiCalibTr((dir / "calib.txt").string());
  EXPECT_NEAR(T.linear()(0, 1), -9.999659513510e-01, 1e-6);
  EXPECT_NEAR(T.translation().z(), -3.339968064433e-01, 1e-12);
  // Close to the nominal axis change.
  EXPECT_LT((T.linear() - kittiAxisChangeCamLidar().linear()).cwiseAbs().maxCoeff(),
            0.02);

  writeText(dir / "raw.txt", "R: 1 0 0 0 1 0 0 0 1\nTr_velo_to_cam: " + tr + "\n");
  EXPECT_TRUE(readKittiCalibTr((dir / "raw.txt").string()).isApprox(T, 1e-12));

  writeText(dir / "none.txt", "P0: " + p + "\n");
  EXPECT_NE(
      errorOf([&] { readKittiCalibTr((dir / "none.txt").string()); }).find("none.txt"),
      std::string::npos);
  writeText(dir / "short.txt", "P0: " + p + "\nTr: 1 0 0\n");
  EXPECT_NE(errorOf([&] {
              readKittiCalibTr((dir / "short.txt").string());
            }).find("short.txt:2:"),
            std::string::npos);
  writeText(dir / "badrot.txt", "Tr: 2 0 0 0 0 1 0 0 0 0 1 0\n");
  EXPECT_NE(errorOf([&] {
              readKittiCalibTr((dir / "badrot.txt").string());
            }).find("not a rotation"),
            std::string::npos);
}

TEST(PoseIo, RealKittiGroundTruth)
{
  PCL_RAST_REQUIRE_SHARED_DATA(data);
  const auto path = data / "kitti-gt-poses" / "00.txt";
  ASSERT_TRUE(fs::exists(path)) << path;
  EXPECT_EQ(detectPoseFormat(path.string()), PoseFormat::kKitti);
  const Trajectory gt = readTrajectory(path.string());
  ASSERT_EQ(gt.poses.size(), 4541u);
  EXPECT_TRUE(gt.poses[0].matrix().isIdentity(1e-6));

  // Round trip through both formats.
  const auto dir = pcl_rast_test::makeTempDir("pose_io");
  writeTumPoses((dir / "00.tum").string(), gt.poses);
  expectPosesNear(readTrajectory((dir / "00.tum").string()).poses, gt.poses, 1e-12);

  // In the LiDAR frame the car drives forward (x) and stays near the ground plane.
  const auto lidar = cameraToLidarPoses(gt.poses, kittiAxisChangeCamLidar());
  EXPECT_TRUE(lidar[0].matrix().isIdentity(1e-12));
  EXPECT_GT(lidar[10].translation().x(), 5.0);
  EXPECT_LT(std::abs(lidar[10].translation().z()), 0.5);
}

} // namespace

} // namespace test_pose_io
