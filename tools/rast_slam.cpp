/// \file rast_slam.cpp
/// \brief pcl_rast_slam: the paper's full SLAM system on a folder of scans.
///
///   pcl_rast_slam -input DIR -output DIR [-gt POSES.txt] [options]
///
/// Writes into the output folder (each file atomically: temporary file, then rename):
/// poses_kitti.txt, poses_tum.txt, map.pcd, render.png and summary.json.
/// Without -input, a loop sequence is simulated into OUTPUT/simulated_input first (and
/// its ground truth is used for -gt), so the tool runs out of the box.
/// Ctrl-C stops reading; what was processed so far is finished and written.
/// With -session DIR the drive extends a saved session (multi-session mapping): it is
/// joined to the session's map by inter-session loops and optimized with its pose graph;
/// poses and map.pcd are then in the session's world frame, and -save-session writes
/// the merged session.

#include "cli.h"
#include "output_set.h"
#include "prefetcher.h"
#include "sensor_choice.h"
#include "stop_signals.h"
#include "tracking_report.h"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <filesystem>
#include <functional>
#include <iostream>
#include <limits>
#include <map>
#include <nlohmann/json.hpp>
#include <optional>
#include <pcl/evaluation/trajectory_evaluation.h>
#include <pcl/io/pose_io.h>
#include <pcl/io/sequence_reader.h>
#include <pcl/segmentation/sac_ground_removal.h>
#include <pcl/simulation/lidar_simulator.h>
#include <pcl/slam/rast_slam.h>
#include <pcl/slam/session.h>
#include <pcl/slam/session_localizer.h>
#include <pcl/slam/session_merge.h>
#include <pcl/slam/slam_map.h>
#include <pcl/visualization/map_render.h>
#include <sstream>
#include <stdexcept>
#include <string>
#include <sys/resource.h>
#include <unistd.h>

namespace {

namespace rast = pcl::rast;
namespace fs = std::filesystem;
using nlohmann::json;
using pcl_rast_tools::ArgParser;

/// Rotation that turns the ground normal around the start of the map into +z, or the
/// identity when no ground is found there (then the picture is drawn as it is).
Eigen::Matrix3d
levellingRotation(const pcl::PointCloud<pcl::PointXYZI>& map)
{
  const auto near = pcl::make_shared<pcl::PointCloud<pcl::PointXYZI>>();
  for (const auto& p : map.points)
    if (p.getVector3fMap().squaredNorm() < 30.0f * 30.0f)
      near->push_back(p);
  rast::SACGroundRemovalParams params;
  params.max_tilt_deg = 60.0; // a handheld sensor may be pitched far down
  params.min_inliers = 50;
  rast::GroundRemovalResult<pcl::PointXYZI> result;
  try {
    rast::SACGroundRemoval<pcl::PointXYZI> ground(params);
    ground.setInputCloud(near);
    ground.segment(result);
  }
  catch (const std::exception&) {
    return Eigen::Matrix3d::Identity();
  }
  if (!result.ground_found)
    return Eigen::Matrix3d::Identity();
  Eigen::Vector3d up = result.plane_coefficients.head<3>().cast<double>().normalized();
  if (up.z() < 0.0)
    up = -up;
  // The shortest rotation of up onto z. up.z() >= 0, so never the half turn for which
  // Quaterniond::FromTwoVectors instantiates an SVD (3.4 s of this file's compile in
  // clang's -ftime-trace).
  const Eigen::Vector3d axis = up.cross(Eigen::Vector3d::UnitZ());
  const double sin_angle = axis.norm();
  if (sin_angle < 1e-12)
    return Eigen::Matrix3d::Identity();
  return Eigen::AngleAxisd(std::atan2(sin_angle, up.z()), axis / sin_angle)
      .toRotationMatrix();
}

/// The map as the picture needs it, gathered tile by tile while map.pcd is written:
/// levelled by R_level and reduced to the highest point per pixel-sized cell of the
/// top-down view, which is all the picture can show. A 5 M-point map of a 4 km drive
/// shrinks about tenfold, and the render needs that much less memory.
class RenderCloud
{
public:
  /// \param[in] keyframe_positions where the map was seen from (its extent, roughly)
  RenderCloud(const Eigen::Matrix3d& R_level,
              const std::vector<Eigen::Vector3d>& keyframe_positions,
              double map_leaf_m,
              const pcl::rast::MapRenderParams& render)
    : R_(R_level.cast<float>())
  {
    constexpr double kMarginM = 50.0; // about what a scan sees beyond its key-frame
    Eigen::Vector2d lo = Eigen::Vector2d::Constant(std::numeric_limits<double>::max());
    Eigen::Vector2d hi = -lo;
    for (const auto& p : keyframe_positions) {
      lo = lo.cwiseMin((R_level * p).head<2>());
      hi = hi.cwiseMax((R_level * p).head<2>());
    }
    if (keyframe_positions.empty())
      return;
    const double metres_per_px = std::max((hi.x() - lo.x() + 2 * kMarginM) / render.width_px,
                                          (hi.y() - lo.y() + 2 * kMarginM) / render.height_px);
    cell_m_ = std::max(metres_per_px, map_leaf_m);
  }

  /// \brief Add one map tile: its highest point per cell joins the picture. A cell
  /// that straddles two tiles may get a point from each (the renderer draws the higher
  /// one on top).
  void add(const pcl::PointCloud<pcl::PointXYZI>& tile)
  {
    cells_.clear();
    for (std::size_t k = 0; k < tile.size(); ++k) {
      const Eigen::Vector3f p = R_ * tile.points[k].getVector3fMap();
      if (!p.allFinite())
        continue;
      const auto ix = static_cast<std::int64_t>(std::floor(p.x() / cell_m_));
      const auto iy = static_cast<std::int64_t>(std::floor(p.y() / cell_m_));
      cells_.push_back({(static_cast<std::uint64_t>(ix & 0xFFFFFFFF) << 32) |
                            static_cast<std::uint64_t>(iy & 0xFFFFFFFF),
                        p.z(), static_cast<std::uint32_t>(k)});
    }
    // Highest first within each cell, then keep the first of every cell.
    std::sort(cells_.begin(), cells_.end(), [](const Cell& a, const Cell& b) {
      return a.key != b.key ? a.key < b.key : a.z > b.z;
    });
    for (std::size_t i = 0; i < cells_.size(); ++i) {
      if (i > 0 && cells_[i].key == cells_[i - 1].key)
        continue;
      pcl::PointXYZI q = tile.points[cells_[i].index];
      q.getVector3fMap() = R_ * q.getVector3fMap();
      top_.push_back(q);
    }
  }

