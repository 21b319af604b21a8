/// \file png_io.cpp
/// \brief savePng and loadPng with libpng's simplified API (png_image): it takes and
/// gives rows top first in BGR order, reports every failure in its message instead of
/// printing or jumping, and converts any PNG (palette, 16-bit) to 8 bits on reading.
/// The picture is encoded in memory and writeFileAtomically puts the bytes on disk, so a
/// full disk or a missing folder is reported and never leaves part of a picture behind.

#include <filesystem>
#include <pcl/rast/atomic_file.h>
#include <pcl/visualization/png_io.h>
#include <png.h>
#include <stdexcept>

namespace pcl {
namespace rast {
namespace {

/// libpng's format for 1-4 interleaved 8-bit channels in OpenCV's order.
png_uint_32
formatOfChannels(int channels)
{
  switch (channels) {
  case 1:
    return PNG_FORMAT_GRAY;
  case 2:
    return PNG_FORMAT_GA;
  case 3:
    return PNG_FORMAT_BGR;
  default:
    return PNG_FORMAT_BGRA;
  }
}

} // namespace

void
savePng(const std::string& path, const Image8& image)
{
  if (image.width <= 0 || image.height <= 0)
    throw std::invalid_argument("savePng: bad image size " + std::to_string(image.width) +
                                " x " + std::to_string(image.height) + " for '" + path +
                                "'");
  if (image.channels < 1 || image.channels > 4)
    throw std::invalid_argument("savePng: bad channel count " +
                                std::to_string(image.channels) + " for '" + path +
                                "' (1 to 4)");
  const std::size_t row_bytes = static_cast<std::size_t>(image.width) * image.channels;
  if (image.pixels.size() != row_bytes * image.height)
    throw std::invalid_argument(
        "savePng: " + std::to_string(image.pixels.size()) + " pixel bytes for a " +
        std::to_string(image.width) + " x " + std::to_string(image.height) + " x " +
        std::to_string(image.channels) + " image ('" + path + "')");

  png_image png{};
  png.version = PNG_IMAGE_VERSION;
  png.width = static_cast<png_uint_32>(image.width);
  png.height = static_cast<png_uint_32>(image.height);
  png.format = formatOfChannels(image.channels);
  // Speed over size, as OpenCV's writer did: a 1600 x 1200 render took 246 ms to encode
  // without this flag (0.70 MB), against 45 ms with cv::imwrite (1.19 MB).
  png.flags = PNG_IMAGE_FLAG_FAST;
  const auto stride = static_cast<png_int_32>(row_bytes);
  png_alloc_size_t size = 0;
  std::string bytes;
  // The first call measures, the second encodes.
  bool encoded = png_image_write_get_memory_size(
                     png, size, 0, image.pixels.data(), stride, nullptr) != 0;
  if (encoded) {
    bytes.resize(size);
    encoded =
        png_image_write_to_memory(
            &png, bytes.data(), &size, 0, image.pixels.data(), stride, nullptr) != 0;
    bytes.resize(size);
  }
  if (!encoded) {
    const std::string why = png.message;
    png_image_free(&png);
    throw std::runtime_error("cannot encode '" + path + "' as PNG: " + why);
  }
  try {
    writeFileAtomically(path, bytes);
  } catch (const std::runtime_error& e) {
    throw std::runtime_error("cannot write '" + path + "': " + e.what());
  }
}

Image8
loadPng(const std::string& path)
{
  std::error_code ec;
  if (!std::filesystem::is_regular_file(path, ec))
    throw std::runtime_error("cannot read '" + path + "': no such file");
  png_image png{};
  png.version = PNG_IMAGE_VERSION;
  if (!png_image_begin_read_from_file(&png, path.c_str())) {
    const std::string why = png.message;
    png_image_free(&png);
    throw std::runtime_error("cannot read '" + path + "': " + why);
  }
  Image8 image;
  image.width = static_cast<int>(png.width);
  image.height = static_cast<int>(png.height);
  image.channels = static_cast<int>(PNG_IMAGE_SAMPLE_CHANNELS(png.format));
  png.format = formatOfChannels(image.channels); // 8 bits, BGR order, no colour map
  image.pixels.resize(PNG_IMAGE_SIZE(png));
  if (!png_image_finish_read(&png, nullptr, image.pixels.data(), 0, nullptr)) {
    const std::string why = png.message;
    png_image_free(&png);
    throw std::runtime_error("cannot read '" + path + "': " + why);
  }
  return image;
}

} // namespace rast
} // namespace pcl
