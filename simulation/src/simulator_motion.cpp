/// \file simulator_motion.cpp
/// \brief The traffic's names and parameters, the motion profiles of stop-and-go paths
/// and vehicles, the vehicles drawn from the seed and the boxes they are made of.

#include "simulator_traffic.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>

namespace pcl {
namespace rast {

// ---- names and parameters ----

TrafficMode
trafficModeFromString(const std::string& name)
{
  if (name == "along-path")
    return TrafficMode::kAlongPath;
  if (name == "realistic")
    return TrafficMode::kRealistic;
  throw std::invalid_argument("trafficModeFromString: unknown traffic '" + name +
                              "' (along-path, realistic)");
}

std::string
toString(TrafficMode mode)
{
  return mode == TrafficMode::kRealistic ? "realistic" : "along-path";
}

bool
TrafficParams::isValid(std::string* why) const
{
  // One check per value: "name must be in [lo, hi], got value".
  auto inRange = [why](const char* name, double value, double lo, double hi) {
    if (value >= lo && value <= hi)
      return true;
    if (why)
      *why = std::string("TrafficParams: ") + name + " must be in [" +
             std::to_string(lo) + ", " + std::to_string(hi) + "], got " +
             std::to_string(value);
    return false;
  };
  return inRange("oncoming_lane_offset_m", oncoming_lane_offset_m, 4.0, 50.0) &&
         inRange("same_direction_gap_m", same_direction_gap_m, 5.0, 1e4) &&
         inRange("oncoming_gap_m", oncoming_gap_m, 5.0, 1e4) &&
         inRange("heavy_vehicle_fraction", heavy_vehicle_fraction, 0.0, 1.0) &&
         inRange("companions_per_stop", companions_per_stop, 0, 5) &&
         inRange("light_stop_min_s", light_stop_min_s, 0.5, 600.0);
}

namespace simulator_detail {

// ---- motion profiles ----

MotionProfile::MotionProfile(double t0_s, double s0_m, double v_mps)
    : phases_{{t0_s, s0_m, v_mps, 0.0}}
{}

const MotionProfile::Phase&
MotionProfile::phaseAt(double t_s) const
{
  auto it =
      std::upper_bound(phases_.begin(), phases_.end(), t_s, [](double t, const Phase& p) {
        return t < p.t0_s;
      });
  return it == phases_.begin() ? phases_.front() : *(it - 1);
}

double
MotionProfile::at(double t_s) const
{
  const Phase& p = phaseAt(t_s);
  const double tau = t_s - p.t0_s;
  return p.s0_m + p.v0_mps * tau + 0.5 * p.a_mps2 * tau * tau;
}

double
MotionProfile::cruiseTimeAt(double s_m) const
{
  const Phase& cruise = phases_.back();
  return cruise.t0_s + (s_m - cruise.s0_m) / cruise.v0_mps;
}

bool
MotionProfile::addStop(double s_stop_m, double decel_mps2, double go_s, double accel_mps2)
{
  const double v = cruiseSpeed();
  if (!(v > 0.0))
    return false;
  const Phase cruise = phases_.back();
  const double brake_m = 0.5 * v * v / decel_mps2;
  const double brake_from_s = cruiseTimeAt(s_stop_m - brake_m);
  if (phases_.size() > 1 && brake_from_s < cruise.t0_s)
    return false;
  const double stand_from_s = brake_from_s + v / decel_mps2;
  const double go = std::max(go_s, stand_from_s);
  phases_.push_back({brake_from_s, s_stop_m - brake_m, v, -decel_mps2});
  phases_.push_back({stand_from_s, s_stop_m, 0.0, 0.0});
  phases_.push_back({go, s_stop_m, 0.0, accel_mps2});
  phases_.push_back({go + v / accel_mps2, s_stop_m + 0.5 * v * v / accel_mps2, v, 0.0});
  return true;
}

void
MotionProfile::addStopAtTime(double stand_from_s,
                             double go_s,
                             double decel_mps2,
                             double accel_mps2)
{
  if (!(cruiseSpeed() > 0.0))
    return;
  const double v = cruiseSpeed();
  // Braking from v to 0 covers what cruising covers in half the braking time.
  addStop(at(stand_from_s - 0.5 * v / decel_mps2), decel_mps2, go_s, accel_mps2);
}

// ---- vehicle shapes ----

void
vehicleBoxes(const MovingVehicle& v, std::vector<VehicleBox>& boxes)
{
  const double c = std::cos(v.yaw_rad), s = std::sin(v.yaw_rad);
  const double L = v.length_m, W = v.width_m, H = v.height_m;
  auto add = [&](double along_m, double z0, double z1, double length, double width) {
    boxes.push_back({v.x_m + along_m * c,
                     v.y_m + along_m * s,
                     z0,
                     z1,
                     length,
                     width,
                     v.yaw_rad,
                     v.reflectivity});
  };
  switch (v.kind) {
  case VehicleKind::kCar:
    add(0.0, 0.25, 1.0, L, W);
    add(-0.08 * L, 1.0, H, 0.55 * L, 0.9 * W);
    break;
  case VehicleKind::kVan:
    add(0.0, 0.3, 1.1, L, W);
    add(-0.08 * L, 1.1, H, 0.8 * L, 0.95 * W);
    break;
  case VehicleKind::kTruck: // cab in front, cargo box behind
    add(0.5 * L - 1.1, 0.5, 2.9, 2.2, W);
    add(-1.3, 0.9, H, L - 2.6, W);
    break;
  case VehicleKind::kBus:
    add(0.0, 0.3, H, L, W);
    break;
  }
}

namespace {

/// Size and reflectivity ranges of each vehicle kind.
struct KindSizes
{
  VehicleKind kind;
  double length_m[2], width_m[2], height_m[2], reflectivity[2];
};
constexpr KindSizes kKindSizes[] = {
    {VehicleKind::kCar, {3.8, 4.9}, {1.7, 1.95}, {1.4, 1.6}, {0.1, 0.9}},
    {VehicleKind::kVan, {4.8, 5.6}, {1.9, 2.05}, {1.9, 2.4}, {0.1, 0.9}},
    {VehicleKind::kTruck, {7.0, 10.0}, {2.4, 2.55}, {3.2, 3.8}, {0.3, 0.8}},
    {VehicleKind::kBus, {11.0, 12.5}, {2.4, 2.55}, {3.0, 3.3}, {0.3, 0.8}}};

} // namespace

MovingVehicle
drawVehicle(Draw& draw, double heavy_fraction)
{
  const double u = draw(0.0, 1.0);
  const int kind = u < 0.5 * heavy_fraction ? 2
                   : u < heavy_fraction     ? 3
                   : draw(0.0, 1.0) < 0.25  ? 1
                                            : 0;
  const KindSizes& k = kKindSizes[kind];
  MovingVehicle v;
  v.kind = k.kind;
  v.length_m = draw(k.length_m[0], k.length_m[1]);
  v.width_m = draw(k.width_m[0], k.width_m[1]);
  v.height_m = draw(k.height_m[0], k.height_m[1]);
  v.reflectivity = static_cast<float>(draw(k.reflectivity[0], k.reflectivity[1]));
  return v;
}

} // namespace simulator_detail
} // namespace rast
} // namespace pcl