  /// \brief The gathered points (the renderer sorts by height itself).
  const pcl::PointCloud<pcl::PointXYZI>& cloud() const { return top_; }

private:
  /// A tile point's cell, height and index (16 bytes: sorting them is cheap).
  struct Cell
  {
    std::uint64_t key;
    float z;
    std::uint32_t index;
  };
  Eigen::Matrix3f R_;
  double cell_m_ = 0.2;
  std::vector<Cell> cells_;
  pcl::PointCloud<pcl::PointXYZI> top_;
};

using pcl_rast_tools::peakRssMb;
using pcl_rast_tools::processCpuS;

/// Save the finished run, or the merged session of a multi-session run, in \a dir
/// (-save-session): the summary's "session" entry. A run that ended with an error saves
/// none (its map may lack what the error cut off). A failed save is reported there and
/// in \a failure; the run's own outputs are still published, and the tool exits 2.
json
saveSessionOf(const std::function<std::size_t()>& save,
              const std::string& dir,
              bool run_failed,
              std::string& failure)
{
  if (run_failed) {
    std::cerr << "pcl_rast_slam: the run failed; no session was saved in " << dir << "\n";
    return {{"dir", dir}, {"saved", false}, {"error", "the run failed"}};
  }
  const auto start = std::chrono::steady_clock::now();
  std::size_t keyframes = 0;
  try {
    keyframes = save();
  } catch (const std::exception& e) {
    failure = std::string("the session was not saved: ") + e.what();
    std::cerr << "pcl_rast_slam: error: " << failure << "\n";
    return {{"dir", dir}, {"saved", false}, {"error", e.what()}};
  }
  const double seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  std::cerr << "Saved session " << dir << " (" << keyframes << " key-frames, " << seconds
            << " s)\n";
  return {{"dir", dir},
          {"saved", true},
          {"keyframes", keyframes},
          {"format_version", rast::kSessionFormatVersion},
          {"save_s", seconds}};
}

/// Poses of the drive's frames on the merged map: each frame's pose relative to its
/// reference key-frame, on that key-frame's merged pose.
rast::PoseVector
framePosesOnMap(const std::vector<rast::FrameRecord>& frames,
                const rast::SessionMergeResult& merge)
{
  rast::PoseVector poses;
  poses.reserve(frames.size());
  for (const rast::FrameRecord& f : frames)
    poses.push_back(f.reference_keyframe == rast::kNoKeyFrame
                        ? rast::normalizedPose(merge.T_prior_drive * f.T_keyframe_lidar)
                        : rast::normalizedPose(
                              merge.drive_keyframe_poses.at(f.reference_keyframe) *
                              f.T_keyframe_lidar));
  return poses;
}

json
timingJson(const rast::StageTiming& t)
{
  return {{"mean", t.mean_ms}, {"median", t.median_ms}, {"max", t.max_ms},
          {"count", t.count}, {"total", t.total_ms}, {"cpu_total", t.cpu_total_ms}};
}

json
poseJson(const rast::Pose3d& T)
{
  json m = json::array();
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 4; ++c)
      m.push_back(T.matrix()(r, c));
  return m;
}

/// Simulates the default demo sequence: a 220-frame HDL-64 loop drive.
std::string
simulateDefaultInput(const std::string& output)
{
  const std::string dir = (fs::path(output) / "simulated_input").string();
  rast::PathParams path;
  path.type = rast::PathType::kLoop;
  path.num_frames = 220;
  rast::LidarSimulatorParams sim_params;
  sim_params.seed = 7;
  sim_params.num_threads = 2;
  rast::LidarSimulator sim(sim_params, rast::generatePath(path));
  pcl_rast_tools::ProgressBar bar("Simulating loop (no -input)", sim.numFrames());
  sim.writeSequence(dir, rast::ScanFormat::kBin, 0, sim.numFrames() - 1, 1,
                    [&](std::size_t done, std::size_t) { bar.update(done); });
  bar.finish();
  return dir;
}

