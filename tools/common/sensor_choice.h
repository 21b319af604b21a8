#pragma once
/// \file sensor_choice.h
/// \brief The tools' -sensor flag: a named preset, or "auto" (guessed from the first
/// readable selected scan).

#include "cli.h"

#include <pcl/slam/odometry.h>
#include <pcl/io/sequence_reader.h>

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

/// \brief What the flags make of \a params for \a reader's scans: the mode (a time
/// field, the azimuth or none) and the time base; \a reason and \a timing say why.
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
