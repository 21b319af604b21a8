/// \file world_objects.cpp
/// \brief SimulatedWorld's static objects: buildings, trees, poles, parked cars, walls
/// and hedges on hashed lots along the path, and the layers of the other scene types.

#include "world_impl.h"

namespace pcl {
namespace rast {

/// Each object lot draws from its own stream hashed from (seed, layer, lot index), so
/// the world is a function of the seed and the path only: body(rng, x, y, d) for every
/// lot of side \a lot whose centre lies between \a d_lo and \a d_hi from the path.
template <class Body>
void
SimulatedWorld::Impl::forLots(
    int layer, double lot, double d_lo, double d_hi, Body&& body)
{
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
}

bool
SimulatedWorld::Impl::isOpenBlock(double x, double y) const
{
  Rng rng(hashOf(seed,
                 100,
                 static_cast<long>(std::floor(x / 64.0)),
                 static_cast<long>(std::floor(y / 64.0))));
  return rng.uniform() < params.open_fraction;
}

bool
SimulatedWorld::Impl::keep(const Primitive& p, double margin)
{
  if (!clearOfCorridor(p, margin))
    return false;
  prims.push_back(p);
  return true;
}

float
SimulatedWorld::Impl::crownFreePath() const
{
  return params.porous_vegetation ? static_cast<float>(params.vegetation_mean_free_path_m)
                                  : 0.0f;
}

/// A tree's crown: an ellipsoid (radii rx, rx, rz) above a trunk of height trunk_h on
/// the ground at g; porous with params.porous_vegetation.
Primitive
SimulatedWorld::Impl::treeCrown(double cx,
                                double cy,
                                double g,
                                double trunk_h,
                                double rx,
                                double rz,
                                float reflectivity) const
{
  Primitive crown;
  crown.kind = Kind::kEllipsoid;
  crown.cx = cx;
  crown.cy = cy;
  crown.cz = g + trunk_h + 0.8 * rz;
  crown.hx = crown.hy = rx;
  crown.hz = rz;
  crown.reflectivity = reflectivity;
  crown.mean_free_path = crownFreePath();
  return crown;
}

/// The trunk of radius \a radius under treeCrown(cx, cy, g, trunk_h, rx, rz): from
/// 0.5 m below the ground into the crown.
Primitive
SimulatedWorld::Impl::treeTrunk(
    double cx, double cy, double g, double trunk_h, double rz, double radius) const
{
  Primitive trunk;
  trunk.kind = Kind::kCylinder;
  trunk.cx = cx;
  trunk.cy = cy;
  trunk.hx = radius;
  trunk.hz = 0.5 * (trunk_h + 0.5 + 0.5 * rz);
  trunk.cz = g - 0.5 + trunk.hz;
  trunk.reflectivity = 0.35f;
  return trunk;
}

/// Buildings on 16 m lots, set back from the corridor, some with an annex (L shape)
/// or a rooftop structure.
/// Urban canyons: only behind their facades (placeSceneObjects), denser.
void
SimulatedWorld::Impl::placeBuildings()
{
  const double corridor = params.corridor_half_width_m;
  const double max_d = params.max_object_distance_m;
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
}

/// Roadside trees and poles (with a sign board) on 4 m lots; urban canyons have
/// hardly any trees.
void
SimulatedWorld::Impl::placeRoadsideTreesAndPoles()
{
  const double corridor = params.corridor_half_width_m;
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
          const Primitive crown = treeCrown(
              cx, cy, g, trunk_h, rx, rz, static_cast<float>(rng.uniform(0.4, 0.6)));
          if (!keep(crown, 0.0))
            return;
          prims.push_back(treeTrunk(cx, cy, g, trunk_h, rz, rng.uniform(0.15, 0.3)));
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
}

/// Trees in parks and gaps further out, denser in open blocks.
/// Highways: sparse, and only beyond ~30 m of the road.
void
SimulatedWorld::Impl::placeParkTrees()
{
  const double corridor = params.corridor_half_width_m;
  const double max_d = params.max_object_distance_m;
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
    const Primitive crown =
        treeCrown(cx, cy, g, trunk_h, rx, rz, static_cast<float>(rng.uniform(0.4, 0.6)));
    if (!keep(crown, 0.0))
      return;
    prims.push_back(treeTrunk(cx, cy, g, trunk_h, rz, rng.uniform(0.2, 0.4)));
  });
}

