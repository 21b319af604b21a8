/// \file rast_localize.cpp
/// \brief pcl_rast_localize: localization of a folder of scans on a saved session
/// (issue 13, doc/session.md).
///
///   pcl_rast_localize -session DIR -input SCANS -output OUT [-initial-pose "x y z qx qy qz qw"]
///                     [-first N] [-last N] [-stride K] [-deskew auto|on|off] [options]
///
/// The first scan is placed on the map by retrieval and verification (or starts at
/// -initial-pose); then each scan is tracked frame to frame and aligned to the map's
/// key-frames; when the map does not confirm a frame it is placed anew, and a jump
/// (kidnapping) is reported. Writes OUT/poses_kitti.txt and poses_tum.txt (the map's
/// frame), status.csv (one row per frame: localized / tracking_only / lost),
/// render.png (the trajectory over the session's map) and summary.json, as one set.
/// Exit codes: 0 ok, 1 bad arguments, 2 I/O error or a bad session, 3 no scan usable.

#include <pcl/io/pose_io.h>
#include <pcl/io/sequence_reader.h>
#include <pcl/registration/voxel_hash_map.h>
#include <pcl/slam/session.h>
#include <pcl/slam/session_localizer.h>
#include <pcl/visualization/map_render.h>

#include "cli.h"
#include "output_set.h"
#include "prefetcher.h"
#include "sensor_choice.h"
#include "stop_signals.h"

#include <nlohmann/json.hpp>

#include <pcl/common/time.h>

#include <algorithm>
#include <cmath>
#include <optional>
#include <cstdio>
#include <filesystem>
#ifdef __GLIBC__
#include <malloc.h>
#endif
#include <map>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

