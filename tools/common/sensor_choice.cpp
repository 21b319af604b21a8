/// \file sensor_choice.cpp
/// \brief -sensor auto|hdl64|vlp16|os1-64|os0-128.

#include "sensor_choice.h"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <stdexcept>

namespace pcl_rast_tools {

std::vector<std::string>
sensorChoices()
{
  return {"auto", "hdl64", "vlp16", "os1-64", "os0-128"};
}

pcl::rast::SensorPreset
resolveSensorPreset(const std::string& choice,
                    const pcl::rast::SequenceReader& reader,
                    std::string& reason)
{
  if (choice != "auto") {
    reason = "given";
    return pcl::rast::sensorPresetFromName(choice);
  }
  // The first readable scan among the first few (a corrupt first file is skipped later).
  for (std::size_t i = 0; i < std::min<std::size_t>(reader.size(), 5); ++i) {
    try {
      const pcl::rast::SensorGuess guess = pcl::rast::guessSensorPreset(*reader.read(i).cloud);
      reason = "guessed from scan " + std::to_string(i) + ": " + guess.reason;
      return guess.preset;
    } catch (const pcl::rast::ScanReadError&) {
      continue;
    }
  }
  reason = "no readable scan to guess from: defaults";
  return pcl::rast::SensorPreset::kHdl64;
}

std::vector<std::string>
deskewChoices()
{
  return {"auto", "on", "off"};
}

namespace {

/// \brief The odometry's motion compensation for -deskew \a choice. "auto": scans are
/// compensated with their own time field where they have one and used as they are
/// otherwise (KITTI's `.bin` scans are compensated already). "on": the time field, else
/// times from the azimuth. "off": never. \a reason says why (log, summary).
pcl::rast::DeskewMode
resolveDeskewMode(const std::string& choice,
                  const pcl::rast::SequenceReader& reader,
                  std::string& reason)
{
  if (choice == "off") {
    reason = "off: scans used as they are";
    return pcl::rast::DeskewMode::kOff;
  }
  if (choice == "on") {
    reason = "on: each scan's time field, else times from the azimuth";
    return pcl::rast::DeskewMode::kOn;
  }
  if (choice != "auto")
    throw std::invalid_argument("-deskew must be auto, on or off, got '" + choice + "'");
  // Scans without a time field are used as they are: KITTI's .bin scans are motion-
  // compensated already, and compensating them again made the real KITTI scans of
  // ../shared/data 1.5-2.6x less smooth (doc/odometry.md).
  const bool bin = reader.size() > 0 && std::filesystem::path(reader.path(0)).extension() == ".bin";
  reason = bin ? "auto: .bin scans carry no time field: used as they are (-deskew on: "
                 "times from the azimuth)"
               : "auto: scans with a time field are compensated, others used as they are";
  return pcl::rast::DeskewMode::kAuto;
}

/// \brief The time base of motion compensation: the sweep period is \a period_s when
/// given (> 0), else the median interval between consecutive scan files from
/// times.txt (the selected frames' interval divided by \a stride), else 0.1 s (10 Hz).
/// Without times.txt the timestamps are file indices: one index is one sweep period.
/// \a note says which (log, summary).
void
configureDeskewTiming(const pcl::rast::SequenceReader& reader,
                      std::size_t stride,
                      double period_s,
                      pcl::rast::DeskewParams& params,
                      std::string& note)
{
  const bool seconds = !reader.timesPath().empty();
  double period = period_s;
  if (period > 0.0) {
    note = "sweep period " + std::to_string(period) + " s (-deskew-period)";
  }
  else if (seconds && reader.size() >= 2) {
    std::vector<double> gaps;
    for (std::size_t i = 1; i < reader.size(); ++i)
      gaps.push_back((reader.timestamp(i) - reader.timestamp(i - 1)) / static_cast<double>(stride));
    std::nth_element(gaps.begin(), gaps.begin() + gaps.size() / 2, gaps.end());
    period = gaps[gaps.size() / 2];
    if (!(period > 0.005 && period < 1.0))
      period = 0.1; // times.txt does not look like sweeps of a spinning head
    note = "sweep period " + std::to_string(period) + " s (times.txt)";
  }
  else {
    period = 0.1;
    note = "sweep period 0.1 s (10 Hz: no times.txt; -deskew-period to change)";
  }
  params.sweep_period_s = period;
  params.seconds_per_timestamp = seconds ? 1.0 : period;
}

} // namespace

void
addDeskewFlags(ArgParser& parser, DeskewFlags& flags)
{
  parser.addChoice("deskew",
                   "motion compensation of raw sweeps (auto: with the scans' own time "
                   "field, others as they are; on: else times from the azimuth; "
                   "doc/odometry.md)",
                   &flags.mode, deskewChoices());
  parser.addDouble("deskew-reference",
                   "azimuth times: azimuth [deg] of the column firing at the frame time "
                   "(0: forward, KITTI; 180: behind)",
                   &flags.reference_deg);
  parser.addDouble("deskew-period", "sweep period [s] (0: from times.txt, else 0.1 s)",
                   &flags.period_s);
  parser.addSwitch("deskew-ccw",
                   "azimuth times: the head spins counter-clockwise seen from above", &flags.ccw);
}

void
checkDeskewFlags(const DeskewFlags& flags)
{
  if (!(flags.period_s >= 0.0 && flags.period_s <= 1.0))
    throw std::invalid_argument("-deskew-period must be in [0, 1] s, got " +
                                std::to_string(flags.period_s));
  if (!(std::abs(flags.reference_deg) <= 360.0))
    throw std::invalid_argument("-deskew-reference must be within +-360 deg, got " +
                                std::to_string(flags.reference_deg));
}

void
applyDeskewFlags(const DeskewFlags& flags,
                 const pcl::rast::SequenceReader& reader,
                 std::size_t stride,
                 pcl::rast::DeskewParams& params,
                 std::string& reason,
                 std::string& timing)
{
  params.mode = resolveDeskewMode(flags.mode, reader, reason);
  params.sweep.reference_azimuth_deg = flags.reference_deg;
  params.sweep.clockwise = !flags.ccw;
  configureDeskewTiming(reader, stride, flags.period_s, params, timing);
}

void
DeskewTally::add(const pcl::rast::OdometryFrameResult& result)
{
  if (!result.deskew_times.empty())
    ++frames_by_time_source[result.deskew_times];
  second_passes += result.deskew_second_pass ? 1 : 0;
}

} // namespace pcl_rast_tools
