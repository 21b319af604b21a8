#pragma once
/// \file world_impl.h
/// \brief Internal to the simulator: SimulatedWorld::Impl and the types it is made of
/// (primitives, grids, deterministic random numbers). Its members are defined in
/// lidar_simulator_world.cpp (parameters, public interface), world_build.cpp (path,
/// scenes, ground, ray grid, moving cars), world_objects.cpp (static objects) and
/// world_rays.cpp (ray casting). Not installed.

#include "simulator_hash.h"
#include "simulator_traffic.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <memory>
#include <pcl/simulation/lidar_simulator.h>
#include <queue>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

namespace pcl {
namespace rast {
namespace world_detail {

using simulator_detail::kPi;
constexpr double kInf = std::numeric_limits<double>::infinity();

// ---- deterministic hashing and random numbers (portable, no std distributions) ----

using simulator_detail::splitmix64;

inline std::uint64_t
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

inline Primitive
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
bool intersect(const Primitive& p,
               const Eigen::Vector3d& o,
               const Eigen::Vector3d& d,
               double t_min,
               double t_max,
               double& t_hit,
               double& cos_inc,
               double* t_exit = nullptr);

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
  /// Ground level (SimulatedWorld::Impl::assignGroundLevels): 0 unless a pass of the
  /// path runs over a place another pass drove at another height.
  int level = 0;
};

struct MovingCar
{
  double s0, speed_mps, length, width;
  int direction;
  float reflectivity;
};

} // namespace world_detail

using namespace world_detail;

struct SimulatedWorld::Impl
{
  WorldParams params;
  std::uint64_t seed = 0;
  std::uint64_t drive_seed = 0; ///< the moving traffic's (SimulatedWorld's drive_seed)
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
  /// Height fields of the ground levels above 0 (level L at L - 1): where a pass of
  /// the trajectory runs over a place another pass drove metres higher or lower
  /// (KITTI ground truth drifts vertically: 02, 08, 09), one field cannot pass below
  /// both, and a sensor below the ground sees none of it. Each level has its own
  /// field; a ray uses the level of the path sample nearest its origin.
  std::vector<std::vector<double>> upper_ground;
  double body_height = 0.0; ///< of the path's poses above the ground
  Grid2 level_grid;         ///< 20 m cells listing the path samples (levels only)
  std::vector<std::vector<std::uint32_t>> level_cells;

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
  /// A grid of \a cell over the path's bounding box grown by \a margin.
  Grid2 gridAroundPath(double cell, double margin) const;
  void buildDistanceField();
  void buildGround();
  /// PathSample::level: a sample gets the lowest level (its predecessor's first) on
  /// which no sample of another pass (> 100 m of path away) within kLevelReach lies
  /// more than kLevelRise higher or lower.
  void assignGroundLevels();
  /// Whether path sample \a k conflicts with a listed sample on \a level.
  bool conflictsWithLevel(std::size_t k, int level) const;
  static constexpr double kLevelReach = 10.0; ///< [m] horizontally
  static constexpr double kLevelRise = 2.0;   ///< [m] of ground height
  void raiseEmbankments(std::vector<double>& field) const;
  /// The static objects, layer by layer (world_objects.cpp).
  void placeObjects();
  void placeBuildings();
  void placeRoadsideTreesAndPoles();
  void placeParkTrees();
  void placeParkedCars();
  void placeWallsAndHedges();
  template <class Body>
  void forLots(int layer, double lot, double d_lo, double d_hi, Body&& body);
  /// Whether the 64 m block at (x, y) is open (parks, fields between buildings).
  bool isOpenBlock(double x, double y) const;
  /// Add \a p when it keeps \a margin from the corridor.
  bool keep(const Primitive& p, double margin);
  /// Mean free path of tree crowns (0: solid).
  float crownFreePath() const;
  Primitive treeCrown(double cx,
                      double cy,
                      double g,
                      double trunk_h,
                      double rx,
                      double rz,
                      float reflectivity) const;
  Primitive treeTrunk(
      double cx, double cy, double g, double trunk_h, double rz, double radius) const;
  /// The layers of the scenes other than suburbs.
  void placeSceneObjects();
  void placeUrbanCanyons();
  void placeGuardRails();
  void placeTunnels();
  void placeFieldObjects();
  template <class Body>
  void forSegments(int layer, SceneType type, double seg_len, Body&& body);
  Primitive besideRoad(const PathSample& ps,
                       double side,
                       double offset,
                       double depth,
                       double length,
                       double z_lo,
                       double z_hi,
                       float reflectivity,
                       double along = 0.0) const;
  void buildRayGrid();
  void placeMovingCars(const PoseVector& poses, const std::vector<double>& timestamps_s);
  void clearCrossRoads();

