#include <pcl/features/range_raster_image.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <vector>

namespace pcl {
namespace rast {

namespace {

bool
fail(std::string* why, const std::string& msg)
{
  if (why)
    *why = msg;
  return false;
}

/// Pixel of continuous coordinates (pixel c is centred on u = c).
inline int
toPixel(float u)
{
  return static_cast<int>(std::floor(u + 0.5f));
}

} // namespace

bool
RangeRasterParams::isValid(std::string* why) const
{
  if (!std::isfinite(min_height_m) || !std::isfinite(max_height_m) ||
      !(max_height_m > min_height_m))
    return fail(why, "height range must satisfy min_height_m < max_height_m, got [" +
                         std::to_string(min_height_m) + ", " + std::to_string(max_height_m) + "]");
  if (projection == RasterProjection::kPinhole) {
    if (!(pinhole.focal_px > 0.0) || !std::isfinite(pinhole.focal_px))
      return fail(why, "pinhole.focal_px must be > 0, got " + std::to_string(pinhole.focal_px));
    if (!std::isfinite(pinhole.principal_u_px) || !std::isfinite(pinhole.principal_v_px) ||
        !std::isfinite(pinhole.t_x_m) || !std::isfinite(pinhole.t_y_m) ||
        !std::isfinite(pinhole.t_z_m))
      return fail(why, "pinhole principal point and translation must be finite");
    if (pinhole.width_px < 1 || pinhole.height_px < 1 || pinhole.width_px > 16384 ||
        pinhole.height_px > 16384)
      return fail(why, "pinhole image size must be in [1, 16384], got " +
                           std::to_string(pinhole.width_px) + " x " +
                           std::to_string(pinhole.height_px));
  }
  else {
    if (!(orthographic.resolution_m > 0.0) || !std::isfinite(orthographic.resolution_m))
      return fail(why, "orthographic.resolution_m must be > 0, got " +
                           std::to_string(orthographic.resolution_m));
    if (!(orthographic.half_extent_m > 0.0) || !std::isfinite(orthographic.half_extent_m))
      return fail(why, "orthographic.half_extent_m must be > 0, got " +
                           std::to_string(orthographic.half_extent_m));
    const double size = 2.0 * orthographic.half_extent_m / orthographic.resolution_m;
    if (size < 1.0 || size > 16384.0)
      return fail(why, "orthographic image size 2*half_extent_m/resolution_m must be in "
                       "[1, 16384] pixels, got " +
                           std::to_string(size));
  }
  return true;
}

int
RangeRasterParams::width() const
{
  if (projection == RasterProjection::kPinhole)
    return pinhole.width_px;
  return static_cast<int>(std::lround(2.0 * orthographic.half_extent_m / orthographic.resolution_m));
}

int
RangeRasterParams::height() const
{
  if (projection == RasterProjection::kPinhole)
    return pinhole.height_px;
  return width();
}

bool
projectToRaster(const RangeRasterParams& params, const Eigen::Vector3f& p, Eigen::Vector2f& uv)
{
  if (!p.allFinite())
    return false;
  if (params.projection == RasterProjection::kPinhole) {
    // Eq. (1): P_c = R (I | t) P_l with R = I; Eq. (2): [u v w] = K P_c.
    const auto& c = params.pinhole;
    const double Z = p.z() + c.t_z_m;
    if (!(Z > 1e-6))
      return false;
    const double X = p.x() + c.t_x_m, Y = p.y() + c.t_y_m;
    uv.x() = static_cast<float>(c.focal_px * X / Z + c.principal_u_px);
    uv.y() = static_cast<float>(c.focal_px * Y / Z + c.principal_v_px);
    return true;
  }
  // Bird's-eye view: forward (+x) is up in the image, left (+y) is left.
  const auto& o = params.orthographic;
  uv.x() = static_cast<float>((o.half_extent_m - p.y()) / o.resolution_m - 0.5);
  uv.y() = static_cast<float>((o.half_extent_m - p.x()) / o.resolution_m - 0.5);
  return true;
}

Eigen::Vector3f
rasterToPoint(const RangeRasterParams& params, const Eigen::Vector2f& uv, float z_m)
{
  if (params.projection == RasterProjection::kPinhole) {
    const auto& c = params.pinhole;
    const double Z = z_m + c.t_z_m;
    const double X = (uv.x() - c.principal_u_px) * Z / c.focal_px;
    const double Y = (uv.y() - c.principal_v_px) * Z / c.focal_px;
    return {static_cast<float>(X - c.t_x_m), static_cast<float>(Y - c.t_y_m), z_m};
  }
  const auto& o = params.orthographic;
  return {static_cast<float>(o.half_extent_m - (uv.y() + 0.5) * o.resolution_m),
          static_cast<float>(o.half_extent_m - (uv.x() + 0.5) * o.resolution_m),
          z_m};
}

void
RasterGrid::setParams(const RangeRasterParams& params)
{
  std::string why;
  if (!params.isValid(&why))
    throw std::invalid_argument("RangeRasterImage::setParams: " + why);
  params_ = params;
  width_ = params.width();
  height_ = params.height();
  computed_ = false;
}

void
RasterGrid::rasterize(const float* xyz,
                      std::size_t stride_bytes,
                      std::size_t num_points,
                      const pcl::Indices* indices)
{
  const int w = width(), h = height();
  const std::size_t num_pixels = static_cast<std::size_t>(w) * static_cast<std::size_t>(h);
  // Reuse the buffers across frames (no page faults on fresh memory), unless a copy of
  // this raster still shares them: then allocate new ones, so copies keep their images.
  if (!buffers_ || buffers_.use_count() > 1)
    buffers_ = std::make_shared<Buffers>();
  const float nan = std::numeric_limits<float>::quiet_NaN();
  buffers_->index.assign(num_pixels, -1);
  buffers_->height.assign(num_pixels, nan);
  buffers_->gray.assign(num_pixels, std::uint8_t(0));
  int* pixel_index = buffers_->index.data();
  float* heights = buffers_->height.data();
  std::uint8_t* gray = buffers_->gray.data();

  // One pass over the points: keep the highest point of every pixel. The occupied
  // pixels are listed on the way, so the gray values touch only those.
  num_projected_ = 0;
  std::vector<int> occupied;
  occupied.reserve(4096);
  const float fw = static_cast<float>(w), fh = static_cast<float>(h);
  auto keep = [&](std::size_t i, float u, float v, float z) {
    // toPixel(u) = floor(u + 0.5); for a shifted value in [0, size) floor is the
    // truncation, and the range test also rejects NaN.
    const float cu = u + 0.5f, cv = v + 0.5f;
    if (!(cu >= 0.0f && cu < fw && cv >= 0.0f && cv < fh))
      return;
    const int col = static_cast<int>(cu), row = static_cast<int>(cv);
    ++num_projected_;
    const int k = row * w + col;
    if (pixel_index[k] < 0) {
      occupied.push_back(k);
      pixel_index[k] = static_cast<int>(i);
      heights[k] = z;
    }
    else if (z > heights[k]) {
      pixel_index[k] = static_cast<int>(i);
      heights[k] = z;
    }
  };
  const auto* bytes = reinterpret_cast<const unsigned char*>(xyz);
  auto pointAt = [&](std::size_t i) {
    return reinterpret_cast<const float*>(bytes + i * stride_bytes);
  };
  if (indices)
    for (const auto i : *indices)
      if (i < 0 || static_cast<std::size_t>(i) >= num_points)
        throw std::out_of_range("RangeRasterImage::compute: index " + std::to_string(i) +
                                " outside the cloud of " + std::to_string(num_points) +
                                " points");
  // Every point (or every indexed one) through \a project: two plain loops, so the
  // common case without indices has no per-point branch.
  auto forEachPoint = [&](auto&& project) {
    if (indices)
      for (const auto i : *indices)
        project(static_cast<std::size_t>(i));
    else
      for (std::size_t i = 0; i < num_points; ++i)
        project(i);
  };
  if (params_.projection == RasterProjection::kOrthographic) {
    // projectToRaster's bird's-eye view, with the parameters hoisted out of the loop.
    const double half_extent = params_.orthographic.half_extent_m;
    const double resolution = params_.orthographic.resolution_m;
    forEachPoint([&](std::size_t i) {
      const float* p = pointAt(i);
      if (!(std::isfinite(p[0]) && std::isfinite(p[1]) && std::isfinite(p[2])))
        return;
      const float u = static_cast<float>((half_extent - p[1]) / resolution - 0.5);
      const float v = static_cast<float>((half_extent - p[0]) / resolution - 0.5);
      keep(i, u, v, p[2]);
    });
  }
  else {
    Eigen::Vector2f uv;
    forEachPoint([&](std::size_t i) {
      const Eigen::Vector3f p = Eigen::Map<const Eigen::Vector3f>(pointAt(i));
      if (projectToRaster(params_, p, uv))
        keep(i, uv.x(), uv.y(), p.z());
    });
  }

  // Gray values of the occupied pixels (empty ones stay 0 with a NaN height).
  num_occupied_ = occupied.size();
  for (const int k : occupied)
    gray[k] = heightToGray(params_, heights[k]);
  computed_ = true;
}

bool
RasterGrid::project(const Eigen::Vector3f& p, Eigen::Vector2f& uv) const
{
  if (!projectToRaster(params_, p, uv))
    return false;
  const int col = toPixel(uv.x()), row = toPixel(uv.y());
  return col >= 0 && row >= 0 && col < width() && row < height();
}

bool
RasterGrid::projectToPixel(const Eigen::Vector3f& p, int& col, int& row) const
{
  Eigen::Vector2f uv;
  if (!project(p, uv))
    return false;
  col = toPixel(uv.x());
  row = toPixel(uv.y());
  return true;
}

int
RasterGrid::pixelIndex(int col, int row) const
{
  if (!computed_ || col < 0 || row < 0 || col >= width() || row >= height())
    return -1;
  return buffers_->index[static_cast<std::size_t>(row) * width() + col];
}

std::uint8_t
RasterGrid::grayAt(int col, int row) const
{
  if (!computed_ || col < 0 || row < 0 || col >= width() || row >= height())
    return 0;
  return buffers_->gray[static_cast<std::size_t>(row) * width() + col];
}

float
RasterGrid::heightAt(int col, int row) const
{
  if (!computed_ || col < 0 || row < 0 || col >= width() || row >= height())
    return std::numeric_limits<float>::quiet_NaN();
  return buffers_->height[static_cast<std::size_t>(row) * width() + col];
}

int
RasterGrid::nearestPixelIndex(int col, int row, int radius_px) const
{
  int index = pixelIndex(col, row);
  if (index >= 0)
    return index;
  for (int ring = 1; ring <= radius_px; ++ring) {
    int best = -1, best_d2 = std::numeric_limits<int>::max();
    for (int dr = -ring; dr <= ring; ++dr)
      for (int dc = -ring; dc <= ring; ++dc) {
        if (std::max(std::abs(dr), std::abs(dc)) != ring)
          continue; // only the ring itself
        const int candidate = pixelIndex(col + dc, row + dr);
        const int d2 = dr * dr + dc * dc;
        if (candidate >= 0 && d2 < best_d2) {
          best = candidate;
          best_d2 = d2;
        }
      }
    if (best >= 0)
      return best;
  }
  return -1;
}

} // namespace rast
} // namespace pcl
