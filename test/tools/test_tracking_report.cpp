// The tools' report of degraded tracking: the degraded frames of a run and their
// longest stretch in a row, in summary.json and as a warning.
#include "tracking_report.h"

#include <gtest/gtest.h>
#include <string>

// This file's names stay its own: a test program compiles several test files as
// one translation unit (test/CMakeLists.txt).
namespace test_tracking_report {

namespace {

using pcl::rast::OdometryFrameResult;
using pcl::rast::TrackingStatus;
using pcl_rast_tools::DegradedStretches;
using pcl_rast_tools::kDegradedStretchWarnFrames;

OdometryFrameResult
frame(std::size_t index, bool degraded, TrackingStatus status = TrackingStatus::kFeatures)
{
  OdometryFrameResult r;
  r.frame_index = index;
  r.degraded = degraded;
  r.status = status;
  return r;
}

TEST(DegradedStretches, CountsTheLongestStretchAndSkipsUnusableScans)
{
  DegradedStretches d;
  for (std::size_t i = 0; i < 5; ++i)
    d.add(frame(i, false));
  for (std::size_t i = 5; i < 10; ++i)
    d.add(frame(i, true, TrackingStatus::kDenseFallback));
  // An unusable scan in between: neither counted nor ending the stretch.
  d.add(frame(10, true, TrackingStatus::kSkipped));
  for (std::size_t i = 11; i < 14; ++i)
    d.add(frame(i, true, TrackingStatus::kConstantVelocity));
  d.add(frame(14, false));
  d.add(frame(15, true));
  d.add(frame(16, true));
  EXPECT_EQ(d.degradedFrames(), 10u);
  EXPECT_EQ(d.longestFrames(), 8u);
  EXPECT_EQ(d.longestFirst(), 5u);
  EXPECT_EQ(d.longestLast(), 13u);
  const nlohmann::json j = d.toJson();
  EXPECT_EQ(j["degraded_frames"].get<std::size_t>(), 10u);
  EXPECT_EQ(j["longest_degraded_stretch"]["frames"].get<std::size_t>(), 8u);
  EXPECT_EQ(j["longest_degraded_stretch"]["first_frame"].get<std::size_t>(), 5u);
  EXPECT_EQ(j["longest_degraded_stretch"]["last_frame"].get<std::size_t>(), 13u);
  EXPECT_TRUE(d.warning("pcl_rast_slam").empty()) << "8 frames are no stretch to warn of";
}

TEST(DegradedStretches, WarnsOfALongStretchOnly)
{
  DegradedStretches shorter, longer;
  shorter.add(frame(0, false));
  longer.add(frame(0, false));
  for (std::size_t i = 1; i < kDegradedStretchWarnFrames; ++i) {
    shorter.add(frame(i, true));
    longer.add(frame(i, true));
  }
  longer.add(frame(kDegradedStretchWarnFrames, true));
  EXPECT_TRUE(shorter.warning("pcl_rast_slam").empty());
  const std::string w = longer.warning("pcl_rast_slam");
  const std::string range = "frames 1-" + std::to_string(kDegradedStretchWarnFrames) +
                            " (" + std::to_string(kDegradedStretchWarnFrames) +
                            " in a row)";
  EXPECT_EQ(w.rfind("pcl_rast_slam: warning: ", 0), 0u) << w;
  EXPECT_NE(w.find(range), std::string::npos) << w;
}

TEST(DegradedStretches, ARunWithoutDegradedFramesHasNoStretch)
{
  DegradedStretches d;
  for (std::size_t i = 0; i < 3; ++i)
    d.add(frame(i, false));
  const nlohmann::json j = d.toJson();
  EXPECT_EQ(j["degraded_frames"].get<std::size_t>(), 0u);
  EXPECT_EQ(j["longest_degraded_stretch"]["frames"].get<std::size_t>(), 0u);
  EXPECT_TRUE(j["longest_degraded_stretch"]["first_frame"].is_null());
  EXPECT_TRUE(j["longest_degraded_stretch"]["last_frame"].is_null());
}

} // namespace

} // namespace test_tracking_report
