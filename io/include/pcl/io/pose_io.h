#pragma once
/// \file pose_io.h
/// \brief Reading and writing trajectories: KITTI (3x4 row-major) and TUM
/// (`t x y z qx qy qz qw`) pose files, and the KITTI camera-0 <-> LiDAR frame change.
/// \ingroup io

#include <pcl/rast/atomic_file.h>
#include <pcl/rast/rigid_pose.h>
#include <pcl/rast/text_lines.h>

#include <cstdio>
#include <functional>
#include <string>
#include <vector>

namespace pcl {
namespace rast {

/// \brief Pose file formats.
enum class PoseFormat
{
  kKitti, ///< 12 numbers per line: the top 3x4 block of T, row-major
  kTum    ///< `timestamp tx ty tz qx qy qz qw` per line; `#` comments allowed
};

/// \brief A trajectory read from a file: poses and their timestamps.
/// For KITTI files the timestamps are the frame indices (0, 1, 2, ...).
struct Trajectory
{
  PoseVector poses;
  std::vector<double> timestamps_s;
  PoseFormat format = PoseFormat::kKitti;
};

/// \brief Guess the format of a pose file from its first non-comment line
/// (12 numbers: KITTI; 8 numbers: TUM).
/// \throws std::runtime_error naming the file when it cannot be read or matches neither.
PoseFormat
detectPoseFormat(const std::string& path);

/// \brief Read a KITTI or TUM pose file; with \a format unset it is auto-detected.
/// \throws std::runtime_error naming the file and the 1-based line of a malformed
/// line (wrong number of fields, non-numeric or non-finite value, non-rotation block).
Trajectory
readTrajectory(const std::string& path);
Trajectory
readTrajectory(const std::string& path, PoseFormat format);

/// \brief Write poses in KITTI format. Atomic: writes a temporary file beside \a path,
/// then renames it.
/// \throws std::runtime_error naming the file when it cannot be written.
void
writeKittiPoses(const std::string& path, const PoseVector& poses);

/// \brief Write poses in TUM format with the given timestamps (seconds); when
/// \a timestamps_s is empty the frame index is used. Atomic like writeKittiPoses.
/// \throws std::invalid_argument when the sizes differ, std::runtime_error on I/O failure.
void
writeTumPoses(const std::string& path,
              const PoseVector& poses,
              const std::vector<double>& timestamps_s = {});

/// \brief The fixed axis change between KITTI's camera frame (x right, y down,
/// z forward) and the LiDAR frame (x forward, y left, z up): T_cam_lidar with zero
/// translation, i.e. x_cam = -y_lidar, y_cam = -z_lidar, z_cam = x_lidar.
Pose3d
kittiAxisChangeCamLidar();

/// \brief Read T_cam_lidar from the `Tr:` line of a KITTI `calib.txt`.
/// \throws std::runtime_error naming the file when the line is missing or malformed.
Pose3d
readKittiCalibTr(const std::string& calib_path);

/// \brief Convert camera-0 poses (T_cam0_cami) to LiDAR poses relative to the first
/// LiDAR frame: T_lidar0_lidari = T_cam_lidar^-1 * T_cam0_cami * T_cam_lidar,
/// then re-based so the first pose is the identity.
PoseVector
cameraToLidarPoses(const PoseVector& T_cam0_cami, const Pose3d& T_cam_lidar);

} // namespace rast
} // namespace pcl
