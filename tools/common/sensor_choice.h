#pragma once
/// \file sensor_choice.h
/// \brief The tools' -sensor flag: a named preset, or "auto" (guessed from the first
/// readable selected scan).

#include "cli.h"

#include <pcl/slam/odometry.h>
#include <pcl/slam/sequence_reader.h>

#include <cstddef>
#include <map>
#include <string>
#include <vector>

namespace pcl_rast_tools {

/// \brief Choices of -sensor: "auto" and the preset names.
std::vector<std::string> sensorChoices();

/// \brief The preset for \a choice: the named one, or for "auto" the guess from the
/// first scan of \a reader that can be read (defaults when none can). \a reason says
/// how it was chosen (for the log and summary.json).
pcl::rast::SensorPreset resolveSensorPreset(const std::string& choice,
                                            const pcl::rast::SequenceReader& reader,
                                            std::string& reason);

/// \brief Choices of -deskew: "auto", "on", "off".
std::vector<std::string> deskewChoices();

/// \brief The odometry's motion compensation for -deskew \a choice. "auto": scans are
/// compensated with their own time field where they have one and used as they are
/// otherwise (KITTI's `.bin` scans are compensated already). "on": the time field, else
/// times from the azimuth. "off": never. \a reason says why (log, summary).
pcl::rast::DeskewMode resolveDeskewMode(const std::string& choice,
                                        const pcl::rast::SequenceReader& reader,
                                        std::string& reason);

/// \brief The time base of motion compensation: the sweep period is \a period_s when
/// given (> 0), else the median interval between consecutive scan files from
/// times.txt (the selected frames' interval divided by \a stride), else 0.1 s (10 Hz).
/// Without times.txt the timestamps are file indices: one index is one sweep period.
/// \a note says which (log, summary).
void configureDeskewTiming(const pcl::rast::SequenceReader& reader,
                           std::size_t stride,
                           double period_s,
                           pcl::rast::DeskewParams& params,
                           std::string& note);

/// \brief The tools' motion-compensation flags (doc/odometry.md, Motion compensation).
struct DeskewFlags
{
  std::string mode = "auto";  ///< -deskew auto|on|off
  double period_s = 0.0;      ///< -deskew-period (0: from times.txt, else 0.1 s)
  double reference_deg = 0.0; ///< -deskew-reference
  bool ccw = false;           ///< -deskew-ccw
};

/// \brief Declare -deskew, -deskew-reference, -deskew-period and -deskew-ccw.
void addDeskewFlags(ArgParser& parser, DeskewFlags& flags);

/// \brief Check the values before any work.
/// \throws std::invalid_argument naming the flag and the value.
void checkDeskewFlags(const DeskewFlags& flags);

/// \brief What the flags make of \a params for \a reader's scans (resolveDeskewMode,
/// configureDeskewTiming); \a reason and \a timing say why (log, summary).
void applyDeskewFlags(const DeskewFlags& flags,
                      const pcl::rast::SequenceReader& reader,
                      std::size_t stride,
                      pcl::rast::DeskewParams& params,
                      std::string& reason,
                      std::string& timing);

/// \brief Counts of a run's motion compensation, for summary.json.
struct DeskewTally
{
  std::map<std::string, std::size_t> frames_by_time_source;
  std::size_t second_passes = 0;
  std::size_t time_field_warnings = 0;

  void add(const pcl::rast::OdometryFrameResult& result);
};

} // namespace pcl_rast_tools
