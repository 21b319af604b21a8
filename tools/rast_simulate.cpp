/// \file rast_simulate.cpp
/// \brief pcl_rast_simulate: write a simulated LiDAR sequence (KITTI layout) along a
/// trajectory file or a generated path.
///
/// The world: `-scene` picks its scene type (or `mixed`: stretches of several along the
/// path), `-rough-ground` and `-porous-vegetation` the rough ground and porous tree
/// crowns and hedges of pcl::rast::WorldParams.
///
/// Trajectory files: a KITTI-format file (12 numbers per line) is read as KITTI
/// camera-0 ground truth (e.g. ../shared/data/kitti-gt-poses/00.txt) and converted to
/// LiDAR poses with the KITTI axis change, unless `-traj-frame lidar`; a TUM file
/// (`t x y z qx qy qz qw`) holds body (LiDAR) poses and its timestamps are kept.
/// `-raw-sweep` writes raw (motion-distorted) sweeps instead of instantaneous scans;
/// the spin convention is documented in pcl/simulation/lidar_simulator.h. `-imperfections`
/// adds the sensor imperfections of pcl::rast::SensorImperfectionParams. DIR/scenes.txt
/// names the scene type (pcl::rast::SceneType) of every written frame.
/// `-moving-cars -traffic realistic` drives realistic traffic around the ego vehicle
/// (pcl::rast::TrafficParams); `-stops N` makes a generated path stop and go.

#include "cli.h"
#include "stop_signals.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <pcl/io/pose_io.h>
#include <pcl/simulation/lidar_simulator.h>
#include <stdexcept>
#include <string>

