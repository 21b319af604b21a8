/// \file sequence_reader.cpp
/// \brief Streaming scan-sequence reader: folder listing, ordering, times.txt; the
/// per-format scan readers are in scan_reading.cpp.

#include "scan_reading.h"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <map>
#include <pcl/io/pose_io.h>
#include <pcl/io/sequence_reader.h>
#include <sstream>
#include <system_error>
#include <utility>

namespace fs = std::filesystem;

namespace pcl {
namespace rast {
namespace {

using io_detail::isScanExtension;
using io_detail::lowerExtension;
using io_detail::PointTimes;
using io_detail::readScanAndTimes;

/// Parse the digits of the last run of digits in \a stem; empty when there is none.
std::string
lastDigitRun(const std::string& stem)
{
  std::size_t end = stem.size();
  while (end > 0 && !std::isdigit(static_cast<unsigned char>(stem[end - 1])))
    --end;
  std::size_t begin = end;
  while (begin > 0 && std::isdigit(static_cast<unsigned char>(stem[begin - 1])))
    --begin;
  std::string digits = stem.substr(begin, end - begin);
  // Strip leading zeros so that numbers compare by (length, digits) without overflow.
  const std::size_t nz = digits.find_first_not_of('0');
  return nz == std::string::npos ? (digits.empty() ? digits : "0") : digits.substr(nz);
}

/// Sort by the numeric index in the file name when every name has one, else by name.
void
sortScans(std::vector<fs::path>& scans)
{
  std::vector<std::string> keys;
  keys.reserve(scans.size());
  bool all_numeric = true;
  for (const fs::path& p : scans) {
    keys.push_back(lastDigitRun(p.stem().string()));
    all_numeric = all_numeric && !keys.back().empty();
  }
  std::vector<std::size_t> order(scans.size());
  for (std::size_t i = 0; i < order.size(); ++i)
    order[i] = i;
  std::sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) {
    if (all_numeric) {
      const std::string& ka = keys[a];
      const std::string& kb = keys[b];
      if (ka.size() != kb.size())
        return ka.size() < kb.size();
      if (ka != kb)
        return ka < kb;
    }
    return scans[a].filename().string() < scans[b].filename().string();
  });
  std::vector<fs::path> sorted;
  sorted.reserve(scans.size());
  for (std::size_t i : order)
    sorted.push_back(scans[i]);
  scans.swap(sorted);
}

/// Scan files directly in \a folder, and the distinct extensions found.
std::vector<fs::path>
listScans(const fs::path& folder, std::map<std::string, std::string>& ext_examples)
{
  std::vector<fs::path> scans;
  std::error_code ec;
  for (fs::directory_iterator it(folder, ec), end; !ec && it != end; it.increment(ec)) {
    const fs::path& p = it->path();
    const std::string ext = lowerExtension(p);
    if (!isScanExtension(ext) || p.filename().string().front() == '.')
      continue;
    scans.push_back(p);
    ext_examples.emplace(ext, p.filename().string());
  }
  if (ec)
    throw std::runtime_error("SequenceReader: cannot list folder '" + folder.string() +
                             "': " + ec.message());
  return scans;
}

/// Read times.txt: one number per non-empty line.
std::vector<double>
readTimes(const std::string& path)
{
  std::ifstream in(path);
  if (!in)
    throw std::runtime_error("SequenceReader: cannot open '" + path + "'");
  std::vector<double> times;
  std::string line;
  std::size_t line_no = 0;
  while (readBoundedLine(in, line, path, line_no + 1)) {
    ++line_no;
    if (line.find_first_not_of(" \t\r") == std::string::npos)
      continue;
    std::istringstream ss(line);
    double t = 0.0;
    std::string rest;
    if (!(ss >> t) || (ss >> rest) || !std::isfinite(t))
      throw std::runtime_error("SequenceReader: '" + path + "' line " +
                               std::to_string(line_no) +
                               ": expected one time in seconds, got '" + line + "'");
    times.push_back(t);
  }
  return times;
}

} // namespace

bool
SequenceReaderOptions::isValid(std::string* why) const
{
  auto fail = [why](const std::string& reason) {
    if (why)
      *why = reason;
    return false;
  };
  if (stride < 1)
    return fail("stride must be >= 1, got 0");
  if (last < -1)
    return fail("last must be >= -1 (-1 = to the end), got " + std::to_string(last));
  if (last >= 0 && static_cast<std::uint64_t>(last) < first)
    return fail("last (" + std::to_string(last) + ") must be >= first (" +
                std::to_string(first) + ")");
  return true;
}

