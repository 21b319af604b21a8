#pragma once
/// \file file_checksum.h
/// \brief CRC-32 of a file, the checksum output sets and saved sessions list their files
/// with.
/// \ingroup common

#include <string>

namespace pcl {
namespace rast {

/// \brief CRC-32 (IEEE, as zlib computes it) of the bytes of \a path, as 8 lowercase hex
/// digits. \throws std::runtime_error naming the file when it cannot be read.
std::string
fileCrc32(const std::string& path);

} // namespace rast
} // namespace pcl
