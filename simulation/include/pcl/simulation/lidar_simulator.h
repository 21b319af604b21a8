#pragma once
/// \file lidar_simulator.h
/// \brief A LiDAR sequence simulator: a procedural, deterministic world built around
/// a trajectory (ground following the path's elevation, buildings, trees, poles,
/// parked cars, walls and fences, optional moving traffic: cars along the path or
/// realistic lanes, stops and cross traffic timed to the ego, see TrafficParams) and
/// ray-cast sensor models (Velodyne HDL-64E, VLP-16, Ouster OS1-64, handheld Ouster
/// OS0-128). Generated paths can stop and go (PathParams::num_stops).
///
/// The world's scene type (SceneType: suburb, urban canyon, highway, open field,
/// tunnel) is fixed for the whole path or, with WorldParams::mixed_scenes, changes
/// along it in stretches of 150-500 m. Optional: rough ground (a few cm of
/// high-frequency relief) and porous vegetation (tree crowns and hedges that rays
/// enter and stop inside at a random depth, or pass through).
///
/// Pipeline: trajectory (T_world_body) -> SimulatedWorld (built once, consistent for
/// every pose) -> per frame: sensor pose T_world_sensor = T_world_body *
/// T_body_sensor(t), one ray per beam and azimuth step, range noise / dropouts /
/// intensity from a counter-based hash of (seed, frame, ray) so frame i never depends on
/// other frames. \ingroup simulation
///
/// With LidarSimulatorParams::imperfections the sensor is as flawed as a real one:
/// per-beam calibration error, spurious early returns, mixed pixels at depth edges and
/// intensity noise (SensorImperfectionParams), all from the seed.
///
/// Scans are instantaneous by default (every column cast from the frame's pose).
/// With LidarSimulatorParams::raw_sweep they are raw sweeps of a spinning sensor, which
/// moves while it turns, as motion compensation (deskewing) sees them.
///
/// Spin convention (KITTI / Velodyne; the deskewing code relies on it): the head spins
/// clockwise seen from above, i.e. the azimuth a = atan2(y, x) in the sensor frame
/// decreases over time. The forward column (a = 0, +x) fires at the frame's timestamp;
/// the sweep starts behind the sensor (a = +180 deg) at timestamp - period / 2 and ends
/// behind it (a = -180 deg) at timestamp + period / 2. A point at azimuth a in (-pi, pi]
/// fires at the offset
///
///     tau(a) = -a / (2 pi) * period
///
/// from the frame's timestamp, where period = LidarSimulator::framePeriod (the
/// difference of neighbouring frame timestamps).

#include <Eigen/Core>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <memory>
#include <pcl/point_cloud.h>
#include <pcl/point_types.h>
#include <pcl/io/pose_io.h>
#include <string>
#include <vector>

