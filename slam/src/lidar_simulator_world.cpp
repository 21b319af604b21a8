/// \file lidar_simulator_world.cpp
/// \brief SimulatedWorld: procedural world generation around a trajectory and ray
/// casting against it (ground height field + analytic primitives in a 2D grid).

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <pcl/slam/lidar_simulator.h>

#include "simulator_hash.h"
#include "simulator_traffic.h"
#include <queue>
#include <sstream>
#include <stdexcept>

namespace pcl {
namespace rast {

namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr double kInf = std::numeric_limits<double>::infinity();

// ---- deterministic hashing and random numbers (portable, no std distributions) ----

using simulator_detail::splitmix64;

std::uint64_t
hashOf(std::uint64_t a, std::int64_t b, std::int64_t c = 0, std::int64_t d = 0)
{
  std::uint64_t h = splitmix64(a);
  h = splitmix64(h ^ static_cast<std::uint64_t>(b));
  h = splitmix64(h ^ static_cast<std::uint64_t>(c));
  return splitmix64(h ^ static_cast<std::uint64_t>(d));
}

class Rng
{
public:
  explicit Rng(std::uint64_t seed) : state_(seed) {}
  double uniform()
  {
    state_ += 0x9E3779B97F4A7C15ULL;
    return static_cast<double>(splitmix64(state_) >> 11) * 0x1.0p-53;
  }
  double uniform(double lo, double hi) { return lo + (hi - lo) * uniform(); }

private:
  std::uint64_t state_;
};

// ---- primitives ----

enum class Kind : std::uint8_t
{
  kBox,      ///< yaw-oriented box: half extents (hx, hy, hz)
  kCylinder, ///< vertical cylinder: radius hx, half height hz
  kEllipsoid ///< axis-aligned ellipsoid: radii (hx, hx, hz)
};

struct Primitive
{
  Kind kind = Kind::kBox;
  float reflectivity = 0.3f;
  double cx = 0, cy = 0, cz = 0;
  double hx = 0, hy = 0, hz = 0;
  double c = 1, s = 0; // cos / sin of yaw (boxes)

  double top() const { return cz + hz; }
  /// Horizontal radius of a circle enclosing the footprint.
  double footprintRadius() const { return kind == Kind::kBox ? std::hypot(hx, hy) : hx; }
};

Primitive
makeBox(double cx,
        double cy,
        double z_min,
        double z_max,
        double length,
        double width,
        double yaw,
        float reflectivity)
{
  Primitive p;
  p.kind = Kind::kBox;
  p.cx = cx;
  p.cy = cy;
  p.cz = 0.5 * (z_min + z_max);
  p.hx = 0.5 * length;
  p.hy = 0.5 * width;
  p.hz = 0.5 * (z_max - z_min);
  p.c = std::cos(yaw);
  p.s = std::sin(yaw);
  p.reflectivity = reflectivity;
  return p;
}

/// Ray-primitive intersection: entry distance t in (t_min, t_max) and |cos incidence|.
bool
intersect(const Primitive& p,
          const Eigen::Vector3d& o,
          const Eigen::Vector3d& d,
          double t_min,
          double t_max,
          double& t_hit,
          double& cos_inc)
{
  const double ox = o.x() - p.cx, oy = o.y() - p.cy, oz = o.z() - p.cz;
  switch (p.kind) {
  case Kind::kBox: {
    // Slab test in the box frame (rotation about z by -yaw).
    const double lo[3] = {p.c * ox + p.s * oy, -p.s * ox + p.c * oy, oz};
    const double ld[3] = {p.c * d.x() + p.s * d.y(), -p.s * d.x() + p.c * d.y(), d.z()};
    const double h[3] = {p.hx, p.hy, p.hz};
    double t0 = -kInf, t1 = kInf;
    int axis = 0;
    for (int k = 0; k < 3; ++k) {
      if (std::abs(ld[k]) < 1e-12) {
        if (std::abs(lo[k]) > h[k])
          return false;
        continue;
      }
      const double inv = 1.0 / ld[k];
      double ta = (-h[k] - lo[k]) * inv, tb = (h[k] - lo[k]) * inv;
      if (ta > tb)
        std::swap(ta, tb);
      if (ta > t0) {
        t0 = ta;
        axis = k;
      }
      t1 = std::min(t1, tb);
      if (t0 > t1)
        return false;
    }
    if (t0 <= t_min || t0 >= t_max)
      return false;
    t_hit = t0;
    cos_inc = std::abs(ld[axis]);
    return true;
  }
  case Kind::kCylinder: {
    double best = kInf, best_cos = 1.0;
    const double a = d.x() * d.x() + d.y() * d.y();
    if (a > 1e-12) {
      const double b = ox * d.x() + oy * d.y();
      const double c = ox * ox + oy * oy - p.hx * p.hx;
      const double disc = b * b - a * c;
      if (disc < 0)
        return false;
      const double t = (-b - std::sqrt(disc)) / a;
      const double z = oz + t * d.z();
      if (t > t_min && std::abs(z) <= p.hz) {
        best = t;
        best_cos = std::abs((ox + t * d.x()) * d.x() + (oy + t * d.y()) * d.y()) / p.hx;
      }
    }
    if (d.z() < -1e-12 && oz > p.hz) { // top cap, seen from above
      const double t = (p.hz - oz) / d.z();
      const double x = ox + t * d.x(), y = oy + t * d.y();
      if (t > t_min && t < best && x * x + y * y <= p.hx * p.hx) {
        best = t;
        best_cos = std::abs(d.z());
      }
    }
    if (best >= t_max)
      return false;
    t_hit = best;
    cos_inc = best_cos;
    return true;
  }
  case Kind::kEllipsoid: {
    // Scale to the unit sphere; t is unchanged by scaling the direction too.
    const double sx = 1.0 / p.hx, sz = 1.0 / p.hz;
    const double qx = ox * sx, qy = oy * sx, qz = oz * sz;
    const double ex = d.x() * sx, ey = d.y() * sx, ez = d.z() * sz;
    const double a = ex * ex + ey * ey + ez * ez;
    const double b = qx * ex + qy * ey + qz * ez;
    const double c = qx * qx + qy * qy + qz * qz - 1.0;
    const double disc = b * b - a * c;
    if (disc < 0)
      return false;
    const double t = (-b - std::sqrt(disc)) / a;
    if (t <= t_min || t >= t_max)
      return false;
    Eigen::Vector3d n((ox + t * d.x()) * sx * sx,
                      (oy + t * d.y()) * sx * sx,
                      (oz + t * d.z()) * sz * sz);
    t_hit = t;
    cos_inc = std::abs(n.normalized().dot(d));
    return true;
  }
  }
  return false;
}

/// A regular 2D grid over the world's bounds.
struct Grid2
{
  double x0 = 0, y0 = 0, cell = 1;
  int nx = 0, ny = 0;

