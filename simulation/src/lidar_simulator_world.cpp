/// \file lidar_simulator_world.cpp
/// \brief SimulatedWorld: procedural world generation around a trajectory and ray
/// casting against it (ground height field + analytic primitives in a 2D grid), with
/// scene types along the path, optional rough ground and porous vegetation.

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <pcl/simulation/lidar_simulator.h>

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
  float mean_free_path = 0.0f; ///< > 0: porous (vegetation), rays stop inside
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

/// Ray-primitive intersection: entry distance t in (t_min, t_max) and |cos incidence|;
/// the exit distance in \a t_exit when asked (boxes and ellipsoids only).
bool
intersect(const Primitive& p,
          const Eigen::Vector3d& o,
          const Eigen::Vector3d& d,
          double t_min,
          double t_max,
          double& t_hit,
          double& cos_inc,
          double* t_exit = nullptr)
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
    if (t_exit)
      *t_exit = t1;
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
    if (t_exit)
      *t_exit = (-b + std::sqrt(disc)) / a;
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

/// A stretch of the path of one scene type, from arc length s_begin to the next
/// stretch's.
struct SceneStretch
{
  double s_begin;
  SceneType type;
};

/// Deterministic value noise of a few centimetres (rough ground): three octaves
/// (wavelengths 1.6, 0.8, 0.4 m) of smoothstep-interpolated lattice values drawn from
/// the seed, summed once into a seamless 25.6 m tile of 0.1 m texels and scaled to the
/// wanted std; queries interpolate the tile bilinearly (cheap inside the ray caster).
class GroundRoughness
{
public:
  GroundRoughness() = default;
  GroundRoughness(std::uint64_t seed, double std_m)
  {
    Rng rng(seed);
    std::vector<double> lattice(128 * 128);
    for (auto& v : lattice) // a sum of uniforms: roughly gaussian, bounded by +-1
      v = (rng.uniform() + rng.uniform() + rng.uniform() - 1.5) / 1.5;
    const double wavelengths[3] = {1.6, 0.8, 0.4}, weights[3] = {1.0, 0.6, 0.35};
    tile_.assign(kTexels * kTexels, 0.0f);
    double sum2 = 0.0;
    for (int j = 0; j < kTexels; ++j)
      for (int i = 0; i < kTexels; ++i) {
        double h = 0.0;
        for (int o = 0; o < 3; ++o) {
          const int n = static_cast<int>(std::lround(kTexels * kTexel / wavelengths[o]));
          const double fx = i * kTexel / wavelengths[o], fy = j * kTexel / wavelengths[o];
          const int li = static_cast<int>(fx), lj = static_cast<int>(fy);
          const double u = fx - li, v = fy - lj;
          const double su = u * u * (3 - 2 * u), sv = v * v * (3 - 2 * v);
          auto value = [&](int a, int b) { // octave o's lattice, wrapped to the tile
            return lattice[((b % n) + 37 * o) % 128 * 128 + ((a % n) + 53 * o) % 128];
          };
          h += weights[o] *
               ((value(li, lj) * (1 - su) + value(li + 1, lj) * su) * (1 - sv) +
                (value(li, lj + 1) * (1 - su) + value(li + 1, lj + 1) * su) * sv);
        }
        tile_[j * kTexels + i] = static_cast<float>(h);
        sum2 += h * h;
      }
    const double scale = std_m / std::sqrt(sum2 / tile_.size());
    bound_m_ = 0.0;
    for (auto& v : tile_) {
      v = static_cast<float>(v * scale);
      bound_m_ = std::max(bound_m_, std::abs(static_cast<double>(v)));
    }
  }

