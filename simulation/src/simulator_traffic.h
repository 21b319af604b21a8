#pragma once
/// \file simulator_traffic.h
/// \brief The simulator's realistic traffic (private to slam/src): vehicles in a lane
/// beside the ego vehicle and in an oncoming lane, companions that stop beside the ego
/// and cross traffic at its stops (TrafficMode::kRealistic), and the piecewise
/// constant-acceleration motion profiles they and generatePath's stops are made of.

#include <Eigen/Core>
#include <cstdint>
#include <memory>
#include <pcl/simulation/lidar_simulator.h>
#include <vector>

#include "simulator_hash.h"

namespace pcl {
namespace rast {
namespace simulator_detail {

/// \brief Arc length over time of a 1D motion made of constant-acceleration phases.
/// Starts cruising; addStop appends brake / stand / accelerate / cruise. Before the
/// first phase the first one is extrapolated.
class MotionProfile
{
public:
  /// \brief Cruising: s(t) = s0_m + v_mps (t - t0_s).
  MotionProfile(double t0_s, double s0_m, double v_mps);

  /// \brief From the final cruise at speed v: brake at \a decel_mps2 to stand exactly
  /// at \a s_stop_m (ahead of where the braking starts), stand until \a go_s (or until
  /// standstill when that is later), accelerate at \a accel_mps2 back to v and cruise.
  /// \return false (and no effect) at v = 0 or when the braking would have to start
  /// before the final cruise does.
  bool addStop(double s_stop_m, double decel_mps2, double go_s, double accel_mps2);

  /// \brief As addStop, given the time the standstill starts instead of its place.
  void
  addStopAtTime(double stand_from_s, double go_s, double decel_mps2, double accel_mps2);

  /// \brief Arc length at \a t_s. Standing phases give exactly the same value.
  double at(double t_s) const;

  /// \brief When the final cruise reaches \a s_m (may be before it starts).
  double cruiseTimeAt(double s_m) const;

private:
  struct Phase
  {
    double t0_s, s0_m, v0_mps, a_mps2;
  };
  const Phase& phaseAt(double t_s) const;
  double cruiseSpeed() const { return phases_.back().v0_mps; }

  std::vector<Phase> phases_;
};

/// \brief A dense sample of the ego path (<= 1 m apart) with its arc length.
struct TrafficPathPoint
{
  double x_m, y_m, heading_rad, s_m;
};

/// \brief One box of a vehicle's shape: centre (x, y), heights above the ground at the
/// vehicle's centre, yaw-oriented.
struct VehicleBox
{
  double x_m, y_m, z_min_m, z_max_m, length_m, width_m, yaw_rad;
  float reflectivity;
};

/// \brief The road the cross traffic of one ego stop drives on: a rectangle.
struct CrossRoad
{
  Eigen::Vector2d centre_xy, along; ///< centre and unit direction of its centre line
  double half_length_m, half_width_m;
};

/// \brief The few boxes (body and cabin, cab and cargo, one for a bus) of \a vehicle.
void vehicleBoxes(const MovingVehicle& vehicle, std::vector<VehicleBox>& boxes);

/// Uniform numbers from a counter: a stream per (seed, purpose, index).
class Draw
{
public:
  Draw(std::uint64_t seed, std::uint64_t purpose, std::uint64_t index)
      : state_(splitmix64(
            splitmix64(seed ^ 0x7AFF1CULL) ^ (purpose << 32) ^ index))
  {}
  double operator()(double lo, double hi)
  {
    state_ = splitmix64(state_);
    return lo + (hi - lo) * static_cast<double>(state_ >> 11) * 0x1.0p-53;
  }

private:
  std::uint64_t state_;
};

/// Kind, size and reflectivity of a new vehicle: a share \a heavy_fraction of trucks
/// and buses, of the rest a quarter vans.
MovingVehicle
drawVehicle(Draw& draw, double heavy_fraction);


/// \brief The realistic traffic around one ego drive, deterministic for the seed.
class TrafficModel
{
public:
  /// \param[in] params the traffic parameters (mode kRealistic)
  /// \param[in] lane_offset_m the lane beside the ego: this far left of the path
  /// \param[in] path dense path samples, increasing arc length
  /// \param[in] T_world_body the ego poses
  /// \param[in] timestamps_s one per pose, increasing
  /// \param[in] seed the world's random seed: where the ego's stops open a cross road
  /// \param[in] drive_seed the vehicles' random seed
  TrafficModel(const TrafficParams& params,
               double lane_offset_m,
               std::vector<TrafficPathPoint> path,
               const PoseVector& T_world_body,
               const std::vector<double>& timestamps_s,
               std::uint64_t seed,
               std::uint64_t drive_seed);
  ~TrafficModel();
  TrafficModel(const TrafficModel&) = delete;
  TrafficModel& operator=(const TrafficModel&) = delete;

  /// \brief The vehicles within reach of the ego at \a time_s (ground not applied:
  /// the caller places the boxes on its ground).
  std::vector<MovingVehicle> vehiclesAt(double time_s) const;

  /// \brief Half width of the road the lanes need around the path.
  double roadHalfWidth() const;

  /// \brief The cross roads (one per ego stop): static objects must keep off them.
  std::vector<CrossRoad> crossRoads() const;

private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

} // namespace simulator_detail
} // namespace rast
} // namespace pcl