namespace {

namespace rast = pcl::rast;
namespace fs = std::filesystem;
using nlohmann::json;

/// "x y z qx qy qz qw" as a pose. \throws std::invalid_argument naming the value.
rast::Pose3d
parsePose(const std::string& text)
{
  std::istringstream in(text);
  double v[7];
  for (double& x : v)
    if (!(in >> x) || !std::isfinite(x))
      throw std::invalid_argument("-initial-pose '" + text +
                                  "': need 7 finite numbers, x y z qx qy qz qw");
  std::string extra;
  if (in >> extra)
    throw std::invalid_argument("-initial-pose '" + text + "': more than 7 numbers");
  const Eigen::Quaterniond q(v[6], v[3], v[4], v[5]);
  if (std::abs(q.norm() - 1.0) > 1e-3)
    throw std::invalid_argument("-initial-pose '" + text + "': the quaternion has norm " +
                                std::to_string(q.norm()) + ", not 1");
  rast::Pose3d T = rast::Pose3d::Identity();
  T.linear() = q.normalized().toRotationMatrix();
  T.translation() = Eigen::Vector3d(v[0], v[1], v[2]);
  return T;
}

/// One status.csv row of frame \a f (its message with commas and line breaks as ';').
std::string
statusRow(const rast::LocalizationFrame& f)
{
  std::string message = f.message;
  for (char& c : message)
    if (c == ',' || c == '\n')
      c = ';';
  char row[160];
  std::snprintf(row,
                sizeof row,
                "%zu,%.6f,%s,%d,%d,%.3f,%u,%d,%.4f,%.2f,",
                f.frame_index,
                f.timestamp_s,
                rast::toString(f.status),
                f.placed ? 1 : 0,
                f.jump ? 1 : 0,
                f.jump_m,
                static_cast<unsigned>(f.keyframe),
                f.correspondences,
                f.rmse_m,
                f.time_ms);
  return row + message + (f.backtracked ? ",1\n" : ",0\n");
}

/// The session's key-frame clouds in its world frame, one point per voxel (render).
pcl::PointCloud<pcl::PointXYZI>
sessionMap(const rast::Session& session, double leaf_m, std::size_t& total)
{
  pcl::PointCloud<pcl::PointXYZI> map;
  rast::VoxelOccupancy occupied(leaf_m); // the first point of each voxel is kept
  total = 0;
  for (const rast::KeyFrame::Ptr& kf : session.keyframes) {
    if (rast::sessionComponentOf(session, kf->id) != 0)
      continue; // a separate map of the session, in another frame
    const pcl::PointCloud<pcl::PointXYZI>::ConstPtr cloud = rast::sessionCloud(session, kf->id);
    if (!cloud)
      continue;
    const Eigen::Isometry3f T = kf->T_world_keyframe.cast<float>();
    for (const auto& p : cloud->points) {
      ++total;
      const Eigen::Vector3f w = T * p.getVector3fMap();
      if (!occupied.insert(w))
        continue;
      pcl::PointXYZI q = p;
      q.getVector3fMap() = w;
      map.push_back(q);
    }
  }
  return map;
}

int
run(int argc, char** argv)
{
  using namespace pcl_rast_tools;
  std::string session_dir, input, output, initial_pose, sensor;
  int first = 0, last = -1, stride = 1;
  bool software_render = false, quiet = false;
  DeskewFlags deskew;
  rast::MapLocalizationParams params;

  ArgParser args("pcl_rast_localize",
                 "Localization on a saved session (pcl_rast_slam -save-session): the first "
                 "scan is placed on the map with no initial pose, then every scan is "
                 "tracked and aligned to the map; a lost or kidnapped run is placed anew. "
                 "Writes poses_kitti.txt, poses_tum.txt (the map's frame), status.csv, "
                 "render.png and summary.json into the output folder.");
  args.addString("session", "the session folder (pcl_rast_slam -save-session)", &session_dir,
                 true);
  args.addString("input", "scan folder (.bin/.pcd/.ply, or with velodyne/ or pcd/)", &input,
                 true);
  args.addString("output", "output folder (created when missing)", &output, true);
  args.addString("initial-pose",
                 "start here (\"x y z qx qy qz qw\", the map's frame) instead of placing the "
                 "first scan by retrieval",
                 &initial_pose);
  args.addString("sensor", "parameter preset; must be the session's (default: the session's)",
                 &sensor);
  args.addInt("first", "first scan index", &first);
  args.addInt("last", "last scan index, inclusive (-1: the last)", &last);
  args.addInt("stride", "use every stride-th scan", &stride);
  addDeskewFlags(args, deskew);
  args.addDouble("map-radius", "align to session key-frames within this distance [m]",
                 &params.map_radius_m);
  args.addDouble("jump", "a placement this far from the prediction is a jump [m]",
                 &params.jump_m);
  args.addInt("max-tracking-only",
              "frames the odometry may carry the pose alone before the run counts as lost",
              &params.max_tracking_only_frames);
  args.addInt("place-backoff",
              "failed placements in a row (off the map) after which they back off "
              "(0: never)",
              &params.placement_backoff_after);
  args.addInt("place-every",
              "after -place-backoff failed placements in a row, try one every N frames "
              "(1: every frame)",
              &params.placement_every);
  args.addDouble(
      "prior-radius",
      "placements verify the key-frames within this distance of the dead-reckoned "
      "pose first, plus " +
          std::to_string(static_cast<int>(100.0 * params.prior_radius_per_m + 0.5)) +
          " % of the distance since the map last confirmed a pose [m] (0: no prior)",
      &params.prior_radius_m);
  args.addInt("place-lag",
              "those attempts run in the background and are taken N frames later, moved "
              "there by the odometry (0: at once, on the main thread)",
              &params.background_placement_lag);
  args.addDouble(
      "far-radius",
      "off the map, a dead-reckoned pose farther than this from every session "
      "key-frame, plus " +
          std::to_string(static_cast<int>(100.0 * params.far_drift_ratio + 0.5)) +
          " % of the distance since the map last confirmed a pose, is far from "
          "it: attempts every -far-every frames, taken -far-lag frames later "
          "[m] (0: never far)",
      &params.far_radius_m);
  args.addInt("far-every",
              "far from the map, backed off: one attempt every N frames",
              &params.far_placement_every);
  args.addInt("far-lag",
              "far from the map: attempts taken N frames later",
              &params.far_placement_lag);
  args.addDouble("leaving-corridor",
                 "where the map stops confirming the pose and no session key-frame lies "
                 "ahead (within -map-radius, and this close to the line of the motion), "
                 "the drive is leaving the map: its attempts back off at once, in the "
                 "background [m] (0: every loss tries every frame first)",
                 &params.leaving_map_corridor_m);
  args.addInt("backtrack",
              "after a placement, align up to N frames before it that the map did not "
              "confirm backwards to the map (written with backtracked=1 in status.csv; "
              "0: none)",
              &params.backtrack_frames);
  // Placement thresholds (SessionLocalizerParams::verification): fewer accept more
  // placements, between passes that share less, at the risk of a wrong one.
  const rast::SessionLocalizerParams localizer_defaults;
  const rast::LoopDetectorParams& placement_defaults = localizer_defaults.verification;
  // The inlier thresholds' defaults are the session's sensor preset's, known once the
  // session is read: these are only the values shown.
  int place_min_score = placement_defaults.min_appearance_score;
  int place_min_initial = placement_defaults.min_initial_inliers;
  int place_min_inliers = placement_defaults.min_inliers;
  args.addInt("place-min-score",
              "placement: appearance votes a key-frame needs to be verified",
              &place_min_score);
  args.addInt("place-min-initial",
              "placement: RANSAC inliers of the first (ratio-test) matches (vlp16: 8)",
              &place_min_initial);
  args.addInt("place-min-inliers",
              "placement: RANSAC inliers after guided matching (vlp16: 30)",
              &place_min_inliers);
  int prior_candidates = localizer_defaults.max_prior_candidates;
  // Like the inlier thresholds, the default is the session's sensor preset's.
  int place_neighbours = localizer_defaults.neighbourhood_keyframes;
  args.addInt(
      "place-neighbours",
      "placement: map key-frames nearest a candidate verified with it, also in the "
      "first attempts (0: none; default: the preset's, and 2 in the first 5 attempts)",
      &place_neighbours);

  int place_polar = localizer_defaults.polar_candidates;
  args.addInt("place-polar",
              "placement: in a start's or relocalization's first attempts, key-frames "
              "nearest by the polar max-height descriptor verified too (0: none)",
              &place_polar);

  int dense_points = localizer_defaults.odometry.dense.max_source_points;
  args.addInt(
      "dense-points",
      "the odometry between map alignments: source points of its dense step, at most",
      &dense_points);
  args.addInt(
      "prior-candidates",
      "placement: key-frames nearest the dead-reckoned pose verified first (0: none)",
      &prior_candidates);
  args.addDouble(
      "prior-overlap",
      "placement once lost: the dense check's least overlap for those key-frames "
      "(negative: the full one)",
      &params.lost_prior_min_dense_overlap);
  bool no_tentative_alignment = false;
  args.addSwitch("no-tentative-alignment",
                 "a tentative placement is taken only when a second placement agrees, not "
                 "when the next scan's alignment to the map confirms it",
                 &no_tentative_alignment);
  bool no_merged_keyframes = false;
  args.addSwitch("no-merged-keyframes",
                 "a scan that aligns to none of the nearest key-frames alone is not "
                 "aligned to their clouds together (as it is within 10 m of them)",
                 &no_merged_keyframes);
  bool no_tracked_together = false;
  args.addSwitch(
      "no-tracked-together",
      "a tracked frame that no nearest key-frame confirms alone is not aligned "
      "to their clouds together (only a tentative placement's next scan is)",
      &no_tracked_together);
  bool no_lookahead = false;
  args.addSwitch(
      "no-lookahead",
      "compute each scan's ground, raster and ORB on the main thread after the "
      "scan before, not on a second thread while it is tracked",
      &no_lookahead);
  bool trust_degraded_odometry = false;
  args.addSwitch("trust-degraded-odometry",
                 "an alignment that keeps a direction the scan does not constrain at the "
                 "odometry's prediction (the vlp16 preset) confirms the frame also where "
                 "the odometry was degraded",
                 &trust_degraded_odometry);
  bool no_elevation_calibration = false;
  args.addSwitch("no-elevation-calibration",
                 "the odometry between map alignments keeps the points at the elevation "
                 "the sensor gave them (no self-calibration of the beams' elevation; "
                 "doc/odometry.md)",
                 &no_elevation_calibration);
  bool all_features = false;
  args.addSwitch("all-features",
                 "make every scan's raster features, also between the placement attempts "
                 "off the map, where the dense step alone tracks most scans",
                 &all_features);
  args.addSwitch("software-render", "render.png with OpenCV instead of VTK (faster)",
                 &software_render);
  args.addSwitch("quiet", "no progress bar", &quiet);
  if (!args.parse(argc, argv))
    return kExitOk;
  installStopSignals();
  params.confirm_tentative_by_alignment = !no_tentative_alignment;
  params.features_on_demand = !all_features;
  params.degenerate_needs_tracked_odometry = !trust_degraded_odometry;
  if (no_merged_keyframes)
    params.merged_keyframes_within_m = 0.0;
  params.tracked_together = !no_tracked_together;

  // ---- validate everything before any work ----
  if (first < 0 || stride < 1 || last < -1 || (last >= 0 && last < first))
    throw std::invalid_argument("bad frame range: -first " + std::to_string(first) + " -last " +
                                std::to_string(last) + " -stride " + std::to_string(stride));
  checkDeskewFlags(deskew);
  std::string why;
  if (!params.isValid(&why))
    throw std::invalid_argument("invalid parameters: " + why);
  if (place_min_score < 1 || place_min_initial < 3 || place_min_inliers < 3)
    throw std::invalid_argument("bad placement thresholds: -place-min-score " +
                                std::to_string(place_min_score) + " (>= 1), -place-min-initial " +
                                std::to_string(place_min_initial) + " (>= 3), -place-min-inliers " +
                                std::to_string(place_min_inliers) + " (>= 3)");
  if (place_neighbours < 0)
    throw std::invalid_argument("bad -place-neighbours " +
                                std::to_string(place_neighbours) + " (>= 0)");
  if (place_polar < 0)
    throw std::invalid_argument("bad -place-polar " + std::to_string(place_polar) +
                                " (>= 0)");
  if (dense_points < 10)
    throw std::invalid_argument("bad -dense-points " + std::to_string(dense_points) +
                                " (>= 10)");
  std::optional<rast::Pose3d> start;
  if (!initial_pose.empty())
    start = parsePose(initial_pose);
  if (!sensor.empty())
    rast::sensorPresetFromName(sensor); // names the value when it is none

  rast::SequenceReaderOptions options;
  options.first = static_cast<std::size_t>(first);
  options.last = last;
  options.stride = static_cast<std::size_t>(stride);
  rast::SequenceReader reader(input, options);
  checkOutputIsNotInput(output, reader.scanFolder());
  if (fs::weakly_canonical(output) == fs::weakly_canonical(session_dir))
    throw std::invalid_argument("-output " + output + " is the session folder");

  // The session: every file checked (version, preset, sizes, checksums) before any work.
  const pcl::StopWatch load_watch;
  rast::SessionLoadOptions load_options;
  load_options.expected_sensor_preset = sensor;
  // Clouds stay in their files: the localizer's index keeps compact dense targets, and
  // the map alignment reads the few key-frames it aligns to (a bounded cache).
  load_options.load_clouds = false;
  rast::Session session;
  try {
    session = rast::loadSession(session_dir, load_options);
  } catch (const rast::SessionError& e) {
    throw std::runtime_error(std::string("bad session: ") + e.what());
  }
  const double load_s = load_watch.getTimeSeconds();
  OutputSet outputs(output, "pcl_rast_localize");
  const rast::SensorPreset preset = rast::sensorPresetFromName(session.info.sensor_preset);
  std::fprintf(stderr, "Session %s [%zu key-frames, sensor %s, loaded in %.2f s]\n",
               session_dir.c_str(), session.keyframes.size(), rast::toString(preset), load_s);
  std::fprintf(stderr, "Input %s [%zu scans, %zu selected]\n", reader.scanFolder().c_str(),
               reader.numFiles(), reader.size());

  rast::SessionLocalizerParams localizer_params;
  rast::applySensorPreset(preset, localizer_params);
  rast::applySensorPreset(preset, params);
  localizer_params.verification.min_appearance_score = place_min_score;
  if (args.given("place-min-initial"))
    localizer_params.verification.min_initial_inliers = place_min_initial;
  if (args.given("place-min-inliers"))
    localizer_params.verification.min_inliers = place_min_inliers;
  localizer_params.max_prior_candidates = prior_candidates;
  if (args.given("place-neighbours")) {
    localizer_params.neighbourhood_keyframes = place_neighbours;
    params.first_attempts_neighbourhood_keyframes = place_neighbours;
  }
  localizer_params.polar_candidates = place_polar;
  localizer_params.odometry.dense.max_source_points = dense_points;
  if (no_elevation_calibration)
    localizer_params.odometry.elevation_calibration.enabled = false;
  std::string deskew_reason, deskew_timing;
  applyDeskewFlags(deskew, reader, static_cast<std::size_t>(stride),
                   localizer_params.odometry.deskew, deskew_reason, deskew_timing);
  // What the render needs of the session (poses, drives, cloud files), kept so that the
  // localizer can be let go before the render map is built: the two never share memory.
  rast::Session map_shape;
  map_shape.drives = session.drives;
  map_shape.cloud_files = session.cloud_files;
  for (const rast::KeyFrame::Ptr& kf : session.keyframes) {
    auto shape = std::make_shared<rast::KeyFrame>();
    shape->id = kf->id;
    shape->T_world_keyframe = kf->T_world_keyframe;
    map_shape.keyframes.push_back(std::move(shape));
  }
  auto localizer =
      std::make_unique<const rast::SessionLocalizer>(std::move(session), localizer_params);
  auto localization =
      std::make_unique<rast::MapLocalization>(*localizer, localizer_params.odometry, params);
  if (start)
    localization->setInitialPose(*start);

  rast::PoseVector poses;
  std::vector<double> times;
  // One status.csv row per frame: a later placement may revise earlier ones
  // (backtracked frames).
  std::vector<std::string> rows;
  std::vector<rast::LocalizationStatus> statuses;
  std::size_t backtracked = 0;
  std::vector<double> frame_ms;
  json skipped = json::array(), jumps = json::array();
  std::size_t usable = 0, stopped_at = reader.size();
  int first_localized = -1;
  std::optional<ProgressBar> bar;
  if (!quiet)
    bar.emplace("Localize", reader.size());
  std::size_t placements_tried = 0, prepared_ahead = 0, alignment_ahead = 0,
              features_skipped = 0;
  const pcl::StopWatch run_watch;
  // Scans are read a few ahead on a thread of their own (about 2 ms a frame).
  Prefetcher prefetcher(reader, 4);
  ReadItem item;
  for (std::size_t i = 0; i < reader.size(); ++i) {
    if (stopRequested() || !prefetcher.next(item)) {
      stopped_at = i;
      reportStop("pcl_rast_localize", i);
      break;
    }
    rast::LocalizationFrame f;
    if (item.ok) {
      // The next scan (read on the prefetcher's thread) for the odometry's look-ahead.
      const ReadItem* next = no_lookahead ? nullptr : prefetcher.peek();
      if (next && next->ok)
        f = localization->addScan(item.frame.cloud,
                                  item.frame.timestamp_s,
                                  i,
                                  item.frame.point_times_s,
                                  {next->frame.cloud,
                                   next->frame.timestamp_s,
                                   i + 1,
                                   next->frame.point_times_s});
      else
        f = localization->addScan(
            item.frame.cloud, item.frame.timestamp_s, i, item.frame.point_times_s);
      ++usable;
    } else {
      std::fprintf(stderr, "\nframe %zu: skipped: %s\n", i, item.error.c_str());
      f = localization->addSkippedScan(item.timestamp_s, i, item.error);
      skipped.push_back({{"frame", i}, {"path", item.path}, {"reason", item.error}});
    }
    placements_tried += f.placement_tried ? 1 : 0;
    prepared_ahead += f.odometry_prepared_ahead ? 1 : 0;
    alignment_ahead += f.alignment_prepared_ahead ? 1 : 0;
    features_skipped += f.odometry_features_skipped ? 1 : 0;
    if (f.status == rast::LocalizationStatus::kLocalized && first_localized < 0)
      first_localized = static_cast<int>(i);
    if (f.jump) {
      std::fprintf(stderr, "\nframe %zu: %s\n", i, f.message.c_str());
      jumps.push_back({{"frame", i}, {"jump_m", f.jump_m}});
    }
    poses.push_back(f.T_world_lidar);
    times.push_back(f.timestamp_s);
    frame_ms.push_back(f.time_ms);
    rows.push_back(statusRow(f));
    statuses.push_back(f.status);
    for (const rast::LocalizationFrame& b : f.backtracked_frames) {
      if (b.frame_index >= rows.size())
        continue; // not one of this run's frames (cannot happen)
      poses[b.frame_index] = b.T_world_lidar;
      rows[b.frame_index] = statusRow(b);
      statuses[b.frame_index] = b.status;
      ++backtracked;
    }
    if (bar)
      bar->update(i + 1);
#ifdef __GLIBC__
    // What the placements and the odometry's restarts freed goes back to the system:
    // glibc keeps it in the arena of the thread that freed it, and the resident size
    // grew by about 40 MB over a 2540-frame drive (simulated KITTI 00), 10-20 MB more
    // than with this. A trim took 4 ms (median of 25; 8 ms at most) on that drive.
    if ((i + 1) % 100 == 0)
      malloc_trim(0);
#endif
  }
  if (bar)
    bar->finish();
  const double wall_s = run_watch.getTimeSeconds();
  if (stopped_at == 0) {
    std::fprintf(stderr, "pcl_rast_localize: %s before the first scan; no output was written\n",
                 stopSignalName());
    return 128 + stopSignal();
  }
  if (usable == 0) {
    std::fprintf(stderr, "pcl_rast_localize: error: none of the %zu scans could be used; no "
                         "output was written\n",
                 poses.size());
    return kExitAlgorithmFailure;
  }

  rast::writeKittiPoses(outputs.path("poses_kitti.txt"), poses);
  rast::writeTumPoses(outputs.path("poses_tum.txt"), poses, times);
  std::string csv =
      "frame,time,status,placed,jump,jump_m,keyframe,correspondences,rmse_m,ms,message,"
      "backtracked\n";
  for (const std::string& row : rows)
    csv += row;
  rast::writeFileAtomically(outputs.path("status.csv"), csv);
  std::map<std::string, std::size_t> status_counts;
  for (const rast::LocalizationStatus status : statuses)
    ++status_counts[rast::toString(status)];

  const std::size_t indexed_keyframes = localizer->numIndexed();
  localization.reset();
  localizer.reset();
  // The localizer's memory goes back to the system before the render map is built:
  // otherwise the peak is the two together (in glibc's free lists and the new map).
#ifdef __GLIBC__
  malloc_trim(0);
#endif
  std::size_t map_total = 0;
  pcl::PointCloud<pcl::PointXYZI> render_map;
  try {
    render_map = sessionMap(map_shape, 0.4, map_total);
  } catch (const rast::SessionError& e) { // a cloud file changed since the load
    std::fprintf(stderr, "pcl_rast_localize: warning: the map is missing from render.png: %s\n",
                 e.what());
  }

  rast::MapRenderParams render_params;
  render_params.force_software_fallback = software_render;
  rast::MapRenderInput render_input;
  render_input.map = &render_map;
  render_input.map_points_total = map_total;
  for (const auto& T : poses)
    render_input.trajectory.push_back(T.translation());
  render_input.title = "pcl_rast_localize: " + fs::path(session_dir).filename().string();
  const auto render =
      rast::renderMapTopDown(render_input, render_params, outputs.path("render.png"));
  if (!render.success)
    std::fprintf(stderr, "pcl_rast_localize: warning: render.png not written: %s\n",
                 render.message.c_str());

  std::vector<double> sorted = frame_ms;
  std::sort(sorted.begin(), sorted.end());
  json summary;
  summary["session"] = session_dir;
  summary["session_keyframes"] = map_shape.keyframes.size();
  summary["session_indexed_keyframes"] = indexed_keyframes;
  summary["session_load_s"] = load_s;
  summary["sensor"] = rast::toString(preset);
  summary["input"] = reader.scanFolder();
  summary["frames_selected"] = reader.size();
  summary["frames"] = poses.size();
  summary["frames_by_status"] = status_counts;
  summary["frames_localized"] =
      status_counts.count("localized") ? status_counts.at("localized") : 0;
  // As the run went: backtracked frames were localized later.
  summary["first_localized_frame"] = first_localized >= 0 ? json(first_localized) : json(nullptr);
  summary["frames_backtracked"] = backtracked;
  summary["initial_pose_given"] = start.has_value();
  summary["jumps"] = jumps;
  summary["skipped_frames"] = skipped;
  summary["median_frame_ms"] = sorted.empty() ? 0.0 : sorted[sorted.size() / 2];
  summary["wall_s"] = wall_s; // reading and localizing the scans, not loading or writing
  summary["fps"] = wall_s > 0.0 ? poses.size() / wall_s : 0.0;
  summary["peak_rss_mb"] = peakRssMb();
  summary["cpu_s"] = processCpuS();
  summary["interrupted"] = stopped_at < reader.size();
  summary["stop_signal"] = stopRequested() ? json(stopSignalName()) : json(nullptr);
  summary["deskew"] = {{"mode", rast::toString(localizer_params.odometry.deskew.mode)},
                       {"reason", deskew_reason}};
  summary["elevation_calibration"] = {
      {"enabled", localizer_params.odometry.elevation_calibration.enabled}};
  summary["placement"] = {
      {"min_score", place_min_score},
      {"min_initial_inliers", localizer_params.verification.min_initial_inliers},
      {"min_inliers", localizer_params.verification.min_inliers},
      {"neighbourhood_keyframes", localizer_params.neighbourhood_keyframes},
      {"first_attempts", params.first_attempts},
      {"first_attempts_neighbourhood_keyframes",
       params.first_attempts_neighbourhood_keyframes},
      {"polar_candidates", localizer_params.polar_candidates},
      {"track_on_map", params.track_on_map},
      {"backoff_after", params.placement_backoff_after},
      {"every", params.placement_every},
      {"prior_radius_m", params.prior_radius_m},
      {"background_lag", params.background_placement_lag},
      {"far_radius_m", params.far_radius_m},
      {"far_drift_ratio", params.far_drift_ratio},
      {"far_every", params.far_placement_every},
      {"far_lag", params.far_placement_lag},
      {"leaving_map_corridor_m", params.leaving_map_corridor_m},
      {"backtrack_frames", params.backtrack_frames},
      {"tentative_by_alignment", params.confirm_tentative_by_alignment},
      {"tried", placements_tried}};
  summary["map_alignment"] = {
      {"merged_keyframes_within_m", params.merged_keyframes_within_m},
      {"tracked_together", params.tracked_together},
      {"tracked_together_min_overlap_ratio", params.tracked_together_min_overlap_ratio},
      {"target_voxel_m", params.alignment.target_voxel_size_m}, // the sensor preset's
      {"degeneracy_min_ratio", params.alignment.degeneracy_min_ratio},
      {"degenerate_needs_tracked_odometry", params.degenerate_needs_tracked_odometry}};
  summary["odometry_features"] = {{"on_demand", params.features_on_demand},
                                  {"frames_without", features_skipped}};
  summary["lookahead"] = {{"on", !no_lookahead},
                          {"frames_prepared_ahead", prepared_ahead},
                          {"alignment_sources_prepared_ahead", alignment_ahead}};
  summary["render_backend"] = render.backend;
  summary["error"] = nullptr;
  outputs.publish(summary);
  std::string counts;
  for (const auto& [name, count] : status_counts)
    counts += " " + name + "=" + std::to_string(count);
  std::fprintf(stderr, "Wrote %s [%zu frames:%s; %zu jumps; median %.1f ms/frame]\n",
               output.c_str(), poses.size(), counts.c_str(), jumps.size(),
               summary["median_frame_ms"].get<double>());
  return kExitOk;
}

} // namespace

int
main(int argc, char** argv)
{
  return pcl_rast_tools::runTool("pcl_rast_localize", [&] { return run(argc, argv); });
}
