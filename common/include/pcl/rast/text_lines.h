#pragma once
/// \file text_lines.h
/// \brief Reading text files line by line with a bound on the line length, for the
/// readers of pose, times.txt, calib.txt and g2o files.

#include <cstddef>
#include <istream>
#include <string>

namespace pcl {
namespace rast {

/// \brief The longest text line the readers of pose, times.txt, calib.txt and g2o files
/// accept (1 MiB): a file with no newline (/dev/zero) is an error, not unbounded memory.
constexpr std::size_t kMaxTextLineBytes = std::size_t{1} << 20;

/// \brief std::getline with a bound: read the next line of \a in into \a line, without
/// its '\n' (and a trailing '\r').
/// \param[in] path the file, for the error
/// \param[in] line_number the 1-based number of the line being read, for the error
/// \return false at the end of the input
/// \throws std::runtime_error naming \a path and the line when it is longer than
/// kMaxTextLineBytes.
bool readBoundedLine(std::istream& in,
                     std::string& line,
                     const std::string& path,
                     std::size_t line_number);

} // namespace rast
} // namespace pcl