namespace pcl {
namespace rast {

/// \brief The simulated sensors.
enum class SensorModel
{
  kHdl64,   ///< Velodyne HDL-64E as on KITTI: 64 beams +2..-24.8 deg, 2000 steps, 120 m
  kVlp16,   ///< Velodyne VLP-16: 16 beams +-15 deg, 0.2 deg steps, 100 m
  kOs1_64,  ///< Ouster OS1-64: 64 beams +-16.6 deg, 1024 steps, 120 m
  kOs0_128, ///< handheld Ouster OS0-128: 128 beams +-45 deg, 1024 steps, 50 m, tilted
  kHdl32    ///< Velodyne HDL-32E: 32 beams +10.67..-30.67 deg, 2170 steps, 100 m
};

/// \brief Built-in generated paths.
enum class PathType
{
  kStraight,   ///< along +x
  kLoop,       ///< a closed rounded-rectangle loop, driven ~1.15 times (revisit)
  kFigureEight ///< a lemniscate of Gerono, driven ~1.1 times, crossing itself at 90 deg
};

/// \brief Kinds of surroundings a drive passes through (WorldParams::scene).
enum class SceneType
{
  kSuburb,      ///< houses, trees, poles, parked cars, walls and fences (the default)
  kUrbanCanyon, ///< near-continuous 10-40 m facades 5-7 m outside the corridor, both
                ///< sides; parked cars, lamp posts, hardly any trees
  kHighway,     ///< wide road, guard rails on both sides, embankments; nothing else
                ///< within ~30 m (degenerate along the road for point-to-plane ICP)
  kOpenField,   ///< parking lot: flat, a few lamp posts, rows of parked cars far out
  kTunnel       ///< two smooth 5-7 m walls 4.8-6 m from the path, partly roofed,
                ///< with a lamp about every 12 m and a cabinet or niche door about
                ///< every 50 m per side; nothing else (nearly degenerate along the road)
};

/// \brief Parse "suburb", "urban", "highway", "field", "tunnel".
/// \throws std::invalid_argument naming the bad value.
SceneType sceneTypeFromString(const std::string& name);
/// \brief The inverse of sceneTypeFromString.
std::string toString(SceneType type);

/// \brief Parse "hdl64", "vlp16", "os1-64", "os0-128".
/// \throws std::invalid_argument naming the bad value.
SensorModel sensorModelFromString(const std::string& name);
/// \brief The inverse of sensorModelFromString.
std::string toString(SensorModel model);
/// \brief Parse "straight", "loop", "eight".
/// \throws std::invalid_argument naming the bad value.
PathType pathTypeFromString(const std::string& name);
/// \brief The inverse of pathTypeFromString.
std::string toString(PathType type);

/// \brief Geometry and error model of one sensor.
struct SensorSpec
{
  std::vector<double> beam_elevations_rad; ///< one per beam, top to bottom
  int azimuth_steps = 2000;                ///< columns per revolution
  double min_range_m = 1.0;                ///< returns closer than this are dropped
  double max_range_m = 120.0;              ///< no return beyond
  double range_noise_std_m = 0.02;         ///< gaussian range noise (1 sigma)
  double dropout_rate = 0.01;              ///< base probability of a missing return
  double mount_height_m = 1.73;            ///< body origin height above the ground
  bool handheld = false;                   ///< tilt and sway applied (T_body_sensor)
  double tilt_pitch_rad = 0.0;             ///< handheld: nose-down pitch of the sensor
  double sway_pitch_rad = 0.0;             ///< handheld: amplitude of the pitch sway
  double sway_roll_rad = 0.0;              ///< handheld: amplitude of the roll sway
  double sway_frequency_hz = 0.0; ///< handheld: pitch sway frequency (roll: half)

  /// \brief Number of rays per frame (beams x azimuth steps).
  std::size_t raysPerFrame() const
  {
    return beam_elevations_rad.size() * static_cast<std::size_t>(azimuth_steps);
  }
};

/// \brief The built-in specification of \a model.
SensorSpec sensorSpec(SensorModel model);

/// \brief Mounting of the sensor on the body at time \a time_s: identity for vehicle
/// sensors, tilt plus sway for the handheld one.
Pose3d bodyToSensor(const SensorSpec& spec, double time_s);

/// \brief Parameters of a generated path.
struct PathParams
{
  PathType type = PathType::kLoop;
  int num_frames = 200;               ///< poses generated
  double speed_mps = 10.0;            ///< 10 m/s at 10 Hz: 1 m per frame, like KITTI
  double rate_hz = 10.0;              ///< frames per second
  double height_m = 1.73;             ///< body origin above the ground
  double elevation_amplitude_m = 2.0; ///< gentle hills: +- this over ~300 m
  double revisit_fraction =
      0.15; ///< loop/eight: extra laps driven after the first (0.15: 1.15 laps)
  /// Stop-and-go: the body stops this many times, evenly spread over the drive's
  /// duration: it brakes at acceleration_mps2, stands still for stop_duration_s (poses
  /// identical, frames still stepping at rate_hz) and accelerates back to speed_mps.
  /// 0: constant speed, bit-identical to the path without stops.
  int num_stops = 0;
  double stop_duration_s = 8.0;   ///< standstill per stop, seconds
  double acceleration_mps2 = 2.0; ///< braking and starting, m/s^2 (cars: ~1.5-2.5)