  /// Relief at (x, y); its gradient is added to (gx, gy) when asked.
  double at(double x, double y, double* gx = nullptr, double* gy = nullptr) const
  {
    const double fx = x / kTexel, fy = y / kTexel;
    const double ffx = std::floor(fx), ffy = std::floor(fy);
    const double u = fx - ffx, v = fy - ffy;
    const int i = static_cast<int>(static_cast<long>(ffx) & (kTexels - 1));
    const int j = static_cast<int>(static_cast<long>(ffy) & (kTexels - 1));
    const int i1 = (i + 1) & (kTexels - 1), j1 = (j + 1) & (kTexels - 1);
    const double h00 = tile_[j * kTexels + i], h10 = tile_[j * kTexels + i1];
    const double h01 = tile_[j1 * kTexels + i], h11 = tile_[j1 * kTexels + i1];
    if (gx)
      *gx += ((h10 - h00) * (1 - v) + (h11 - h01) * v) / kTexel;
    if (gy)
      *gy += ((h01 - h00) * (1 - u) + (h11 - h10) * u) / kTexel;
    return (h00 * (1 - u) + h10 * u) * (1 - v) + (h01 * (1 - u) + h11 * u) * v;
  }
  /// The largest |at(x, y)|.
  double bound() const { return bound_m_; }

private:
  static constexpr int kTexels = 256;   ///< per tile side (a power of two; 256 KB)
  static constexpr double kTexel = 0.1; ///< m
  std::vector<float> tile_;
  double bound_m_ = 0.0;
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

// ---- scene names ----

SceneType
sceneTypeFromString(const std::string& name)
{
  if (name == "suburb")
    return SceneType::kSuburb;
  if (name == "urban")
    return SceneType::kUrbanCanyon;
  if (name == "highway")
    return SceneType::kHighway;
  if (name == "field")
    return SceneType::kOpenField;
  if (name == "tunnel")
    return SceneType::kTunnel;
  throw std::invalid_argument("sceneTypeFromString: unknown scene '" + name +
                              "' (suburb, urban, highway, field, tunnel)");
}

std::string
toString(SceneType type)
{
  switch (type) {
  case SceneType::kSuburb:
    return "suburb";
  case SceneType::kUrbanCanyon:
    return "urban";
  case SceneType::kHighway:
    return "highway";
  case SceneType::kOpenField:
    return "field";
  case SceneType::kTunnel:
    return "tunnel";
  }
  return "unknown";
}

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
  if (toString(scene) == "unknown")
    return fail("scene is not a SceneType: " + std::to_string(static_cast<int>(scene)));
  if (!(scene_min_length_m >= 10.0 && scene_min_length_m <= 1e5))
    return fail("scene_min_length_m must be in [10, 1e5], got " +
                std::to_string(scene_min_length_m));
  if (!(scene_max_length_m >= scene_min_length_m && scene_max_length_m <= 1e5))
    return fail("scene_max_length_m must be in [scene_min_length_m, 1e5], got " +
                std::to_string(scene_max_length_m));
  if (!(highway_half_width_m >= corridor_half_width_m && highway_half_width_m <= 30.0))
    return fail("highway_half_width_m must be in [corridor_half_width_m, 30], got " +
                std::to_string(highway_half_width_m));
  if (!(ground_roughness_std_m >= 0.0 && ground_roughness_std_m <= 0.2))
    return fail("ground_roughness_std_m must be in [0, 0.2], got " +
                std::to_string(ground_roughness_std_m));
  if (!(vegetation_mean_free_path_m > 0.0 && vegetation_mean_free_path_m <= 20.0))
    return fail("vegetation_mean_free_path_m must be in (0, 20], got " +
                std::to_string(vegetation_mean_free_path_m));
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

  std::vector<SceneStretch> stretches;       ///< by arc length, the first at s = 0
  std::vector<std::uint32_t> sample_stretch; ///< per path sample: its stretch
  bool plain = true; ///< one suburb scene: the world of earlier versions
  bool has_highway = false;
  GroundRoughness roughness; ///< when params.rough_ground

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
  void buildScenes();
  void buildDistanceField();
  void buildGround();
  void raiseEmbankments();
  void placeObjects();
  /// The layers of the scenes other than suburbs, with placeObjects' lot iterator and
  /// corridor-checked insertion.
  template <class ForLots, class Keep>
  void placeSceneObjects(const ForLots& forLots, const Keep& keep);
  void buildRayGrid();
  void placeMovingCars(const PoseVector& poses, const std::vector<double>& timestamps_s);
  void clearCrossRoads();

