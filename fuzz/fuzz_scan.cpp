/// \file fuzz_scan.cpp
/// \brief libFuzzer harness of the scan readers: the input is one scan file's bytes,
/// parsed as the extension FUZZ_EXT (".pcd", ".ply" or ".bin") says, with per-point
/// times. A ScanReadError is the expected answer to a bad file; anything else (a crash,
/// a sanitizer report, another exception, more than -rss_limit_mb) is a finding.

#include "scan_reading.h"

#include <cstddef>
#include <cstdint>
#include <pcl/io/sequence_reader.h>
#include <string>

extern "C" int
LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size)
{
  const std::string bytes(reinterpret_cast<const char*>(data), size);
  pcl::rast::io_detail::PointTimes times;
  try {
    std::size_t dropped = 0;
    pcl::rast::io_detail::scanFromBytes(
        "fuzz" FUZZ_EXT, FUZZ_EXT, bytes, &dropped, &times);
  } catch (const pcl::rast::ScanReadError&) {
  }
  return 0;
}