int
run(int argc, char** argv)
{
  const rast::SlamParams defaults;
  std::string input, output, gt_path, save_session, session_dir, threads = defaults.deterministic ? "off" : "on";
  int first = 0, last = -1, stride = 1;
  bool no_loop = !defaults.loop_closing.enable;
  bool no_revisit_culling = !defaults.loop_closing.cull_revisits;
  int young_map_scans = defaults.odometry.dense.young_map_scans;
  double degeneracy_support = defaults.odometry.dense.degeneracy_min_support;
  double map_nearer = defaults.odometry.dense.map_nearer_ratio;
  double weak_feature_share = defaults.odometry.weak_feature_share;
  double visibility_margin = defaults.odometry.visibility_margin_m;
  bool no_vehicle_prior = false;
  bool no_elevation_calibration = false;
  bool no_ba = false;
  bool ba = false;
  bool global_ba = defaults.loop_closing.global_bundle_adjustment;
  bool features_on_demand = defaults.features_on_demand;
  double map_leaf_m = 0.2;
  bool software_render = false, quiet = false;
  std::string sensor = "auto";
  pcl_rast_tools::DeskewFlags deskew;

  ArgParser parser("pcl_rast_slam",
                   "LiDAR SLAM on rasterized ORB features (tracking, local mapping with optional "
                   "bundle adjustment, loop closing with a pose graph) on a folder of "
                   ".bin/.pcd/.ply scans (a velodyne/ or pcd/ subfolder is found). Writes "
                   "poses_kitti.txt, poses_tum.txt, map.pcd, render.png and summary.json "
                   "into the output folder. Without -input, a loop sequence is simulated "
                   "first (OUTPUT/simulated_input) and evaluated against its ground truth.");
  parser.addString("input", "scan folder (default: simulate a loop sequence)", &input);
  parser.addString("output", "output folder (created when missing)", &output, true);
  parser.addString("gt", "ground-truth poses (KITTI or TUM, LiDAR frame), one per scan "
                         "of the folder or per selected frame",
                   &gt_path);
  parser.addString("save-session",
                   "also save the map as a session in this folder (key-frames, features, "
                   "pose graph; doc/session.md), for localization and later runs",
                   &save_session);
  parser.addString("session",
                   "extend this session (multi-session mapping, doc/session.md): the drive "
                   "is joined to its map by inter-session loops and optimized with its pose "
                   "graph; poses and map.pcd are then in the session's frame",
                   &session_dir);
  parser.addInt("first", "first scan index", &first);
  parser.addInt("last", "last scan index, inclusive (-1: the last)", &last);
  parser.addInt("stride", "use every stride-th scan", &stride);
  parser.addChoice("threads", "on: three threads; off: deterministic, one thread", &threads,
                   {"on", "off"});
  pcl_rast_tools::addDeskewFlags(parser, deskew);
  parser.addChoice("sensor", "parameter preset (auto: guessed from the first scan)", &sensor,
                   pcl_rast_tools::sensorChoices());
  parser.addSwitch("no-loop", "disable loop closure", &no_loop);
  parser.addSwitch("no-revisit-culling",
                   "add every key-frame to the loop database, also where the map already "
                   "has one (memory then grows with the time spent, not the area mapped)",
                   &no_revisit_culling);
  parser.addSwitch("no-ba", "disable local bundle adjustment (the default)", &no_ba);
  parser.addSwitch("ba", "enable local bundle adjustment", &ba);
  parser.addSwitch("global-ba",
                   "global bundle adjustment after each pose-graph optimisation "
                   "(comparison, slow)",
                   &global_ba);
  parser.addSwitch(
      "features-on-demand",
      "tracking makes a scan's features only where its dense step cannot track "
      "it alone (key-frames always have them; doc/odometry.md)",
      &features_on_demand);
  parser.addInt("young-map-scans",
                "tracking: every scan joins the local map while it holds fewer (1: key-frames "
                "only; see doc/odometry.md)",
                &young_map_scans);
  parser.addDouble(
      "weak-feature-share",
      "tracking: weak features (fewer than 40 inliers) near the prior move "
      "it this share of the way to them where the scan does not constrain "
      "the motion (0: the prior alone; the vlp16 preset 0.25; doc/odometry.md)",
      &weak_feature_share);
  parser.addDouble(
      "map-nearer",
      "tracking: a full local-map voxel takes a point seen from less than "
      "this fraction of its farthest point's range in that point's place (0: "
      "the first points stay, as in KISS-ICP; see doc/odometry.md)",
      &map_nearer);
  parser.addDouble("degeneracy-support",
                   "tracking in tunnels, corridors: a direction needs this many points on "
                   "surfaces facing along it, else the prior keeps it (0: off; "
                   "doc/odometry.md)",
                   &degeneracy_support);
  parser.addSwitch("no-vehicle-prior",
                   "tracking: the prior gates stay fixed and the dense step has no pull to "
                   "the prior (the odometry before session 18; doc/odometry.md)",
                   &no_vehicle_prior);
  parser.addSwitch("no-elevation-calibration",
                   "tracking: the points stay at the elevation the sensor gave them (no "
                   "self-calibration of the beams' elevation; doc/odometry.md)",
                   &no_elevation_calibration);
  parser.addDouble("visibility-margin",
                   "tracking, moving objects: map voxels the scan sees through, and scan "
                   "points the key-frame saw through, by more than this are left out of the "
                   "dense step (m, e.g. 1; 0: off, the default; doc/odometry.md)",
                   &visibility_margin);
  bool no_lookahead = false;
  parser.addSwitch(
      "no-lookahead",
      "tracking: compute each scan's ground, raster and ORB on the tracking "
      "thread after the scan before, not on a thread of their own while it is "
      "tracked (the poses are the same)",
      &no_lookahead);
  parser.addDouble("map-leaf", "voxel size of map.pcd [m]", &map_leaf_m);
  parser.addSwitch("software-render", "render.png with OpenCV instead of VTK (faster)",
                   &software_render);
  parser.addSwitch("quiet", "no progress bar", &quiet);
  if (!parser.parse(argc, argv))
    return pcl_rast_tools::kExitOk;
  pcl_rast_tools::installStopSignals(); // a stop before the first frame ends the run there

  // ---- validate everything before any work ----
  if (first < 0 || stride < 1 || last < -1 || (last >= 0 && last < first))
    throw std::invalid_argument("bad frame range: -first " + std::to_string(first) +
                                " -last " + std::to_string(last) + " -stride " +
                                std::to_string(stride));
  if (young_map_scans < 1)
    throw std::invalid_argument("-young-map-scans must be >= 1, got " +
                                std::to_string(young_map_scans));
  if (!(weak_feature_share >= 0.0 && weak_feature_share <= 1.0))
    throw std::invalid_argument("-weak-feature-share must be in [0, 1], got " +
                                std::to_string(weak_feature_share));
  if (!(map_nearer >= 0.0 && map_nearer <= 1.0))
    throw std::invalid_argument("-map-nearer must be in [0, 1], got " +
                                std::to_string(map_nearer));
  if (!(degeneracy_support >= 0.0) || !std::isfinite(degeneracy_support))
    throw std::invalid_argument("-degeneracy-support must be finite and >= 0, got " +
                                std::to_string(degeneracy_support));
  if (!(visibility_margin >= 0.0) || !std::isfinite(visibility_margin))
    throw std::invalid_argument("-visibility-margin must be finite and >= 0, got " +
                                std::to_string(visibility_margin));
  pcl_rast_tools::checkDeskewFlags(deskew);
  if (!(map_leaf_m > 0.0))
    throw std::invalid_argument("-map-leaf must be > 0, got " + std::to_string(map_leaf_m));
  if (ba && no_ba)
    throw std::invalid_argument("-ba and -no-ba contradict each other");
  rast::SlamParams params = defaults;
  params.deterministic = threads == "off";
  params.loop_closing.enable = !no_loop;
  params.loop_closing.cull_revisits = !no_revisit_culling;
  if (ba)
    params.local_mapping.enable_bundle_adjustment = true;
  if (no_ba)
    params.local_mapping.enable_bundle_adjustment = false;
  params.loop_closing.global_bundle_adjustment = global_ba;
  params.features_on_demand = features_on_demand;
  std::string why;
  if (!params.isValid(&why))
    throw std::invalid_argument("invalid parameters: " + why);

  // The run's files are staged and published together at the end (output_set.h): a
  // failure or a second signal leaves the previous set as it was. I/O errors (exit 2)
  // come here, before any work.
  pcl_rast_tools::OutputSet outputs(output, "pcl_rast_slam");
  // Key-frame clouds wait for the final map in an anonymous file there, not in memory.
  params.spill_directory = output;
  if (input.empty()) {
    if (!gt_path.empty())
      throw std::invalid_argument("-gt needs -input");
    input = simulateDefaultInput(output);
    gt_path = (fs::path(input) / "poses.txt").string();
  }

  rast::SequenceReaderOptions options;
  options.first = static_cast<std::size_t>(first);
  options.last = last;
  options.stride = static_cast<std::size_t>(stride);
  rast::SequenceReader reader(input, options);
  pcl_rast_tools::checkOutputIsNotInput(output, reader.scanFolder());
  if (!save_session.empty()) {
    pcl_rast_tools::checkOutputIsNotInput(save_session, reader.scanFolder());
    rast::checkSessionDestination(save_session);
  }
  std::cerr << "Input " << reader.scanFolder() << " [" << reader.numFiles() << " scans, "
            << reader.size() << " selected"
            << (reader.timesPath().empty() ? "" : ", times from " + reader.timesPath())
            << "]\n";
  // A session to extend: every file checked (version, preset, sizes, checksums) before
  // any work. Its sensor preset is the run's unless -sensor names another (an error).
  std::optional<rast::Session> prior;
  double session_load_s = 0.0;
  if (!session_dir.empty()) {
    if (fs::weakly_canonical(output) == fs::weakly_canonical(session_dir))
      throw std::invalid_argument("-output " + output + " is the -session folder");
    const auto load_start = std::chrono::steady_clock::now();
    rast::SessionLoadOptions load_options;
    // The clouds are checked now and read when needed (placements, the merged map and
    // session): holding them all was a third of a multi-session run's memory.
    load_options.load_clouds = false;
    if (sensor != "auto")
      load_options.expected_sensor_preset = sensor;
    try {
      prior = rast::loadSession(session_dir, load_options);
    } catch (const rast::SessionError& e) {
      throw std::runtime_error(std::string("bad session: ") + e.what());
    }
    session_load_s =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - load_start).count();
    std::cerr << "Session " << session_dir << " [" << prior->keyframes.size()
              << " key-frames, " << prior->drives.size() << " drive(s), sensor "
              << prior->info.sensor_preset << ", loaded in " << session_load_s << " s]\n";
    if (sensor == "auto")
      sensor = prior->info.sensor_preset;
  }
  std::string sensor_reason;
  const rast::SensorPreset preset =
      pcl_rast_tools::resolveSensorPreset(sensor, reader, sensor_reason);
  if (prior && !parser.given("sensor"))
    sensor_reason = "the session's";
  std::cerr << "Sensor preset " << rast::toString(preset) << " (" << sensor_reason << ")\n";
  rast::applySensorPreset(preset, params.odometry);
  std::string deskew_reason, deskew_timing;
  pcl_rast_tools::applyDeskewFlags(deskew, reader, static_cast<std::size_t>(stride),
                                   params.odometry.deskew, deskew_reason, deskew_timing);
  std::cerr << "Deskew " << rast::toString(params.odometry.deskew.mode) << " (" << deskew_reason
            << "; " << deskew_timing << ")\n";
  if (parser.given("young-map-scans"))
    params.odometry.dense.young_map_scans = young_map_scans;
  if (parser.given("map-nearer"))
    params.odometry.dense.map_nearer_ratio = map_nearer;
  if (parser.given("weak-feature-share"))
    params.odometry.weak_feature_share = weak_feature_share;
  if (parser.given("degeneracy-support"))
    params.odometry.dense.degeneracy_min_support = degeneracy_support;
  if (parser.given("visibility-margin"))
    params.odometry.visibility_margin_m = visibility_margin;
  if (no_vehicle_prior)
    rast::disableVehiclePrior(params.odometry);
  if (no_elevation_calibration)
    params.odometry.elevation_calibration.enabled = false;
  if (!params.isValid(&why))
    throw std::logic_error("sensor preset made invalid parameters: " + why);
  // The session's map indexed for placing the drive's key-frames on it (after the run).
  std::unique_ptr<rast::SessionLocalizer> localizer;
  rast::SessionLocalizerParams localizer_params;
  if (prior) {
    // The placement thresholds of the session's sensor (a VLP-16 places with fewer
    // inliers), the odometry as set up above (flags included).
    rast::applySensorPreset(preset, localizer_params);
    localizer_params.odometry = params.odometry;
    // The merge places every key-frame of the drive and was measured with the loop
    // closure's appearance score (session 21); the localization's lower one is not.
    localizer_params.verification.min_appearance_score =
        rast::LoopDetectorParams().min_appearance_score;
    localizer_params.polar_candidates = 0; // the merge does not use them: no descriptors
    localizer = std::make_unique<rast::SessionLocalizer>(std::move(*prior), localizer_params);
    prior.reset();
  }

  // Ground truth paired with the selected frames as pcl_rast_eval pairs poses_tum.txt
  // with it: a TUM file by timestamp (nearest within 0.01 s, each pose used once), a
  // KITTI file by index. Re-based on the first paired pose.
  std::vector<std::size_t> gt_frame; // the selected frame each gt pose belongs to
  rast::PoseVector gt;
  if (!gt_path.empty()) {
    const rast::Trajectory trajectory = rast::readTrajectory(gt_path);
    const std::size_t n = trajectory.poses.size();
    if (trajectory.format == rast::PoseFormat::kTum) {
      std::vector<double> frame_times(reader.size());
      for (std::size_t i = 0; i < reader.size(); ++i)
        frame_times[i] = reader.timestamp(i);
      const rast::EvaluationParams defaults;
      for (const auto& [i, j] : rast::associateByTimestamp(frame_times, trajectory.timestamps_s,
                                                           defaults.max_time_difference_s)) {
        gt_frame.push_back(i);
        gt.push_back(trajectory.poses[j]);
      }
      if (gt.size() < 2)
        throw std::invalid_argument(
            "-gt " + gt_path + ": only " + std::to_string(gt.size()) + " of its " +
            std::to_string(n) + " TUM poses have a scan within " +
            std::to_string(defaults.max_time_difference_s) + " s (scan times come from " +
            (reader.timesPath().empty() ? std::string("the file index: no times.txt")
                                        : reader.timesPath()) +
            "); need at least 2");
    }
    else if (n == reader.numFiles()) {
      for (std::size_t i = 0; i < reader.size(); ++i) {
        gt_frame.push_back(i);
        gt.push_back(trajectory.poses.at(first + i * stride));
      }
    }
    else if (n == reader.size()) {
      for (std::size_t i = 0; i < n; ++i)
        gt_frame.push_back(i);
      gt = trajectory.poses;
    }
    else {
      throw std::invalid_argument("-gt " + gt_path + " has " + std::to_string(n) +
                                  " poses, but the sequence has " +
                                  std::to_string(reader.numFiles()) + " scans (" +
                                  std::to_string(reader.size()) + " selected)");
    }
    const rast::Pose3d T_first_inv = gt.front().inverse();
    for (auto& T : gt)
      T = T_first_inv * T;
  }

  const pcl_rast_tools::InjectedFault fault =
      pcl_rast_tools::injectedFault({"tracking", "local_mapping", "loop_closing"});

  // ---- run ----
  const auto wall_start = std::chrono::steady_clock::now();
  rast::RastSlam slam(params);
  if (fault.active)
    slam.setKeyFrameObserver([fault](rast::SlamStage stage, const rast::KeyFrame& kf) {
      fault.check(rast::toString(stage), kf.id);
    });
  json skipped = json::array();
  std::size_t processed = 0;
  pcl_rast_tools::DeskewTally tally;
  pcl_rast_tools::DegradedStretches degraded;
  const auto record = [&](const rast::OdometryFrameResult& r) {
    tally.add(r);
    degraded.add(r);
  };
  // An error after frames were processed ends the run, not its results: what was
  // processed is written below, summary.json names the error, and the exit code is 3.
  std::exception_ptr run_error;
  try {
    pcl_rast_tools::Prefetcher prefetcher(reader, 4);
    std::optional<pcl_rast_tools::ProgressBar> bar;
    if (!quiet)
      bar.emplace("pcl_rast_slam", reader.size());
    pcl_rast_tools::ReadItem item;
    while (!pcl_rast_tools::stopRequested() && prefetcher.next(item)) {
      if (item.ok) {
        if (item.frame.cloud->empty()) {
          std::cerr << "\nframe " << item.sequence_index << ": skipped: " << item.path
                    << ": empty scan\n";
          slam.addSkippedScan(item.sequence_index, item.timestamp_s, "empty scan", item.path);
          skipped.push_back({{"frame", item.sequence_index}, {"path", item.path},
                             {"reason", "empty scan"}});
        }
        else {
          if (!item.frame.time_warning.empty() && tally.time_field_warnings++ == 0)
            std::cerr << "\npcl_rast_slam: warning: " << item.path << ": "
                      << item.frame.time_warning << " (reported once per run)\n";
          // The next scan's ground, raster and ORB on a thread of their own meanwhile.
          const pcl_rast_tools::ReadItem* next =
              no_lookahead ? nullptr : prefetcher.peek();
          if (next && next->ok && !next->frame.cloud->empty())
            record(slam.addScan(item.frame.cloud,
                                item.timestamp_s,
                                item.sequence_index,
                                item.frame.point_times_s,
                                {next->frame.cloud,
                                 next->timestamp_s,
                                 next->sequence_index,
                                 next->frame.point_times_s},
                                item.path));
          else
            record(slam.addScan(item.frame.cloud,
                                item.timestamp_s,
                                item.sequence_index,
                                item.frame.point_times_s,
                                item.path));
        }
      }
      else {
        std::cerr << "\nframe " << item.sequence_index << ": skipped: " << item.error << "\n";
        slam.addSkippedScan(item.sequence_index, item.timestamp_s, item.error, item.path);
        skipped.push_back(
            {{"frame", item.sequence_index}, {"path", item.path}, {"reason", item.error}});
      }
      ++processed;
      if (bar)
        bar->update(processed);
    }
    if (bar)
      bar->finish();
  } catch (...) {
    run_error = std::current_exception();
  }
  const bool interrupted = pcl_rast_tools::stopRequested();
  if (interrupted)
    std::cerr << "pcl_rast_slam: " << pcl_rast_tools::stopSignalName() << " after " << processed
              << " frames; finishing and writing the results so far (a second signal ends "
                 "at once and keeps the previous output)\n";
  try {
    slam.finish(); // joins the stages; rethrows a stage's error once
  } catch (...) {
    if (!run_error)
      run_error = std::current_exception();
  }
  const std::string error_message = run_error ? pcl_rast_tools::exceptionMessage(run_error) : "";
  if (run_error) {
    if (slam.frames().empty())
      std::rethrow_exception(run_error); // nothing was processed: nothing to save
    std::cerr << "\npcl_rast_slam: error: " << error_message << "\npcl_rast_slam: writing the "
              << slam.frames().size() << " frames processed before it\n";
  }
  if (pcl_rast_tools::stopRequested() && processed == 0) {
    std::cerr << "pcl_rast_slam: " << pcl_rast_tools::stopSignalName()
              << " before the first scan; no output was written\n";
    return 128 + pcl_rast_tools::stopSignal();
  }
  const rast::SlamStatistics counts = slam.statistics();
  if (counts.frames == counts.skipped_frames && !run_error) {
    // Identity poses for scans that were never read would pass for a result.
    std::cerr << "pcl_rast_slam: error: none of the " << processed << " scans could be used ("
              << skipped.size() << " unreadable or empty"
              << (skipped.empty() ? std::string()
                                  : ", the first: " + skipped.front()["reason"].get<std::string>())
              << "); no output was written\n";
    return pcl_rast_tools::kExitAlgorithmFailure;
  }
  const double processing_peak_rss_mb = peakRssMb();
  const double wall_s =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - wall_start).count();

  // ---- multi-session: the drive joined to the session's map ----
  std::optional<rast::SessionMergeResult> merge;
  if (localizer && !run_error) {
    rast::SessionInfo info;
    info.sensor_preset = rast::toString(preset);
    info.created_by = "pcl_rast_slam";
    // The drive's clouds are expanded from the run's map when the merge needs them.
    rast::Session drive = rast::sessionFromSlam(slam, info, /*clouds_on_demand=*/true);
    drive.drives.front().input = reader.scanFolder();
    rast::SessionMergeParams merge_params;
    merge_params.loop_closing = params.loop_closing;
    merge_params.pose_graph = params.pose_graph;
    merge = rast::mergeSessions(*localizer, drive, merge_params);
    std::cerr << "Multi-session: " << merge->message << " (" << merge->time_ms / 1000.0
              << " s)\n";
  }
  const bool on_map = merge && merge->connected;

  // ---- outputs (each atomic) ----
  // On a session's map the poses are in its world frame; otherwise in the first scan's.
  rast::PoseVector poses = on_map ? framePosesOnMap(slam.frames(), *merge) : slam.framePoses();
  if (!poses.empty() && !on_map) {
    const rast::Pose3d T_first_inv = poses.front().inverse();
    for (auto& T : poses)
      T = T_first_inv * T;
  }
  std::vector<double> times;
  for (const auto& f : slam.frames())
    times.push_back(f.timestamp_s);
  rast::writeKittiPoses(outputs.path("poses_kitti.txt"), poses);
  rast::writeTumPoses(outputs.path("poses_tum.txt"), poses, times);

  const rast::PoseVector kf_poses = slam.keyFramePoses();
  const auto keyframes = slam.keyFrames();
  // The key-frames of the map drawn and written: the run's, or on a session's map
  // those of the merged map's anchored component (the session's world frame).
  std::vector<rast::KeyFrame::Ptr> map_keyframes;
  if (on_map)
    for (const rast::KeyFrame::Ptr& kf : merge->merged.keyframes)
      if (rast::sessionComponentOf(merge->merged, kf->id) == 0)
        map_keyframes.push_back(kf);
  // The picture (not the outputs) is levelled by the ground around the start of the
  // map, so a tilted or handheld first scan still renders as a view from above.
  Eigen::Matrix3d R_level = Eigen::Matrix3d::Identity();
  if (!kf_poses.empty()) {
    const pcl::PointCloud<pcl::PointXYZI>::ConstPtr first_cloud =
        on_map ? rast::sessionCloud(merge->merged, map_keyframes.front()->id)
               : slam.map()->keyFrameCloud(0);
    pcl::PointCloud<pcl::PointXYZI> first;
    if (first_cloud)
      first = *first_cloud;
    const rast::Pose3d T_first = on_map ? map_keyframes.front()->T_world_keyframe
                                        : kf_poses.front();
    const Eigen::Matrix3f R = T_first.rotation().cast<float>();
    const Eigen::Vector3f t = T_first.translation().cast<float>();
    for (auto& p : first.points)
      p.getVector3fMap() = R * p.getVector3fMap() + t;
    R_level = levellingRotation(first);
  }
  pcl::rast::MapRenderParams render_params;
  render_params.force_software_fallback = software_render;
  std::vector<Eigen::Vector3d> kf_positions;
  if (on_map)
    for (const auto& kf : map_keyframes)
      kf_positions.push_back(kf->T_world_keyframe.translation());
  else
    for (const auto& T : kf_poses)
      kf_positions.push_back(T.translation());
  RenderCloud render_map(R_level, kf_positions, map_leaf_m, render_params);
  // map.pcd is written tile by tile: the whole map is never held in memory.
  rast::PcdStreamWriter pcd(outputs.path("map.pcd"));
  const auto add_tile = [&](const pcl::PointCloud<pcl::PointXYZI>& tile) {
    pcd.append(tile);
    render_map.add(tile);
  };
  if (on_map)
    rast::forEachSessionMapTile(merge->merged, map_keyframes, map_leaf_m, add_tile);
  else
    slam.map()->forEachMapTile(map_leaf_m, add_tile);
  pcd.commit();
  const std::size_t map_points = pcd.size();
  pcl::rast::MapRenderInput render_input;
  render_input.map = &render_map.cloud();
  render_input.map_points_total = map_points;
  // The trajectory in the frame of the map drawn (unrebased when not on a session's).
  const rast::PoseVector drawn = on_map ? poses : slam.framePoses();
  for (const auto& T : drawn)
    render_input.trajectory.push_back(R_level * T.translation());
  // Ground truth starts where the drawn trajectory does.
  const rast::Pose3d T_gt_start =
      !gt.empty() && gt_frame.front() < drawn.size() ? drawn[gt_frame.front()] : rast::Pose3d::Identity();
  for (std::size_t k = 0; k < gt.size() && gt_frame[k] < poses.size(); ++k)
    render_input.ground_truth.push_back(R_level * (T_gt_start * gt[k]).translation());
  if (on_map)
    for (const auto& e : merge->merged.loops)
      if (e.active && e.query >= merge->drive_first_keyframe &&
          e.candidate < merge->drive_first_keyframe) // the inter-session loops
        render_input.loop_edges.emplace_back(
            R_level * merge->merged.keyframes.at(e.candidate)->T_world_keyframe.translation(),
            R_level * merge->merged.keyframes.at(e.query)->T_world_keyframe.translation());
  json loop_json = json::array();
  for (const auto& e : slam.loops()) {
    if (e.active && !on_map)
      render_input.loop_edges.emplace_back(R_level * kf_poses.at(e.candidate).translation(),
                                           R_level * kf_poses.at(e.query).translation());
    loop_json.push_back({{"query_keyframe", e.query},
                         {"candidate_keyframe", e.candidate},
                         {"query_frame", keyframes.at(e.query)->frame_index},
                         {"candidate_frame", keyframes.at(e.candidate)->frame_index},
                         {"inliers", e.num_inliers},
                         {"active", e.active},
                         {"T_candidate_query", poseJson(e.T_candidate_query)}});
  }
  fs::path sequence_name = fs::path(reader.scanFolder()).filename();
  if (sequence_name == "velodyne" || sequence_name == "pcd" || sequence_name == "ply")
    sequence_name = fs::path(reader.scanFolder()).parent_path().filename();
  render_input.title = "pcl_rast_slam: " + sequence_name.string();
  const auto render = pcl::rast::renderMapTopDown(render_input, render_params,
                                                       outputs.path("render.png"));
  if (!render.success)
    std::cerr << "pcl_rast_slam: warning: render.png not written: " << render.message << "\n";

  const rast::SlamStatistics stats = slam.statistics();
  json summary;
  summary["input"] = reader.scanFolder();
  summary["frames"] = stats.frames;
  summary["frames_selected"] = reader.size();
  summary["interrupted"] = interrupted;
  summary["stop_signal"] = interrupted ? json(pcl_rast_tools::stopSignalName()) : json(nullptr);
  summary["error"] = run_error ? json(error_message) : json(nullptr);
  summary["elevation_calibration"] =
      pcl_rast_tools::elevationCalibrationJson(slam.elevationCalibration());
  summary["deskew"] = {{"mode", rast::toString(params.odometry.deskew.mode)},
                       {"frames_by_time_source", tally.frames_by_time_source},
                       {"second_passes", tally.second_passes},
                       {"time_field_warnings", tally.time_field_warnings}};
  {
    // How far the stored poses are from SO(3) (max of |R^T R - I| and |det R - 1|).
    rast::PoseVector stored = kf_poses;
    const rast::PoseVector frame_poses = slam.framePoses();
    stored.insert(stored.end(), frame_poses.begin(), frame_poses.end());
    for (const auto& e : slam.loops())
      stored.push_back(e.T_candidate_query);
    summary["max_rotation_error"] = rast::maxRotationError(stored);
  }
  summary["skipped_frames"] = skipped;
  summary["keyframes"] = stats.keyframes;
  summary["map_points"] = stats.map_points;
  summary["map_points_created"] = stats.map_points_created;
  summary["map_pcd_points"] = map_points;
  summary["loops_accepted"] = stats.loops_accepted;
  summary["loops_rejected"] = stats.loops_rejected;
  summary["loops_dropped_inconsistent"] = stats.loops_inconsistent;
  summary["loop_candidates"] = stats.loop_candidates;
  summary["pose_graph_runs"] = stats.pose_graph_runs;
  summary["loop_searches_skipped"] = stats.loop_searches_skipped;
  summary["loop_database_keyframes"] = stats.loop_database_keyframes;
  summary["loop_database_revisits_culled"] = stats.loop_database_revisits_culled;
  summary["map_cloud_mb"] = stats.memory_bytes.at("map_clouds") / (1024.0 * 1024.0);
  for (const auto& [part, bytes] : stats.memory_bytes)
    summary["memory_mb"][part] = bytes / (1024.0 * 1024.0);
  summary["loop_edges"] = loop_json;
  summary["tracking_status"] = stats.tracking_status;
  summary["frames_without_features"] = stats.frames_without_features;
  summary.update(degraded.toJson());
  json timing;
  for (const auto& [stage, t] : stats.timing)
    timing[stage] = timingJson(t);
  summary["timing_ms"] = timing;
  summary["wall_s"] = wall_s;
  summary["fps"] = wall_s > 0.0 ? stats.frames / wall_s : 0.0;
  summary["peak_rss_mb"] = peakRssMb();
  summary["processing_peak_rss_mb"] = processing_peak_rss_mb; // before the outputs
  summary["cpu_s"] = processCpuS();
  summary["render_backend"] = render.backend;
  summary["render_message"] = render.message;
  summary["params"] = {
      {"threads", threads},
      {"sensor", rast::toString(preset)},
      {"deskew", rast::toString(params.odometry.deskew.mode)},
      {"deskew_reason", deskew_reason},
      {"deskew_timing", deskew_timing},
      {"sensor_choice", sensor_reason},
      {"loop_closure", params.loop_closing.enable},
      {"revisit_culling", params.loop_closing.cull_revisits},
      {"young_map_scans", params.odometry.dense.young_map_scans},
      {"map_nearer", params.odometry.dense.map_nearer_ratio},
      {"weak_feature_share", params.odometry.weak_feature_share},
      {"degeneracy_support", params.odometry.dense.degeneracy_min_support},
      {"visibility_margin_m", params.odometry.visibility_margin_m},
      {"lookahead", !no_lookahead},
      {"local_ba", params.local_mapping.enable_bundle_adjustment},
      {"global_ba", params.loop_closing.global_bundle_adjustment},
      {"features_on_demand", params.features_on_demand},
      {"map_leaf_m", map_leaf_m},
      {"first", first},
      {"last", last},
      {"stride", stride},
      {"ba_window", params.local_mapping.window_size}};
  if (!gt.empty()) {
    rast::PoseVector gt_n, est_n; // the pairs whose frame was processed
    for (std::size_t k = 0; k < gt.size() && gt_frame[k] < poses.size(); ++k) {
      gt_n.push_back(gt[k]);
      est_n.push_back(poses[gt_frame[k]]);
    }
    summary["gt"] = gt_path;
    summary["gt_pairs"] = gt_n.size();
    if (gt_n.size() >= 2) {
      const rast::EvaluationResult ev = rast::evaluateTrajectory(est_n, gt_n);
      summary["ate_rmse_m"] = ev.ate_rmse_m;
      summary["ate_max_m"] = ev.ate_max_m;
      summary["kitti_t_err_pct"] =
          ev.kitti_t_err_pct ? json(*ev.kitti_t_err_pct) : json(nullptr);
      summary["kitti_r_err_deg_per_100m"] =
          ev.kitti_r_err_deg_per_100m ? json(*ev.kitti_r_err_deg_per_100m) : json(nullptr);
      summary["rpe_trans_rmse_m"] = ev.rpe_trans_rmse_m;
      summary["gt_length_m"] = ev.gt_length_m;
    }
    else {
      summary["ate_rmse_m"] = nullptr;
      summary["kitti_t_err_pct"] = nullptr;
      summary["kitti_r_err_deg_per_100m"] = nullptr;
    }
  }
  summary["poses_frame"] = on_map ? "session" : "first_scan";
  if (merge) {
    json loops = json::array();
    for (const auto& l : merge->loops)
      loops.push_back({{"prior_keyframe", l.prior_keyframe},
                       {"drive_keyframe", l.drive_keyframe},
                       {"drive_frame", keyframes.at(l.drive_keyframe)->frame_index},
                       {"inliers", l.num_inliers},
                       {"agrees", l.agrees},
                       {"dropped", l.dropped}});
    summary["multi_session"] = {
        {"session", session_dir},
        {"session_keyframes", merge->drive_first_keyframe},
        {"session_load_s", session_load_s},
        {"connected", merge->connected},
        {"component", merge->component},
        {"merged_keyframes", merge->merged.keyframes.size()},
        {"merged_drives", merge->merged.drives.size()},
        {"keyframes_tried", merge->keyframes_tried},
        {"placement",
         {{"min_initial_inliers", localizer_params.verification.min_initial_inliers},
          {"min_inliers", localizer_params.verification.min_inliers},
          {"min_appearance_score", localizer_params.verification.min_appearance_score}}},
        {"placements", merge->loops.size()},
        {"loops_agreeing", merge->loops_agreeing},
        {"loops_used", merge->loops_used},
        {"T_session_drive", poseJson(merge->T_prior_drive)},
        {"pose_graph", merge->optimization.BriefReport()},
        {"merge_s", merge->time_ms / 1000.0},
        {"message", merge->message},
        {"inter_session_loops", loops}};
  }
  else if (localizer) {
    summary["multi_session"] = {{"session", session_dir},
                                {"connected", false},
                                {"message", "the run failed: not merged"}};
  }
  std::string session_failure;
  if (!save_session.empty()) {
    const json parameters = summary["params"];
    const auto save = [&]() -> std::size_t {
      if (merge) {
        rast::Session merged = std::move(merge->merged);
        merged.info.parameters_json =
            parameters.dump(-1, ' ', false, json::error_handler_t::replace);
        rast::saveSession(merged, save_session);
        return merged.keyframes.size();
      }
      rast::SessionInfo info;
      info.sensor_preset = rast::toString(preset);
      info.created_by = "pcl_rast_slam";
      info.parameters_json = parameters.dump(-1, ' ', false, json::error_handler_t::replace);
      rast::saveSession(slam, save_session, info);
      return slam.statistics().keyframes;
    };
    summary["session"] =
        saveSessionOf(save, save_session, run_error != nullptr, session_failure);
  }
  outputs.publish(summary); // summary.json last: it lists the files of this run

  std::cerr << "Wrote " << (fs::path(output) / "poses_kitti.txt").string()
            << ", poses_tum.txt, map.pcd ("
            << map_points << " points), render.png (" << render.backend
            << "), summary.json\n";
  std::cerr << stats.frames << " frames, " << stats.keyframes << " key-frames, "
            << stats.loops_accepted << " loops accepted, " << wall_s << " s ("
            << (wall_s > 0 ? stats.frames / wall_s : 0.0) << " fps)";
  if (summary.contains("ate_rmse_m") && !summary["ate_rmse_m"].is_null())
    std::cerr << ", ATE RMSE " << summary["ate_rmse_m"].get<double>() << " m";
  std::cerr << "\n";
  if (const std::string warning = degraded.warning("pcl_rast_slam"); !warning.empty())
    std::cerr << warning << "\n";
  if (run_error) {
    std::cerr << "pcl_rast_slam: error: " << error_message
              << " (the results up to it were written)\n";
    return pcl_rast_tools::kExitAlgorithmFailure;
  }
  if (!session_failure.empty()) {
    std::cerr << "pcl_rast_slam: error: " << session_failure
              << " (the run's outputs were written)\n";
    return pcl_rast_tools::kExitIoError;
  }
  return pcl_rast_tools::kExitOk;
}

} // namespace

int
main(int argc, char** argv)
{
  return pcl_rast_tools::runTool("pcl_rast_slam", [&] { return run(argc, argv); });
}
