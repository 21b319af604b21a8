/// \file world_build.cpp
/// \brief SimulatedWorld's construction steps: the path, its scenes, the distance field,
/// the ground, the ray grid and the moving cars.

#include "world_impl.h"

namespace pcl {
namespace rast {

void
SimulatedWorld::Impl::buildPath(const PoseVector& poses, double body_height_m)
{
  // Dense samples (<= 1 m apart) of the path, each with the ground height below it.
  body_height = body_height_m;
  auto yawOf = [](const Pose3d& T) {
    const Eigen::Vector3d x = T.linear().col(0);
    return std::atan2(x.y(), x.x());
  };
  double s = 0.0;
  for (std::size_t i = 0; i < poses.size(); ++i) {
    const Eigen::Vector3d a = poses[i].translation();
    if (i + 1 == poses.size()) {
      const double h = path.empty() ? yawOf(poses[i]) : path.back().heading;
      path.push_back({a.x(), a.y(), a.z() - body_height_m, h, s});
      break;
    }
    const Eigen::Vector3d b = poses[i + 1].translation();
    const double len = (b - a).head<2>().norm();
    const double h =
        len > 1e-3 ? std::atan2(b.y() - a.y(), b.x() - a.x()) : yawOf(poses[i]);
    const int n = std::max(1, static_cast<int>(std::ceil(len / 1.0)));
    for (int k = 0; k < n; ++k) {
      const double f = static_cast<double>(k) / n;
      const Eigen::Vector3d p = a + f * (b - a);
      path.push_back({p.x(), p.y(), p.z() - body_height_m, h, s + f * len});
    }
    s += len;
  }
}

void
SimulatedWorld::Impl::buildScenes()
{
  // Stretches by arc length; each path sample knows its own.
  const double length = path.back().s;
  if (!params.mixed_scenes) {
    stretches = {{0.0, params.scene}};
  } else {
    // Shares along a drive, roughly as a drive meets them: suburb 35 %, urban canyon
    // 25 %, highway 20 %, open field 10 %, tunnel 10 %. The drive starts in a suburb
    // or an urban canyon (a scan with structure: no odometry can tell its speed from
    // a first scan in a tunnel), and a stretch never repeats the previous type.
    constexpr double kShare[5] = {0.35, 0.25, 0.20, 0.10, 0.10}; // SceneType order
    Rng rng(hashOf(seed, 200));
    int prev = -1;
    for (double s = 0.0; s <= length;) {
      const int allowed = prev < 0 ? 2 : 5; // the first stretch: suburb or urban
      double total = 0.0;
      for (int t = 0; t < allowed; ++t)
        total += t == prev ? 0.0 : kShare[t];
      double u = rng.uniform() * total;
      int type = 0;
      for (int t = 0; t < allowed; ++t) {
        if (t == prev)
          continue;
        type = t;
        if (u < kShare[t])
          break;
        u -= kShare[t];
      }
      stretches.push_back({s, static_cast<SceneType>(type)});
      prev = type;
      s += rng.uniform(params.scene_min_length_m, params.scene_max_length_m);
    }
  }
  // A place driven again keeps the scene of its first visit: every 2 m cell within 6 m
  // of the path remembers the first sample near it, and a sample takes that sample's
  // stretch (the same stretch, or the previous one near its start, on a first visit).
  std::vector<std::uint32_t> own(path.size());
  std::size_t k = 0;
  for (std::size_t i = 0; i < path.size(); ++i) {
    while (k + 1 < stretches.size() && stretches[k + 1].s_begin <= path[i].s)
      ++k;
    own[i] = static_cast<std::uint32_t>(k);
  }
  const Grid2& g = dist_grid;
  std::vector<std::uint32_t> first_visit(static_cast<std::size_t>(g.nx) * g.ny,
                                         std::numeric_limits<std::uint32_t>::max());
  sample_stretch.resize(path.size());
  for (std::size_t i = 0; i < path.size(); ++i) {
    const int ci = g.ix(path[i].x), cj = g.iy(path[i].y);
    for (int j = std::max(0, cj - 3); j <= std::min(g.ny - 1, cj + 3); ++j)
      for (int c = std::max(0, ci - 3); c <= std::min(g.nx - 1, ci + 3); ++c) {
        auto& f = first_visit[g.index(c, j)];
        f = std::min(f, static_cast<std::uint32_t>(i));
      }
    sample_stretch[i] = own[first_visit[g.index(ci, cj)]];
  }
  plain = stretches.size() == 1 && stretches[0].type == SceneType::kSuburb;
  for (const auto& st : stretches)
    has_highway = has_highway || st.type == SceneType::kHighway;
  if (params.rough_ground)
    roughness = GroundRoughness(hashOf(seed, 201), params.ground_roughness_std_m);
}

Grid2
SimulatedWorld::Impl::gridAroundPath(double cell, double margin) const
{
  double min_x = kInf, min_y = kInf, max_x = -kInf, max_y = -kInf;
  for (const auto& p : path) {
    min_x = std::min(min_x, p.x);
    min_y = std::min(min_y, p.y);
    max_x = std::max(max_x, p.x);
    max_y = std::max(max_y, p.y);
  }
  Grid2 g;
  g.cell = cell;
  g.x0 = min_x - margin;
  g.y0 = min_y - margin;
  g.nx = static_cast<int>(std::ceil((max_x - min_x + 2 * margin) / cell)) + 1;
  g.ny = static_cast<int>(std::ceil((max_y - min_y + 2 * margin) / cell)) + 1;
  return g;
}

void
SimulatedWorld::Impl::buildDistanceField()
{
  const double margin = params.max_object_distance_m + 24.0;
  dist_grid = gridAroundPath(2.0, margin);
  ground_grid = gridAroundPath(4.0, margin);
  ray_grid = gridAroundPath(8.0, margin);

  const std::size_t n = static_cast<std::size_t>(dist_grid.nx) * dist_grid.ny;
  // Far cells keep a large finite value (not infinity: interpolation weights of 0).
  dist.assign(n, 1e6f);
  heading.assign(n, 0.0f);
  nearest.assign(n, 0);
  // Stamp every sample into the cells within reach (exact distances to samples).
  const double reach = params.max_object_distance_m + 12.0;
  const int r = static_cast<int>(std::ceil(reach / dist_grid.cell));
  for (std::size_t k = 0; k < path.size(); ++k) {
    const auto& p = path[k];
    const int ci = dist_grid.ix(p.x), cj = dist_grid.iy(p.y);
    for (int j = std::max(0, cj - r); j <= std::min(dist_grid.ny - 1, cj + r); ++j) {
      const double y = dist_grid.y0 + (j + 0.5) * dist_grid.cell - p.y;
      for (int i = std::max(0, ci - r); i <= std::min(dist_grid.nx - 1, ci + r); ++i) {
        const double x = dist_grid.x0 + (i + 0.5) * dist_grid.cell - p.x;
        const float d = static_cast<float>(std::sqrt(x * x + y * y));
        const std::size_t idx = dist_grid.index(i, j);
        if (d < dist[idx]) {
          dist[idx] = d;
          heading[idx] = static_cast<float>(p.heading);
          nearest[idx] = static_cast<std::uint32_t>(k);
        }
      }
    }
  }
}

void
SimulatedWorld::Impl::assignGroundLevels()
{
  // Greedy, in path order: a sample keeps its predecessor's level unless a sample of
  // another pass on that level conflicts with it (conflictsWithLevel, over the samples
  // listed so far), else takes the lowest free one.
  constexpr int kMaxLevels = 3;
  level_grid = gridAroundPath(kLevelReach, kLevelReach);
  const Grid2& g = level_grid;
  level_cells.assign(static_cast<std::size_t>(g.nx) * g.ny, {});
  int levels = 1;
  for (std::size_t k = 0; k < path.size(); ++k) {
    int level = k > 0 ? path[k - 1].level : 0;
    for (int l = 0; conflictsWithLevel(k, level) && l < kMaxLevels; ++l)
      level = l;
    if (conflictsWithLevel(k, level)) // every level taken here: the least bad, the last
      level = kMaxLevels - 1;
    path[k].level = level;
    levels = std::max(levels, level + 1);
    level_cells[g.index(g.ix(path[k].x), g.iy(path[k].y))].push_back(
        static_cast<std::uint32_t>(k));
  }
  if (levels == 1) { // the usual case: no lookups needed
    level_cells.clear();
    return;
  }
  upper_ground.resize(static_cast<std::size_t>(levels - 1));
}

bool
SimulatedWorld::Impl::conflictsWithLevel(std::size_t k, int level) const
{
  // A conflict: within kLevelReach horizontally, more than kLevelRise apart in ground
  // height, and more than kOtherPass of path apart (a slope never conflicts with
  // itself).
  constexpr double kOtherPass = 100.0;
  const PathSample& p = path[k];
  const Grid2& g = level_grid;
  const int ci = g.ix(p.x), cj = g.iy(p.y);
  for (int j = std::max(0, cj - 1); j <= std::min(g.ny - 1, cj + 1); ++j)
    for (int i = std::max(0, ci - 1); i <= std::min(g.nx - 1, ci + 1); ++i)
      for (const std::uint32_t o : level_cells[g.index(i, j)]) {
        const PathSample& q = path[o];
        if (q.level == level && std::abs(p.s - q.s) > kOtherPass &&
            std::abs(p.ground_z - q.ground_z) > kLevelRise &&
            (p.x - q.x) * (p.x - q.x) + (p.y - q.y) * (p.y - q.y) <
                kLevelReach * kLevelReach)
          return true;
      }
  return false;
}

int
SimulatedWorld::Impl::levelOfOrigin(const Eigen::Vector3d& o) const
{
  if (upper_ground.empty())
    return 0;
  const Grid2& g = level_grid;
  const int ci = g.ix(o.x()), cj = g.iy(o.y());
  double best = kInf;
  int level = 0;
  for (int j = std::max(0, cj - 1); j <= std::min(g.ny - 1, cj + 1); ++j)
    for (int i = std::max(0, ci - 1); i <= std::min(g.nx - 1, ci + 1); ++i)
      for (const std::uint32_t k : level_cells[g.index(i, j)]) {
        const PathSample& p = path[k];
        const double dz = o.z() - body_height - p.ground_z;
        const double d2 =
            (o.x() - p.x) * (o.x() - p.x) + (o.y() - p.y) * (o.y() - p.y) + dz * dz;
        if (d2 < best) {
          best = d2;
          level = p.level;
        }
      }
  return level;
}

void
SimulatedWorld::Impl::buildGround()
{
  // Shepard (inverse-distance) blend of the path's ground heights,
  // w = 1 / (d^2 + s^2)^2 within 60 m: the nearest samples dominate, so the ground
  // passes ~exactly below every pose, and it is smooth in between. Nodes out of reach
  // take their neighbours' value (breadth-first fill). One field per ground level:
  // level L's leaves out the samples of other levels that conflict with it.
  assignGroundLevels();
  const Grid2& g = ground_grid;
  const std::size_t n = static_cast<std::size_t>(g.nx) * g.ny;
  const double soft2 = params.ground_smoothing_m * params.ground_smoothing_m;
  const double reach = 60.0;
  const int r = static_cast<int>(std::ceil(reach / g.cell));
  auto blend = [&](int level) {
    std::vector<double> wsum(n, 0.0), hsum(n, 0.0);
    for (std::size_t k = 0; k < path.size(); ++k) {
      const PathSample& p = path[k];
      if (p.level != level && conflictsWithLevel(k, level))
        continue;
      const int ci = static_cast<int>(std::lround((p.x - g.x0) / g.cell));
      const int cj = static_cast<int>(std::lround((p.y - g.y0) / g.cell));
      for (int j = std::max(0, cj - r); j <= std::min(g.ny - 1, cj + r); ++j)
        for (int i = std::max(0, ci - r); i <= std::min(g.nx - 1, ci + r); ++i) {
          const double dx = g.x0 + i * g.cell - p.x, dy = g.y0 + j * g.cell - p.y;
          const double d2 = dx * dx + dy * dy;
          if (d2 > reach * reach)
            continue;
          const double w = 1.0 / ((d2 + soft2) * (d2 + soft2));
          wsum[g.index(i, j)] += w;
          hsum[g.index(i, j)] += w * p.ground_z;
        }
    }
    std::vector<double> field(n, 0.0);
    std::vector<char> known(n, 0);
    std::queue<std::size_t> todo;
    for (std::size_t i = 0; i < n; ++i)
      if (wsum[i] > 0.0) {
        field[i] = hsum[i] / wsum[i];
        known[i] = 1;
        todo.push(i);
      }
    while (!todo.empty()) {
      const std::size_t idx = todo.front();
      todo.pop();
      const int i = static_cast<int>(idx % g.nx), j = static_cast<int>(idx / g.nx);
      const int nb[4][2] = {{i - 1, j}, {i + 1, j}, {i, j - 1}, {i, j + 1}};
      for (const auto& q : nb) {
        if (q[0] < 0 || q[1] < 0 || q[0] >= g.nx || q[1] >= g.ny)
          continue;
        const std::size_t k = g.index(q[0], q[1]);
        if (!known[k]) {
          known[k] = 1;
          field[k] = field[idx];
          todo.push(k);
        }
      }
    }
    raiseEmbankments(field);
    return field;
  };
  ground = blend(0);
  for (std::size_t l = 0; l < upper_ground.size(); ++l)
    upper_ground[l] = blend(static_cast<int>(l) + 1);
}

void
SimulatedWorld::Impl::raiseEmbankments(std::vector<double>& field) const
{
  // Highway stretches: on each side (drawn per stretch: one or both) an earth bank
  // whose toe is 12-15 m from the path, rising 1:2 to a 3-6 m plateau 10-30 m wide and
  // falling back. Baked into the 4 m ground nodes, so the road itself stays level.
  if (!has_highway)
    return;
  struct Bank
  {
    double toe_m = 0, height_m = 0, plateau_m = 0;
  };
  std::vector<std::array<Bank, 2>> banks(stretches.size());
  for (std::size_t k = 0; k < stretches.size(); ++k) {
    Rng rng(hashOf(seed, 202, static_cast<std::int64_t>(k)));
    const double which = rng.uniform(); // < 0.4 left only, < 0.8 right only, else both
    for (int side = 0; side < 2; ++side) {
      Bank& b = banks[k][side];
      b.toe_m = rng.uniform(12.0, 15.0);
      b.height_m = rng.uniform(3.0, 6.0);
      b.plateau_m = rng.uniform(10.0, 30.0);
      if ((side == 0 && which >= 0.4 && which < 0.8) || (side == 1 && which < 0.4))
        b.height_m = 0.0;
    }
  }
  const Grid2& g = ground_grid;
  for (int j = 0; j < g.ny; ++j)
    for (int i = 0; i < g.nx; ++i) {
      const double x = g.x0 + i * g.cell, y = g.y0 + j * g.cell;
      const std::size_t cell = dist_grid.index(dist_grid.ix(x), dist_grid.iy(y));
      if (dist[cell] > 1e5f)
        continue;
      const std::size_t k = nearest[cell];
      if (sceneOfSample(k) != SceneType::kHighway)
        continue;
      const PathSample& ps = path[k];
      const double lateral =
          (x - ps.x) * -std::sin(ps.heading) + (y - ps.y) * std::cos(ps.heading);
      const Bank& b = banks[sample_stretch[k]][lateral >= 0 ? 0 : 1];
      const double d = distanceAt(x, y);
      const double up = d - b.toe_m, down = b.toe_m + 4.0 * b.height_m + b.plateau_m - d;
      field[g.index(i, j)] += std::clamp(0.5 * std::min(up, down), 0.0, b.height_m);
    }
}

bool
SimulatedWorld::Impl::clearOfCorridor(const Primitive& p, double margin) const
{
  // The 2 m distance field interpolates a 1-Lipschitz function: its error is below
  // the half cell diagonal (1.42 m), covered by the 1.5 m slack added here.
  const double min_d = params.corridor_half_width_m + margin + 1.5;
  if (p.kind != Kind::kBox)
    return distanceAt(p.cx, p.cy) - p.hx > min_d;
  // Sample the footprint's outline every <= 1.5 m.
  const double ex[2] = {p.c, p.s}, ey[2] = {-p.s, p.c};
  const int corners[5][2] = {{1, 1}, {-1, 1}, {-1, -1}, {1, -1}, {1, 1}};
  for (int e = 0; e < 4; ++e) {
    const double ax = corners[e][0] * p.hx, ay = corners[e][1] * p.hy;
    const double bx = corners[e + 1][0] * p.hx, by = corners[e + 1][1] * p.hy;
    const int n =
        std::max(1, static_cast<int>(std::ceil(std::hypot(bx - ax, by - ay) / 1.5)));
    for (int k = 0; k < n; ++k) {
      const double f = static_cast<double>(k) / n;
      const double lx = ax + f * (bx - ax), ly = ay + f * (by - ay);
      const double x = p.cx + lx * ex[0] + ly * ey[0], y = p.cy + lx * ex[1] + ly * ey[1];
      if (distanceAt(x, y) <= min_d)
        return false;
    }
  }
  return true;
}

void
SimulatedWorld::Impl::addCar(
    double x, double y, double yaw, Rng& rng, std::vector<Primitive>& out) const
{
  const double length = rng.uniform(3.8, 4.9), width = rng.uniform(1.7, 1.95);
  const float refl = static_cast<float>(rng.uniform(0.1, 0.9));
  const double g = groundAt(x, y);
  out.push_back(makeBox(x, y, g + 0.25, g + 1.0, length, width, yaw, refl));
  const double back = -0.08 * length;
  out.push_back(makeBox(x + back * std::cos(yaw),
                        y + back * std::sin(yaw),
                        g + 1.0,
                        g + rng.uniform(1.4, 1.6),
                        0.55 * length,
                        0.9 * width,
                        yaw,
                        refl));
}

void
SimulatedWorld::Impl::buildRayGrid()
{
  const Grid2& g = ray_grid;
  const std::size_t n = static_cast<std::size_t>(g.nx) * g.ny;
  std::vector<std::uint32_t> count(n + 1, 0);
  auto cellsOf = [&](const Primitive& p, auto&& visit) {
    // The footprint's bounding box: for a box its rotated rectangle's, much tighter
    // than the enclosing circle for long walls.
    const double rx = p.kind == Kind::kBox ? std::abs(p.c) * p.hx + std::abs(p.s) * p.hy
                                           : p.footprintRadius();
    const double ry = p.kind == Kind::kBox ? std::abs(p.s) * p.hx + std::abs(p.c) * p.hy
                                           : p.footprintRadius();
    for (int j = g.iy(p.cy - ry); j <= g.iy(p.cy + ry); ++j)
      for (int i = g.ix(p.cx - rx); i <= g.ix(p.cx + rx); ++i)
        visit(g.index(i, j));
  };
  for (const auto& p : prims)
    cellsOf(p, [&](std::size_t c) { ++count[c + 1]; });
  cell_start.assign(n + 1, 0);
  for (std::size_t c = 0; c < n; ++c)
    cell_start[c + 1] = cell_start[c] + count[c + 1];
  cell_items.assign(cell_start[n], 0);
  cell_top.assign(n, -std::numeric_limits<float>::infinity());
  std::vector<std::uint32_t> fill(cell_start.begin(), cell_start.end() - 1);
  for (std::size_t k = 0; k < prims.size(); ++k) {
    const Primitive& p = prims[k];
    max_top = std::max(max_top, p.top());
    cellsOf(p, [&](std::size_t c) {
      cell_items[fill[c]++] = static_cast<std::uint32_t>(k);
      cell_top[c] = std::max(cell_top[c], static_cast<float>(p.top()) + 0.01f);
    });
  }
}

void
SimulatedWorld::Impl::placeMovingCars(const PoseVector& poses,
                                      const std::vector<double>& timestamps_s)
{
  if (!params.moving_cars || path.size() < 2)
    return;
  if (params.traffic.mode == TrafficMode::kRealistic) {
    std::vector<simulator_detail::TrafficPathPoint> points;
    points.reserve(path.size());
    for (const auto& p : path)
      points.push_back({p.x, p.y, p.heading, p.s});
    traffic = std::make_unique<simulator_detail::TrafficModel>(params.traffic,
                                                               params.lane_offset_m,
                                                               std::move(points),
                                                               poses,
                                                               timestamps_s,
                                                               seed,
                                                               drive_seed);
    return;
  }
  Rng rng(hashOf(drive_seed, 7));
  const double length = path.back().s;
  for (int k = 0; k < params.num_moving_cars; ++k)
    cars.push_back({rng.uniform(0.0, length),
                    rng.uniform(5.0, 12.0),
                    rng.uniform(3.8, 4.9),
                    rng.uniform(1.7, 1.95),
                    rng.uniform() < 0.5 ? -1 : 1,
                    static_cast<float>(rng.uniform(0.1, 0.9))});
}

void
SimulatedWorld::Impl::clearCrossRoads()
{
  if (!traffic)
    return;
  // Static objects whose footprint circle reaches a cross road go: an intersection.
  for (const auto& road : traffic->crossRoads()) {
    auto onRoad = [&road](const Primitive& p) {
      const Eigen::Vector2d d = Eigen::Vector2d(p.cx, p.cy) - road.centre_xy;
      const double along = std::abs(d.dot(road.along));
      const double across = std::abs(d.x() * road.along.y() - d.y() * road.along.x());
      const double r = p.footprintRadius();
      return along < road.half_length_m + r && across < road.half_width_m + r;
    };
    prims.erase(std::remove_if(prims.begin(), prims.end(), onRoad), prims.end());
  }
}

std::vector<MovingVehicle>
SimulatedWorld::Impl::movingVehicles(double time_s) const
{
  if (traffic)
    return traffic->vehiclesAt(time_s);
  std::vector<MovingVehicle> vehicles;
  if (cars.empty())
    return vehicles;
  const double length = path.back().s;
  for (const auto& car : cars) {
    // Drive back and forth along the path (ping-pong at its ends).
    double s = std::fmod(car.s0 + car.direction * car.speed_mps * time_s, 2.0 * length);
    if (s < 0)
      s += 2.0 * length;
    bool reversed = car.direction < 0;
    if (s > length) {
      s = 2.0 * length - s;
      reversed = !reversed;
    }
    const auto it =
        std::lower_bound(path.begin(), path.end(), s, [](const PathSample& p, double v) {
          return p.s < v;
        });
    const PathSample& ps = it == path.end() ? path.back() : *it;
    const double nx = -std::sin(ps.heading), ny = std::cos(ps.heading);
    MovingVehicle v;
    v.id = static_cast<int>(vehicles.size());
    v.x_m = ps.x + params.lane_offset_m * nx;
    v.y_m = ps.y + params.lane_offset_m * ny;
    v.yaw_rad = ps.heading + (reversed ? kPi : 0.0);
    v.length_m = car.length;
    v.width_m = car.width;
    v.reflectivity = car.reflectivity;
    vehicles.push_back(v);
  }
  return vehicles;
}

std::vector<Primitive>
SimulatedWorld::Impl::movingCarBoxes(double time_s) const
{
  std::vector<Primitive> boxes;
  if (traffic) {
    std::vector<simulator_detail::VehicleBox> parts;
    for (const MovingVehicle& v : traffic->vehiclesAt(time_s)) {
      parts.clear();
      simulator_detail::vehicleBoxes(v, parts);
      const double g = groundAt(v.x_m, v.y_m);
      for (const auto& b : parts)
        boxes.push_back(makeBox(b.x_m,
                                b.y_m,
                                g + b.z_min_m,
                                g + b.z_max_m,
                                b.length_m,
                                b.width_m,
                                b.yaw_rad,
                                b.reflectivity));
    }
    return boxes;
  }
  for (const MovingVehicle& v : movingVehicles(time_s)) {
    const double g = groundAt(v.x_m, v.y_m);
    boxes.push_back(makeBox(v.x_m,
                            v.y_m,
                            g + 0.25,
                            g + 1.0,
                            v.length_m,
                            v.width_m,
                            v.yaw_rad,
                            v.reflectivity));
    boxes.push_back(makeBox(v.x_m,
                            v.y_m,
                            g + 1.0,
                            g + 1.5,
                            0.55 * v.length_m,
                            0.9 * v.width_m,
                            v.yaw_rad,
                            v.reflectivity));
  }
  return boxes;
}

} // namespace rast
} // namespace pcl