  /// \brief True when every value is usable; otherwise \a why says which is not.
  bool isValid(std::string* why = nullptr) const;
};

/// \brief Body poses T_world_body of a generated path (x forward, z up, following
/// the terrain's slope). The first pose is at the origin heading along +x. Frame i is
/// at time i / rate_hz; with PathParams::num_stops the speed profile brakes, stands
/// and accelerates (stop k's standstill is centred at (k + 1) / (num_stops + 1) of the
/// duration), so the path is shorter than speed_mps times the duration.
/// \throws std::invalid_argument when \a params is invalid.
PoseVector generatePath(const PathParams& params);

/// \brief Models of the moving traffic (WorldParams::moving_cars).
enum class TrafficMode
{
  kAlongPath, ///< cars ping-pong along the path, lane_offset_m left of it, 5-12 m/s,
              ///< independent of the ego vehicle (the default; unchanged)
  kRealistic  ///< lanes beside and opposite the ego, stops beside it, cross traffic
};

/// \brief Parse "along-path", "realistic".
/// \throws std::invalid_argument naming the bad value.
TrafficMode trafficModeFromString(const std::string& name);
/// \brief The inverse of trafficModeFromString.
std::string toString(TrafficMode mode);

/// \brief Parameters of the moving traffic.
///
/// TrafficMode::kRealistic knows the ego vehicle's timing (the world's timestamps) and
/// is deterministic for the seed:
/// - a lane lane_offset_m left of the path in the ego's direction and an oncoming lane
///   oncoming_lane_offset_m left of it. Each lane has its own speed (9-13 and 10-14
///   m/s) and vehicles of varied size and kind: cars, vans and a share
///   heavy_vehicle_fraction of trucks and buses (7-12.5 m long, 3-3.8 m tall). A lane
///   never overlaps itself (bumper gaps >= 3 m along the lane, also in bends) and no
///   lane enters the ego's;
/// - every ego standstill longer than light_stop_min_s (consecutive frames slower than
///   0.25 m/s, from the poses and timestamps) is a red light: companions_per_stop cars or
///   vans in the lane beside brake with the ego 3-6 s before it stands, stand beside it
///   (the first within -2.5..+0.5 m of its centre) or queue behind, and pull away with
///   their own acceleration (1.2-3 m/s^2) 0.7-1.5 s before or 0.7-2.5 s after the ego
///   does; the free vehicles of both lanes that arrive during the red queue (the oncoming
///   ones beyond the cross road) and go one after the other;
/// - cross traffic on a perpendicular road 10-25 m ahead of the stopped ego, both
///   directions, 8-14 m/s, 2-4.5 s apart: it crosses the path only while the ego
///   stands (the last car 2.5 s before it moves on), visible +- 60 m along its road;
///   the static objects on that road are removed (an open intersection);
/// - the road is widened: static objects keep oncoming_lane_offset_m + 1.5 m from the
///   path (at least corridor_half_width_m).
/// Lane vehicles are shown within 150 m of arc length of the ego's position at the
/// query time (less where the path comes back to a place sooner, so the two passes'
/// lanes do not meet), cross traffic within 250 m of it. The lanes follow the path's
/// geometry and the poses' heading; where a bend is much tighter than the lane offset
/// (a turn at a crossing) a lane vehicle that would touch the ego is not shown. Vehicles
/// are two boxes
/// (body and cabin, cab and cargo) or one (bus): as cheap to ray-cast as before.
struct TrafficParams
{
  TrafficMode mode = TrafficMode::kAlongPath;
  double oncoming_lane_offset_m = 6.5;  ///< oncoming lane: this far left of the path
  double same_direction_gap_m = 60.0;   ///< mean gap between vehicles beside the ego
  double oncoming_gap_m = 45.0;         ///< mean gap between oncoming vehicles
  double heavy_vehicle_fraction = 0.15; ///< share of trucks and buses
  int companions_per_stop = 2;          ///< cars that stop beside the ego at a light
  double light_stop_min_s = 2.0;        ///< ego standstill that is a red light

