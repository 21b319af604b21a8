/// \file sensor_choice.cpp
/// \brief -sensor auto|hdl64|vlp16|os1-64|os0-128.

#include "sensor_choice.h"

#include <algorithm>

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

} // namespace pcl_rast_tools