/// Parked cars at the kerb, aligned with the road, never overlapping each other.
void
SimulatedWorld::Impl::placeParkedCars()
{
  const double corridor = params.corridor_half_width_m;
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
}

/// Walls and fences parallel to the road behind the kerb (suburbs); with porous
/// vegetation, hedges on some of the lots without a wall.
void
SimulatedWorld::Impl::placeWallsAndHedges()
{
  const double corridor = params.corridor_half_width_m;
  const float crown_free_path = crownFreePath();
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
}

void
SimulatedWorld::Impl::placeObjects()
{
  placeBuildings();
  placeRoadsideTreesAndPoles();
  placeParkTrees();
  placeParkedCars();
  placeWallsAndHedges();
  if (!plain)
    placeSceneObjects();
}

/// Structures along the road: body(rng, sample, k) for the middle sample of every
/// seg_len of arc length in stretches of scene \a type, each segment with its own
/// stream. A segment driven a second time (its cell is nearest to a sample >= 30 m
/// earlier on the path) has its structures already.
template <class Body>
void
SimulatedWorld::Impl::forSegments(int layer, SceneType type, double seg_len, Body&& body)
{
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
}

/// A box along the road whose inner face is `offset` beside the path sample on `side`
/// (+1 left, -1 right), `along` ahead of it, heights relative to the smooth ground
/// (long structures do not follow the few cm of rough relief).
Primitive
SimulatedWorld::Impl::besideRoad(const PathSample& ps,
                                 double side,
                                 double offset,
                                 double depth,
                                 double length,
                                 double z_lo,
                                 double z_hi,
                                 float reflectivity,
                                 double along) const
{
  const double c = std::cos(ps.heading), s = std::sin(ps.heading);
  const double lateral = side * (offset + 0.5 * depth);
  const double x = ps.x - lateral * s + along * c, y = ps.y + lateral * c + along * s;
  const double g = smoothGroundAt(x, y);
  return makeBox(x, y, g + z_lo, g + z_hi, length, depth, ps.heading, reflectivity);
}

/// Urban canyon: 12 m facade segments 5-7 m outside the corridor, 10 % gaps.
void
SimulatedWorld::Impl::placeUrbanCanyons()
{
  const double corridor = params.corridor_half_width_m;
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
}

/// Highway: guard rails (0.3 m at 0.5-0.8 m) 0.5 m beyond the road's edge on both
/// sides, on posts every 2.67 m. Embankments are in the ground (raiseEmbankments).
void
SimulatedWorld::Impl::placeGuardRails()
{
  const double rail = params.highway_half_width_m + 0.5;
  forSegments(21, SceneType::kHighway, 8.0, [&](Rng&, const PathSample& ps, std::size_t) {
    for (const double side : {-1.0, 1.0}) {
      keep(besideRoad(ps, side, rail, 0.1, 8.05, 0.5, 0.8, 0.6f), 0.0);
      for (int p = -1; p <= 1; ++p)
        keep(besideRoad(ps, side, rail + 0.1, 0.15, 0.15, -0.3, 0.75, 0.5f, p * 8.0 / 3),
             0.0);
    }
  });
}

/// Tunnel: per stretch two smooth walls 0.8-2 m outside the corridor, 5-7 m tall, and
/// a ceiling over part of it (70 % of the stretches). Like a real tunnel, the walls
/// carry small fixtures at irregular spacing: lamps high up (about one per 12 m and
/// side), cabinets and emergency-niche doors at the bottom (one per ~50 m). Only
/// they fix a position along the road.
/// 10 m segments: fewer boxes per ray-grid cell (every ray in a tunnel is near them).
void
SimulatedWorld::Impl::placeTunnels()
{
  const double corridor = params.corridor_half_width_m;
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
}

/// Open field / parking lot: a few lamp posts (with an arm) ...
void
SimulatedWorld::Impl::placeFieldObjects()
{
  const double corridor = params.corridor_half_width_m;
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
SimulatedWorld::Impl::placeSceneObjects()
{
  placeUrbanCanyons();
  placeGuardRails();
  placeTunnels();
  placeFieldObjects();
}

} // namespace rast
} // namespace pcl
