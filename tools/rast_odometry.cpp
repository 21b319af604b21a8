/// \file rast_odometry.cpp
/// \brief pcl_rast_odometry: rasterized-ORB LiDAR odometry over a folder of scans.
///
///   pcl_rast_odometry -input DIR -output DIR [-first N] [-last N] [-stride K]
///                     [-sensor auto|hdl64|vlp16|os1-64|os0-128] [-deskew auto|on|off]
///                     [options]
///
/// Writes DIR/poses_kitti.txt (one line per selected input frame, LiDAR frame, first
/// pose the identity), DIR/poses_tum.txt (times.txt timestamps when present, else the
/// file index), DIR/timing.csv (one row per frame) and DIR/summary.json (counts,
/// median time, `error`), each atomically. Unreadable frames get the constant-velocity
/// pose and are reported on stderr. An error after frames were processed ends the run
/// but not its results: the frames before it are written, summary.json names the error.
/// Exit codes: 0 ok, 1 bad arguments, 2 I/O error, 3 no frame could be tracked or the
/// run ended by an error.

#include "cli.h"
#include "output_set.h"
#include "prefetcher.h"
#include "sensor_choice.h"
#include "stop_signals.h"
#include "tracking_report.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <map>
#include <nlohmann/json.hpp>
#include <optional>
#include <pcl/io/pose_io.h>
#include <pcl/io/sequence_reader.h>
#include <pcl/slam/odometry.h>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

