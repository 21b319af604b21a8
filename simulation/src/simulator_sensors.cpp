/// \file simulator_sensors.cpp
/// \brief The simulated sensors (HDL-64, VLP-16, OS1-64, OS0-128 handheld): beam
/// layouts, ranges, noise, mounting and motion, and their names.

#include <pcl/simulation/lidar_simulator.h>

#include "simulator_hash.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>

namespace pcl {
namespace rast {

namespace {

using simulator_detail::kPi;

double
deg(double d)
{
  return d * kPi / 180.0;
}

std::vector<double>
linearBeams(int n, double top_deg, double bottom_deg)
{
  std::vector<double> b(n);
  for (int k = 0; k < n; ++k)
    b[k] = deg(top_deg + (bottom_deg - top_deg) * k / std::max(1, n - 1));
  return b;
}

} // namespace

// ---- names ----

SensorModel
sensorModelFromString(const std::string& name)
{
  if (name == "hdl64")
    return SensorModel::kHdl64;
  if (name == "vlp16")
    return SensorModel::kVlp16;
  if (name == "os1-64")
    return SensorModel::kOs1_64;
  if (name == "os0-128")
    return SensorModel::kOs0_128;
  throw std::invalid_argument("sensorModelFromString: unknown sensor '" + name +
                              "' (hdl64, vlp16, os1-64, os0-128)");
}

std::string
toString(SensorModel model)
{
  switch (model) {
  case SensorModel::kHdl64:
    return "hdl64";
  case SensorModel::kVlp16:
    return "vlp16";
  case SensorModel::kOs1_64:
    return "os1-64";
  case SensorModel::kOs0_128:
    return "os0-128";
  }
  return "unknown";
}

// ---- sensors ----

SensorSpec
sensorSpec(SensorModel model)
{
  SensorSpec s;
  switch (model) {
  case SensorModel::kHdl64: {
    // Two laser blocks as on the real unit: 1/3 deg spacing above -8.33 deg, ~1/2 below.
    s.beam_elevations_rad = linearBeams(32, 2.0, -8.33);
    const auto lower = linearBeams(32, -8.83, -24.8);
    s.beam_elevations_rad.insert(s.beam_elevations_rad.end(), lower.begin(), lower.end());
    s.azimuth_steps = 2000;
    s.min_range_m = 2.0;
    s.max_range_m = 120.0;
    s.range_noise_std_m = 0.02;
    s.dropout_rate = 0.01;
    s.mount_height_m = 1.73;
    break;
  }
  case SensorModel::kVlp16:
    s.beam_elevations_rad = linearBeams(16, 15.0, -15.0);
    s.azimuth_steps = 1800;
    s.min_range_m = 1.0;
    s.max_range_m = 100.0;
    s.range_noise_std_m = 0.03;
    s.dropout_rate = 0.01;
    s.mount_height_m = 1.73;
    break;
  case SensorModel::kOs1_64:
    s.beam_elevations_rad = linearBeams(64, 16.6, -16.6);
    s.azimuth_steps = 1024;
    s.min_range_m = 0.8;
    s.max_range_m = 120.0;
    s.range_noise_std_m = 0.015;
    s.dropout_rate = 0.005;
    s.mount_height_m = 1.73;
    break;
  case SensorModel::kOs0_128:
    s.beam_elevations_rad = linearBeams(128, 45.0, -45.0);
    s.azimuth_steps = 1024;
    s.min_range_m = 0.5;
    s.max_range_m = 50.0;
    s.range_noise_std_m = 0.02;
    s.dropout_rate = 0.01;
    s.mount_height_m = 1.5;
    s.handheld = true;
    s.tilt_pitch_rad = deg(25.0);
    s.sway_pitch_rad = deg(3.0);
    s.sway_roll_rad = deg(2.0);
    s.sway_frequency_hz = 0.9;
    break;
  }
  return s;
}

Pose3d
bodyToSensor(const SensorSpec& spec, double time_s)
{
  Pose3d T = Pose3d::Identity();
  if (!spec.handheld)
    return T;
  // Positive pitch about y turns x towards -z: the sensor looks down ahead. The sway
  // follows a walking cadence: pitch at f, roll at f/2.
  const double w = 2 * kPi * spec.sway_frequency_hz * time_s;
  const double pitch = spec.tilt_pitch_rad + spec.sway_pitch_rad * std::sin(w);
  const double roll = spec.sway_roll_rad * std::sin(0.5 * w + 0.7);
  T.linear() = (Eigen::AngleAxisd(pitch, Eigen::Vector3d::UnitY()) *
                Eigen::AngleAxisd(roll, Eigen::Vector3d::UnitX()))
                   .toRotationMatrix();
  return T;
}

} // namespace rast
} // namespace pcl
