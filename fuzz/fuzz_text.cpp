/// \file fuzz_text.cpp
/// \brief libFuzzer harness of the text readers, one per build (FUZZ_READER): pose files
/// (KITTI or TUM, auto-detected), times.txt (through SequenceReader), calib.txt and g2o.
/// The input is written to a file, as the readers take paths. std::runtime_error and
/// std::invalid_argument are the readers' documented answers to a bad file; anything
/// else is a finding.

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <pcl/io/pose_io.h>
#include <pcl/io/sequence_reader.h>
#include <pcl/slam/g2o_io.h>
#include <stdexcept>
#include <string>
#include <unistd.h>

namespace {

namespace fs = std::filesystem;

/// A folder of this process for the input file (and, for times.txt, one scan).
const fs::path&
workDir()
{
  static const fs::path dir = [] {
    const fs::path shm("/dev/shm");
    const fs::path d = (fs::is_directory(shm) ? shm : fs::temp_directory_path()) /
                       ("pcl_rast_fuzz_" + std::to_string(::getpid()));
    fs::create_directories(d);
    // One valid 16-byte scan, so that SequenceReader reads the times.txt beside it.
    const float point[4] = {1.0f, 2.0f, 3.0f, 0.5f};
    std::ofstream(d / "000000.bin", std::ios::binary)
        .write(reinterpret_cast<const char*>(point), sizeof point);
    return d;
  }();
  return dir;
}

} // namespace

extern "C" int
LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size)
{
  const std::string reader = FUZZ_READER;
  const fs::path file = workDir() / (reader == "times" ? "times.txt" : "input.txt");
  std::ofstream(file, std::ios::binary | std::ios::trunc)
      .write(reinterpret_cast<const char*>(data), static_cast<std::streamsize>(size));
  try {
    if (reader == "poses")
      pcl::rast::readTrajectory(file.string());
    else if (reader == "calib")
      pcl::rast::readKittiCalibTr(file.string());
    else if (reader == "g2o")
      pcl::rast::readG2o(file.string());
    else
      pcl::rast::SequenceReader(workDir().string());
  } catch (const std::runtime_error&) {
  } catch (const std::invalid_argument&) {
  }
  return 0;
}