namespace {

std::string
fmt(double v, int precision = 3)
{
  char buf[64];
  std::snprintf(buf, sizeof(buf), "%.*f", precision, v);
  return buf;
}

int
run(int argc, char** argv)
{
  using namespace pcl_rast_tools;
  namespace rast = pcl::rast;
  rast::OdometryParams params;
  std::string input, output, sensor = "auto";
  DeskewFlags deskew;
  int first = 0, last = -1, stride = 1;
  bool no_refine = false, no_lookahead = false, no_loose_rematch = false,
       level = params.ground.level_cloud;
  bool no_vehicle_prior = false, quiet = false, no_elevation_calibration = false;
  int max_features = params.orb.max_features;
  double min_range = params.min_range_m, max_range = params.max_range_m;
  double ratio = params.registration.matching.ratio;

  ArgParser args("pcl_rast_odometry",
                 "Rasterized-ORB LiDAR odometry (ground removal, top-down raster, ORB,\n"
                 "RANSAC against the last key-frame, point-to-plane refinement against a\n"
                 "local map). Writes OUTPUT/poses_kitti.txt, OUTPUT/poses_tum.txt and\n"
                 "OUTPUT/timing.csv. Exit codes: 0 ok, 1 bad arguments, 2 I/O, 3 nothing tracked.");
  args.addString("input", "scan folder (.bin/.pcd/.ply, or with velodyne/ or pcd/)", &input, true);
  args.addString("output", "output folder (created)", &output, true);
  args.addInt("first", "first scan (0-based, sorted order)", &first);
  args.addInt("last", "last scan, inclusive (-1: the last one)", &last);
  args.addInt("stride", "use every K-th scan (5 turns 10 Hz into 2 Hz)", &stride);
  addDeskewFlags(args, deskew);
  args.addChoice("sensor", "parameter preset (auto: guessed from the first scan)", &sensor,
                 sensorChoices());
  args.addSwitch("level", "level the non-ground cloud by the ground normal (tilted sensors)",
                 &level);
  args.addSwitch("no-refine", "feature estimate only (no dense refinement)", &no_refine);
  args.addSwitch("no-loose-rematch",
                 "weak features: no second, nearest-neighbour matching of the key-frame",
                 &no_loose_rematch);
  args.addInt("max-features", "ORB features per scan", &max_features);
  args.addDouble("ratio", "Lowe's ratio of the Hamming matching", &ratio);
  args.addDouble("min-range", "drop points closer than this [m]", &min_range);
  args.addDouble("max-range", "drop points farther than this [m]", &max_range);
  args.addInt("keyframe-min-frames", "paper: frames since the last key-frame, at least",
              &params.keyframe_min_frames);
  args.addInt("keyframe-max-common", "paper: inliers in common with it, at most",
              &params.keyframe_max_common_points);
  args.addInt("keyframe-min-inliers", "force a key-frame below this many inliers",
              &params.keyframe_min_inliers);
  args.addDouble("keyframe-max-distance", "force a key-frame beyond this distance [m]",
                 &params.keyframe_max_distance_m);
  args.addDouble("keyframe-voxel", "voxel leaf of a key-frame's cloud [m]",
                 &params.keyframe_voxel_size_m);
  args.addInt("min-feature-inliers", "feature-consistency check: fewer inliers -> fallback",
              &params.min_feature_inliers);
  args.addInt("dense-iterations", "Gauss-Newton iterations of the refinement",
              &params.dense.max_iterations);
  args.addInt("dense-points", "source points of the refinement, at most",
              &params.dense.max_source_points);
  args.addInt("young-map-scans",
              "every tracked scan joins the local map while it holds fewer (1: key-frames only)",
              &params.dense.young_map_scans);
  args.addDouble("map-nearer",
                 "a full local-map voxel takes a point seen from less than this fraction "
                 "of its farthest point's range in that point's place (0: the first "
                 "points stay, as in KISS-ICP; doc/odometry.md)",
                 &params.dense.map_nearer_ratio);
  args.addDouble("degeneracy-support",
                 "tunnels, corridors: a direction needs this many points on surfaces "
                 "facing along it, else the prior keeps it (0: off; doc/odometry.md)",
                 &params.dense.degeneracy_min_support);
  args.addSwitch("no-vehicle-prior",
                 "the prior gates stay fixed and the dense step has no pull to the prior "
                 "(the odometry before session 18; doc/odometry.md)",
                 &no_vehicle_prior);
  args.addSwitch("no-elevation-calibration",
                 "the points stay at the elevation the sensor gave them (no "
                 "self-calibration of the beams' elevation; doc/odometry.md)",
                 &no_elevation_calibration);
  args.addSwitch(
      "no-lookahead",
      "compute each scan's ground, raster and ORB on the main thread after the "
      "scan before, not on a second thread while it is tracked",
      &no_lookahead);
  args.addDouble(
      "visibility-margin",
      "moving objects: map voxels the scan sees through, and scan points the "
      "key-frame saw through, by more than this are left out of the dense step "
      "(m, e.g. 1; 0: off, the default; doc/odometry.md)",
      &params.visibility_margin_m);
  args.addDouble(
      "weak-feature-share",
      "weak features (fewer than 40 inliers) near the prior move it this share of "
      "the way to them where the scan does not constrain the motion (0: the "
      "prior alone; the vlp16 preset 0.25; doc/odometry.md)",
      &params.weak_feature_share);
  args.addInt("failed-features-skip",
              "scans wanting no features (-features-every): for this many scans after "
              "features failed, a dense step the scan constrains only weakly is taken, "
              "kept near the prior there (0: off; doc/odometry.md)",
              &params.failed_features_skip_frames);
  int features_every = 1;
  args.addInt("features-every",
              "want the raster features of every N-th scan only; the dense step alone "
              "tracks the scans between where it can (0: of none; 1: of all, the "
              "default; what pcl_rast_localize does off the map; doc/odometry.md)",
              &features_every);
  args.addSwitch("quiet", "no progress bar", &quiet);
  if (!args.parse(argc, argv))
    return kExitOk;
  installStopSignals(); // a stop before the first frame ends the run there

  // Validate everything before any work.
  if (first < 0 || stride < 1 || last < -1 || (last >= 0 && last < first))
    throw std::invalid_argument("need -first >= 0, -stride >= 1, -last -1 or >= -first");
  if (features_every < 0)
    throw std::invalid_argument("-features-every " + std::to_string(features_every) +
                                " (>= 0)");
  checkDeskewFlags(deskew);
  // The flags given win over the sensor preset, which is known only once the input is
  // listed; they are checked before any work all the same.
  const rast::OdometryParams cli_params = params;
  const auto applyFlags = [&](rast::OdometryParams& p) {
    if (args.given("keyframe-voxel"))
      p.keyframe_voxel_size_m = cli_params.keyframe_voxel_size_m;
    if (args.given("keyframe-max-distance"))
      p.keyframe_max_distance_m = cli_params.keyframe_max_distance_m;
    if (args.given("keyframe-min-inliers"))
      p.keyframe_min_inliers = cli_params.keyframe_min_inliers;
    if (args.given("min-feature-inliers"))
      p.min_feature_inliers = cli_params.min_feature_inliers;
    if (args.given("level"))
      p.ground.level_cloud = level;
    if (args.given("dense-iterations"))
      p.dense.max_iterations = cli_params.dense.max_iterations;
    if (args.given("dense-points"))
      p.dense.max_source_points = cli_params.dense.max_source_points;
    if (args.given("young-map-scans"))
      p.dense.young_map_scans = cli_params.dense.young_map_scans;
    if (args.given("map-nearer"))
      p.dense.map_nearer_ratio = cli_params.dense.map_nearer_ratio;
    if (args.given("degeneracy-support"))
      p.dense.degeneracy_min_support = cli_params.dense.degeneracy_min_support;
    if (args.given("visibility-margin"))
      p.visibility_margin_m = cli_params.visibility_margin_m;
    if (args.given("weak-feature-share"))
      p.weak_feature_share = cli_params.weak_feature_share;
    if (args.given("failed-features-skip"))
      p.failed_features_skip_frames = cli_params.failed_features_skip_frames;
    p.registration.refine = !no_refine;
    if (no_loose_rematch)
      p.loose_rematch = false;
    if (no_vehicle_prior)
      rast::disableVehiclePrior(p);
    if (no_elevation_calibration)
      p.elevation_calibration.enabled = false;
    p.orb.max_features = max_features;
    p.registration.matching.ratio = ratio;
    p.min_range_m = min_range;
    p.max_range_m = max_range;
    std::string why;
    if (!p.isValid(&why))
      throw std::invalid_argument("invalid parameters: " + why);
  };
  applyFlags(params);

  rast::SequenceReaderOptions options;
  options.first = static_cast<std::size_t>(first);
  options.last = last;
  options.stride = static_cast<std::size_t>(stride);
  rast::SequenceReader reader(input, options);
  checkOutputIsNotInput(output, reader.scanFolder());
  // Staged, then published together (output_set.h): a failure or a second signal
  // leaves the previous set as it was.
  OutputSet outputs(output, "pcl_rast_odometry");
  std::fprintf(stderr, "Listed %s [%zu of %zu scans%s]\n", reader.scanFolder().c_str(),
               reader.size(), reader.numFiles(),
               reader.timesPath().empty() ? "" : ", times.txt");

  std::string sensor_reason;
  const rast::SensorPreset preset = resolveSensorPreset(sensor, reader, sensor_reason);
  std::fprintf(stderr, "Sensor preset %s (%s)\n", rast::toString(preset), sensor_reason.c_str());
  params = cli_params;
  rast::applySensorPreset(preset, params);
  std::string deskew_reason, deskew_timing;
  applyDeskewFlags(deskew, reader, static_cast<std::size_t>(stride), params.deskew, deskew_reason,
                   deskew_timing);
  std::fprintf(stderr, "Deskew %s (%s; %s)\n", rast::toString(params.deskew.mode),
               deskew_reason.c_str(), deskew_timing.c_str());
  applyFlags(params);

  const InjectedFault fault = injectedFault({"tracking"});
  rast::Odometry odometry(params);
  rast::PoseVector poses;
  std::vector<double> times;
  std::ostringstream csv;
  // clang-format off
  csv << "frame,status,ground_ms,raster_ms,orb_ms,match_ms,refine_ms,keyframe_ms,total_ms,"
         "num_features,num_inliers,keyframe,degraded,deskew_ms,deskew,degenerate_directions,"
         "extracted_ahead\n";
  // clang-format on
  std::map<std::string, int> status_counts;
  std::vector<double> totals;
  std::size_t num_tracked = 0, frames_without_features = 0;
  std::size_t frames_degenerate = 0;
  DeskewTally tally;
  DegradedStretches degraded;
  std::optional<ProgressBar> bar;
  if (!quiet)
    bar.emplace("Odometry", reader.size());
  std::exception_ptr run_error; // ends the run; the frames before it are written
  nlohmann::json skipped = nlohmann::json::array(); // scans that could not be read
  std::size_t stopped_at = reader.size();
  // Scans are read a few ahead on a thread of their own.
  Prefetcher prefetcher(reader, 4);
  for (std::size_t i = 0; i < reader.size() && !run_error; ++i) {
    if (stopRequested()) {
      stopped_at = i;
      reportStop("pcl_rast_odometry", i);
      break;
    }
    rast::OdometryFrameResult r;
    ReadItem item;
    try {
      fault.check("tracking", i);
      if (!prefetcher.next(item)) { // only after a stop signal
        stopped_at = i;
        reportStop("pcl_rast_odometry", i);
        break;
      }
      if (item.ok) {
        const rast::ScanFrame& frame = item.frame;
        if (!frame.time_warning.empty() && tally.time_field_warnings++ == 0)
          std::fprintf(stderr,
                       "\npcl_rast_odometry: warning: %s: %s (reported once per run)\n",
                       frame.path.c_str(),
                       frame.time_warning.c_str());
        // The next scan's ground, raster and ORB on a second thread meanwhile.
        const ReadItem* next = no_lookahead ? nullptr : prefetcher.peek();
        odometry.setFeaturesWanted(features_every == 1 ||
                                   (features_every > 1 && i % features_every == 0));
        r = next && next->ok
                ? odometry.processFrame(frame.cloud,
                                        frame.timestamp_s,
                                        i,
                                        frame.point_times_s,
                                        {next->frame.cloud,
                                         next->frame.timestamp_s,
                                         i + 1,
                                         next->frame.point_times_s})
                : odometry.processFrame(
                      frame.cloud, frame.timestamp_s, i, frame.point_times_s);
      } else {
        std::fprintf(stderr, "\nframe %zu: skipped: %s\n", i, item.error.c_str());
        r = odometry.skipFrame(item.timestamp_s, i, item.error);
        skipped.push_back({{"frame", i}, {"path", item.path}, {"reason", item.error}});
      }
    } catch (...) {
      run_error = std::current_exception();
      continue;
    }
    if (r.status != rast::TrackingStatus::kSkipped)
      ++num_tracked;
    frames_without_features += r.features_skipped ? 1 : 0;
    if (r.degraded && r.status != rast::TrackingStatus::kSkipped)
      std::fprintf(stderr, "\nframe %zu: %s: %s\n", i, rast::toString(r.status),
                   r.message.c_str());
    poses.push_back(r.T_world_lidar);
    times.push_back(r.timestamp_s);
    ++status_counts[rast::toString(r.status)];
    totals.push_back(r.timings.total_ms);
    const auto& t = r.timings;
    csv << i << ',' << rast::toString(r.status) << ',' << fmt(t.ground_ms) << ','
        << fmt(t.raster_ms) << ',' << fmt(t.orb_ms) << ',' << fmt(t.match_ms) << ','
        << fmt(t.refine_ms) << ',' << fmt(t.keyframe_ms) << ',' << fmt(t.total_ms) << ','
        << r.num_features << ',' << r.num_inliers << ',' << (r.keyframe ? 1 : 0) << ','
        << (r.degraded ? 1 : 0) << ',' << fmt(t.deskew_ms) << ','
        << (r.deskew_times.empty() ? "none" : r.deskew_times)
        << (r.deskew_second_pass ? "+2" : "") << ',' << r.dense_degenerate_directions
        << ',' << (r.extracted_ahead ? 1 : 0) << '\n';
    tally.add(r);
    degraded.add(r);
    frames_degenerate += r.dense_degenerate_directions > 0 ? 1 : 0;
    if (bar)
      bar->update(i + 1);
  }
  if (bar)
    bar->finish();
  const std::string error_message = run_error ? exceptionMessage(run_error) : "";
  if (run_error) {
    if (poses.empty())
      std::rethrow_exception(run_error); // nothing was processed: nothing to save
    std::fprintf(stderr, "\npcl_rast_odometry: error at frame %zu: %s\n", poses.size(),
                 error_message.c_str());
  }
  if (stopped_at == 0) {
    std::fprintf(stderr, "pcl_rast_odometry: %s before the first scan; no output was written\n",
                 stopSignalName());
    return 128 + stopSignal();
  }
  if (num_tracked == 0 && !run_error) {
    // Identity poses for scans that were never read would pass for a result.
    std::fprintf(stderr,
                 "pcl_rast_odometry: error: none of the %zu scans could be used (%zu "
                 "unreadable%s%s); no output was written\n",
                 poses.size(), skipped.size(), skipped.empty() ? "" : ", the first: ",
                 skipped.empty() ? "" : skipped.front()["reason"].get<std::string>().c_str());
    return kExitAlgorithmFailure;
  }

  rast::writeKittiPoses(outputs.path("poses_kitti.txt"), poses);
  rast::writeTumPoses(outputs.path("poses_tum.txt"), poses, times);
  rast::writeFileAtomically(outputs.path("timing.csv"), csv.str());

  std::sort(totals.begin(), totals.end());
  const double median = totals.empty() ? 0.0 : totals[totals.size() / 2];
  nlohmann::json summary;
  summary["input"] = reader.scanFolder();
  summary["frames_selected"] = reader.size();
  summary["frames"] = poses.size();
  summary["frames_tracked"] = num_tracked;
  summary["skipped_frames"] = skipped;
  summary["interrupted"] = stopped_at < reader.size();
  summary["stop_signal"] = stopRequested() ? nlohmann::json(stopSignalName()) : nlohmann::json(nullptr);
  summary["keyframes"] = odometry.numKeyFrames();
  summary["features"] = {{"every", features_every},
                         {"frames_without", frames_without_features}};
  summary["tracking_status"] = status_counts;
  summary["median_frame_ms"] = median;
  summary["frames_with_degenerate_directions"] = frames_degenerate;
  summary["sensor"] = rast::toString(preset);
  summary["elevation_calibration"] =
      pcl_rast_tools::elevationCalibrationJson(odometry.elevationCalibration());
  summary["deskew"] = {{"mode", rast::toString(params.deskew.mode)},
                       {"reason", deskew_reason},
                       {"timing", deskew_timing},
                       {"frames_by_time_source", tally.frames_by_time_source},
                       {"second_passes", tally.second_passes},
                       {"time_field_warnings", tally.time_field_warnings}};
  summary["params"] = {
      {"visibility_margin_m", params.visibility_margin_m},
      {"weak_feature_share", params.weak_feature_share},
      {"failed_features_skip_frames", params.failed_features_skip_frames},
      {"lookahead", !no_lookahead}};
  summary.update(degraded.toJson());
  summary["max_rotation_error"] = rast::maxRotationError(poses);
  summary["error"] = run_error ? nlohmann::json(error_message) : nlohmann::json(nullptr);
  outputs.publish(summary); // summary.json last: it lists the files of this run
  std::string counts;
  for (const auto& [name, count] : status_counts)
    counts += " " + name + "=" + std::to_string(count);
  std::fprintf(stderr, "Wrote %s [done : %zu frames, %zu key-frames, median %.1f ms/frame,%s]\n",
               output.c_str(), poses.size(), odometry.numKeyFrames(), median, counts.c_str());
  if (const std::string warning = degraded.warning("pcl_rast_odometry"); !warning.empty())
    std::fprintf(stderr, "%s\n", warning.c_str());
  if (run_error) {
    std::fprintf(stderr, "pcl_rast_odometry: error: %s (the frames before it were written)\n",
                 error_message.c_str());
    return kExitAlgorithmFailure;
  }
  if (num_tracked == 0) {
    std::fprintf(stderr, "pcl_rast_odometry: error: no frame could be tracked\n");
    return kExitAlgorithmFailure;
  }
  return kExitOk;
}

} // namespace

int
main(int argc, char** argv)
{
  return pcl_rast_tools::runTool("pcl_rast_odometry", [&] { return run(argc, argv); });
}