  int ix(double x) const
  {
    return std::clamp(static_cast<int>(std::floor((x - x0) / cell)), 0, nx - 1);
  }
  int iy(double y) const
  {
    return std::clamp(static_cast<int>(std::floor((y - y0) / cell)), 0, ny - 1);
  }
  std::size_t index(int i, int j) const { return static_cast<std::size_t>(j) * nx + i; }
};

struct PathSample
{
  double x, y, ground_z, heading, s;
};

struct MovingCar
{
  double s0, speed_mps, length, width;
  int direction;
  float reflectivity;
};

} // namespace

// ---- parameters ----

bool
WorldParams::isValid(std::string* why) const
{
  auto fail = [why](const std::string& msg) {
    if (why)
      *why = "WorldParams: " + msg;
    return false;
  };
  auto prob = [](double p) { return p >= 0.0 && p <= 1.0; };
  if (!(corridor_half_width_m >= 0.0 && corridor_half_width_m <= 50.0))
    return fail("corridor_half_width_m must be in [0, 50]");
  if (!(max_object_distance_m > corridor_half_width_m && max_object_distance_m <= 500.0))
    return fail("max_object_distance_m must be in (corridor_half_width_m, 500]");
  if (!prob(building_probability) || !prob(open_fraction) || !prob(tree_probability) ||
      !prob(pole_probability) || !prob(parked_car_probability) || !prob(wall_probability))
    return fail("probabilities must be in [0, 1]");
  if (!(tree_probability + pole_probability <= 1.0))
    return fail("tree_probability + pole_probability must be <= 1");
  if (!(ground_smoothing_m > 0.0 && ground_smoothing_m <= 200.0))
    return fail("ground_smoothing_m must be in (0, 200]");
  if (!traffic.isValid(why))
    return false;
  if (num_moving_cars < 0 || num_moving_cars > 1000)
    return fail("num_moving_cars must be in [0, 1000]");
  if (!(lane_offset_m >= 0.0 && lane_offset_m <= 50.0))
    return fail("lane_offset_m must be in [0, 50]");
  return true;
}

// ---- the world ----

struct SimulatedWorld::Impl
{
  WorldParams params;
  std::uint64_t seed = 0;
  std::vector<PathSample> path;

  Grid2 dist_grid; ///< 2 m: distance to the path and heading of the nearest sample
  std::vector<float> dist;
  std::vector<float> heading;
  std::vector<std::uint32_t> nearest;

  Grid2 ground_grid; ///< 4 m nodes of the ground height field
  std::vector<double> ground;

