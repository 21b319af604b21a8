/// \file lidar_simulator_traffic.cpp
/// \brief The simulator's realistic traffic (TrafficMode::kRealistic): free lanes beside
/// and opposite the ego vehicle, companions that stop beside it at its stops, cross
/// traffic ahead of it during them (the motion profiles are in simulator_motion.cpp).

#include "simulator_hash.h"
#include "simulator_traffic.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>

namespace pcl {
namespace rast {

namespace {

using simulator_detail::kPi;
constexpr double kReachM = 250.0;      ///< cross traffic exists this close to the ego
constexpr double kLaneWindowM = 150.0; ///< lane vehicles: at most this much arc length
                                       ///< around it
constexpr double kCrossHalfLengthM = 60.0; ///< cross traffic drives +- this from the path
constexpr double kStandingMps = 0.25;      ///< the ego is standing below this speed
constexpr double kLaneMarginM = 3.0; ///< least bumper gap in a lane (inner side of bends)

/// Whether two yaw-oriented rectangles (centre, yaw, half length, half width) overlap:
/// no separating axis among their four edge directions.
bool
rectanglesOverlap(const double a[5], const double b[5])
{
  for (const double* axis_of : {a, b})
    for (int k = 0; k < 2; ++k) {
      const double yaw = axis_of[2] + k * 0.5 * kPi;
      const double ux = std::cos(yaw), uy = std::sin(yaw);
      auto reach = [ux, uy](const double r[5]) { // half extent of r along u
        const double c = std::abs(std::cos(r[2]) * ux + std::sin(r[2]) * uy);
        const double s = std::abs(-std::sin(r[2]) * ux + std::cos(r[2]) * uy);
        return r[3] * c + r[4] * s;
      };
      const double gap = std::abs((b[0] - a[0]) * ux + (b[1] - a[1]) * uy);
      if (gap > reach(a) + reach(b))
        return false;
    }
  return true;
}

/// Distance covered \a tau_s after starting from rest at \a accel_mps2 up to \a v_mps.
double
startFromRest(double tau_s, double accel_mps2, double v_mps)
{
  if (tau_s <= 0.0)
    return 0.0;
  const double ramp_s = v_mps / accel_mps2;
  if (tau_s <= ramp_s)
    return 0.5 * accel_mps2 * tau_s * tau_s;
  return 0.5 * v_mps * ramp_s + v_mps * (tau_s - ramp_s);
}

} // namespace

namespace simulator_detail {

// ---- the traffic ----

// The traffic's own types: named (not anonymous), as TrafficModel::Impl holds them.

/// One vehicle of the realistic traffic and how it moves.
struct Agent
{
  MovingVehicle shape;
  double from_s = -1e300, to_s = 1e300; ///< exists in this time span
  // Lane vehicles: arc length along the path, lateral offset, +1 with the path.
  double lateral_m = 0.0;
  int direction = 1;
  // Free lane vehicles: s(t) = s_ref + direction * profile(t), queueing at the lights.
  double s_ref_m = 0.0, v_mps = 0.0;
  MotionProfile profile{0.0, 0.0, 0.0};
  // Companions (stop beside the ego): index of the stop, offset to the ego, approach.
  int stop = -1, leader = -1;
  double offset_m = 0.0, join_s = 0.0, go_s = 0.0, accel_mps2 = 0.0;
  // Cross traffic: crosses the path at centre_s, from origin along dir.
  double centre_s = 0.0;
  Eigen::Vector2d origin{0, 0}, dir{1, 0};
};

struct EgoStop
{
  double from_s, to_s, s_m;
  Eigen::Vector2d xy, forward;
  double cross_m; ///< the cross road's centre line is this far ahead
};



struct TrafficModel::Impl
{
  TrafficParams params;
  double lane_offset_m = 3.0;
  double lane_window_m = kLaneWindowM; ///< lane vehicles this close in arc length show
  double lane_speed_mps[2] = {10.0, 10.0}; ///< same way, oncoming
  std::vector<TrafficPathPoint> path;
  std::vector<double> ego_t, ego_s; ///< per frame: time and arc length
  std::vector<EgoStop> stops;
  std::vector<Agent> companions, cross;
  std::vector<Agent> lanes[2]; ///< free vehicles, front to back: same way, oncoming
  /// Per companion: (time, arc length) every 0.1 s of its life.
  std::vector<std::vector<std::pair<double, double>>> companion_tracks;