  // -- queries --
  /// The ground without its roughness (height field of the path plus embankments).
  double
  smoothGroundAt(double x, double y, double* gx = nullptr, double* gy = nullptr) const;
  /// The ground: smoothGroundAt plus the roughness when params.rough_ground.
  double groundAt(double x, double y, double* gx = nullptr, double* gy = nullptr) const
  {
    const double h = smoothGroundAt(x, y, gx, gy);
    return params.rough_ground ? h + roughness.at(x, y, gx, gy) : h;
  }
  SceneType sceneOfSample(std::size_t k) const
  {
    return stretches[sample_stretch[k]].type;
  }
  SceneType sceneAt(double x, double y) const
  {
    return sceneOfSample(nearest[dist_grid.index(dist_grid.ix(x), dist_grid.iy(y))]);
  }
  /// Half width of the paved road at (x, y) (darker ground).
  double roadHalfWidthAt(double x, double y) const
  {
    return has_highway && sceneAt(x, y) == SceneType::kHighway
               ? params.highway_half_width_m
               : params.corridor_half_width_m;
  }
  /// A porous primitive \a id entered at t_in and left at t_out along the ray: true
  /// and the stopping depth in \a t (and a leaf's |cos incidence|) when the ray stops
  /// inside before t_stop_max.
  bool porousStop(std::uint32_t id,
                  const Eigen::Vector3d& o,
                  const Eigen::Vector3d& d,
                  double t_in,
                  double t_out,
                  double t_stop_max,
                  double& t,
                  double& cos_inc) const;
  /// Ground crossing of a ray the Newton steps missed (terrain with embankments):
  /// march in 2 m steps to the first crossing, then refine.
  bool marchGround(const Eigen::Vector3d& o,
                   const Eigen::Vector3d& d,
                   double t_max,
                   double& t,
                   double& cos_inc) const;
  /// A smooth-ground crossing at \a t with gradient (gx, gy) made a hit: refined on
  /// the rough ground if there is one, kept when within (0, t_max), with its incidence.
  bool finishGroundHit(const Eigen::Vector3d& o,
                       const Eigen::Vector3d& d,
                       double t_max,
                       double gx,
                       double gy,
                       double& t,
                       double& cos_inc) const;
  /// The rough ground's crossing near the smooth ground's at \a t (refined in place);
  /// (gx, gy): in the smooth ground's gradient there, out the rough ground's.
  void refineOnRoughGround(const Eigen::Vector3d& o,
                           const Eigen::Vector3d& d,
                           double& t,
                           double& gx,
                           double& gy) const;
  double distanceAt(double x, double y) const;
  float headingAt(double x, double y) const
  {
    return heading[dist_grid.index(dist_grid.ix(x), dist_grid.iy(y))];
  }
  /// Ground below the origin (h0, gx0, gy0: smooth ground) is shared by all rays of a
  /// frame. \a march: rays the Newton steps miss are marched (origins on highways,
  /// whose embankments rise beside the road).
  bool groundHit(const Eigen::Vector3d& o,
                 const Eigen::Vector3d& d,
                 double t_max,
                 double h0,
                 double gx0,
                 double gy0,
                 bool march,
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
  raiseEmbankments();
}

void
SimulatedWorld::Impl::raiseEmbankments()
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
      ground[g.index(i, j)] += std::clamp(0.5 * std::min(up, down), 0.0, b.height_m);
    }
}

