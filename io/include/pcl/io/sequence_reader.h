#pragma once
/// \file sequence_reader.h
/// \brief Streaming reader for a folder of LiDAR scans (KITTI `.bin`, PCD, PLY):
/// lists the files once, then reads one scan at a time on demand.
/// \ingroup io

#include <cstddef>
#include <cstdint>
#include <memory>
#include <pcl/point_cloud.h>
#include <pcl/point_types.h>
#include <stdexcept>
#include <string>
#include <vector>

namespace pcl {
namespace rast {

/// \brief A single scan could not be read: the file is missing, unreadable, empty,
/// truncated or unparseable. The message names the file and what is wrong; the
/// caller may skip the frame and continue with the next one.
/// \ingroup io
class ScanReadError : public std::runtime_error
{
public:
  /// \brief Build the error.
  /// \param[in] path the scan file that failed
  /// \param[in] what_failed what is wrong with it (appended to the path in what())
  ScanReadError(const std::string& path, const std::string& what_failed)
      : std::runtime_error(path + ": " + what_failed), path_(path)
  {}

  /// \brief The scan file that failed.
  const std::string& path() const { return path_; }

private:
  std::string path_;
};

/// \brief Read one scan as x y z intensity, dropping points with a NaN/Inf coordinate.
/// Intensity is optional: without an intensity field, or where it is NaN/Inf, it is 0.
/// The format follows the extension (case-insensitive):
/// `.bin` (KITTI: float32 x y z intensity, little-endian, 16 bytes per point),
/// `.pcd` (ascii, binary, binary_compressed) or `.ply` (the vertex element; ascii or
/// binary). PCD/PLY fields of any numeric type are converted to float; an intensity
/// field may also be named `scalar_intensity`, `reflectance`, `remission` or `i`.
/// Nothing in a header is trusted: every declared count and size is checked against the
/// file, and against 1 GiB of point data, before anything is allocated; an ascii value
/// that is not a number of its declared type is an error, not a zero.
/// The result is unorganized (height 1) and dense. Per-point times are not read here:
/// SequenceReader::read() gives them (ScanFrame::point_times_s).
/// \param[in] path the scan file
/// \param[out] num_dropped_non_finite if not null, the number of dropped points
/// \return the cloud (never null)
/// \throws ScanReadError naming the file when it is missing, unreadable, empty,
/// a truncated `.bin` (size not a multiple of 16), has a header that lies or data that
/// does not parse, lacks x/y/z, or has an unsupported extension.
/// \ingroup io
pcl::PointCloud<pcl::PointXYZI>::Ptr
readScan(const std::string& path, std::size_t* num_dropped_non_finite = nullptr);

/// \brief Write a cloud as a KITTI `.bin` (float32 x y z intensity per point).
/// Atomic: writes a temporary file in the same folder, then renames it over \a path.
/// \param[in] path the output file
/// \param[in] cloud the points, written as they are (non-finite values included)
/// \throws std::runtime_error naming the file when it cannot be written.
/// \ingroup io
void writeKittiBin(const std::string& path, const pcl::PointCloud<pcl::PointXYZI>& cloud);

/// \brief Which frames of a sequence to read.
/// \ingroup io
struct SequenceReaderOptions
{
  /// First file index to read (0-based, in sorted order).
  std::size_t first = 0;
  /// Last file index to read, inclusive; -1 reads to the end.
  std::int64_t last = -1;
  /// Read every stride-th file from \a first (>= 1).
  std::size_t stride = 1;