  bool isValid(std::string* why = nullptr) const;
};

/// \brief Kinds of moving vehicles (their size and box shape).
enum class VehicleKind
{
  kCar,   ///< 3.8-4.9 m long, 1.4-1.6 m tall
  kVan,   ///< 4.8-5.6 m long, 1.9-2.4 m tall
  kTruck, ///< 7-10 m long, 3.2-3.8 m tall: cab and cargo box
  kBus    ///< 11-12.5 m long, 3-3.3 m tall
};

/// \brief Where a moving vehicle drives.
enum class TrafficLane
{
  kAlongPath,     ///< TrafficMode::kAlongPath
  kSameDirection, ///< beside the ego, its direction
  kOncoming,      ///< opposite direction
  kCross          ///< perpendicular road ahead of a stopped ego
};

/// \brief A moving vehicle at one time: its bounding box on the ground (ground truth
/// of the dynamic objects).
struct MovingVehicle
{
  int id = 0; ///< stable over time
  VehicleKind kind = VehicleKind::kCar;
  TrafficLane lane = TrafficLane::kAlongPath;
  double x_m = 0.0, y_m = 0.0; ///< centre of the footprint (world frame)
  double yaw_rad = 0.0;        ///< heading of the vehicle's front
  double length_m = 4.5, width_m = 1.8, height_m = 1.5;
  float reflectivity = 0.5f;
};

/// \brief Parameters of the procedural world.
struct WorldParams
{
  /// The scene along the whole path, unless mixed_scenes. kSuburb is the world of
  /// earlier versions, bit-identical.
  SceneType scene = SceneType::kSuburb;
  /// Cut the path by arc length into stretches of scene_min_length_m to
  /// scene_max_length_m, each of a scene type drawn from the seed (never twice in a
  /// row) with shares suburb 35 %, urban canyon 25 %, highway 20 %, open field 10 %,
  /// tunnel 10 %; the first stretch is a suburb or an urban canyon (a first scan with
  /// structure). scene is then ignored. Every object layer uses the scene of the
  /// nearest path sample.
  bool mixed_scenes = false;
  double scene_min_length_m = 150.0; ///< mixed_scenes: shortest stretch
  double scene_max_length_m = 500.0; ///< mixed_scenes: longest stretch
  double highway_half_width_m = 8.0; ///< highway: road half width, rails 0.5 m beyond
  /// Deterministic relief of the ground: value noise of wavelengths 0.4-2 m from the
  /// seed, std ground_roughness_std_m. false: the smooth ground of earlier versions.
  bool rough_ground = false;
  double ground_roughness_std_m = 0.03; ///< rough_ground: std of the relief
  /// Tree crowns (and hedges, added along fences in suburbs) are porous: a ray that
  /// enters one stops at an exponential depth of mean vegetation_mean_free_path_m
  /// (hedges: half of it), or passes through when that lies beyond the exit. The depth
  /// is hashed from the seed, the primitive and the ray (origin and direction), so
  /// frames stay independent. false: solid crowns, no hedges.
  bool porous_vegetation = false;
  double vegetation_mean_free_path_m = 1.0; ///< porous_vegetation: crowns' mean depth
  double corridor_half_width_m = 4.0;  ///< kept free of static objects around the path
  double max_object_distance_m = 80.0; ///< objects are generated up to this from the path
  double building_probability = 0.6;   ///< chance a 16 m lot holds a building
  double open_fraction = 0.2;          ///< fraction of 64 m blocks without buildings
  double tree_probability = 0.2;       ///< chance a roadside 4 m lot holds a tree
  double pole_probability = 0.1;       ///< chance a roadside 4 m lot holds a pole
  double parked_car_probability = 0.2; ///< chance a kerbside 5 m lot holds a car
  double wall_probability = 0.2; ///< chance an 8 m lot beside the road holds a wall/fence
  double ground_smoothing_m =
      2.0;                    ///< softening length of the ground's blend of path heights
  bool moving_cars = false;   ///< cars driving along the path (not static)
  int num_moving_cars = 8;    ///< when moving_cars
  double lane_offset_m = 3.0; ///< moving cars drive this far left of the path
  TrafficParams traffic;      ///< the traffic model (default: along the path)

  bool isValid(std::string* why = nullptr) const;
};

/// \brief Result of casting one ray.
struct RayHit
{
  double range_m = 0.0;       ///< distance along the unit ray
  double cos_incidence = 1.0; ///< |cos| of the angle between ray and surface normal
  float reflectivity = 0.0f;  ///< material reflectivity in [0, 1]
  bool is_ground = false;     ///< hit the ground height field
};

/// \brief A static procedural world around a trajectory plus optional moving cars,
/// with a 2D grid of analytic primitives (oriented boxes, vertical cylinders,
/// ellipsoids) for fast ray casting. Deterministic for (params, trajectory, seed).
class SimulatedWorld
{
public:
  using Ptr = std::shared_ptr<SimulatedWorld>;
  using ConstPtr = std::shared_ptr<const SimulatedWorld>;