SequenceReader::SequenceReader(const std::string& folder,
                               const SequenceReaderOptions& options)
{
  std::string why;
  if (!options.isValid(&why))
    throw std::invalid_argument("SequenceReader: invalid options: " + why);

  std::error_code ec;
  if (!fs::exists(folder, ec))
    throw std::invalid_argument("SequenceReader: folder '" + folder + "' does not exist");
  if (!fs::is_directory(folder, ec))
    throw std::invalid_argument("SequenceReader: '" + folder + "' is not a folder");

  // The folder itself, else the one of velodyne/, pcd/, ply/ that holds scans.
  fs::path scan_folder = folder;
  std::map<std::string, std::string> ext_examples;
  std::vector<fs::path> scans = listScans(scan_folder, ext_examples);
  if (scans.empty()) {
    for (const char* sub : {"velodyne", "pcd", "ply"}) {
      const fs::path candidate = fs::path(folder) / sub;
      if (!fs::is_directory(candidate, ec))
        continue;
      std::map<std::string, std::string> sub_examples;
      std::vector<fs::path> sub_scans = listScans(candidate, sub_examples);
      if (sub_scans.empty())
        continue;
      if (!scans.empty())
        throw std::invalid_argument("SequenceReader: folder '" + folder +
                                    "' has scans in both '" + scan_folder.string() +
                                    "' and '" + candidate.string() +
                                    "': pass one of them");
      scan_folder = candidate;
      scans.swap(sub_scans);
      ext_examples.swap(sub_examples);
    }
  }
  if (scans.empty())
    throw std::invalid_argument(
        "SequenceReader: no scans (.bin, .pcd, .ply) in folder '" + folder +
        "' nor in its velodyne/, pcd/ or ply/ subfolder");
  if (ext_examples.size() > 1) {
    std::string kinds;
    for (const auto& [ext, example] : ext_examples)
      kinds += (kinds.empty() ? "" : " and ") + ext + " (e.g. " + example + ")";
    throw std::invalid_argument("SequenceReader: folder '" + scan_folder.string() +
                                "' mixes scan extensions: " + kinds);
  }
  sortScans(scans);
  scan_folder_ = scan_folder.string();
  files_.reserve(scans.size());
  for (const fs::path& p : scans)
    files_.push_back(p.string());

  // Timestamps: times.txt in the scan folder or its parent, else the file index.
  // The parent is taken from the absolute, normalized path: "pcd/" or "." have one too.
  fs::path abs_folder = fs::absolute(scan_folder, ec).lexically_normal();
  if (!abs_folder.has_filename())
    abs_folder = abs_folder.parent_path();
  for (const fs::path& candidate :
       {scan_folder / "times.txt", abs_folder.parent_path() / "times.txt"}) {
    if (fs::is_regular_file(candidate, ec)) {
      times_path_ = candidate.string();
      break;
    }
  }
  if (!times_path_.empty()) {
    file_timestamps_s_ = readTimes(times_path_);
    if (file_timestamps_s_.size() != files_.size())
      throw std::runtime_error("SequenceReader: '" + times_path_ + "' has " +
                               std::to_string(file_timestamps_s_.size()) +
                               " timestamps but folder '" + scan_folder_ + "' has " +
                               std::to_string(files_.size()) + " scans");
  } else {
    file_timestamps_s_.resize(files_.size());
    for (std::size_t i = 0; i < files_.size(); ++i)
      file_timestamps_s_[i] = static_cast<double>(i);
  }

  // Selection.
  if (options.first >= files_.size())
    throw std::invalid_argument(
        "SequenceReader: first = " + std::to_string(options.first) + " but folder '" +
        scan_folder_ + "' has only " + std::to_string(files_.size()) + " scans");
  std::size_t last = files_.size() - 1;
  if (options.last >= 0) {
    if (static_cast<std::uint64_t>(options.last) >= files_.size())
      throw std::invalid_argument(
          "SequenceReader: last = " + std::to_string(options.last) + " but folder '" +
          scan_folder_ + "' has only " + std::to_string(files_.size()) + " scans");
    last = static_cast<std::size_t>(options.last);
  }
  for (std::size_t i = options.first; i <= last; i += options.stride)
    selected_.push_back(i);
}

const std::string&
SequenceReader::path(std::size_t i) const
{
  if (i >= selected_.size())
    throw std::out_of_range("SequenceReader::path: index " + std::to_string(i) +
                            " >= size " + std::to_string(selected_.size()));
  return files_[selected_[i]];
}

double
SequenceReader::timestamp(std::size_t i) const
{
  if (i >= selected_.size())
    throw std::out_of_range("SequenceReader::timestamp: index " + std::to_string(i) +
                            " >= size " + std::to_string(selected_.size()));
  return file_timestamps_s_[selected_[i]];
}

ScanFrame
SequenceReader::read(std::size_t i) const
{
  if (i >= selected_.size())
    throw std::out_of_range("SequenceReader::read: index " + std::to_string(i) +
                            " >= size " + std::to_string(selected_.size()));
  ScanFrame frame;
  frame.sequence_index = i;
  frame.file_index = selected_[i];
  frame.path = files_[frame.file_index];
  frame.timestamp_s = file_timestamps_s_[frame.file_index];
  PointTimes times;
  frame.cloud = readScanAndTimes(frame.path, &frame.num_dropped_non_finite, &times);
  frame.point_times_s = std::move(times.times_s);
  frame.time_field = std::move(times.field);
  frame.time_warning = std::move(times.warning);
  return frame;
}

bool
SequenceReader::next(ScanFrame& frame)
{
  if (cursor_ >= selected_.size())
    return false;
  const std::size_t i = cursor_++; // advance first: a bad frame must not block the rest
  frame = read(i);
  return true;
}

void
SequenceReader::seek(std::size_t i)
{
  if (i > selected_.size())
    throw std::out_of_range("SequenceReader::seek: index " + std::to_string(i) +
                            " > size " + std::to_string(selected_.size()));
  cursor_ = i;
}

} // namespace rast
} // namespace pcl
