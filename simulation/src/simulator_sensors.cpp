/// \file simulator_sensors.cpp
/// \brief The simulated sensors (HDL-64, VLP-16, OS1-64, OS0-128 handheld, HDL-32E): beam
/// layouts, ranges, noise, mounting and motion, and their names.

#include <pcl/simulation/lidar_simulator.h>

#include "simulator_hash.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <utility>

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

/// A head spinning on a car's roof, 1.73 m up as on KITTI's car.
SensorSpec
spinningHead(std::vector<double> beam_elevations_rad,
             int azimuth_steps,
             double min_range_m,
             double max_range_m,
             double range_noise_std_m,
             double dropout_rate)
{
  SensorSpec s;
  s.beam_elevations_rad = std::move(beam_elevations_rad);
  s.azimuth_steps = azimuth_steps;
  s.min_range_m = min_range_m;
  s.max_range_m = max_range_m;
  s.range_noise_std_m = range_noise_std_m;
  s.dropout_rate = dropout_rate;
  s.mount_height_m = 1.73;
  return s;
}

} // namespace

// ---- names ----

SensorModel
sensorModelFromString(const std::string& name)
{
  std::string known;
  for (const SensorModel model : {SensorModel::kHdl64,
                                  SensorModel::kVlp16,
                                  SensorModel::kOs1_64,
                                  SensorModel::kOs0_128,
                                  SensorModel::kHdl32}) {
    if (name == toString(model))
      return model;
    known += (known.empty() ? "" : ", ") + toString(model);
  }
  throw std::invalid_argument("sensorModelFromString: unknown sensor '" + name + "' (" +
                              known + ")");
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
  case SensorModel::kHdl32:
    return "hdl32";
  }
  return "unknown";
}

// ---- sensors ----

SensorSpec
sensorSpec(SensorModel model)
{
  switch (model) {
  case SensorModel::kHdl64: {
    // Two laser blocks as on the real unit: 1/3 deg spacing above -8.33 deg, ~1/2 below.
    std::vector<double> beams = linearBeams(32, 2.0, -8.33);
    const auto lower = linearBeams(32, -8.83, -24.8);
    beams.insert(beams.end(), lower.begin(), lower.end());
    return spinningHead(std::move(beams), 2000, 2.0, 120.0, 0.02, 0.01);
  }
  case SensorModel::kVlp16:
    return spinningHead(linearBeams(16, 15.0, -15.0), 1800, 1.0, 100.0, 0.03, 0.01);
  case SensorModel::kOs1_64:
    return spinningHead(linearBeams(64, 16.6, -16.6), 1024, 0.8, 120.0, 0.015, 0.005);
  case SensorModel::kOs0_128: {
    SensorSpec s =
        spinningHead(linearBeams(128, 45.0, -45.0), 1024, 0.5, 50.0, 0.02, 0.01);
    s.mount_height_m = 1.5;
    s.handheld = true;
    s.tilt_pitch_rad = deg(25.0);
    s.sway_pitch_rad = deg(3.0);
    s.sway_roll_rad = deg(2.0);
    s.sway_frequency_hz = 0.9;
    return s;
  }
  case SensorModel::kHdl32:
    // 32 beams 4/3 deg apart over 41 deg, between a VLP-16 and an HDL-64: no
    // odometry preset was made for such a head.
    return spinningHead(linearBeams(32, 10.67, -30.67), 2170, 1.0, 100.0, 0.02, 0.01);
  }
  return SensorSpec();
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
