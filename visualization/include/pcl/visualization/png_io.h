#pragma once
/// \file png_io.h
/// \ingroup visualization
/// \brief PNG files for the pictures the tools write (renders, feature images), read and
/// written with libpng's simplified API.
///
/// The tools write PNGs through these two calls rather than OpenCV's imgcodecs: that
/// module brings GDAL and about 140 shared libraries with it, whose symbol lookups made
/// every start of a tool take 0.3 s instead of a few hundredths (doc/architecture.md,
/// "Start-up time"). libpng is loaded anyway, by PCL's io module.

#include <cstdint>
#include <string>
#include <vector>

namespace pcl {
namespace rast {

/// \brief An 8-bit image in memory, rows from top to bottom, pixels interleaved, colour
/// channels in OpenCV's order (blue, green, red[, alpha]) as a cv::Mat holds them.
struct Image8
{
  int width = 0, height = 0;
  int channels = 0;                 ///< 1 (grey), 2 (grey, alpha), 3 (BGR) or 4 (BGRA)
  std::vector<std::uint8_t> pixels; ///< height * width * channels bytes
};

/// \brief Write \a image to \a path as a PNG, through a temporary file in the same folder
/// and a rename: \a path is afterwards the whole picture, or what it was before.
/// \throws std::invalid_argument for an image whose size, channels or pixel count do
///         not agree (naming the value); std::runtime_error naming the file when it
///         cannot be written.
void savePng(const std::string& path, const Image8& image);

/// \brief Read an 8-bit PNG (grey, grey + alpha, RGB or RGBA) from \a path.
/// \throws std::runtime_error naming the file when it is missing, not a PNG, or not
/// 8-bit.
Image8 loadPng(const std::string& path);

} // namespace rast
} // namespace pcl