  std::vector<Primitive> prims;
  Grid2 ray_grid; ///< 4 m cells listing the primitives overlapping them
  std::vector<std::uint32_t> cell_start, cell_items;
  std::vector<float> cell_top;
  double max_top = -kInf;

  std::vector<MovingCar> cars;                             ///< TrafficMode::kAlongPath
  std::unique_ptr<simulator_detail::TrafficModel> traffic; ///< TrafficMode::kRealistic

  // -- construction steps --
  void buildPath(const PoseVector& poses, double body_height_m);
  void buildDistanceField();
  void buildGround();
  void placeObjects();
  void buildRayGrid();
  void placeMovingCars(const PoseVector& poses, const std::vector<double>& timestamps_s);
  void clearCrossRoads();

  // -- queries --
  double groundAt(double x, double y, double* gx = nullptr, double* gy = nullptr) const;
  double distanceAt(double x, double y) const;
  float headingAt(double x, double y) const
  {
    return heading[dist_grid.index(dist_grid.ix(x), dist_grid.iy(y))];
  }
  /// Ground below the origin (h0, gx0, gy0) is shared by all rays of a frame.
  bool groundHit(const Eigen::Vector3d& o,
                 const Eigen::Vector3d& d,
                 double t_max,
                 double h0,
                 double gx0,
                 double gy0,
                 double& t,
                 double& cos_inc) const;
  /// Moving vehicles and their boxes at time t.
  std::vector<MovingVehicle> movingVehicles(double time_s) const;
  std::vector<Primitive> movingCarBoxes(double time_s) const;
  /// Both castRays: ray r starts at origins[r] (kOwnOrigins) or all at origins[0].
  /// Each run of consecutive rays with the same origin shares the ground below it and
  /// the moving cars near it. A template so that one origin per frame costs what it
  /// did before rays had their own.
  template <bool kOwnOrigins>
  void castRays(const Eigen::Vector3d* origins,
                const std::vector<Eigen::Vector3d>& dirs,
                double max_range_m,
                double time_s,
                std::vector<RayHit>& hits) const;

