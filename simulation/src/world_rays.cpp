/// \file world_rays.cpp
/// \brief Ray casting against SimulatedWorld: ray-primitive intersection, the ground
/// (Newton steps, marching, rough ground), porous vegetation and the 2D ray grid.

#include "world_impl.h"

namespace pcl {
namespace rast {

namespace world_detail {

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
          double* t_exit)
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

} // namespace world_detail

inline bool
SimulatedWorld::Impl::groundHit(const Eigen::Vector3d& o,
                                const Eigen::Vector3d& d,
                                double t_max,
                                const RayOrigin& origin,
                                double& t,
                                double& cos_inc) const
{
  // Newton on f(t) = o_z + t d_z - h(o_xy + t d_xy) on the smooth ground, started
  // from the tangent plane of the ground below the origin. Embankments (highways)
  // fall back to marching; rough ground refines the smooth crossing.
  double gx, gy;
  const bool march = origin.march;
  const int level = origin.level;
  const double slope0 = d.z() - origin.gx0 * d.x() - origin.gy0 * d.y();
  if (slope0 >= -1e-9 || o.z() <= origin.h0)
    return march && marchGround(o, d, t_max, level, t, cos_inc);
  t = (o.z() - origin.h0) / -slope0;
  const int iterations = march ? 12 : 6;
  for (int it = 0; it < iterations; ++it) {
    if (t > 2.0 * t_max)
      break;
    const double h =
        smoothGroundAt(o.x() + t * d.x(), o.y() + t * d.y(), &gx, &gy, level);
    const double f = o.z() + t * d.z() - h;
    const double df = d.z() - gx * d.x() - gy * d.y();
    if (std::abs(f) < 5e-4)
      return finishGroundHit(o, d, t_max, gx, gy, level, t, cos_inc);
    if (df >= -1e-9)
      break;
    t -= f / df;
  }
  return march && marchGround(o, d, t_max, level, t, cos_inc);
}

bool
SimulatedWorld::Impl::finishGroundHit(const Eigen::Vector3d& o,
                                      const Eigen::Vector3d& d,
                                      double t_max,
                                      double gx,
                                      double gy,
                                      int level,
                                      double& t,
                                      double& cos_inc) const
{
  if (params.rough_ground)
    refineOnRoughGround(o, d, level, t, gx, gy);
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
                                  int level,
                                  double& t,
                                  double& cos_inc) const
{
  auto f = [&](double tt) {
    return o.z() + tt * d.z() -
           smoothGroundAt(
               o.x() + tt * d.x(), o.y() + tt * d.y(), nullptr, nullptr, level);
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
    smoothGroundAt(o.x() + t * d.x(), o.y() + t * d.y(), &gx, &gy, level);
    return finishGroundHit(o, d, t_max, gx, gy, level, t, cos_inc);
  }
  return false;
}

void
SimulatedWorld::Impl::refineOnRoughGround(const Eigen::Vector3d& o,
                                          const Eigen::Vector3d& d,
                                          int level,
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
                                  : groundAt(x, y, &gx, &gy, level);
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

/// Step 3 of a ray: the primitives of the ray grid, by a 2D DDA (Amanatides & Woo) over
/// the cells the ray's footprint crosses, up to the nearest hit so far.
void
SimulatedWorld::Impl::traverseRayGrid(const Eigen::Vector3d& o,
                                      const Eigen::Vector3d& d,
                                      std::uint32_t ray_id,
                                      std::vector<std::uint32_t>& mailbox,
                                      NearestHit& hit) const
{
  const Grid2& g = ray_grid;
  const double gx_min = g.x0, gy_min = g.y0;
  const double gx_max = g.x0 + g.nx * g.cell, gy_max = g.y0 + g.ny * g.cell;
  double t_enter = 0.0, t_exit = hit.t;
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
  if (!prims.empty() && clip(o.x(), dx, gx_min, gx_max) &&
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
    while (t_cell < hit.t) {
      const double t_next = std::min(t_max_x, t_max_y);
      const std::size_t c = g.index(i, j);
      const double z_low =
          o.z() + std::min(t_cell * d.z(), std::min(t_next, hit.t) * d.z());
      if (z_low <= cell_top[c]) {
        for (std::uint32_t k = cell_start[c]; k < cell_start[c + 1]; ++k) {
          const std::uint32_t id = cell_items[k];
          if (mailbox[id] == ray_id)
            continue;
          mailbox[id] = ray_id;
          const Primitive& prim = prims[id];
          double t, cos_inc, t_out;
          const bool porous = prim.mean_free_path > 0.0f;
          if (intersect(prim, o, d, 1e-6, hit.t, t, cos_inc, porous ? &t_out : nullptr) &&
              (!porous || porousStop(id, o, d, t, t_out, hit.t, t, cos_inc))) {
            hit.t = t;
            hit.cos_inc = cos_inc;
            hit.reflectivity = prim.reflectivity;
            hit.found = true;
            hit.ground = false;
          }
        }
      } else if (d.z() > 0 && z_low > max_top) {
        break; // above everything, climbing
      }
      if (t_next >= hit.t)
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
}

/// One ray: the ground (steps 1), the moving cars near its origin (2) and the static
/// primitives (3); the nearest wins.
RayHit
SimulatedWorld::Impl::castRay(const Eigen::Vector3d& o,
                              const Eigen::Vector3d& d,
                              double max_range_m,
                              const RayOrigin& origin,
                              std::uint32_t ray_id,
                              std::vector<std::uint32_t>& mailbox) const
{
  NearestHit hit;
  hit.t = max_range_m;
  double t_ground, cos_ground;
  if (groundHit(o, d, max_range_m, origin, t_ground, cos_ground)) {
    hit.t = t_ground;
    hit.cos_inc = cos_ground;
    const Eigen::Vector3d p = o + t_ground * d;
    hit.reflectivity =
        distanceAt(p.x(), p.y()) < roadHalfWidthAt(p.x(), p.y()) ? 0.12f : 0.28f;
    hit.found = hit.ground = true;
  }
  for (const auto& b : *origin.near_movers) {
    const double ox = b.cx - o.x(), oy = b.cy - o.y(), oz = b.cz - o.z();
    const double tca = ox * d.x() + oy * d.y() + oz * d.z();
    const double rad2 = b.hx * b.hx + b.hy * b.hy + b.hz * b.hz;
    if (ox * ox + oy * oy + oz * oz - tca * tca > rad2)
      continue;
    double t, c;
    if (intersect(b, o, d, 1e-6, hit.t, t, c)) {
      hit.t = t;
      hit.cos_inc = c;
      hit.reflectivity = b.reflectivity;
      hit.found = true;
      hit.ground = false;
    }
  }
  traverseRayGrid(o, d, ray_id, mailbox, hit);
  RayHit out;
  if (hit.found) {
    out.range_m = hit.t;
    out.cos_incidence = hit.cos_inc;
    out.reflectivity = hit.reflectivity;
    out.is_ground = hit.ground;
  }
  return out;
}

template <bool kOwnOrigins>
void
SimulatedWorld::Impl::castRays(const Eigen::Vector3d* origins,
                               const std::vector<Eigen::Vector3d>& dirs,
                               double max_range_m,
                               double time_s,
                               std::vector<RayHit>& hits) const
{
  hits.assign(dirs.size(), RayHit());
  std::vector<std::uint32_t> mailbox(prims.size(),
                                     std::numeric_limits<std::uint32_t>::max());
  const std::vector<Primitive> movers = movingCarBoxes(time_s);
  std::vector<Primitive> near_movers;
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
    RayOrigin origin;
    origin.level = levelOfOrigin(o);
    origin.h0 = smoothGroundAt(o.x(), o.y(), &origin.gx0, &origin.gy0, origin.level);
    origin.march = has_highway && sceneAt(o.x(), o.y()) == SceneType::kHighway;
    origin.near_movers = &near_movers;
    for (std::size_t r = r0; r < r1; ++r)
      hits[r] = castRay(
          o, dirs[r], max_range_m, origin, static_cast<std::uint32_t>(r), mailbox);
    r0 = r1;
  }
}

template void SimulatedWorld::Impl::castRays<true>(const Eigen::Vector3d*,
                                                   const std::vector<Eigen::Vector3d>&,
                                                   double,
                                                   double,
                                                   std::vector<RayHit>&) const;
template void SimulatedWorld::Impl::castRays<false>(const Eigen::Vector3d*,
                                                    const std::vector<Eigen::Vector3d>&,
                                                    double,
                                                    double,
                                                    std::vector<RayHit>&) const;

} // namespace rast
} // namespace pcl