  /// \param[in] params world parameters
  /// \param[in] T_world_body the trajectory the world is built around
  /// \param[in] body_height_m height of the body origin above the ground
  /// \param[in] seed random seed
  /// \param[in] timestamps_s time of each pose (the ego's timing, for the realistic
  /// traffic), or empty for poses 0.1 s apart
  /// \param[in] drive_seed seeds the moving traffic instead of \a seed (0: \a seed):
  /// another drive through the same static world
  /// \throws std::invalid_argument on invalid params, an empty trajectory or
  /// timestamps that do not match the poses (realistic traffic: or do not increase).
  SimulatedWorld(const WorldParams& params,
                 const PoseVector& T_world_body,
                 double body_height_m,
                 std::uint64_t seed,
                 const std::vector<double>& timestamps_s = {},
                 std::uint64_t drive_seed = 0);
  ~SimulatedWorld();
  SimulatedWorld(const SimulatedWorld&) = delete;
  SimulatedWorld& operator=(const SimulatedWorld&) = delete;

  /// \brief Ground height at (x, y): a smooth field following the path's elevation.
  double groundHeight(double x, double y) const;
  /// \brief Horizontal distance from (x, y) to the nearest path sample (2 m grid,
  /// accurate to ~1.5 m; exact path samples are every <= 1 m).
  double distanceToPath(double x, double y) const;
  /// \brief Scene type at (x, y): that of the nearest path sample (2 m grid).
  SceneType sceneAt(double x, double y) const;
  /// \brief Scene type at arc length \a s_m along the path (clamped to the path). A
  /// place driven again keeps the scene of its first visit.
  SceneType sceneAtArcLength(double s_m) const;
  /// \brief Length of the path the world was built around (arc length, horizontal).
  double pathLength() const;
  /// \brief Number of static primitives.
  std::size_t numPrimitives() const;
  /// \brief The moving vehicles at time \a time_s (empty without moving cars): the
  /// ground truth of what castRays sees moving.
  std::vector<MovingVehicle> movingVehicles(double time_s) const;

  /// \brief Cast rays from \a origin along unit directions \a dirs (world frame)
  /// at time \a time_s (moving cars). hits[k].range_m <= 0 means no return.
  void castRays(const Eigen::Vector3d& origin,
                const std::vector<Eigen::Vector3d>& dirs,
                double max_range_m,
                double time_s,
                std::vector<RayHit>& hits) const;

  /// \brief Cast rays with their own origins: dirs[k] from origins[k] (world frame),
  /// at time \a time_s (moving cars). Consecutive rays with the same origin share its
  /// set-up (ground below it, cars in range), so keep them together: one origin per
  /// column of a raw sweep costs as much as one per frame.
  /// \throws std::invalid_argument when the sizes differ.
  void castRays(const std::vector<Eigen::Vector3d>& origins,
                const std::vector<Eigen::Vector3d>& dirs,
                double max_range_m,
                double time_s,
                std::vector<RayHit>& hits) const;

  /// \brief Cast one ray; false when nothing is hit within \a max_range_m.
  bool castRay(const Eigen::Vector3d& origin,
               const Eigen::Vector3d& dir,
               double max_range_m,
               double time_s,
               RayHit& hit) const;

private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

/// \brief Magnitudes of the sensor imperfections (used only with
/// LidarSimulatorParams::imperfections). The defaults model a street-worn spinning
/// LiDAR; setting one to 0 turns that effect off, which isolates the others in tests.
///
/// - Per-beam calibration error, fixed for the whole sequence (drawn from the seed):
///   beam b is fired at elevation e_b + d_b, d_b ~ N(0, elevation_bias_std_rad), and
///   its ranges read r + c_b, c_b ~ N(0, range_bias_std_m). The sensor believes the
///   nominal elevation e_b, so the point lands at the nominal direction times the range
///   measured along the biased ray.
/// - Range outliers: a share outlier_rate of the returns gets a uniform range in
///   [min_range_m, hit range] (spurious early returns: dust, rain, exhaust).
/// - Mixed pixels: when the same beam's ray in the next column hits something more than
///   mixed_pixel_jump_m nearer or farther, with mixed_pixel_probability the return
///   reads a uniform interpolation of the two ranges (a point floating between
///   foreground and background). Uses the hits already cast: no extra rays.
/// - Intensity noise: each intensity times N(1, intensity_noise_std), clamped to
///   [0, 1].
struct SensorImperfectionParams
{
  double elevation_bias_std_rad = 0.05 * 3.14159265358979323846 / 180.0; ///< 0.05 deg
  double range_bias_std_m = 0.015;      ///< per-beam range offset, 1 sigma
  double outlier_rate = 0.001;          ///< share of returns with a spurious early range
  double mixed_pixel_probability = 0.3; ///< chance a return at a depth edge is mixed
  double mixed_pixel_jump_m = 1.0;      ///< range jump to the next column that is an edge
  double intensity_noise_std = 0.1;     ///< multiplicative intensity noise, 1 sigma