  /// \brief Check the options without knowing the folder.
  /// \param[out] why if not null and the options are invalid, the reason
  /// \return true when stride >= 1, last >= -1 and (last == -1 or last >= first)
  bool isValid(std::string* why = nullptr) const;
};

/// \brief One scan of a sequence.
///
/// **Per-point time** (for motion compensation). A PCD or PLY scan may carry the time
/// of every point in a field; the first present of `time` (Velodyne / rslidar drivers,
/// seconds since the sweep start), `t` (Ouster, uint32 nanoseconds), `timestamp`
/// (Hesai and others, often absolute seconds as double), `time_stamp`, `offset_time`
/// (Livox, nanoseconds) and `ts` is used, whatever its numeric type (doubles are read
/// as double, so absolute times keep their precision). Only the kept points count
/// (a dropped point's time is ignored, so point_times_s stays aligned with `cloud`).
/// The unit follows from the span of the raw values: the first of s, ms, us, ns that
/// makes it lie in [0.005, 0.5] s (a 2-100 Hz sweep). The times are then centred on
/// the middle of the sweep and stored as float. They are rejected (point_times_s and
/// time_field empty, time_warning saying why; the cloud is read as usual) when a value
/// is NaN or infinite, when all are equal, when the span fits no unit, or when more than
/// 1 % of the steps between consecutive points go backwards (along each row of an
/// organized cloud, along the whole list otherwise): the cloud has lost its firing
/// order. KITTI `.bin` scans have no time field: no times, no warning.
/// \ingroup io
struct ScanFrame
{
  /// Position in the selected (first/last/stride) list: 0, 1, 2, ...
  std::size_t sequence_index = 0;
  /// Position of the file among all scans of the folder, in sorted order.
  std::size_t file_index = 0;
  /// Path of the scan file.
  std::string path;
  /// Timestamp in seconds from `times.txt`, else the file index.
  double timestamp_s = 0.0;
  /// The points (finite only); null until read.
  pcl::PointCloud<pcl::PointXYZI>::Ptr cloud;
  /// Number of points dropped because a value was NaN or Inf.
  std::size_t num_dropped_non_finite = 0;
  /// Per point of `cloud` (same order), its time in seconds relative to the middle
  /// of the sweep: t - (t_min + t_max) / 2, so values lie in [-span/2, span/2].
  /// Empty when the scan has no usable time field (see time_warning).
  std::vector<float> point_times_s;
  /// The field the times came from ("time", "t", ...), empty when none.
  std::string time_field;
  /// Why a time field that was present was not used (empty otherwise).
  std::string time_warning;
};

/// \brief Streams the scans of a folder in order, one frame in memory at a time.
///
/// The constructor only lists the folder: scans are read by next() or read().
/// Scans are `.bin`, `.pcd` or `.ply` files (one kind per folder). When the folder
/// holds no scans but has a `velodyne/`, `pcd/` or `ply/` subfolder with scans, that
/// subfolder is used. Files are ordered by the last run of digits in their name
/// (`000010.bin` after `000009.bin`, `251370668.pcd`), or lexicographically when a
/// name has no digits. An optional `times.txt` (one time in seconds per line) in the
/// scan folder or its parent gives the timestamps; otherwise timestamp = file index.
/// Each frame of a PCD or PLY scan with a time field also carries the time of every
/// point (ScanFrame::point_times_s, validated: see ScanFrame).
///
/// \code
/// pcl::rast::SequenceReader reader("data/kitti-raw-78");
/// pcl::rast::ScanFrame frame;
/// while (true) {
///   try {
///     if (!reader.next(frame))
///       break;
///   } catch (const pcl::rast::ScanReadError& e) {
///     std::cerr << "skipping " << e.what() << "\n";
///     continue;
///   }
///   process(frame);
/// }
/// \endcode
/// \ingroup io
class SequenceReader
{
public:
  using Ptr = std::shared_ptr<SequenceReader>;
  using ConstPtr = std::shared_ptr<const SequenceReader>;

  /// \brief List the scans of \a folder and select the frames to read.
  /// \param[in] folder the scan folder, or a folder with a velodyne/, pcd/ or ply/
  /// subfolder \param[in] options which frames to read \throws std::invalid_argument
  /// naming the folder when it does not exist, holds no scans, or mixes extensions
  /// (naming them); or when the options are invalid or \a first / \a last lie beyond the
  /// last file. \throws std::runtime_error naming `times.txt` when it is malformed or its
  /// number of lines differs from the number of scans (both counts given).
  explicit SequenceReader(const std::string& folder,
                          const SequenceReaderOptions& options = SequenceReaderOptions());

  /// \brief Number of selected frames.
  std::size_t size() const { return selected_.size(); }

  /// \brief Number of scan files in the folder, before selection.
  std::size_t numFiles() const { return files_.size(); }

  /// \brief The folder the scans were listed from (possibly a subfolder of the one
  /// given).
  const std::string& scanFolder() const { return scan_folder_; }

  /// \brief Path of the `times.txt` used, or empty when timestamps are file indices.
  const std::string& timesPath() const { return times_path_; }

  /// \brief Path of the \a i-th selected frame.
  /// \throws std::out_of_range when i >= size()
  const std::string& path(std::size_t i) const;

  /// \brief Timestamp in seconds of the \a i-th selected frame.
  /// \throws std::out_of_range when i >= size()
  double timestamp(std::size_t i) const;

  /// \brief Read the \a i-th selected frame (random access; does not move the cursor),
  /// with its per-point times when the scan has a usable time field. An unusable one
  /// is not an error: the frame says why in ScanFrame::time_warning.
  /// \throws std::out_of_range when i >= size()
  /// \throws ScanReadError when the scan cannot be read
  ScanFrame read(std::size_t i) const;

  /// \brief Read the frame at the cursor and advance the cursor.
  /// The cursor advances even when the scan cannot be read, so that after a
  /// ScanReadError the next call continues with the following frame.
  /// \param[out] frame the frame read; unchanged when false is returned or on error
  /// \return false when all frames have been read
  /// \throws ScanReadError when the scan cannot be read
  bool next(ScanFrame& frame);

  /// \brief Index (in the selected list) of the frame next() will read.
  std::size_t position() const { return cursor_; }

  /// \brief Move the cursor so that next() reads the \a i-th selected frame
  /// (i == size() means at the end).
  /// \throws std::out_of_range when i > size()
  void seek(std::size_t i);

private:
  std::string scan_folder_;
  std::string times_path_;
  std::vector<std::string> files_;        // all scans, sorted
  std::vector<double> file_timestamps_s_; // one per file
  std::vector<std::size_t> selected_;     // file indices of the selected frames
  std::size_t cursor_ = 0;
};

} // namespace rast
} // namespace pcl
