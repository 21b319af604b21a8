/// \file rast_eval.cpp
/// \brief pcl_rast_eval: accuracy of an estimated trajectory against ground truth
/// (ATE after alignment, KITTI devkit relative errors, per-frame RPE).
///
///   pcl_rast_eval EST GT [-json] [-align se3|sim3|none] [-associate auto|index|time]
///                        [-max_dt 0.01]
///
/// Each file is KITTI (12 numbers a line) or TUM (8), detected automatically.

#include "cli.h"
#include "output_set.h"

#include <chrono>
#include <filesystem>
#include <iostream>
#include <pcl/io/pose_io.h>
#include <pcl/evaluation/trajectory_evaluation.h>
#include <stdexcept>
#include <string>

namespace {

namespace rast = pcl::rast;
using pcl_rast_tools::ArgParser;

/// Reads a trajectory, printing `Loading x [done, 12 ms : 4541 poses]` on stderr.
rast::Trajectory
loadTrajectory(const std::string& path)
{
  std::cerr << "Loading " << path << " " << std::flush;
  const auto start = std::chrono::steady_clock::now();
  rast::Trajectory trajectory;
  try {
    trajectory = rast::readTrajectory(path);
  } catch (...) {
    std::cerr << "[failed]\n";
    throw;
  }
  const auto ms = std::chrono::duration_cast<std::chrono::milliseconds>(
                      std::chrono::steady_clock::now() - start)
                      .count();
  std::cerr << "[done, " << ms << " ms : " << trajectory.poses.size() << " poses, "
            << (trajectory.format == rast::PoseFormat::kKitti ? "KITTI" : "TUM") << "]\n";
  return trajectory;
}

int
run(int argc, char** argv)
{
  const rast::EvaluationParams defaults;
  std::string estimate_path, gt_path, check_dir;
  bool json = false;
  std::string align = rast::toString(defaults.alignment);
  std::string associate = "auto";
  double max_dt_s = defaults.max_time_difference_s;

  ArgParser parser("pcl_rast_eval",
                   "Evaluate an estimated trajectory against ground truth (KITTI or TUM "
                   "pose files, auto-detected): ATE after alignment, KITTI odometry "
                   "relative errors (devkit definition), per-frame RPE.");
  parser.addString("check-output",
                   "only check that the output folder DIR holds one complete set (every file "
                   "summary.json lists, with its size and CRC-32): exit 0 when it does, 2 when "
                   "not; EST and GT are then not given",
                   &check_dir);
  parser.addPositional("EST", "estimated poses (KITTI or TUM)", &estimate_path, true);
  parser.addPositional("GT", "ground-truth poses (KITTI or TUM)", &gt_path, true);
  parser.addSwitch("json", "print one JSON object instead of text", &json);
  parser.addChoice("align",
                   "alignment of the estimate before the ATE",
                   &align,
                   {"se3", "sim3", "none"});
  parser.addChoice(
      "associate",
      "pairing of poses; auto: by time when both files are TUM, else by index",
      &associate,
      {"auto", "index", "time"});
  parser.addDouble("max_dt", "largest timestamp difference of a pair [s]", &max_dt_s);
  if (!parser.parse(argc, argv))
    return pcl_rast_tools::kExitOk;
  if (!check_dir.empty()) {
    if (!estimate_path.empty() || !gt_path.empty())
      throw pcl_rast_tools::ArgumentError("-check-output takes no EST or GT");
    const pcl_rast_tools::OutputSetCheck set = pcl_rast_tools::checkOutputSet(check_dir);
    if (set.complete) {
      std::cout << check_dir << ": complete output set of run " << set.run_id << "\n";
      return pcl_rast_tools::kExitOk;
    }
    std::cout << check_dir << ": not a complete output set"
              << (set.run_id.empty() ? "" : " (summary.json of run " + set.run_id + ")") << "\n";
    for (const std::string& p : set.problems)
      std::cout << "  " << p << "\n";
    return pcl_rast_tools::kExitIoError;
  }
  if (estimate_path.empty() || gt_path.empty())
    throw pcl_rast_tools::ArgumentError("EST and GT are required (or -check-output DIR)");

  rast::EvaluationParams params;
  params.alignment = align == "none"   ? rast::TrajectoryAlignment::kNone
                     : align == "sim3" ? rast::TrajectoryAlignment::kSim3
                                       : rast::TrajectoryAlignment::kSE3;
  params.association = associate == "index"  ? rast::PoseAssociation::kByIndex
                       : associate == "time" ? rast::PoseAssociation::kByTimestamp
                                             : rast::PoseAssociation::kAuto;
  params.max_time_difference_s = max_dt_s;
  std::string why;
  if (!params.isValid(&why))
    throw std::invalid_argument(why);

  // An estimate from a pcl_rast output folder must belong to the set its summary.json
  // lists: a file left by another run (a mixed folder) would be evaluated silently.
  const std::filesystem::path estimate_dir =
      std::filesystem::path(estimate_path).parent_path().empty()
          ? std::filesystem::path(".")
          : std::filesystem::path(estimate_path).parent_path();
  const pcl_rast_tools::OutputSetCheck set = pcl_rast_tools::checkOutputSet(estimate_dir.string());
  if (set.has_manifest && !set.complete) {
    std::string problems;
    for (const std::string& p : set.problems)
      problems += "\n  " + p;
    throw std::runtime_error(estimate_path + " is in a mixed output set (run " + set.run_id +
                             " in summary.json):" + problems);
  }
  const rast::Trajectory estimate = loadTrajectory(estimate_path);
  const rast::Trajectory ground_truth = loadTrajectory(gt_path);

  rast::EvaluationResult result;
  try {
    result = rast::evaluateTrajectory(estimate, ground_truth, params);
  } catch (const std::invalid_argument& e) {
    // The files were read but cannot be compared (length mismatch, no association).
    std::cerr << "pcl_rast_eval: error: " << e.what() << "\n";
    return pcl_rast_tools::kExitAlgorithmFailure;
  }
  std::cout << (json ? rast::toJson(result) + "\n" : rast::toText(result)) << std::flush;
  return pcl_rast_tools::kExitOk;
}

} // namespace

int
main(int argc, char** argv)
{
  return pcl_rast_tools::runTool("pcl_rast_eval", [&] { return run(argc, argv); });
}