  // -- helpers for placement --
  bool clearOfCorridor(const Primitive& p, double margin) const;
  void
  addCar(double x, double y, double yaw, Rng& rng, std::vector<Primitive>& out) const;
};

void
SimulatedWorld::Impl::buildPath(const PoseVector& poses, double body_height_m)
{
  // Dense samples (<= 1 m apart) of the path, each with the ground height below it.
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
SimulatedWorld::Impl::buildDistanceField()
{
  double min_x = kInf, min_y = kInf, max_x = -kInf, max_y = -kInf;
  for (const auto& p : path) {
    min_x = std::min(min_x, p.x);
    min_y = std::min(min_y, p.y);
    max_x = std::max(max_x, p.x);
    max_y = std::max(max_y, p.y);
  }
  const double margin = params.max_object_distance_m + 24.0;
  auto makeGrid = [&](double cell) {
    Grid2 g;
    g.cell = cell;
    g.x0 = min_x - margin;
    g.y0 = min_y - margin;
    g.nx = static_cast<int>(std::ceil((max_x - min_x + 2 * margin) / cell)) + 1;
    g.ny = static_cast<int>(std::ceil((max_y - min_y + 2 * margin) / cell)) + 1;
    return g;
  };
  dist_grid = makeGrid(2.0);
  ground_grid = makeGrid(4.0);
  ray_grid = makeGrid(8.0);

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
SimulatedWorld::Impl::buildGround()
{
  // Shepard (inverse-distance) blend of the path's ground heights,
  // w = 1 / (d^2 + s^2)^2 within 60 m: the nearest samples dominate, so the ground
  // passes ~exactly below every pose, and it is smooth in between. Nodes out of reach
  // take their neighbours' value (breadth-first fill).
  const Grid2& g = ground_grid;
  const std::size_t n = static_cast<std::size_t>(g.nx) * g.ny;
  std::vector<double> wsum(n, 0.0), hsum(n, 0.0);
  const double soft2 = params.ground_smoothing_m * params.ground_smoothing_m;
  const double reach = 60.0;
  const int r = static_cast<int>(std::ceil(reach / g.cell));
  for (const auto& p : path) {
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
  ground.assign(n, 0.0);
  std::vector<char> known(n, 0);
  std::queue<std::size_t> todo;
  for (std::size_t i = 0; i < n; ++i)
    if (wsum[i] > 0.0) {
      ground[i] = hsum[i] / wsum[i];
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
        ground[k] = ground[idx];
        todo.push(k);
      }
    }
  }
}

inline double
SimulatedWorld::Impl::groundAt(double x, double y, double* gx, double* gy) const
{
  // Bilinear interpolation between nodes at (x0 + i * cell, y0 + j * cell).
  const Grid2& g = ground_grid;
  const double fx = std::clamp((x - g.x0) / g.cell, 0.0, g.nx - 1.0001);
  const double fy = std::clamp((y - g.y0) / g.cell, 0.0, g.ny - 1.0001);
  const int i = static_cast<int>(fx), j = static_cast<int>(fy);
  const double u = fx - i, v = fy - j;
  const double h00 = ground[g.index(i, j)], h10 = ground[g.index(i + 1, j)];
  const double h01 = ground[g.index(i, j + 1)], h11 = ground[g.index(i + 1, j + 1)];
  if (gx)
    *gx = ((h10 - h00) * (1 - v) + (h11 - h01) * v) / g.cell;
  if (gy)
    *gy = ((h01 - h00) * (1 - u) + (h11 - h10) * u) / g.cell;
  return (h00 * (1 - u) + h10 * u) * (1 - v) + (h01 * (1 - u) + h11 * u) * v;
}

inline double
SimulatedWorld::Impl::distanceAt(double x, double y) const
{
  // Bilinear between cell centres; beyond the stamped reach the value is 1e6.
  const Grid2& g = dist_grid;
  const double fx = std::clamp((x - g.x0) / g.cell - 0.5, 0.0, g.nx - 1.0001);
  const double fy = std::clamp((y - g.y0) / g.cell - 0.5, 0.0, g.ny - 1.0001);
  const int i = static_cast<int>(fx), j = static_cast<int>(fy);
  const double u = fx - i, v = fy - j;
  const double d00 = dist[g.index(i, j)], d10 = dist[g.index(i + 1, j)];
  const double d01 = dist[g.index(i, j + 1)], d11 = dist[g.index(i + 1, j + 1)];
  return (d00 * (1 - u) + d10 * u) * (1 - v) + (d01 * (1 - u) + d11 * u) * v;
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
SimulatedWorld::Impl::placeObjects()
{
  const double corridor = params.corridor_half_width_m;
  const double max_d = params.max_object_distance_m;
  // Each object lot draws from its own stream hashed from (seed, layer, lot index), so
  // the world is a function of the seed and the path only.
  auto forLots = [&](int layer, double lot, double d_lo, double d_hi, auto&& body) {
    const Grid2& g = dist_grid;
    const long i0 = static_cast<long>(std::floor(g.x0 / lot));
    const long j0 = static_cast<long>(std::floor(g.y0 / lot));
    const long i1 = static_cast<long>(std::ceil((g.x0 + g.nx * g.cell) / lot));
    const long j1 = static_cast<long>(std::ceil((g.y0 + g.ny * g.cell) / lot));
    for (long j = j0; j < j1; ++j)
      for (long i = i0; i < i1; ++i) {
        const double x = (i + 0.5) * lot, y = (j + 0.5) * lot;
        const double d = distanceAt(x, y);
        if (d < d_lo || d > d_hi)
          continue;
        Rng rng(hashOf(seed, layer, i, j));
        body(rng, x, y, d);
      }
  };
  auto isOpenBlock = [&](double x, double y) {
    Rng rng(hashOf(seed,
                   100,
                   static_cast<long>(std::floor(x / 64.0)),
                   static_cast<long>(std::floor(y / 64.0))));
    return rng.uniform() < params.open_fraction;
  };
  auto keep = [&](const Primitive& p, double margin) {
    if (!clearOfCorridor(p, margin))
      return false;
    prims.push_back(p);
    return true;
  };

  // Buildings on 16 m lots, set back from the corridor, some with an annex (L shape)
  // or a rooftop structure.
  forLots(1, 16.0, corridor + 6.0, max_d, [&](Rng& rng, double x, double y, double) {
    if (isOpenBlock(x, y) || rng.uniform() >= params.building_probability)
      return;
    const double yaw = headingAt(x, y) + (rng.uniform() < 0.75 ? rng.uniform(-0.05, 0.05)
                                                               : rng.uniform(-0.8, 0.8));
    double length = rng.uniform(6.0, 15.0), width = rng.uniform(6.0, 15.0);
    const double u = rng.uniform();
    const double height = 3.5 + 24.0 * u * u;
    const double cx = x + rng.uniform(-2.0, 2.0), cy = y + rng.uniform(-2.0, 2.0);
    const float refl = static_cast<float>(rng.uniform(0.25, 0.6));
    const double annex = rng.uniform(), roof = rng.uniform();
    for (int attempt = 0; attempt < 3; ++attempt, length *= 0.7, width *= 0.7) {
      const double g = groundAt(cx, cy);
      Primitive b = makeBox(cx, cy, g - 1.0, g + height, length, width, yaw, refl);
      if (!keep(b, 2.0))
        continue;
      if (annex < 0.35) { // a lower wing along one side
        const double side = rng.uniform() < 0.5 ? -1.0 : 1.0;
        const double al = length * rng.uniform(0.4, 0.8),
                     aw = width * rng.uniform(0.5, 0.9);
        const double ox = side * (0.5 * length + 0.5 * al) - side * 0.5;
        const double oy = 0.5 * (width - aw) * (rng.uniform() < 0.5 ? -1 : 1);
        keep(makeBox(cx + b.c * ox - b.s * oy,
                     cy + b.s * ox + b.c * oy,
                     g - 1.0,
                     g + height * rng.uniform(0.3, 0.8),
                     al,
                     aw,
                     yaw,
                     refl),
             2.0);
      }
      if (roof < 0.25 && length > 5.0 && width > 5.0)
        prims.push_back(makeBox(cx,
                                cy,
                                g + height - 0.1,
                                g + height + rng.uniform(1.0, 3.0),
                                rng.uniform(2.0, 4.0),
                                rng.uniform(2.0, 4.0),
                                yaw,
                                static_cast<float>(rng.uniform(0.3, 0.7))));
      break;
    }
  });

  // Roadside trees and poles (with a sign board) on 4 m lots.
  forLots(
      2, 4.0, corridor + 0.5, corridor + 8.0, [&](Rng& rng, double x, double y, double) {
        const double u = rng.uniform();
        const double cx = x + rng.uniform(-1.5, 1.5), cy = y + rng.uniform(-1.5, 1.5);
        const double g = groundAt(cx, cy);
        if (u < params.tree_probability) {
          const double trunk_h = rng.uniform(1.8, 3.5), rx = rng.uniform(1.2, 2.8);
          const double rz = rng.uniform(1.5, 3.5);
          Primitive crown;
          crown.kind = Kind::kEllipsoid;
          crown.cx = cx;
          crown.cy = cy;
          crown.cz = g + trunk_h + 0.8 * rz;
          crown.hx = crown.hy = rx;
          crown.hz = rz;
          crown.reflectivity = static_cast<float>(rng.uniform(0.4, 0.6));
          if (!clearOfCorridor(crown, 0.0))
            return;
          prims.push_back(crown);
          Primitive trunk;
          trunk.kind = Kind::kCylinder;
          trunk.cx = cx;
          trunk.cy = cy;
          trunk.hx = rng.uniform(0.15, 0.3);
          trunk.cz = g - 0.5 + 0.5 * (trunk_h + 0.5 + 0.5 * rz);
          trunk.hz = 0.5 * (trunk_h + 0.5 + 0.5 * rz);
          trunk.reflectivity = 0.35f;
          prims.push_back(trunk);
        } else if (u < params.tree_probability + params.pole_probability) {
          Primitive pole;
          pole.kind = Kind::kCylinder;
          pole.cx = cx;
          pole.cy = cy;
          pole.hx = rng.uniform(0.07, 0.15);
          const double h = rng.uniform(3.0, 9.0);
          pole.cz = g - 0.5 + 0.5 * (h + 0.5);
          pole.hz = 0.5 * (h + 0.5);
          pole.reflectivity = 0.7f;
          if (!keep(pole, 0.0))
            return;
          if (rng.uniform() < 0.5) {
            const double z = g + rng.uniform(2.0, std::min(3.0, h - 0.2));
            const double yaw = headingAt(cx, cy) + kPi / 2;
            const double off = pole.hx + 0.04;
            keep(makeBox(cx + off * std::cos(yaw - kPi / 2),
                         cy + off * std::sin(yaw - kPi / 2),
                         z - 0.35,
                         z + 0.35,
                         0.7,
                         0.05,
                         yaw,
                         0.9f),
                 0.0);
          }
        }
      });

  // Trees in parks and gaps further out, denser in open blocks.
  forLots(3, 9.0, corridor + 8.0, max_d, [&](Rng& rng, double x, double y, double) {
    const double p = isOpenBlock(x, y) ? 0.45 : 0.5 * params.tree_probability;
    if (rng.uniform() >= p)
      return;
    const double cx = x + rng.uniform(-3.0, 3.0), cy = y + rng.uniform(-3.0, 3.0);
    const double g = groundAt(cx, cy);
    const double trunk_h = rng.uniform(1.5, 4.0), rx = rng.uniform(1.5, 4.0);
    const double rz = rng.uniform(2.0, 5.0);
    Primitive crown;
    crown.kind = Kind::kEllipsoid;
    crown.cx = cx;
    crown.cy = cy;
    crown.cz = g + trunk_h + 0.8 * rz;
    crown.hx = crown.hy = rx;
    crown.hz = rz;
    crown.reflectivity = static_cast<float>(rng.uniform(0.4, 0.6));
    if (!keep(crown, 0.0))
      return;
    Primitive trunk = crown;
    trunk.kind = Kind::kCylinder;
    trunk.hx = rng.uniform(0.2, 0.4);
    trunk.hz = 0.5 * (trunk_h + 0.5 + 0.5 * rz);
    trunk.cz = g - 0.5 + trunk.hz;
    trunk.reflectivity = 0.35f;
    prims.push_back(trunk);
  });

  // Parked cars at the kerb, aligned with the road, never overlapping each other.
  std::vector<std::pair<double, double>> car_xy;
  forLots(4, 5.0, corridor, corridor + 6.0, [&](Rng& rng, double x, double y, double) {
    if (rng.uniform() >= params.parked_car_probability)
      return;
    const std::size_t idx = dist_grid.index(dist_grid.ix(x), dist_grid.iy(y));
    const PathSample& ps = path[nearest[idx]];
    const double nx = -std::sin(ps.heading), ny = std::cos(ps.heading); // left normal
    const double side = (x - ps.x) * nx + (y - ps.y) * ny >= 0 ? 1.0 : -1.0;
    const double off = corridor + 2.6 + rng.uniform(0.0, 0.4);
    const double cx = ps.x + side * off * nx, cy = ps.y + side * off * ny;
    for (const auto& c : car_xy)
      if (std::hypot(c.first - cx, c.second - cy) < 5.5)
        return;
    std::vector<Primitive> car;
    addCar(cx, cy, ps.heading + rng.uniform(-0.05, 0.05), rng, car);
    // Clearance of the car outline: it stands 1.6-2.1 m outside the corridor.
    for (const auto& b : car)
      if (!clearOfCorridor(b, -1.5))
        return;
    car_xy.emplace_back(cx, cy);
    prims.insert(prims.end(), car.begin(), car.end());
  });

  // Walls and fences parallel to the road behind the kerb.
  forLots(
      5, 8.0, corridor + 4.5, corridor + 10.0, [&](Rng& rng, double x, double y, double) {
        if (rng.uniform() >= params.wall_probability)
          return;
        const bool wall = rng.uniform() < 0.5;
        const double g = groundAt(x, y);
        const double h = wall ? rng.uniform(1.5, 3.0) : rng.uniform(0.9, 1.6);
        keep(makeBox(x,
                     y,
                     g - 0.5,
                     g + h,
                     rng.uniform(5.0, 9.0),
                     wall ? 0.3 : 0.08,
                     headingAt(x, y),
                     static_cast<float>(wall ? rng.uniform(0.3, 0.5) : 0.6)),
             0.0);
      });
}

void
SimulatedWorld::Impl::buildRayGrid()
{
  const Grid2& g = ray_grid;
  const std::size_t n = static_cast<std::size_t>(g.nx) * g.ny;
  std::vector<std::uint32_t> count(n + 1, 0);
  auto cellsOf = [&](const Primitive& p, auto&& visit) {
    const double r = p.footprintRadius();
    for (int j = g.iy(p.cy - r); j <= g.iy(p.cy + r); ++j)
      for (int i = g.ix(p.cx - r); i <= g.ix(p.cx + r); ++i)
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
                                                               seed);
    return;
  }
  Rng rng(hashOf(seed, 7));
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

inline bool
SimulatedWorld::Impl::groundHit(const Eigen::Vector3d& o,
                                const Eigen::Vector3d& d,
                                double t_max,
                                double h0,
                                double gx0,
                                double gy0,
                                double& t,
                                double& cos_inc) const
{
  // Newton on f(t) = o_z + t d_z - h(o_xy + t d_xy), started from the tangent plane
  // of the ground below the origin.
  double gx, gy;
  const double slope0 = d.z() - gx0 * d.x() - gy0 * d.y();
  if (slope0 >= -1e-9 || o.z() <= h0)
    return false;
  t = (o.z() - h0) / -slope0;
  for (int it = 0; it < 6; ++it) {
    if (t > 2.0 * t_max)
      return false;
    const double h = groundAt(o.x() + t * d.x(), o.y() + t * d.y(), &gx, &gy);
    const double f = o.z() + t * d.z() - h;
    const double df = d.z() - gx * d.x() - gy * d.y();
    if (std::abs(f) < 5e-4) {
      if (t <= 0.0 || t >= t_max)
        return false;
      const Eigen::Vector3d n(-gx, -gy, 1.0);
      cos_inc = std::abs(n.dot(d)) / n.norm();
      return true;
    }
    if (df >= -1e-9)
      return false;
    t -= f / df;
  }
  return false;
}

// ---- public interface ----

SimulatedWorld::SimulatedWorld(const WorldParams& params,
                               const PoseVector& T_world_body,
                               double body_height_m,
                               std::uint64_t seed,
                               const std::vector<double>& timestamps_s)
    : impl_(std::make_unique<Impl>())
{
  std::string why;
  if (!params.isValid(&why))
    throw std::invalid_argument("SimulatedWorld: " + why);
  if (T_world_body.empty())
    throw std::invalid_argument("SimulatedWorld: empty trajectory");
  if (!(body_height_m >= 0.0 && body_height_m < 100.0))
    throw std::invalid_argument("SimulatedWorld: body_height_m out of [0, 100): " +
                                std::to_string(body_height_m));
  if (!timestamps_s.empty() && timestamps_s.size() != T_world_body.size())
    throw std::invalid_argument("SimulatedWorld: " + std::to_string(timestamps_s.size()) +
                                " timestamps for " + std::to_string(T_world_body.size()) +
                                " poses");
  impl_->params = params;
  impl_->seed = seed;
  impl_->buildPath(T_world_body, body_height_m);
  impl_->buildDistanceField();
  impl_->buildGround();
  const bool realistic =
      params.moving_cars && params.traffic.mode == TrafficMode::kRealistic;
  if (realistic) // the lanes need a wider road: keep static objects off it
    impl_->params.corridor_half_width_m = std::max(
        params.corridor_half_width_m, params.traffic.oncoming_lane_offset_m + 1.5);
  impl_->placeObjects();
  impl_->placeMovingCars(T_world_body, timestamps_s);
  impl_->clearCrossRoads();
  impl_->buildRayGrid();
}

SimulatedWorld::~SimulatedWorld() = default;

double
SimulatedWorld::groundHeight(double x, double y) const
{
  return impl_->groundAt(x, y);
}

double
SimulatedWorld::distanceToPath(double x, double y) const
{
  return impl_->distanceAt(x, y);
}

std::size_t
SimulatedWorld::numPrimitives() const
{
  return impl_->prims.size();
}

std::vector<MovingVehicle>
SimulatedWorld::movingVehicles(double time_s) const
{
  return impl_->movingVehicles(time_s);
}

bool
SimulatedWorld::castRay(const Eigen::Vector3d& origin,
                        const Eigen::Vector3d& dir,
                        double max_range_m,
                        double time_s,
                        RayHit& hit) const
{
  std::vector<RayHit> hits;
  castRays(origin, {dir}, max_range_m, time_s, hits);
  hit = hits[0];
  return hit.range_m > 0.0;
}

void
SimulatedWorld::castRays(const Eigen::Vector3d& origin,
                         const std::vector<Eigen::Vector3d>& dirs,
                         double max_range_m,
                         double time_s,
                         std::vector<RayHit>& hits) const
{
  impl_->castRays<false>(&origin, dirs, max_range_m, time_s, hits);
}

void
SimulatedWorld::castRays(const std::vector<Eigen::Vector3d>& origins,
                         const std::vector<Eigen::Vector3d>& dirs,
                         double max_range_m,
                         double time_s,
                         std::vector<RayHit>& hits) const
{
  if (origins.size() != dirs.size())
    throw std::invalid_argument(
        "SimulatedWorld::castRays: " + std::to_string(origins.size()) + " origins for " +
        std::to_string(dirs.size()) + " directions");
  impl_->castRays<true>(origins.data(), dirs, max_range_m, time_s, hits);
}

template <bool kOwnOrigins>
void
SimulatedWorld::Impl::castRays(const Eigen::Vector3d* origins,
                               const std::vector<Eigen::Vector3d>& dirs,
                               double max_range_m,
                               double time_s,
                               std::vector<RayHit>& hits) const
{
  const Impl& w = *this;
  const Grid2& g = w.ray_grid;
  hits.assign(dirs.size(), RayHit());
  std::vector<std::uint32_t> mailbox(w.prims.size(),
                                     std::numeric_limits<std::uint32_t>::max());

  const std::vector<Primitive> movers = w.movingCarBoxes(time_s);
  std::vector<Primitive> near_movers;

  const double gx_min = g.x0, gy_min = g.y0;
  const double gx_max = g.x0 + g.nx * g.cell, gy_max = g.y0 + g.ny * g.cell;

  // Runs of rays with the same origin share its set-up.
  for (std::size_t r0 = 0; r0 < dirs.size();) {
    const Eigen::Vector3d o = origins[kOwnOrigins ? r0 : 0];
    std::size_t r1 = kOwnOrigins ? r0 + 1 : dirs.size();
    while (kOwnOrigins && r1 < dirs.size() && origins[r1] == o)
      ++r1;

    // Moving cars: only those that can be in range, tested via an enclosing sphere.
    near_movers.clear();
    for (const auto& b : movers)
      if (std::hypot(b.cx - o.x(), b.cy - o.y()) < max_range_m + 5.0)
        near_movers.push_back(b);
    double gx0, gy0;
    const double h0 = w.groundAt(o.x(), o.y(), &gx0, &gy0);

    for (std::size_t r = r0; r < r1; ++r) {
      const Eigen::Vector3d& d = dirs[r];
      RayHit& out = hits[r];
      double best = max_range_m, best_cos = 1.0;
      float best_refl = 0.0f;
      bool found = false, is_ground = false;

      double t_ground, cos_ground;
      if (w.groundHit(o, d, max_range_m, h0, gx0, gy0, t_ground, cos_ground)) {
        best = t_ground;
        best_cos = cos_ground;
        const Eigen::Vector3d p = o + t_ground * d;
        best_refl =
            w.distanceAt(p.x(), p.y()) < w.params.corridor_half_width_m ? 0.12f : 0.28f;
        found = is_ground = true;
      }

      for (const auto& b : near_movers) {
        const double ox = b.cx - o.x(), oy = b.cy - o.y(), oz = b.cz - o.z();
        const double tca = ox * d.x() + oy * d.y() + oz * d.z();
        const double rad2 = b.hx * b.hx + b.hy * b.hy + b.hz * b.hz;
        if (ox * ox + oy * oy + oz * oz - tca * tca > rad2)
          continue;
        double t, c;
        if (intersect(b, o, d, 1e-6, best, t, c)) {
          best = t;
          best_cos = c;
          best_refl = b.reflectivity;
          found = true;
          is_ground = false;
        }
      }

      // 2D DDA (Amanatides & Woo) over the cells the ray's footprint crosses, up to
      // the nearest hit so far.
      double t_enter = 0.0, t_exit = best;
      const double dx = d.x(), dy = d.y();
      auto clip = [&](double o_k, double d_k, double lo, double hi) {
        if (std::abs(d_k) < 1e-12)
          return o_k >= lo && o_k < hi;
        double ta = (lo - o_k) / d_k, tb = (hi - o_k) / d_k;
        if (ta > tb)
          std::swap(ta, tb);
        t_enter = std::max(t_enter, ta);
        t_exit = std::min(t_exit, tb);
        return true;
      };
      if (!w.prims.empty() && clip(o.x(), dx, gx_min, gx_max) &&
          clip(o.y(), dy, gy_min, gy_max) && t_enter < t_exit) {
        const double px = o.x() + t_enter * dx, py = o.y() + t_enter * dy;
        int i = g.ix(px), j = g.iy(py);
        const int step_i = dx > 0 ? 1 : -1, step_j = dy > 0 ? 1 : -1;
        const double inv_dx = std::abs(dx) > 1e-12 ? 1.0 / dx : kInf;
        const double inv_dy = std::abs(dy) > 1e-12 ? 1.0 / dy : kInf;
        double t_max_x = std::abs(dx) > 1e-12
                             ? (g.x0 + (i + (dx > 0 ? 1 : 0)) * g.cell - o.x()) * inv_dx
                             : kInf;
        double t_max_y = std::abs(dy) > 1e-12
                             ? (g.y0 + (j + (dy > 0 ? 1 : 0)) * g.cell - o.y()) * inv_dy
                             : kInf;
        const double t_delta_x = std::abs(g.cell * inv_dx),
                     t_delta_y = std::abs(g.cell * inv_dy);
        double t_cell = t_enter;
        const std::uint32_t ray_id = static_cast<std::uint32_t>(r);
        while (t_cell < best) {
          const double t_next = std::min(t_max_x, t_max_y);
          const std::size_t c = g.index(i, j);
          const double z_low =
              o.z() + std::min(t_cell * d.z(), std::min(t_next, best) * d.z());
          if (z_low <= w.cell_top[c]) {
            for (std::uint32_t k = w.cell_start[c]; k < w.cell_start[c + 1]; ++k) {
              const std::uint32_t id = w.cell_items[k];
              if (mailbox[id] == ray_id)
                continue;
              mailbox[id] = ray_id;
              double t, cos_inc;
              if (intersect(w.prims[id], o, d, 1e-6, best, t, cos_inc)) {
                best = t;
                best_cos = cos_inc;
                best_refl = w.prims[id].reflectivity;
                found = true;
                is_ground = false;
              }
            }
          } else if (d.z() > 0 && z_low > w.max_top) {
            break; // above everything, climbing
          }
          if (t_next >= best)
            break;
          t_cell = t_next;
          if (t_max_x < t_max_y) {
            i += step_i;
            t_max_x += t_delta_x;
            if (i < 0 || i >= g.nx)
              break;
          } else {
            j += step_j;
            t_max_y += t_delta_y;
            if (j < 0 || j >= g.ny)
              break;
          }
        }
      }
      if (found) {
        out.range_m = best;
        out.cos_incidence = best_cos;
        out.reflectivity = best_refl;
        out.is_ground = is_ground;
      }
    }
    r0 = r1;
  }
}

} // namespace rast
} // namespace pcl