namespace {

int
run(int argc, char** argv)
{
  using namespace pcl_rast_tools;
  pcl::rast::LidarSimulatorParams params;
  pcl::rast::PathParams path_params;
  std::string traj, path, output, sensor = pcl::rast::toString(params.sensor);
  std::string traj_frame = "camera", format = "bin";
  int first = 0, last = -1, every = 1, seed = static_cast<int>(params.seed);
  int drive_seed = 0;
  int threads = params.num_threads;
  double rate_hz = path_params.rate_hz, speed_mps = path_params.speed_mps;
  bool moving_cars = params.world.moving_cars;
  std::string traffic = pcl::rast::toString(params.world.traffic.mode);
  bool raw_sweep = params.raw_sweep;
  bool imperfections = params.imperfections;
  double elevation_bias_deg =
      params.imperfection_params.elevation_bias_std_rad * 180.0 / M_PI;
  std::string scene = pcl::rast::toString(params.world.scene);
  bool rough_ground = params.world.rough_ground;
  bool porous_vegetation = params.world.porous_vegetation;

  ArgParser args(
      "pcl_rast_simulate",
      "Simulate a LiDAR sequence in a procedural world around a trajectory.\n"
      "Writes DIR/velodyne/000000.bin... (or DIR/pcd/000000.pcd), DIR/poses.txt\n"
      "(KITTI format, sensor frame, first pose identity) and DIR/times.txt.\n"
      "A KITTI-format -traj is read as KITTI camera-0 poses unless -traj-frame\n"
      "lidar; a TUM -traj holds LiDAR (body) poses and its timestamps.");
  args.addString(
      "traj", "trajectory file (KITTI or TUM); exactly one of -traj/-path", &traj);
  args.addChoice("path",
                 "generated path; exactly one of -traj/-path",
                 &path,
                 {"straight", "loop", "eight"});
  args.addString("output", "output folder", &output, true);
  args.addChoice("sensor",
                 "sensor model",
                 &sensor,
                 {"hdl64", "vlp16", "os1-64", "os0-128", "hdl32"});
  args.addChoice("traj-frame",
                 "frame of a KITTI-format -traj: camera (KITTI GT) or lidar",
                 &traj_frame,
                 {"camera", "lidar"});
  args.addInt("first", "first trajectory frame written", &first);
  args.addInt("last", "last trajectory frame written (-1: the last one)", &last);
  args.addInt("every", "write every K-th frame (K = 5 at 10 Hz gives 2 Hz)", &every);
  args.addInt("seed", "random seed (the world, and its drive unless -drive-seed)", &seed);
  args.addInt("drive-seed",
              "another drive through the world of -seed: its traffic, noise and sensor "
              "calibration from this seed (0: -seed)",
              &drive_seed);
  args.addChoice("format", "scan format", &format, {"bin", "pcd"});
  args.addInt("frames", "generated path: number of poses", &path_params.num_frames);
  args.addDouble(
      "speed", "generated path: speed in m/s (os0-128 default 1.5)", &speed_mps);
  double laps = 1.0 + path_params.revisit_fraction;
  args.addDouble("laps", "generated loop/eight: times the closed path is driven", &laps);
  args.addDouble(
      "rate", "frame rate in Hz (generated paths, times of KITTI files)", &rate_hz);
  args.addSwitch("moving-cars", "add moving traffic (model: -traffic)", &moving_cars);
  args.addChoice("traffic",
                 "traffic of -moving-cars: along-path (cars ping-pong beside the path) "
                 "or realistic (lanes both ways, trucks and buses, cars stopping beside "
                 "the ego, cross traffic ahead while it stands > 2 s)",
                 &traffic,
                 {"along-path", "realistic"});
  args.addInt("stops",
              "generated path: number of stops (brake, stand, accelerate), evenly "
              "spread over the drive",
              &path_params.num_stops);
  args.addDouble("stop-duration",
                 "generated path: seconds standing still per stop",
                 &path_params.stop_duration_s);
  args.addDouble("accel",
                 "generated path: braking and starting acceleration of the stops, "
                 "m/s^2",
                 &path_params.acceleration_mps2);
  args.addSwitch("raw-sweep",
                 "raw (motion-distorted) sweeps: each column from the pose at its "
                 "firing time, azimuth +180 deg at t - T/2, 0 at t, -180 deg at "
                 "t + T/2; -format pcd adds a float field time (s since sweep start)",
                 &raw_sweep);
  args.addSwitch("imperfections",
                 "sensor imperfections: per-beam calibration error, 0.1 % early "
                 "outliers, mixed pixels at depth edges, intensity noise (fixed by "
                 "-seed, or by -drive-seed when given)",
                 &imperfections);
  args.addDouble("elevation-bias",
                 "with -imperfections: each beam's elevation calibration error, 1 "
                 "sigma [deg] (0: calibrated; the rest of the world and its noise stay "
                 "the same)",
                 &elevation_bias_deg);
  args.addChoice("scene",
                 "scene type of the world, or mixed: stretches of 150-500 m of "
                 "different types along the path (drawn from -seed)",
                 &scene,
                 {"suburb", "urban", "highway", "field", "tunnel", "mixed"});
  args.addSwitch("rough-ground",
                 "rough ground: ~3 cm of relief, wavelengths 0.4-2 m",
                 &rough_ground);
  args.addSwitch("porous-vegetation",
                 "porous tree crowns and hedges: rays stop inside at a random depth "
                 "(mean 1 m) or pass through",
                 &porous_vegetation);
  args.addInt("threads", "ray-casting threads (output does not depend on it)", &threads);
  if (!args.parse(argc, argv))
    return kExitOk;
  installStopSignals(); // a stop before the first frame ends the run there

  if (traj.empty() == path.empty())
    throw std::invalid_argument("give exactly one of -traj FILE and -path TYPE");
  if (!traj.empty() &&
      (args.given("frames") || args.given("speed") || args.given("laps") ||
       args.given("stops") || args.given("stop-duration") || args.given("accel")))
    throw std::invalid_argument(
        "-frames, -speed, -laps, -stops, -stop-duration and -accel apply to -path only");
  if (args.given("traffic") && !moving_cars)
    throw std::invalid_argument("-traffic " + traffic + " needs -moving-cars");
  if (path.empty() == false && args.given("traj-frame"))
    throw std::invalid_argument("-traj-frame applies to -traj only");
  if (seed < 0)
    throw std::invalid_argument("-seed must be >= 0, got " + std::to_string(seed));
  if (drive_seed < 0)
    throw std::invalid_argument("-drive-seed must be >= 0, got " +
                                std::to_string(drive_seed));
  if (every < 1)
    throw std::invalid_argument("-every must be >= 1, got " + std::to_string(every));
  if (!(rate_hz > 0.0))
    throw std::invalid_argument("-rate must be > 0");

  params.sensor = pcl::rast::sensorModelFromString(sensor);
  params.seed = static_cast<std::uint64_t>(seed);
  params.drive_seed = static_cast<std::uint64_t>(drive_seed);
  params.world.moving_cars = moving_cars;
  params.world.traffic.mode = pcl::rast::trafficModeFromString(traffic);
  params.raw_sweep = raw_sweep;
  params.imperfections = imperfections;
  if (args.given("elevation-bias") && !imperfections)
    throw std::invalid_argument("-elevation-bias needs -imperfections");
  if (!(elevation_bias_deg >= 0.0 && elevation_bias_deg <= 0.5))
    throw std::invalid_argument("-elevation-bias must be in [0, 0.5] deg, got " +
                                std::to_string(elevation_bias_deg));
  params.imperfection_params.elevation_bias_std_rad = elevation_bias_deg * M_PI / 180.0;
  params.world.mixed_scenes = scene == "mixed";
  if (scene != "mixed")
    params.world.scene = pcl::rast::sceneTypeFromString(scene);
  params.world.rough_ground = rough_ground;
  params.world.porous_vegetation = porous_vegetation;
  params.num_threads = threads;
  params.frame_period_s = 1.0 / rate_hz;
  std::string why;
  if (!params.isValid(&why))
    throw std::invalid_argument(why);

  // Load or generate the body trajectory.
  pcl::rast::PoseVector T_world_body;
  std::vector<double> times_s;
  if (!traj.empty()) {
    const pcl::rast::Trajectory t = pcl::rast::readTrajectory(traj);
    if (t.poses.empty())
      throw std::runtime_error("no poses in '" + traj + "'");
    if (t.format == pcl::rast::PoseFormat::kKitti) {
      T_world_body = traj_frame == "camera"
                         ? pcl::rast::cameraToLidarPoses(
                               t.poses, pcl::rast::kittiAxisChangeCamLidar())
                         : t.poses;
    } else {
      if (args.given("traj-frame"))
        throw std::invalid_argument("-traj-frame applies to KITTI-format files only");
      T_world_body = t.poses;
      times_s = t.timestamps_s;
    }
    std::fprintf(stderr, "Loaded %s [%zu poses]\n", traj.c_str(), T_world_body.size());
  } else {
    path_params.type = pcl::rast::pathTypeFromString(path);
    path_params.rate_hz = rate_hz;
    if (!(laps >= 1.0 && laps <= 100.0))
      throw std::invalid_argument("-laps must be in [1, 100], got " +
                                  std::to_string(laps));
    path_params.revisit_fraction = laps - 1.0;
    if (path_params.type == pcl::rast::PathType::kStraight && args.given("laps"))
      throw std::invalid_argument("-laps applies to -path loop and eight only");
    path_params.speed_mps =
        args.given("speed") || params.sensor != pcl::rast::SensorModel::kOs0_128
            ? speed_mps
            : 1.5;
    path_params.height_m = pcl::rast::sensorSpec(params.sensor).mount_height_m;
    if (!path_params.isValid(&why))
      throw std::invalid_argument(why);
    T_world_body = pcl::rast::generatePath(path_params);
  }

  const int n = static_cast<int>(T_world_body.size());
  if (last < 0)
    last = n - 1;
  if (first < 0 || first > last || last >= n)
    throw std::invalid_argument("-first " + std::to_string(first) + " -last " +
                                std::to_string(last) + " outside the " +
                                std::to_string(n) + " poses");

  const auto t0 = std::chrono::steady_clock::now();
  pcl::rast::LidarSimulator sim(params, T_world_body, times_s);
  const auto t1 = std::chrono::steady_clock::now();
  std::fprintf(stderr,
               "Building world [done, %.0f ms : %zu primitives]\n",
               std::chrono::duration<double, std::milli>(t1 - t0).count(),
               sim.world().numPrimitives());

  const std::size_t total = static_cast<std::size_t>((last - first) / every + 1);
  ProgressBar bar("Simulating " + sensor, total);
  const std::size_t written = sim.writeSequence(
      output,
      format == "bin" ? pcl::rast::ScanFormat::kBin : pcl::rast::ScanFormat::kPcd,
      static_cast<std::size_t>(first),
      static_cast<std::size_t>(last),
      static_cast<std::size_t>(every),
      [&bar](std::size_t done, std::size_t) { bar.update(done); },
      [] { return stopRequested(); });
  bar.finish();
  if (stopRequested())
    std::fprintf(stderr,
                 "pcl_rast_simulate: %s after %zu of %zu frames; the sequence holds those "
                 "(a second signal ends at once)\n",
                 stopSignalName(), written, total);
  const double ms =
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t1)
          .count();
  std::fprintf(stderr,
               "Wrote %s [done, %.0f ms : %zu frames, %.1f ms/frame]\n",
               output.c_str(),
               ms,
               written,
               ms / static_cast<double>(std::max<std::size_t>(written, 1)));

