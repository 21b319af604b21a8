#pragma once
/// \file tracking_report.h
/// \brief What a run's tracking was like, for summary.json and the closing lines:
/// its degraded frames and their longest stretch in a row.

#include <cstddef>
#include <nlohmann/json.hpp>
#include <pcl/slam/odometry.h>
#include <string>

namespace pcl_rast_tools {

/// \brief A stretch of at least this many degraded frames in a row is warned about.
/// Simulated drives the odometry tracks have stretches of at most 11 frames (HDL-64 and
/// VLP-16, realistic settings), 49 on KITTI 01 with an HDL-64; a VLP-16 that lost the
/// speed on a highway had 438 (doc/odometry.md, "Degraded stretches").
constexpr std::size_t kDegradedStretchWarnFrames = 100;

/// \brief The frames tracked degraded (OdometryFrameResult::degraded: a dense fallback,
/// constant velocity, a direction kept at the prediction, ...) and the longest stretch of
/// them in a row. Skipped scans are neither counted nor end a stretch.
class DegradedStretches
{
public:
  void add(const pcl::rast::OdometryFrameResult& result);

  std::size_t degradedFrames() const { return degraded_; }
  std::size_t longestFrames() const { return longest_; }
  std::size_t longestFirst() const { return longest_first_; } ///< its first frame index
  std::size_t longestLast() const { return longest_last_; }   ///< its last frame index

  /// \brief {"degraded_frames": N, "longest_degraded_stretch": {"frames", "first_frame",
  /// "last_frame"}} (the frame indices null when no frame was degraded).
  nlohmann::json toJson() const;
  /// \brief "TOOL: warning: ..." when the longest stretch has at least
  /// kDegradedStretchWarnFrames frames, else empty.
  std::string warning(const std::string& tool) const;

private:
  std::size_t degraded_ = 0;
  std::size_t longest_ = 0, longest_first_ = 0, longest_last_ = 0;
  std::size_t current_ = 0, current_first_ = 0;
};

/// \brief The elevation self-calibration's estimate for summary.json: {"enabled",
/// "updates", "bins_corrected", "rms_correction_deg", "max_abs_correction_deg",
/// "corrections": [[elevation_deg, correction_deg], ...]}.
nlohmann::json
elevationCalibrationJson(const pcl::rast::ElevationCalibrationState& state);

} // namespace pcl_rast_tools
