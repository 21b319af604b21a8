#include "tracking_report.h"

namespace pcl_rast_tools {

void
DegradedStretches::add(const pcl::rast::OdometryFrameResult& result)
{
  if (result.status == pcl::rast::TrackingStatus::kSkipped)
    return;
  if (!result.degraded) {
    current_ = 0;
    return;
  }
  ++degraded_;
  if (current_ == 0)
    current_first_ = result.frame_index;
  ++current_;
  if (current_ > longest_) {
    longest_ = current_;
    longest_first_ = current_first_;
    longest_last_ = result.frame_index;
  }
}

nlohmann::json
DegradedStretches::toJson() const
{
  const nlohmann::json none(nullptr);
  return {{"degraded_frames", degraded_},
          {"longest_degraded_stretch",
           {{"frames", longest_},
            {"first_frame", longest_ > 0 ? nlohmann::json(longest_first_) : none},
            {"last_frame", longest_ > 0 ? nlohmann::json(longest_last_) : none}}}};
}

std::string
DegradedStretches::warning(const std::string& tool) const
{
  if (longest_ < kDegradedStretchWarnFrames)
    return {};
  return tool + ": warning: frames " + std::to_string(longest_first_) + "-" +
         std::to_string(longest_last_) + " (" + std::to_string(longest_) +
         " in a row) were tracked degraded: the scans there hardly constrained the "
         "motion (an open road or field, a tunnel?) and the poses rest on the "
         "constant-velocity prior; they may be far off (doc/odometry.md, \"Degraded "
         "stretches\")";
}

nlohmann::json
elevationCalibrationJson(const pcl::rast::ElevationCalibrationState& state)
{
  nlohmann::json corrections = nlohmann::json::array();
  for (const auto& [elevation_deg, correction_deg] : state.corrections)
    corrections.push_back({elevation_deg, correction_deg});
  return {{"enabled", state.enabled},
          {"updates", state.updates},
          {"bins_corrected", state.bins_corrected},
          {"rms_correction_deg", state.rms_correction_deg},
          {"max_abs_correction_deg", state.max_abs_correction_deg},
          {"corrections", corrections}};
}

} // namespace pcl_rast_tools