  // -- queries --
  /// The ground without its roughness (height field of the path plus embankments) on
  /// \a level; -1: the level of the path sample nearest (x, y) (objects, cars).
  double smoothGroundAt(double x,
                        double y,
                        double* gx = nullptr,
                        double* gy = nullptr,
                        int level = -1) const;
  /// The ground: smoothGroundAt plus the roughness when params.rough_ground.
  double groundAt(double x,
                  double y,
                  double* gx = nullptr,
                  double* gy = nullptr,
                  int level = -1) const
  {
    const double h = smoothGroundAt(x, y, gx, gy, level);
    return params.rough_ground ? h + roughness.at(x, y, gx, gy) : h;
  }
  /// The ground level of a sensor at \a o: that of the path sample nearest to it in 3D
  /// (the sample's ground plus the body height), 0 without upper levels.
  int levelOfOrigin(const Eigen::Vector3d& o) const;
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
                   int level,
                   double& t,
                   double& cos_inc) const;
  /// A smooth-ground crossing at \a t with gradient (gx, gy) made a hit: refined on
  /// the rough ground if there is one, kept when within (0, t_max), with its incidence.
  bool finishGroundHit(const Eigen::Vector3d& o,
                       const Eigen::Vector3d& d,
                       double t_max,
                       double gx,
                       double gy,
                       int level,
                       double& t,
                       double& cos_inc) const;
  /// The rough ground's crossing near the smooth ground's at \a t (refined in place);
  /// (gx, gy): in the smooth ground's gradient there, out the rough ground's.
  void refineOnRoughGround(const Eigen::Vector3d& o,
                           const Eigen::Vector3d& d,
                           int level,
                           double& t,
                           double& gx,
                           double& gy) const;
  double distanceAt(double x, double y) const;
  float headingAt(double x, double y) const
  {
    return heading[dist_grid.index(dist_grid.ix(x), dist_grid.iy(y))];
  }
  /// Moving vehicles and their boxes at time t.
  std::vector<MovingVehicle> movingVehicles(double time_s) const;
  std::vector<Primitive> movingCarBoxes(double time_s) const;
  /// Both castRays: ray r starts at origins[r] (kOwnOrigins) or all at origins[0].
  /// Each run of consecutive rays with the same origin shares the ground below it and
  /// the moving cars near it. A template so that one origin per frame costs what it
  /// did before rays had their own.
  /// What the rays of one origin share: the smooth ground below it, whether rays that
  /// miss the Newton steps are marched, the moving cars in range.
  struct RayOrigin
  {
    double h0 = 0.0, gx0 = 0.0, gy0 = 0.0;
    int level = 0; ///< of the ground (levelOfOrigin)
    bool march = false;
    const std::vector<Primitive>* near_movers = nullptr;
  };
  /// The ground below the origin (\a origin: smooth ground, its level) is shared by
  /// all rays of a frame. origin.march: rays the Newton steps miss are marched
  /// (origins on highways, whose embankments rise beside the road).
  bool groundHit(const Eigen::Vector3d& o,
                 const Eigen::Vector3d& d,
                 double t_max,
                 const RayOrigin& origin,
                 double& t,
                 double& cos_inc) const;
  /// The nearest hit of a ray so far (range t, incidence, reflectivity).
  struct NearestHit
  {
    double t = 0.0, cos_inc = 1.0;
    float reflectivity = 0.0f;
    bool found = false, ground = false;
  };
  RayHit castRay(const Eigen::Vector3d& o,
                 const Eigen::Vector3d& d,
                 double max_range_m,
                 const RayOrigin& origin,
                 std::uint32_t ray_id,
                 std::vector<std::uint32_t>& mailbox) const;
  void traverseRayGrid(const Eigen::Vector3d& o,
                       const Eigen::Vector3d& d,
                       std::uint32_t ray_id,
                       std::vector<std::uint32_t>& mailbox,
                       NearestHit& hit) const;
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

inline double
SimulatedWorld::Impl::smoothGroundAt(
    double x, double y, double* gx, double* gy, int level) const
{
  // Bilinear interpolation between nodes at (x0 + i * cell, y0 + j * cell).
  const Grid2& g = ground_grid;
  if (level < 0 && !upper_ground.empty())
    level = path[nearest[dist_grid.index(dist_grid.ix(x), dist_grid.iy(y))]].level;
  const std::vector<double>& ground = level > 0 ? upper_ground[level - 1] : this->ground;
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

} // namespace rast
} // namespace pcl
