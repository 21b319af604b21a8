/// \file lidar_simulator_world.cpp
/// \brief SimulatedWorld: procedural world generation around a trajectory and ray
/// casting against it (ground height field + analytic primitives in a 2D grid), with
/// scene types along the path, optional rough ground and porous vegetation.

/// The world is split over world_build.cpp, world_objects.cpp and world_rays.cpp
/// (see world_impl.h); this file holds the parameters and the public interface.

#include "world_impl.h"

namespace pcl {
namespace rast {

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

// ---- public interface ----

SimulatedWorld::SimulatedWorld(const WorldParams& params,
                               const PoseVector& T_world_body,
                               double body_height_m,
                               std::uint64_t seed,
                               const std::vector<double>& timestamps_s,
                               std::uint64_t drive_seed)
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
  impl_->drive_seed = drive_seed != 0 ? drive_seed : seed;
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

} // namespace rast
} // namespace pcl