  /// Position and heading on the path at arc length s (extrapolated beyond its ends).
  void pathAt(double s, double& x, double& y, double& heading) const
  {
    const TrafficPathPoint& first = path.front();
    const TrafficPathPoint& last = path.back();
    const TrafficPathPoint* a = nullptr;
    double f = 0.0;
    if (s <= first.s_m) {
      a = &first;
      f = s - first.s_m;
    } else if (s >= last.s_m) {
      a = &last;
      f = s - last.s_m;
    } else {
      auto it = std::upper_bound(
          path.begin(), path.end(), s, [](double v, const TrafficPathPoint& p) {
            return v < p.s_m;
          });
      a = &*(it - 1);
      f = s - a->s_m;
    }
    heading = a->heading_rad;
    x = a->x_m + f * std::cos(heading);
    y = a->y_m + f * std::sin(heading);
  }

  /// Ego arc length at time t (linear between frames, constant beyond).
  double egoS(double t) const
  {
    if (t <= ego_t.front())
      return ego_s.front();
    if (t >= ego_t.back())
      return ego_s.back();
    const std::size_t k =
        std::upper_bound(ego_t.begin(), ego_t.end(), t) - ego_t.begin(); // >= 1
    const double f = (t - ego_t[k - 1]) / (ego_t[k] - ego_t[k - 1]);
    return ego_s[k - 1] + f * (ego_s[k] - ego_s[k - 1]);
  }

  double freeS(const Agent& a, double t) const
  {
    return a.s_ref_m + a.direction * a.profile.at(t);
  }

  /// Path arc length per metre of a lane \a lateral_m left of the path near s: > 1 on
  /// the inside of a left bend (the lane is shorter there).
  double stretch(double s, double lateral_m) const
  {
    double x, y, h0, h1;
    pathAt(s - 2.0, x, y, h0);
    pathAt(s + 2.0, x, y, h1);
    const double curvature = std::remainder(h1 - h0, 2.0 * kPi) / 4.0;
    return 1.0 / std::clamp(1.0 - lateral_m * curvature, 0.2, 1.0);
  }

  /// Arc lengths of a lane's free vehicles at t: none closer than a bumper gap to the
  /// one ahead, measured along the lane (a safety net: their profiles already queue at
  /// the lights).
  void
  lanePositions(const std::vector<Agent>& lane, double t, std::vector<double>& s) const
  {
    s.clear();
    for (std::size_t i = 0; i < lane.size(); ++i) {
      double u = lane[i].direction * freeS(lane[i], t);
      if (i > 0) {
        const double ahead_u = lane[i - 1].direction * s.back();
        const double gap_m =
            0.5 * (lane[i - 1].shape.length_m + lane[i].shape.length_m) + kLaneMarginM;
        if (u > ahead_u - 3.0 * gap_m) // near: measure along the lane
          u = std::min(u,
                       ahead_u -
                           gap_m * std::max(stretch(s.back(), lane[i].lateral_m),
                                            stretch(lane[i].direction * (ahead_u - gap_m),
                                                    lane[i].lateral_m)));
      }
      s.push_back(lane[i].direction * u);
    }
  }

  /// Companion k's arc length at t; \a earlier holds those of companions 0..k-1.
  double companionS(const Agent& a, double t, const std::vector<double>& earlier) const
  {
    const EgoStop& stop = stops[a.stop];
    double s;
    if (t <= a.join_s) // cruising with the lane (the ego catches up or is caught up)
      s = egoS(a.join_s) + a.offset_m - a.v_mps * (a.join_s - t);
    else if (t <= stop.from_s) // braking with the ego
      s = egoS(t) + a.offset_m;
    else // standing beside it, then pulling away
      s = stop.s_m + a.offset_m + startFromRest(t - a.go_s, a.accel_mps2, a.v_mps);
    if (a.leader >= 0)
      s = std::min(s,
                   earlier[a.leader] -
                       0.5 * (companions[a.leader].shape.length_m + a.shape.length_m) -
                       kLaneMarginM);
    return s;
  }

  void companionPositions(double t, std::vector<double>& s) const
  {
    s.clear();
    for (const Agent& a : companions)
      s.push_back(companionS(a, t, s));
  }

