#pragma once
/// \file scan_reading.h
/// \brief Internal to the io library: one scan file read into a cloud (KITTI .bin, PCD,
/// PLY) with its per-point times, for readScan() and SequenceReader. Not installed.

#include <filesystem>
#include <pcl/point_cloud.h>
#include <pcl/point_types.h>
#include <string>
#include <string_view>
#include <vector>

namespace pcl {
namespace rast {
namespace io_detail {

/// The validated times of one scan, as ScanFrame carries them.
struct PointTimes
{
  std::vector<float> times_s;
  std::string field;
  std::string warning;
};

/// The extension of \a p in lower case (".pcd").
std::string lowerExtension(const std::filesystem::path& p);

/// Whether \a ext (lower case) is a scan file's: .bin, .pcd or .ply.
bool isScanExtension(const std::string& ext);

/// A scan file's \a bytes parsed as its extension \a ext (".bin", ".pcd", ".ply")
/// says; \a path only names it in errors. What readScanAndTimes() does after reading the
/// file, and what the fuzz harnesses (fuzz/) call.
/// \throws ScanReadError naming \a path
pcl::PointCloud<pcl::PointXYZI>::Ptr scanFromBytes(const std::string& path,
                                                   const std::string& ext,
                                                   std::string_view bytes,
                                                   std::size_t* num_dropped_non_finite,
                                                   PointTimes* times);

/// readScan(), and when \a times is not null the validated per-point times.
pcl::PointCloud<pcl::PointXYZI>::Ptr readScanAndTimes(const std::string& path,
                                                      std::size_t* num_dropped_non_finite,
                                                      PointTimes* times);

} // namespace io_detail
} // namespace rast
} // namespace pcl
