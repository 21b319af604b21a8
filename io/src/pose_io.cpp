/// \file pose_io.cpp
/// \brief KITTI / TUM pose files and the KITTI camera <-> LiDAR frame change.

#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <limits>
#include <pcl/io/pose_io.h>
#include <pcl/rast/atomic_file.h>
#include <sstream>
#include <stdexcept>
#include <unistd.h>

namespace pcl {
namespace rast {
namespace {

/// Tolerance on | |q| - 1 | for a TUM quaternion (files often carry 4-6 decimals).
constexpr double kQuaternionNormTolerance = 1e-2;

std::string
location(const std::string& path, std::size_t line_number)
{
  return path + ":" + std::to_string(line_number) + ": ";
}

/// Split a line into whitespace-separated tokens.
std::vector<std::string>
tokenize(const std::string& line)
{
  std::istringstream in(line);
  std::vector<std::string> tokens;
  std::string token;
  while (in >> token)
    tokens.push_back(token);
  return tokens;
}

/// A line that carries no pose: empty, blank or a `#` comment.
bool
isSkippable(const std::string& line)
{
  const auto first = line.find_first_not_of(" \t\r");
  return first == std::string::npos || line[first] == '#';
}

/// Parse a whole token as a finite double; false (with \a why) otherwise.
bool
parseFinite(const std::string& token, double* value, std::string* why)
{
  errno = 0;
  char* end = nullptr;
  const double v = std::strtod(token.c_str(), &end);
  if (end == token.c_str() || *end != '\0') {
    *why = "'" + token + "' is not a number";
    return false;
  }
  if (!std::isfinite(v) || errno == ERANGE) {
    *why = "'" + token + "' is not a finite number";
    return false;
  }
  *value = v;
  return true;
}

/// Parse all tokens as finite doubles; throws naming the file and line on failure.
std::vector<double>
parseNumbers(const std::vector<std::string>& tokens,
             const std::string& path,
             std::size_t line_number)
{
  std::vector<double> values(tokens.size());
  std::string why;
  for (std::size_t i = 0; i < tokens.size(); ++i)
    if (!parseFinite(tokens[i], &values[i], &why))
      throw std::runtime_error(location(path, line_number) + "field " +
                               std::to_string(i + 1) + ": " + why);
  return values;
}

/// The pose of a row-major 3x4 block, projected onto SE(3) (rigid_pose.h); false with
/// \a why when the block is further than kRotationTolerance from a rotation.
bool
poseFromRowMajor3x4(const double* v, Pose3d* pose, std::string* why)
{
  Pose3d T = Pose3d::Identity();
  T.linear() << v[0], v[1], v[2], v[4], v[5], v[6], v[8], v[9], v[10];
  T.translation() << v[3], v[7], v[11];
  return projectToRigid(T, pose, why);
}

std::string
formatName(PoseFormat format)
{
  return format == PoseFormat::kKitti ? "KITTI" : "TUM";
}

} // namespace

PoseFormat
detectPoseFormat(const std::string& path)
{
  std::ifstream in(path);
  if (!in)
    throw std::runtime_error("detectPoseFormat: cannot open '" + path + "'");
  std::string line;
  std::size_t line_number = 0;
  while (readBoundedLine(in, line, path, line_number + 1)) {
    ++line_number;
    if (isSkippable(line))
      continue;
    const std::size_t n = tokenize(line).size();
    if (n == 12)
      return PoseFormat::kKitti;
    if (n == 8)
      return PoseFormat::kTum;
    throw std::runtime_error("detectPoseFormat: " + location(path, line_number) + "has " +
                             std::to_string(n) +
                             " fields; expected 12 (KITTI) or 8 (TUM)");
  }
  throw std::runtime_error("detectPoseFormat: '" + path + "' contains no pose line");
}

Trajectory
readTrajectory(const std::string& path)
{
  return readTrajectory(path, detectPoseFormat(path));
}

Trajectory
readTrajectory(const std::string& path, PoseFormat format)
{
  std::ifstream in(path);
  if (!in)
    throw std::runtime_error("readTrajectory: cannot open '" + path + "'");
  const std::size_t expected = format == PoseFormat::kKitti ? 12 : 8;

  Trajectory trajectory;
  trajectory.format = format;
  std::string line;
  std::size_t line_number = 0;
  while (readBoundedLine(in, line, path, line_number + 1)) {
    ++line_number;
    if (isSkippable(line))
      continue;
    const auto tokens = tokenize(line);
    if (tokens.size() != expected)
      throw std::runtime_error("readTrajectory: " + location(path, line_number) + "has " +
                               std::to_string(tokens.size()) + " fields; expected " +
                               std::to_string(expected) + " (" + formatName(format) +
                               ")");
    const auto v = parseNumbers(tokens, path, line_number);

    Pose3d pose = Pose3d::Identity();
    double timestamp_s = 0.0;
    if (format == PoseFormat::kKitti) {
      std::string why;
      if (!poseFromRowMajor3x4(v.data(), &pose, &why))
        throw std::runtime_error("readTrajectory: " + location(path, line_number) + why);
      timestamp_s = static_cast<double>(trajectory.poses.size());
    } else {
      timestamp_s = v[0];
      Eigen::Quaterniond q(v[7], v[4], v[5], v[6]); // (w, x, y, z)
      const double norm = q.norm();
      if (std::abs(norm - 1.0) > kQuaternionNormTolerance) {
        std::ostringstream msg;
        msg << "quaternion norm " << norm << " is not 1 (tolerance "
            << kQuaternionNormTolerance << ")";
        throw std::runtime_error("readTrajectory: " + location(path, line_number) +
                                 msg.str());
      }
      q.normalize();
      pose.linear() = q.toRotationMatrix();
      pose.translation() << v[1], v[2], v[3];
    }
    trajectory.poses.push_back(pose);
    trajectory.timestamps_s.push_back(timestamp_s);
  }
  if (in.bad())
    throw std::runtime_error("readTrajectory: error while reading '" + path + "'");
  return trajectory;
}


namespace {

/// Doubles written with enough digits to read back exactly.
std::ostream&
setFullPrecision(std::ostream& out)
{
  return out << std::setprecision(std::numeric_limits<double>::max_digits10);
}

} // namespace

void
writeKittiPoses(const std::string& path, const PoseVector& poses)
{
  std::ostringstream out;
  setFullPrecision(out);
  for (const auto& pose : poses) {
    const Eigen::Matrix4d T = pose.matrix();
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 4; ++c)
        out << T(r, c) << (r == 2 && c == 3 ? '\n' : ' ');
  }
  writeFileAtomically(path, out.str());
}

void
writeTumPoses(const std::string& path,
              const PoseVector& poses,
              const std::vector<double>& timestamps_s)
{
  if (!timestamps_s.empty() && timestamps_s.size() != poses.size())
    throw std::invalid_argument("writeTumPoses: " + std::to_string(poses.size()) +
                                " poses but " + std::to_string(timestamps_s.size()) +
                                " timestamps");
  std::ostringstream out;
  out << "# timestamp tx ty tz qx qy qz qw\n";
  setFullPrecision(out);
  for (std::size_t i = 0; i < poses.size(); ++i) {
    const double t = timestamps_s.empty() ? static_cast<double>(i) : timestamps_s[i];
    const Eigen::Vector3d p = poses[i].translation();
    const Eigen::Quaterniond q(poses[i].rotation());
    out << t << ' ' << p.x() << ' ' << p.y() << ' ' << p.z() << ' ' << q.x() << ' '
        << q.y() << ' ' << q.z() << ' ' << q.w() << '\n';
  }
  writeFileAtomically(path, out.str());
}

Pose3d
kittiAxisChangeCamLidar()
{
  Pose3d T_cam_lidar = Pose3d::Identity();
  // Rows: x_cam = -y_lidar, y_cam = -z_lidar, z_cam = x_lidar.
  T_cam_lidar.linear() << 0, -1, 0, //
      0, 0, -1,                     //
      1, 0, 0;
  return T_cam_lidar;
}

Pose3d
readKittiCalibTr(const std::string& calib_path)
{
  std::ifstream in(calib_path);
  if (!in)
    throw std::runtime_error("readKittiCalibTr: cannot open '" + calib_path + "'");
  std::string line;
  std::size_t line_number = 0;
  while (readBoundedLine(in, line, calib_path, line_number + 1)) {
    ++line_number;
    auto tokens = tokenize(line);
    if (tokens.empty() || (tokens[0] != "Tr:" && tokens[0] != "Tr_velo_to_cam:"))
      continue;
    tokens.erase(tokens.begin());
    if (tokens.size() != 12)
      throw std::runtime_error("readKittiCalibTr: " + location(calib_path, line_number) +
                               "Tr has " + std::to_string(tokens.size()) +
                               " numbers; expected 12");
    std::vector<double> v;
    try {
      v = parseNumbers(tokens, calib_path, line_number);
    } catch (const std::runtime_error& e) {
      throw std::runtime_error(std::string("readKittiCalibTr: ") + e.what());
    }
    Pose3d T_cam_lidar;
    std::string why;
    if (!poseFromRowMajor3x4(v.data(), &T_cam_lidar, &why))
      throw std::runtime_error("readKittiCalibTr: " + location(calib_path, line_number) +
                               why);
    return T_cam_lidar;
  }
  throw std::runtime_error("readKittiCalibTr: '" + calib_path +
                           "' has no 'Tr:' or 'Tr_velo_to_cam:' line");
}

PoseVector
cameraToLidarPoses(const PoseVector& T_cam0_cami, const Pose3d& T_cam_lidar)
{
  PoseVector T_lidar0_lidari;
  T_lidar0_lidari.reserve(T_cam0_cami.size());
  if (T_cam0_cami.empty())
    return T_lidar0_lidari;
  const Pose3d T_lidar_cam = T_cam_lidar.inverse();
  for (const auto& T : T_cam0_cami)
    T_lidar0_lidari.push_back(T_lidar_cam * T * T_cam_lidar);
  // Re-base: the first LiDAR frame is the world frame.
  const Pose3d T_first_inv = T_lidar0_lidari.front().inverse();
  for (auto& T : T_lidar0_lidari)
    T = T_first_inv * T;
  T_lidar0_lidari.front().setIdentity();
  return T_lidar0_lidari;
}

} // namespace rast
} // namespace pcl