  /// \brief True when every value is usable; otherwise \a why says which is not.
  bool isValid(std::string* why = nullptr) const;
};

/// \brief Parameters of the simulator.
struct LidarSimulatorParams
{
  SensorModel sensor = SensorModel::kHdl64;
  WorldParams world;
  std::uint64_t seed = 1;          ///< seeds the world and every frame's noise
  /// Another drive through the world of \a seed: when not 0, the moving traffic, every
  /// frame's noise and the sensor's imperfections (another unit's calibration) are
  /// drawn from it instead. The static world, the trajectory's intersections (where
  /// cross traffic may pass) and the porous vegetation stay those of \a seed.
  std::uint64_t drive_seed = 0;
  double frame_period_s = 0.1;     ///< times when no timestamps are given
  double range_noise_std_m = -1.0; ///< < 0: the sensor's default
  double dropout_rate = -1.0;      ///< < 0: the sensor's default
  int num_threads = 1;             ///< ray-casting threads (results do not depend on it)
  /// Raw sweeps instead of instantaneous scans: each column is cast from the sensor
  /// pose at its own firing time (see the spin convention in this file's doc) and its
  /// points are expressed in the sensor frame at that time, not motion-compensated.
  /// Moving cars (WorldParams::moving_cars) stay where they are at the frame's
  /// timestamp for the whole sweep. false: bit-identical to the instantaneous scans.
  bool raw_sweep = false;
  /// Sensor imperfections (per-beam calibration error, range outliers, mixed pixels at
  /// depth edges, intensity noise; see SensorImperfectionParams), deterministic for the
  /// seed, at no extra ray casts. false: bit-identical to the clean sensor.
  bool imperfections = false;
  SensorImperfectionParams imperfection_params; ///< magnitudes, when imperfections

  bool isValid(std::string* why = nullptr) const;
};

/// \brief Output file format of writeSequence.
enum class ScanFormat
{
  kBin, ///< DIR/velodyne/NNNNNN.bin, KITTI float32 x y z intensity
  kPcd  ///< DIR/pcd/NNNNNN.pcd, binary PCD (raw sweeps: plus a float field `time`)
};

/// \brief Called after each written frame with (frames done, frames total).
using ProgressCallback = std::function<void(std::size_t, std::size_t)>;

/// \brief Simulates a LiDAR sequence along a body trajectory.
///
/// \code
/// pcl::rast::LidarSimulatorParams params;
/// params.sensor = pcl::rast::SensorModel::kVlp16;
/// pcl::rast::LidarSimulator sim(params, pcl::rast::generatePath({}));
/// pcl::PointCloud<pcl::PointXYZI> cloud;
/// sim.simulateFrame(0, cloud);               // sensor frame
/// sim.writeSequence("out", pcl::rast::ScanFormat::kBin, 0, sim.numFrames() - 1);
/// \endcode
class LidarSimulator
{
public:
  using Ptr = std::shared_ptr<LidarSimulator>;
  using ConstPtr = std::shared_ptr<const LidarSimulator>;

  /// \param[in] params simulator parameters
  /// \param[in] T_world_body body poses (for vehicle sensors the LiDAR poses)
  /// \param[in] timestamps_s one per pose, or empty for i * frame_period_s
  /// \throws std::invalid_argument on invalid params, no poses or mismatched sizes.
  LidarSimulator(const LidarSimulatorParams& params,
                 const PoseVector& T_world_body,
                 const std::vector<double>& timestamps_s = {});

