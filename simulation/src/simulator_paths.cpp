/// \file simulator_paths.cpp
/// \brief Generated paths of the simulator (straight, loop, figure eight over gentle
/// relief): PathParams and generatePath.

#include <pcl/simulation/lidar_simulator.h>

#include "simulator_hash.h"

#include "simulator_traffic.h" // MotionProfile

#include <algorithm>
#include <cmath>
#include <sstream>
#include <stdexcept>

namespace pcl {
namespace rast {

namespace {

using simulator_detail::kPi;

/// Gentle hills: h(x, y) with h(0, 0) = 0 and slopes below ~4 % for A = 2 m.
double
elevation(double A, double x, double y, double* gx, double* gy)
{
  const double kx = 2 * kPi / 320.0, ky = 2 * kPi / 260.0, ph = 0.3;
  *gx = A * kx * std::cos(kx * x + ph) * std::cos(ky * y);
  *gy = -A * ky * std::sin(kx * x + ph) * std::sin(ky * y);
  return A * (std::sin(kx * x + ph) * std::cos(ky * y) - std::sin(ph));
}

/// A dense closed or open 2D polyline with cumulative arc length.
struct Polyline
{
  std::vector<Eigen::Vector2d> p;
  std::vector<double> s;

  void finish()
  {
    s.assign(p.size(), 0.0);
    for (std::size_t k = 1; k < p.size(); ++k)
      s[k] = s[k - 1] + (p[k] - p[k - 1]).norm();
  }
  Eigen::Vector2d at(double v) const
  {
    const auto it = std::upper_bound(s.begin(), s.end(), v);
    if (it == s.begin())
      return p.front();
    if (it == s.end())
      return p.back();
    const std::size_t k = static_cast<std::size_t>(it - s.begin());
    const double f = (v - s[k - 1]) / std::max(1e-12, s[k] - s[k - 1]);
    return p[k - 1] + f * (p[k] - p[k - 1]);
  }
};

} // namespace

PathType
pathTypeFromString(const std::string& name)
{
  if (name == "straight")
    return PathType::kStraight;
  if (name == "loop")
    return PathType::kLoop;
  if (name == "eight")
    return PathType::kFigureEight;
  throw std::invalid_argument("pathTypeFromString: unknown path '" + name +
                              "' (straight, loop, eight)");
}

std::string
toString(PathType type)
{
  switch (type) {
  case PathType::kStraight:
    return "straight";
  case PathType::kLoop:
    return "loop";
  case PathType::kFigureEight:
    return "eight";
  }
  return "unknown";
}

// ---- paths ----

bool
PathParams::isValid(std::string* why) const
{
  auto fail = [why](const std::string& msg) {
    if (why)
      *why = "PathParams: " + msg;
    return false;
  };
  if (num_frames < 1 || num_frames > 10000000)
    return fail("num_frames must be in [1, 1e7], got " + std::to_string(num_frames));
  if (!(speed_mps >= 0.0 && speed_mps <= 100.0))
    return fail("speed_mps must be in [0, 100], got " + std::to_string(speed_mps));
  if (!(rate_hz > 0.0 && rate_hz <= 1000.0))
    return fail("rate_hz must be in (0, 1000], got " + std::to_string(rate_hz));
  if (!(height_m >= 0.0 && height_m <= 20.0))
    return fail("height_m must be in [0, 20], got " + std::to_string(height_m));
  if (!(elevation_amplitude_m >= 0.0 && elevation_amplitude_m <= 50.0))
    return fail("elevation_amplitude_m must be in [0, 50]");
  if (!(revisit_fraction >= 0.0 && revisit_fraction <= 99.0))
    return fail("revisit_fraction must be in [0, 99]");
  if (num_stops < 0 || num_stops > 1000)
    return fail("num_stops must be in [0, 1000], got " + std::to_string(num_stops));
  if (num_stops == 0)
    return true;
  if (!(stop_duration_s > 0.0 && stop_duration_s <= 3600.0))
    return fail("stop_duration_s must be in (0, 3600], got " +
                std::to_string(stop_duration_s));
  if (!(acceleration_mps2 >= 0.1 && acceleration_mps2 <= 20.0))
    return fail("acceleration_mps2 must be in [0.1, 20], got " +
                std::to_string(acceleration_mps2));
  // Each stop (brake, stand, accelerate) must fit in its share of the duration.
  const double duration_s = (num_frames - 1) / rate_hz;
  const double per_stop_s = stop_duration_s + 2.0 * speed_mps / acceleration_mps2;
  if (per_stop_s > duration_s / (num_stops + 1))
    return fail(std::to_string(num_stops) + " stops of " + std::to_string(per_stop_s) +
                " s (braking, stop_duration_s, starting) do not fit in " +
                std::to_string(duration_s) + " s of num_frames / rate_hz");
  return true;
}

PoseVector
generatePath(const PathParams& params)
{
  std::string why;
  if (!params.isValid(&why))
    throw std::invalid_argument("generatePath: " + why);
  const double step = params.speed_mps / params.rate_hz;
  // Stop-and-go: arc length over time with the stops evenly spread over the duration.
  const double duration_s = (params.num_frames - 1) / params.rate_hz;
  simulator_detail::MotionProfile profile(0.0, 0.0, params.speed_mps);
  for (int k = 0; k < params.num_stops; ++k) {
    const double centre_s = duration_s * (k + 1) / (params.num_stops + 1);
    profile.addStopAtTime(centre_s - 0.5 * params.stop_duration_s,
                          centre_s + 0.5 * params.stop_duration_s,
                          params.acceleration_mps2,
                          params.acceleration_mps2);
  }
  auto arcLength = [&](int i) {
    return params.num_stops == 0 ? step * i : profile.at(i / params.rate_hz);
  };
  const double driven = arcLength(params.num_frames - 1);

  // Unit-size dense shape, scaled so that the driven length covers it 1 + revisit times.
  Polyline line;
  bool closed = params.type != PathType::kStraight;
  if (params.type == PathType::kStraight) {
    line.p = {Eigen::Vector2d(0, 0), Eigen::Vector2d(std::max(driven, 1e-6), 0)};
  } else {
    const int n = 20000;
    for (int k = 0; k <= n; ++k) {
      const double t = 2 * kPi * k / n;
      if (params.type == PathType::kLoop) {
        // Superellipse |x/a|^4 + |y/b|^4 = 1 (a rounded rectangle), from its bottom
        // middle.
        const double phi = t - kPi / 2;
        const double c = std::cos(phi), s = std::sin(phi);
        line.p.emplace_back(1.6 * std::copysign(std::sqrt(std::abs(c)), c),
                            std::copysign(std::sqrt(std::abs(s)), s) + 1.0);
      } else {
        // Lemniscate of Gerono, rotated so that it starts along +x.
        const Eigen::Vector2d q(std::sin(t), std::sin(t) * std::cos(t));
        line.p.push_back(Eigen::Rotation2Dd(-kPi / 4) * q);
      }
    }
  }
  const Eigen::Vector2d start = line.p.front(); // exactly at the origin
  for (auto& p : line.p)
    p -= start;
  line.finish();
  if (closed) {
    const double perimeter = std::max(driven / (1.0 + params.revisit_fraction), 1e-6);
    const double scale = perimeter / line.s.back();
    for (auto& p : line.p)
      p *= scale;
    line.finish();
  }

  PoseVector poses;
  poses.reserve(params.num_frames);
  const double A = params.elevation_amplitude_m;
  const double ds = std::min(0.5, std::max(1e-3, 0.25 * line.s.back()));
  for (int i = 0; i < params.num_frames; ++i) {
    double s = arcLength(i);
    if (closed)
      s = std::fmod(s, line.s.back());
    const Eigen::Vector2d p = line.at(s);
    const Eigen::Vector2d ahead = closed ? line.at(std::fmod(s + ds, line.s.back()))
                                         : line.at(std::min(s + ds, line.s.back()));
    Eigen::Vector2d dir = ahead - p;
    if (dir.norm() < 1e-9)
      dir = p - line.at(std::max(0.0, s - ds));
    const double yaw = dir.norm() < 1e-9 ? 0.0 : std::atan2(dir.y(), dir.x());
    double gx, gy;
    const double h = elevation(A, p.x(), p.y(), &gx, &gy);
    // Follow the terrain: z along its normal, x along the heading.
    const Eigen::Vector3d z = Eigen::Vector3d(-gx, -gy, 1.0).normalized();
    Eigen::Vector3d x(std::cos(yaw), std::sin(yaw), 0.0);
    x = (x - x.dot(z) * z).normalized();
    Pose3d T = Pose3d::Identity();
    T.linear().col(0) = x;
    T.linear().col(1) = z.cross(x);
    T.linear().col(2) = z;
    T.translation() = Eigen::Vector3d(p.x(), p.y(), h + params.height_m);
    poses.push_back(T);
  }
  return poses;
}

} // namespace rast
} // namespace pcl