  void findStops(const PoseVector& poses, std::uint64_t seed);
  void placeCompanions(std::uint64_t seed);
  void placeFreeLane(std::uint64_t seed, int direction);
  void placeCrossTraffic(std::uint64_t seed);
  bool clearOfCompanions(const Agent& a) const;
};

void
TrafficModel::Impl::findStops(const PoseVector& poses, std::uint64_t seed)
{
  // Arc length per frame as SimulatedWorld's path samples measure it (2D).
  ego_s.assign(poses.size(), 0.0);
  for (std::size_t i = 1; i < poses.size(); ++i)
    ego_s[i] = ego_s[i - 1] +
               (poses[i].translation() - poses[i - 1].translation()).head<2>().norm();
  // A stop: consecutive frames slower than 0.25 m/s (ground truth of a standing car
  // jitters by millimetres) for at least light_stop_min_s.
  auto still = [&](std::size_t k) {
    return k + 1 < poses.size() &&
           ego_s[k + 1] - ego_s[k] < kStandingMps * (ego_t[k + 1] - ego_t[k]);
  };
  for (std::size_t i = 0; i < poses.size();) {
    if (!still(i)) {
      ++i;
      continue;
    }
    std::size_t j = i + 1; // frames i..j stand
    while (still(j))
      ++j;
    if (ego_t[j] - ego_t[i] >= params.light_stop_min_s) {
      const Eigen::Vector3d x = poses[i].linear().col(0);
      const Eigen::Vector2d forward = Eigen::Vector2d(x.x(), x.y()).normalized();
      Draw draw(seed, 6, stops.size());
      stops.push_back({ego_t[i],
                       ego_t[j],
                       ego_s[i],
                       poses[i].translation().head<2>(),
                       forward,
                       draw(10.0, 25.0)});
    }
    i = j + 1;
  }
}

void
TrafficModel::Impl::placeCompanions(std::uint64_t seed)
{
  for (std::size_t k = 0; k < stops.size(); ++k) {
    const EgoStop& stop = stops[k];
    for (int m = 0; m < params.companions_per_stop; ++m) {
      Draw draw(seed, 1, k * 16 + m);
      Agent a;
      a.shape = drawVehicle(draw, 0.0);
      a.stop = static_cast<int>(k);
      a.lateral_m = lane_offset_m;
      if (m == 0) { // beside the ego, its front at most ~3 m ahead of the ego's centre
        a.offset_m = draw(-2.5, 0.5);
        a.go_s = stop.to_s + (draw(0.0, 1.0) < 0.5 ? -draw(0.7, 1.5) : draw(0.7, 2.5));
      } else {
        const Agent& ahead = companions.back();
        a.leader = static_cast<int>(companions.size()) - 1;
        a.offset_m = ahead.offset_m - 0.5 * (ahead.shape.length_m + a.shape.length_m) -
                     kLaneMarginM - draw(0.0, 1.5);
        a.go_s = ahead.go_s + draw(0.6, 1.5);
      }
      a.join_s = stop.from_s - draw(3.0, 6.0);
      a.accel_mps2 = draw(1.2, 3.0);
      a.v_mps = lane_speed_mps[0];
      // Each stop's companions drive from halfway since the previous stop to halfway
      // to the next (they appear and vanish there).
      if (k > 0)
        a.from_s = 0.5 * (stops[k - 1].to_s + stop.from_s);
      if (k + 1 < stops.size())
        a.to_s = 0.5 * (stop.to_s + stops[k + 1].from_s);
      companions.push_back(a);
    }
  }
  // Their tracks over the drive, for keeping free traffic off them.
  std::vector<double> s;
  for (std::size_t i = 0; i < companions.size(); ++i) {
    const Agent& c = companions[i];
    companion_tracks.emplace_back();
    for (double t = std::max(c.from_s, ego_t.front() - 5.0);
         t <= std::min(c.to_s, ego_t.back() + 5.0);
         t += 0.1) {
      companionPositions(t, s);
      companion_tracks.back().push_back({t, s[i]});
    }
  }
}

bool
TrafficModel::Impl::clearOfCompanions(const Agent& a) const
{
  if (a.direction < 0)
    return true;
  for (std::size_t i = 0; i < companions.size(); ++i)
    for (const auto& [t, s] : companion_tracks[i])
      if (std::abs(freeS(a, t) - s) <
          0.5 * (a.shape.length_m + companions[i].shape.length_m) + 2.0 * kLaneMarginM)
        return false;
  return true;
}

void
TrafficModel::Impl::placeFreeLane(std::uint64_t seed, int direction)
{
  const bool same = direction > 0;
  const double v_lane = lane_speed_mps[same ? 0 : 1];
  const double gap_mean = same ? params.same_direction_gap_m : params.oncoming_gap_m;
  const double t0 = ego_t.front(), duration_s = ego_t.back() - t0;
  const double length_m = path.back().s_m;
  // Queues at the lights, in driving coordinates u = direction * s: where the next
  // vehicle's front stops and when the one before it went. The same way queues behind
  // the companions; the oncoming way beyond the cross road.
  std::vector<double> tail_u, last_go_s;
  for (std::size_t k = 0; k < stops.size(); ++k) {
    const EgoStop& stop = stops[k];
    double tail = same ? stop.s_m + 2.5 : -(stop.s_m + stop.cross_m + 5.0);
    double go = stop.to_s;
    for (const Agent& c : companions)
      if (same && c.stop == static_cast<int>(k)) {
        tail =
            std::min(tail, stop.s_m + c.offset_m - 0.5 * c.shape.length_m - kLaneMarginM);
        go = std::max(go, c.go_s);
      }
    tail_u.push_back(tail);
    last_go_s.push_back(go);
  }
  // Positions at the first frame, front to back, such that the lane is populated along
  // the path at every time.
  const double travel_m = v_lane * duration_s + kLaneWindowM;
  const double u_front = same ? length_m + kLaneWindowM : kLaneWindowM;
  const double u_back = same ? -travel_m : -(length_m + travel_m);
  std::vector<Agent>& lane = lanes[same ? 0 : 1];
  double u = u_front, prev_half = 0.0;
  for (std::uint64_t k = 0;; ++k) {
    Draw draw(seed, same ? 4 : 5, k);
    Agent a;
    a.shape = drawVehicle(draw, params.heavy_vehicle_fraction);
    u -= prev_half + 0.5 * a.shape.length_m + kLaneMarginM + gap_mean * draw(0.2, 1.8);
    if (u < u_back)
      break;
    prev_half = 0.5 * a.shape.length_m;
    a.direction = direction;
    a.lateral_m = same ? lane_offset_m : params.oncoming_lane_offset_m;
    a.s_ref_m = direction * u;
    a.v_mps = v_lane;
    a.profile = MotionProfile(t0, 0.0, v_lane);
    // Red while the ego stands: a vehicle arriving then joins the queue and goes a
    // little after the one before it.
    for (std::size_t j = 0; j < stops.size(); ++j) {
      const double stop_u = tail_u[j] - 0.5 * a.shape.length_m; // its centre
      const double arrive_s = a.profile.cruiseTimeAt(stop_u - u);
      if (arrive_s < stops[j].from_s - 4.0 || arrive_s > stops[j].to_s - 0.5)
        continue;
      const double go_s = last_go_s[j] + draw(0.8, 1.5);
      if (!a.profile.addStop(stop_u - u, draw(1.5, 3.0), go_s, draw(1.2, 2.5)))
        continue;
      tail_u[j] -= a.shape.length_m + kLaneMarginM;
      last_go_s[j] = go_s;
    }
    if (clearOfCompanions(a))
      lane.push_back(a);
  }
}

void
TrafficModel::Impl::placeCrossTraffic(std::uint64_t seed)
{
  for (std::size_t k = 0; k < stops.size(); ++k) {
    const EgoStop& stop = stops[k];
    Draw road(seed, 8, k);
    const Eigen::Vector2d ahead = stop.forward;
    const Eigen::Vector2d left(-ahead.y(), ahead.x());
    const Eigen::Vector2d centre = stop.xy + stop.cross_m * ahead;
    for (int direction : {1, -1}) {
      // Right-hand traffic: a car heading left drives in the far lane.
      const Eigen::Vector2d lane = centre + direction * 1.75 * ahead;
      const Eigen::Vector2d dir = direction * left;
      double centre_s = stop.from_s + road(0.5, 2.0);
      const Agent* prev = nullptr;
      for (std::uint64_t m = 0; centre_s <= stop.to_s - 2.5; ++m) {
        Draw draw(seed, 7, (k * 2 + (direction > 0)) * 1024 + m);
        Agent a;
        a.shape = drawVehicle(draw, params.heavy_vehicle_fraction);
        a.v_mps = draw(8.0, 14.0);
        a.dir = dir;
        a.origin = lane;
        // Keep a bumper gap to the car ahead: the gap changes linearly, so check it
        // where both exist first and last.
        for (;; centre_s += 0.5) {
          a.centre_s = centre_s;
          a.from_s = centre_s - kCrossHalfLengthM / a.v_mps;
          a.to_s = centre_s + kCrossHalfLengthM / a.v_mps;
          if (!prev)
            break;
          const double need =
              0.5 * (prev->shape.length_m + a.shape.length_m) + kLaneMarginM;
          const double t0 = std::max(prev->from_s, a.from_s),
                       t1 = std::min(prev->to_s, a.to_s);
          auto gap = [&](double t) {
            return prev->v_mps * (t - prev->centre_s) - a.v_mps * (t - a.centre_s);
          };
          if (t0 > t1 || (gap(t0) >= need && gap(t1) >= need))
            break;
        }
        if (centre_s > stop.to_s - 2.5)
          break;
        cross.push_back(a);
        prev = &cross.back();
        centre_s += draw(2.0, 4.5);
      }
    }
  }
}

TrafficModel::TrafficModel(const TrafficParams& params,
                           double lane_offset_m,
                           std::vector<TrafficPathPoint> path,
                           const PoseVector& T_world_body,
                           const std::vector<double>& timestamps_s,
                           std::uint64_t seed,
                           std::uint64_t drive_seed)
    : impl_(std::make_unique<Impl>())
{
  Impl& m = *impl_;
  m.params = params;
  m.lane_offset_m = lane_offset_m;
  m.path = std::move(path);
  if (m.path.empty() || T_world_body.empty())
    throw std::invalid_argument("TrafficModel: empty path");
  m.ego_t = timestamps_s;
  if (m.ego_t.empty())
    for (std::size_t i = 0; i < T_world_body.size(); ++i)
      m.ego_t.push_back(0.1 * static_cast<double>(i));
  for (std::size_t i = 0; i < m.ego_t.size(); ++i)
    if (!std::isfinite(m.ego_t[i]) || (i > 0 && !(m.ego_t[i] > m.ego_t[i - 1])))
      throw std::invalid_argument("SimulatedWorld: realistic traffic needs finite, "
                                  "increasing timestamps, got timestamps_s[" +
                                  std::to_string(i) +
                                  "] = " + std::to_string(m.ego_t[i]));
  m.findStops(T_world_body, seed);
  // Headings from the poses' orientation, interpolated along the arc length: the
  // direction between two poses is noise where the ego stands (ground truth jitters by
  // millimetres), and the lanes beside it would spin.
  std::vector<double> yaw;
  for (const Pose3d& T : T_world_body)
    yaw.push_back(std::atan2(T.linear()(1, 0), T.linear()(0, 0)));
  for (TrafficPathPoint& p : m.path) {
    const std::size_t k =
        std::upper_bound(m.ego_s.begin(), m.ego_s.end(), p.s_m) - m.ego_s.begin();
    if (k == 0 || k == m.ego_s.size()) {
      p.heading_rad = yaw[k == 0 ? 0 : k - 1];
      continue;
    }
    const double f = (p.s_m - m.ego_s[k - 1]) / (m.ego_s[k] - m.ego_s[k - 1]);
    p.heading_rad = yaw[k - 1] + f * std::remainder(yaw[k] - yaw[k - 1], 2.0 * kPi);
  }
  // Where the path comes back to a place, the lanes of both passes meet: show lane
  // vehicles within less than half the shortest revisit (in arc length) of the ego.
  std::vector<const TrafficPathPoint*> coarse;
  for (const TrafficPathPoint& p : m.path)
    if (coarse.empty() || p.s_m - coarse.back()->s_m >= 2.0)
      coarse.push_back(&p);
  for (std::size_t i = 0; i < coarse.size(); ++i)
    for (std::size_t j = i + 1; j < coarse.size(); ++j)
      if (coarse[j]->s_m - coarse[i]->s_m > 60.0 &&
          std::hypot(coarse[j]->x_m - coarse[i]->x_m, coarse[j]->y_m - coarse[i]->y_m) <
              20.0)
        m.lane_window_m =
            std::min(m.lane_window_m, 0.45 * (coarse[j]->s_m - coarse[i]->s_m));

  // The stops (and the cross roads they open) are the world's; the vehicles are the
  // drive's.
  Draw lane_draw(drive_seed, 2, 0);
  m.lane_speed_mps[0] = lane_draw(9.0, 13.0);
  m.lane_speed_mps[1] = lane_draw(10.0, 14.0);
  m.placeCompanions(drive_seed);
  m.placeFreeLane(drive_seed, 1);
  m.placeFreeLane(drive_seed, -1);
  m.placeCrossTraffic(drive_seed);

  int id = 0;
  for (auto* group : {&m.companions, &m.lanes[0], &m.lanes[1], &m.cross})
    for (Agent& a : *group)
      a.shape.id = id++;
  for (auto* group : {&m.companions, &m.lanes[0]})
    for (Agent& a : *group)
      a.shape.lane = TrafficLane::kSameDirection;
  for (Agent& a : m.lanes[1])
    a.shape.lane = TrafficLane::kOncoming;
  for (Agent& a : m.cross)
    a.shape.lane = TrafficLane::kCross;
}

TrafficModel::~TrafficModel() = default;

double
TrafficModel::roadHalfWidth() const
{
  return impl_->params.oncoming_lane_offset_m + 1.5;
}

std::vector<CrossRoad>
TrafficModel::crossRoads() const
{
  std::vector<CrossRoad> roads;
  for (const EgoStop& stop : impl_->stops) {
    const Eigen::Vector2d left(-stop.forward.y(), stop.forward.x());
    // Two 3.5 m lanes and a pavement each side.
    roads.push_back(
        {stop.xy + stop.cross_m * stop.forward, left, kCrossHalfLengthM + 10.0, 6.0});
  }
  return roads;
}

std::vector<MovingVehicle>
TrafficModel::vehiclesAt(double time_s) const
{
  const Impl& m = *impl_;
  std::vector<MovingVehicle> out;
  double ex, ey, eh;
  const double ego_s = m.egoS(time_s);
  m.pathAt(ego_s, ex, ey, eh);
  const double ego_box[5] = {ex, ey, eh, 2.6, 1.3};
  auto emit = [&](const Agent& a, double x, double y, double yaw) {
    if (std::hypot(x - ex, y - ey) > kReachM)
      return;
    MovingVehicle v = a.shape;
    v.x_m = x;
    v.y_m = y;
    v.yaw_rad = yaw;
    out.push_back(v);
  };
  auto emitOnLane = [&](const Agent& a, double s) {
    // Along the path near the ego only: a revisit of a place must not show the
    // vehicles of the other pass.
    if (std::abs(s - ego_s) > m.lane_window_m)
      return;
    double x, y, h;
    m.pathAt(s, x, y, h);
    x -= a.lateral_m * std::sin(h);
    y += a.lateral_m * std::cos(h);
    // In a bend much tighter than the lane offset (a turn at a crossing) the lane's
    // geometry folds onto the ego's: such a vehicle is not shown (ego 4.6 x 2 m plus
    // 0.3 m).
    const double vehicle[5] = {x, y, h, 0.5 * a.shape.length_m, 0.5 * a.shape.width_m};
    if (rectanglesOverlap(vehicle, ego_box))
      return;
    emit(a, x, y, a.direction > 0 ? h : h + kPi);
  };
  std::vector<double> s;
  m.companionPositions(time_s, s);
  for (std::size_t i = 0; i < m.companions.size(); ++i)
    if (time_s >= m.companions[i].from_s && time_s <= m.companions[i].to_s)
      emitOnLane(m.companions[i], s[i]);
  for (const auto& lane : m.lanes) {
    m.lanePositions(lane, time_s, s);
    for (std::size_t i = 0; i < lane.size(); ++i)
      emitOnLane(lane[i], s[i]);
  }
  for (const Agent& a : m.cross)
    if (time_s >= a.from_s && time_s <= a.to_s) {
      const Eigen::Vector2d p = a.origin + a.v_mps * (time_s - a.centre_s) * a.dir;
      emit(a, p.x(), p.y(), std::atan2(a.dir.y(), a.dir.x()));
    }
  return out;
}

} // namespace simulator_detail
} // namespace rast
} // namespace pcl