  std::size_t numFrames() const { return T_world_body_.size(); }
  const SensorSpec& sensorSpec() const { return spec_; }
  const SimulatedWorld& world() const { return *world_; }
  double timestamp(std::size_t i) const;
  /// \brief Ground-truth sensor pose T_world_sensor of frame \a i (includes the
  /// handheld tilt and sway).
  Pose3d sensorPose(std::size_t i) const;
  /// \brief Ground-truth sensor pose T_world_sensor at any time \a time_s: the body
  /// pose interpolated between the neighbouring trajectory poses (slerp of the
  /// rotation, lerp of the translation), extrapolated with the first / last step's
  /// motion before the first / after the last pose, then the mounting at \a time_s.
  /// Equals sensorPose(i) at timestamp(i). With one pose the body does not move.
  /// \throws std::invalid_argument when \a time_s is not finite.
  Pose3d sensorPoseAt(double time_s) const;
  /// \brief Sweep period of frame \a i in seconds: timestamp(i + 1) - timestamp(i)
  /// (timestamp(i) - timestamp(i - 1) for the last frame), frame_period_s when there
  /// is only one frame.
  /// \throws std::out_of_range when \a i >= numFrames(), std::invalid_argument when
  /// the timestamps do not increase there.
  double framePeriod(std::size_t i) const;

  /// \brief Simulate frame \a i into \a cloud (sensor frame, x y z intensity): an
  /// instantaneous scan, or a raw sweep with LidarSimulatorParams::raw_sweep (each
  /// point in the sensor frame at its own firing time).
  /// \param[in] i frame index
  /// \param[out] cloud the points, column by column (azimuth 0 first, then
  /// counter-clockwise, so not in firing order), beams top to bottom within a column
  /// \param[out] point_times_s when not null: per point of \a cloud (same order) its
  /// firing-time offset tau(azimuth) = -azimuth / (2 pi) * framePeriod(i) from
  /// timestamp(i), in [-period / 2, period / 2]. Filled in both modes (an
  /// instantaneous scan has the same firing times, it just ignores them).
  /// \throws std::out_of_range when \a i >= numFrames().
  void simulateFrame(std::size_t i,
                     pcl::PointCloud<pcl::PointXYZI>& cloud,
                     std::vector<float>* point_times_s = nullptr) const;

  /// \brief Write frames first, first + every, ..., <= last as a KITTI-like sequence:
  /// DIR/velodyne/000000.bin... (or DIR/pcd/000000.pcd), DIR/poses.txt (sensor
  /// poses re-based so the first written pose is the identity) and DIR/times.txt
  /// (timestamps relative to the first written frame). A raw sweep written as PCD has
  /// one more float field `time`: seconds since the sweep start (tau + period / 2, in
  /// [0, period]) as the Velodyne driver writes it; `.bin` files cannot carry it (it
  /// is implied by the azimuth) and are written as for instantaneous scans.
  /// When \a stop returns true before a frame, the sequence ends there: poses.txt and
  /// times.txt describe the frames written so far.
  /// \return the number of frames written.
  /// \throws std::invalid_argument on a bad range, std::runtime_error on I/O failure.
  std::size_t writeSequence(const std::string& dir,
                            ScanFormat format,
                            std::size_t first,
                            std::size_t last,
                            std::size_t every = 1,
                            const ProgressCallback& progress = {},
                            const std::function<bool()>& stop = {}) const;

private:
  /// Step 1 of simulateFrame: every ray cast from the frame's pose, or from its
  /// column's pose (\a T_world_column) for a raw sweep; moving cars at the frame's
  /// time either way. Split into contiguous chunks over num_threads.
  std::vector<RayHit> castFrame(std::size_t i, const PoseVector& T_world_column) const;
  /// Step 2: the sensor effects on each hit (noise, dropouts, intensity,
  /// imperfections) into \a cloud, in firing order for a raw sweep.
  void sensorEffects(std::size_t i,
                     const std::vector<RayHit>& hits,
                     const std::vector<double>& column_tau_s,
                     pcl::PointCloud<pcl::PointXYZI>& cloud,
                     std::vector<float>* point_times_s) const;

  LidarSimulatorParams params_;
  SensorSpec spec_;
  PoseVector T_world_body_;
  std::vector<double> timestamps_s_;
  std::vector<Eigen::Vector3d> ray_dirs_sensor_; ///< column-major: azimuth, then beam
  /// Directions the rays are cast along: ray_dirs_sensor_ with each beam's elevation
  /// bias (imperfections), else empty (cast along ray_dirs_sensor_).
  std::vector<Eigen::Vector3d> ray_dirs_cast_;
  std::vector<double> beam_range_bias_m_; ///< per beam (imperfections), else empty
  std::shared_ptr<const SimulatedWorld> world_;
};

} // namespace rast
} // namespace pcl