  if (written == 0) // stopped before the first frame: no sequence
    return stopRequested() ? 128 + stopSignal() : kExitAlgorithmFailure;
  // The scene each written frame is in (DIR/scenes.txt, one name per line), and the
  // stretches on the console: per-scene figures need to know where each frame was.
  std::string scenes, stretches, previous;
  std::size_t line = 0, since = 0;
  for (int i = first; line < written; i += every, ++line) {
    const Eigen::Vector3d t = T_world_body[static_cast<std::size_t>(i)].translation();
    const std::string name = pcl::rast::toString(sim.world().sceneAt(t.x(), t.y()));
    scenes += name + "\n";
    if (name != previous && !previous.empty())
      stretches +=
          previous + " " + std::to_string(since) + "-" + std::to_string(line - 1) + ", ";
    if (name != previous)
      since = line;
    previous = name;
  }
  stretches += previous + " " + std::to_string(since) + "-" + std::to_string(line - 1);
  pcl::rast::writeFileAtomically(output + "/scenes.txt", scenes);
  std::fprintf(stderr, "Scenes by written frame [%s]\n", stretches.c_str());
  return kExitOk;
}

} // namespace

int
main(int argc, char** argv)
{
  return pcl_rast_tools::runTool("pcl_rast_simulate", [&] { return run(argc, argv); });
}
