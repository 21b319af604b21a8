/// \file file_checksum.cpp
/// \brief CRC-32 of a file's bytes (Boost.CRC), read in 1 MiB blocks.

#include <pcl/rast/file_checksum.h>

#include <boost/crc.hpp>

#include <cstdio>
#include <fstream>
#include <stdexcept>
#include <vector>

namespace pcl {
namespace rast {

std::string
fileCrc32(const std::string& path)
{
  std::ifstream in(path, std::ios::binary);
  if (!in)
    throw std::runtime_error("cannot read " + path);
  boost::crc_32_type crc;
  std::vector<char> buffer(1 << 20);
  while (in) {
    in.read(buffer.data(), static_cast<std::streamsize>(buffer.size()));
    crc.process_bytes(buffer.data(), static_cast<std::size_t>(in.gcount()));
  }
  if (in.bad())
    throw std::runtime_error("cannot read " + path + ": read error");
  char hex[9];
  std::snprintf(hex, sizeof hex, "%08x", crc.checksum());
  return hex;
}

} // namespace rast
} // namespace pcl