inline double
SimulatedWorld::Impl::smoothGroundAt(double x, double y, double* gx, double* gy) const
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
  const float crown_free_path =
      params.porous_vegetation ? static_cast<float>(params.vegetation_mean_free_path_m)
                               : 0.0f;

  // Buildings on 16 m lots, set back from the corridor, some with an annex (L shape)
  // or a rooftop structure.
  // Urban canyons: only behind their facades (placeSceneObjects), denser.
  forLots(1, 16.0, corridor + 6.0, max_d, [&](Rng& rng, double x, double y, double d) {
    const SceneType scene = sceneAt(x, y);
    const bool urban = scene == SceneType::kUrbanCanyon;
    if (!(scene == SceneType::kSuburb || (urban && d > corridor + 24.0)))
      return;
    if ((!urban && isOpenBlock(x, y)) ||
        rng.uniform() >= (urban ? 0.8 : params.building_probability))
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

  // Roadside trees and poles (with a sign board) on 4 m lots; urban canyons have
  // hardly any trees.
  forLots(
      2, 4.0, corridor + 0.5, corridor + 8.0, [&](Rng& rng, double x, double y, double) {
        const SceneType scene = sceneAt(x, y);
        if (scene != SceneType::kSuburb && scene != SceneType::kUrbanCanyon)
          return;
        const bool urban = scene == SceneType::kUrbanCanyon;
        const double tree_p = urban ? 0.03 : params.tree_probability;
        const double pole_p = urban ? 0.15 : params.pole_probability;
        const double u = rng.uniform();
        const double cx = x + rng.uniform(-1.5, 1.5), cy = y + rng.uniform(-1.5, 1.5);
        const double g = groundAt(cx, cy);
        if (u < tree_p) {
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
          crown.mean_free_path = crown_free_path;
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
        } else if (u < tree_p + pole_p) {
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
  // Highways: sparse, and only beyond ~30 m of the road.
  forLots(3, 9.0, corridor + 8.0, max_d, [&](Rng& rng, double x, double y, double d) {
    const SceneType scene = sceneAt(x, y);
    const bool highway = scene == SceneType::kHighway;
    if (!(scene == SceneType::kSuburb || (highway && d > 40.0)))
      return;
    const double p = highway             ? 0.1
                     : isOpenBlock(x, y) ? 0.45
                                         : 0.5 * params.tree_probability;
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
    crown.mean_free_path = crown_free_path;
    if (!keep(crown, 0.0))
      return;
    Primitive trunk = crown;
    trunk.mean_free_path = 0.0f;
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
    const SceneType scene = sceneAt(x, y);
    if (scene != SceneType::kSuburb && scene != SceneType::kUrbanCanyon)
      return;
    const double car_p =
        scene == SceneType::kUrbanCanyon ? 0.5 : params.parked_car_probability;
    if (rng.uniform() >= car_p)
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

  // Walls and fences parallel to the road behind the kerb (suburbs); with porous
  // vegetation, hedges on some of the lots without a wall.
  forLots(
      5, 8.0, corridor + 4.5, corridor + 10.0, [&](Rng& rng, double x, double y, double) {
        if (sceneAt(x, y) != SceneType::kSuburb)
          return;
        if (rng.uniform() >= params.wall_probability) {
          if (params.porous_vegetation && rng.uniform() < 0.3) {
            const double g = groundAt(x, y);
            Primitive hedge = makeBox(x,
                                      y,
                                      g - 0.3,
                                      g + rng.uniform(1.0, 2.2),
                                      rng.uniform(4.0, 8.0),
                                      rng.uniform(0.8, 1.6),
                                      headingAt(x, y),
                                      static_cast<float>(rng.uniform(0.35, 0.55)));
            hedge.mean_free_path = static_cast<float>(0.5 * crown_free_path);
            keep(hedge, 0.0);
          }
          return;
        }
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

  if (!plain)
    placeSceneObjects(forLots, keep);
}

template <class ForLots, class Keep>
void
SimulatedWorld::Impl::placeSceneObjects(const ForLots& forLots, const Keep& keep)
{
  const double corridor = params.corridor_half_width_m;
  // Structures along the road: body(rng, sample) for the middle sample of every
  // seg_len of arc length in stretches of scene `type`, each segment with its own
  // stream. A segment driven a second time (its cell is nearest to a sample >= 30 m
  // earlier on the path) has its structures already.
  auto forSegments = [&](int layer, SceneType type, double seg_len, auto&& body) {
    const double length = path.back().s;
    std::size_t k = 0;
    for (long seg = 0; seg * seg_len <= length; ++seg) {
      const double s_mid = std::min(length, (seg + 0.5) * seg_len);
      while (k + 1 < path.size() && path[k].s < s_mid)
        ++k;
      const PathSample& ps = path[k];
      const std::size_t cell = dist_grid.index(dist_grid.ix(ps.x), dist_grid.iy(ps.y));
      if (sceneOfSample(k) != type || path[nearest[cell]].s < ps.s - 30.0)
        continue;
      Rng rng(hashOf(seed, layer, seg));
      body(rng, ps, k);
    }
  };
  // A box along the road whose inner face is `offset` beside the path sample on
  // `side` (+1 left, -1 right), `along` ahead of it, heights relative to the smooth
  // ground (long structures do not follow the few cm of rough relief).
  auto besideRoad = [&](const PathSample& ps,
                        double side,
                        double offset,
                        double depth,
                        double length,
                        double z_lo,
                        double z_hi,
                        float reflectivity,
                        double along = 0.0) {
    const double c = std::cos(ps.heading), s = std::sin(ps.heading);
    const double lateral = side * (offset + 0.5 * depth);
    const double x = ps.x - lateral * s + along * c, y = ps.y + lateral * c + along * s;
    const double g = smoothGroundAt(x, y);
    return makeBox(x, y, g + z_lo, g + z_hi, length, depth, ps.heading, reflectivity);
  };

  // Urban canyon: 12 m facade segments 5-7 m outside the corridor, 10 % gaps.
  forSegments(20,
              SceneType::kUrbanCanyon,
              12.0,
              [&](Rng& rng, const PathSample& ps, std::size_t) {
                for (const double side : {-1.0, 1.0}) {
                  if (rng.uniform() < 0.1)
                    continue;
                  const double offset = corridor + rng.uniform(5.0, 7.0);
                  const double depth = rng.uniform(8.0, 15.0);
                  const double height = rng.uniform(10.0, 40.0);
                  const auto refl = static_cast<float>(rng.uniform(0.25, 0.6));
                  keep(besideRoad(ps, side, offset, depth, 12.4, -1.0, height, refl),
                       0.0);
                }
              });

  // Highway: guard rails (0.3 m at 0.5-0.8 m) 0.5 m beyond the road's edge on both
  // sides, on posts every 2.67 m. Embankments are in the ground (raiseEmbankments).
  const double rail = params.highway_half_width_m + 0.5;
  forSegments(21, SceneType::kHighway, 8.0, [&](Rng&, const PathSample& ps, std::size_t) {
    for (const double side : {-1.0, 1.0}) {
      keep(besideRoad(ps, side, rail, 0.1, 8.05, 0.5, 0.8, 0.6f), 0.0);
      for (int p = -1; p <= 1; ++p)
        keep(besideRoad(ps, side, rail + 0.1, 0.15, 0.15, -0.3, 0.75, 0.5f, p * 8.0 / 3),
             0.0);
    }
  });

  // Tunnel: per stretch two smooth walls 0.8-2 m outside the corridor, 5-7 m tall, and
  // a ceiling over part of it (70 % of the stretches). Like a real tunnel, the walls
  // carry small fixtures at irregular spacing: lamps high up (about one per 12 m and
  // side), cabinets and emergency-niche doors at the bottom (one per ~50 m). Only
  // they fix a position along the road.
  // 10 m segments: fewer boxes per ray-grid cell (every ray in a tunnel is near them).
  const double tunnel_seg = 10.0;
  forSegments(
      24,
      SceneType::kTunnel,
      tunnel_seg,
      [&](Rng& rng, const PathSample& ps, std::size_t k) {
        const std::uint32_t st = sample_stretch[k];
        Rng srng(hashOf(seed, 203, st));
        const double offset = corridor + srng.uniform(0.8, 2.0);
        const double height = srng.uniform(5.0, 7.0);
        const double begin = stretches[st].s_begin;
        const double end =
            st + 1 < stretches.size() ? stretches[st + 1].s_begin : path.back().s;
        const bool roofed = srng.uniform() < 0.7;
        const double roof_a = begin + (end - begin) * srng.uniform(0.0, 0.3);
        const double roof_b = begin + (end - begin) * srng.uniform(0.6, 1.0);
        for (const double side : {-1.0, 1.0}) {
          keep(besideRoad(ps, side, offset, 0.5, tunnel_seg + 0.3, -0.5, height, 0.35f),
               -1.5);
          // A lamp high on the wall in most 10 m segments (tunnel lighting), off its
          // regular spacing by up to 3 m; a cabinet or an emergency-niche door at the
          // bottom in about one segment in five.
          if (rng.uniform() < 0.8)
            keep(besideRoad(ps,
                            side,
                            offset - 0.25,
                            0.25,
                            1.2,
                            height - 1.3,
                            height - 1.0,
                            static_cast<float>(rng.uniform(0.6, 0.9)),
                            rng.uniform(-0.3, 0.3) * tunnel_seg),
                 -1.5);
          if (rng.uniform() < 0.2)
            keep(besideRoad(ps,
                            side,
                            offset - 0.4,
                            0.4,
                            rng.uniform(0.8, 1.6),
                            -0.5,
                            rng.uniform(1.2, 2.2),
                            static_cast<float>(rng.uniform(0.4, 0.8)),
                            rng.uniform(-0.4, 0.4) * tunnel_seg),
                 -1.5);
        }
        if (roofed && ps.s >= roof_a && ps.s <= roof_b) {
          const double g = smoothGroundAt(ps.x, ps.y);
          prims.push_back(makeBox(ps.x,
                                  ps.y,
                                  g + height,
                                  g + height + 0.4,
                                  tunnel_seg + 0.3,
                                  2.0 * offset + 1.0,
                                  ps.heading,
                                  0.3f));
        }
      });

  // Open field / parking lot: a few lamp posts (with an arm) ...
  forLots(23, 20.0, corridor + 2.0, 60.0, [&](Rng& rng, double x, double y, double) {
    if (sceneAt(x, y) != SceneType::kOpenField || rng.uniform() >= 0.3)
      return;
    const double cx = x + rng.uniform(-6.0, 6.0), cy = y + rng.uniform(-6.0, 6.0);
    const double g = groundAt(cx, cy), h = rng.uniform(6.0, 10.0);
    Primitive pole;
    pole.kind = Kind::kCylinder;
    pole.cx = cx;
    pole.cy = cy;
    pole.hx = rng.uniform(0.1, 0.15);
    pole.cz = g - 0.5 + 0.5 * (h + 0.5);
    pole.hz = 0.5 * (h + 0.5);
    pole.reflectivity = 0.7f;
    if (!keep(pole, 0.0))
      return;
    const double yaw = rng.uniform(0.0, 2.0 * kPi);
    keep(makeBox(cx + 0.8 * std::cos(yaw),
                 cy + 0.8 * std::sin(yaw),
                 g + h - 0.25,
                 g + h,
                 1.6,
                 0.3,
                 yaw,
                 0.8f),
         0.0);
  });
  // ... and rows of parked cars far out, nose to the row's line.
  forLots(22, 32.0, corridor + 14.0, 70.0, [&](Rng& rng, double x, double y, double) {
    if (sceneAt(x, y) != SceneType::kOpenField || rng.uniform() >= 0.4)
      return;
    const double row_yaw = headingAt(x, y);
    const int n = 3 + static_cast<int>(rng.uniform() * 8.0);
    for (int c = 0; c < n; ++c) {
      if (rng.uniform() < 0.25) // an empty bay
        continue;
      const double along = (c - 0.5 * (n - 1)) * 2.7;
      std::vector<Primitive> car;
      addCar(x + along * std::cos(row_yaw),
             y + along * std::sin(row_yaw),
             row_yaw + 0.5 * kPi + rng.uniform(-0.05, 0.05),
             rng,
             car);
      if (std::all_of(car.begin(), car.end(), [&](const Primitive& b) {
            return clearOfCorridor(b, 0.0);
          }))
        prims.insert(prims.end(), car.begin(), car.end());
    }
  });
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
                                bool march,
                                double& t,
                                double& cos_inc) const
{
  // Newton on f(t) = o_z + t d_z - h(o_xy + t d_xy) on the smooth ground, started
  // from the tangent plane of the ground below the origin. Embankments (highways)
  // fall back to marching; rough ground refines the smooth crossing.
  double gx, gy;
  const double slope0 = d.z() - gx0 * d.x() - gy0 * d.y();
  if (slope0 >= -1e-9 || o.z() <= h0)
    return march && marchGround(o, d, t_max, t, cos_inc);
  t = (o.z() - h0) / -slope0;
  const int iterations = march ? 12 : 6;
  for (int it = 0; it < iterations; ++it) {
    if (t > 2.0 * t_max)
      break;
    const double h = smoothGroundAt(o.x() + t * d.x(), o.y() + t * d.y(), &gx, &gy);
    const double f = o.z() + t * d.z() - h;
    const double df = d.z() - gx * d.x() - gy * d.y();
    if (std::abs(f) < 5e-4)
      return finishGroundHit(o, d, t_max, gx, gy, t, cos_inc);
    if (df >= -1e-9)
      break;
    t -= f / df;
  }
  return march && marchGround(o, d, t_max, t, cos_inc);
}

bool
SimulatedWorld::Impl::finishGroundHit(const Eigen::Vector3d& o,
                                      const Eigen::Vector3d& d,
                                      double t_max,
                                      double gx,
                                      double gy,
                                      double& t,
                                      double& cos_inc) const
{
  if (params.rough_ground)
    refineOnRoughGround(o, d, t, gx, gy);
  if (t <= 0.0 || t >= t_max)
    return false;
  const Eigen::Vector3d n(-gx, -gy, 1.0);
  cos_inc = std::abs(n.dot(d)) / n.norm();
  return true;
}

bool
SimulatedWorld::Impl::marchGround(const Eigen::Vector3d& o,
                                  const Eigen::Vector3d& d,
                                  double t_max,
                                  double& t,
                                  double& cos_inc) const
{
  auto f = [&](double tt) {
    return o.z() + tt * d.z() - smoothGroundAt(o.x() + tt * d.x(), o.y() + tt * d.y());
  };
  // 8 m steps up to 80 m (embankments rise 3-6 m over 6-12 m and end within ~70 m of
  // the road), bisection down to 5 cm, then the secant: the ground is bilinear
  // between 4 m nodes, so nearly linear along that little of the ray.
  const double step = 8.0, t_end = std::min(t_max, 80.0);
  double t_lo = 0.0, f_lo = f(0.0);
  if (f_lo <= 0.0)
    return false;
  for (double t_hi = step; t_lo < t_end; t_lo = t_hi, t_hi += step) {
    double f_hi = f(t_hi);
    if (f_hi > 0.0) {
      f_lo = f_hi;
      continue;
    }
    while (t_hi - t_lo > 0.05) {
      const double mid = 0.5 * (t_lo + t_hi), f_mid = f(mid);
      if (f_mid > 0.0) {
        t_lo = mid;
        f_lo = f_mid;
      } else {
        t_hi = mid;
        f_hi = f_mid;
      }
    }
    t = t_lo + (t_hi - t_lo) * f_lo / (f_lo - f_hi);
    double gx, gy;
    smoothGroundAt(o.x() + t * d.x(), o.y() + t * d.y(), &gx, &gy);
    return finishGroundHit(o, d, t_max, gx, gy, t, cos_inc);
  }
  return false;
}

void
SimulatedWorld::Impl::refineOnRoughGround(const Eigen::Vector3d& o,
                                          const Eigen::Vector3d& d,
                                          double& t,
                                          double& gx,
                                          double& gy) const
{
  // Safeguarded Newton (rtsafe, Numerical Recipes 9.4) on f(t) = o_z + t d_z - ground(t),
  // ground = smooth + relief. The relief is bounded by b, so f changes sign in [t - b /
  // |f'|, t + b / |f'|] around the smooth crossing t (f' the smooth ground's slope
  // there): Newton steps with the full slope while they stay inside that shrinking
  // bracket, bisection otherwise. Steep rays take 2-3 steps; grazing rays, where Newton
  // on the relief alone would wander off, still converge.
  const double df_smooth = std::min(d.z() - gx * d.x() - gy * d.y(), -1e-3);
  const double reach = 1.05 * roughness.bound() / -df_smooth;
  double lo = std::max(0.0, t - reach), hi = t + reach;
  // At most 4 steps: by then grazing rays are within a few mm of a crossing (the
  // relief's first and last crossings differ by more than that anyway). The first
  // needs only the relief: t is on the smooth ground.
  for (int it = 0; it < 4; ++it) {
    const double x = o.x() + t * d.x(), y = o.y() + t * d.y();
    const double ground = it == 0 ? o.z() + t * d.z() + roughness.at(x, y, &gx, &gy)
                                  : groundAt(x, y, &gx, &gy);
    const double f = o.z() + t * d.z() - ground;
    if (std::abs(f) < 2e-3 || hi - lo < 2e-3)
      return;
    (f > 0.0 ? lo : hi) = t;
    const double df = d.z() - gx * d.x() - gy * d.y();
    const double t_newton = df < -1e-9 ? t - f / df : kInf;
    t = t_newton > lo && t_newton < hi ? t_newton : 0.5 * (lo + hi);
  }
}

inline bool
SimulatedWorld::Impl::porousStop(std::uint32_t id,
                                 const Eigen::Vector3d& o,
                                 const Eigen::Vector3d& d,
                                 double t_in,
                                 double t_out,
                                 double t_stop_max,
                                 double& t,
                                 double& cos_inc) const
{
  // Exponential free path from a hash of (seed, primitive, ray): the ray's origin and
  // direction quantized to 0.1 mm and 1e-7, so a frame's rays draw the same depths
  // whatever else is simulated and however the rays are split among threads.
  auto q = [](double v, double unit) {
    return static_cast<std::int64_t>(std::llround(v / unit));
  };
  std::uint64_t h = hashOf(seed ^ 0x7E6E7A710AULL, id, q(d.x(), 1e-7), q(d.y(), 1e-7));
  h = hashOf(h, q(d.z(), 1e-7), q(o.x(), 1e-4), q(o.y(), 1e-4));
  h = hashOf(h, q(o.z(), 1e-4));
  const double u = static_cast<double>(h >> 11) * 0x1.0p-53;
  const double depth = -prims[id].mean_free_path * std::log1p(-u);
  t = std::max(t_in, 0.0) + depth;
  if (t >= std::min(t_out, t_stop_max))
    return false;
  // A leaf facing a random way: |cos incidence| from the hash's other bits.
  cos_inc = 0.2 + 0.8 * static_cast<double>(splitmix64(h) >> 11) * 0x1.0p-53;
  return true;
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
  impl_->buildScenes();
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

SceneType
SimulatedWorld::sceneAt(double x, double y) const
{
  return impl_->sceneAt(x, y);
}

SceneType
SimulatedWorld::sceneAtArcLength(double s_m) const
{
  const auto& path = impl_->path;
  const auto it =
      std::lower_bound(path.begin(), path.end(), s_m, [](const PathSample& p, double v) {
        return p.s < v;
      });
  const auto k = std::min<std::ptrdiff_t>(it - path.begin(), path.size() - 1);
  return impl_->sceneOfSample(static_cast<std::size_t>(k));
}

double
SimulatedWorld::pathLength() const
{
  return impl_->path.back().s;
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
    const double h0 = w.smoothGroundAt(o.x(), o.y(), &gx0, &gy0);
    const bool march = w.has_highway && w.sceneAt(o.x(), o.y()) == SceneType::kHighway;

    for (std::size_t r = r0; r < r1; ++r) {
      const Eigen::Vector3d& d = dirs[r];
      RayHit& out = hits[r];
      double best = max_range_m, best_cos = 1.0;
      float best_refl = 0.0f;
      bool found = false, is_ground = false;

      double t_ground, cos_ground;
      if (w.groundHit(o, d, max_range_m, h0, gx0, gy0, march, t_ground, cos_ground)) {
        best = t_ground;
        best_cos = cos_ground;
        const Eigen::Vector3d p = o + t_ground * d;
        best_refl =
            w.distanceAt(p.x(), p.y()) < w.roadHalfWidthAt(p.x(), p.y()) ? 0.12f : 0.28f;
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
              const Primitive& prim = w.prims[id];
              double t, cos_inc, t_out;
              const bool porous = prim.mean_free_path > 0.0f;
              if (intersect(
                      prim, o, d, 1e-6, best, t, cos_inc, porous ? &t_out : nullptr) &&
                  (!porous || w.porousStop(id, o, d, t, t_out, best, t, cos_inc))) {
                best = t;
                best_cos = cos_inc;
                best_refl = prim.reflectivity;
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
