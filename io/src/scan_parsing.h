#pragma once
/// \file scan_parsing.h
/// \brief Internal to the io library: PCD and PLY files parsed from memory into a
/// pcl::PCLPointCloud2 without trusting their headers. Every count, size and offset a
/// header declares is checked, with overflow-safe arithmetic, against the bytes the file
/// holds and against kMaxScanDataBytes before anything is allocated: PCL's own readers
/// crash or allocate gigabytes on such headers (issue 12). Not installed.

#include <cstdint>
#include <pcl/PCLPointCloud2.h>
#include <string>
#include <string_view>

namespace pcl {
namespace rast {
namespace io_detail {

/// The most point data one scan file may declare, after decompression (1 GiB: a
/// 128-beam sweep of 2^21 points with 32 fields of 8 bytes is 0.5 GiB).
constexpr std::uint64_t kMaxScanDataBytes = std::uint64_t{1} << 30;

/// Parse a whole PCD file (ascii, binary or binary_compressed) held in \a bytes into
/// \a blob: fields, offsets, width, height and packed point data. With \a binary_data
/// not null, points stored as binary stay where they are: *binary_data views exactly
/// them in \a bytes, and blob.data stays empty (no copy of the scan; else an empty view).
/// \throws ScanReadError naming \a path and the first thing that is wrong
void parsePcd(const std::string& path,
              std::string_view bytes,
              pcl::PCLPointCloud2& blob,
              std::string_view* binary_data = nullptr);

/// Parse the vertex element of a whole PLY file (ascii, binary little or big endian)
/// held in \a bytes into \a blob. Elements after the vertices (faces) are not read.
/// \throws ScanReadError naming \a path and the first thing that is wrong
void parsePly(const std::string& path, std::string_view bytes, pcl::PCLPointCloud2& blob);

} // namespace io_detail
} // namespace rast
} // namespace pcl
