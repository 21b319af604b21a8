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

/// Reuse \a image's buffer across frames (no page faults on fresh memory), unless
/// a copy of this raster still shares it: then allocate a new one, so copies keep
/// the image they were made with.
void
prepareImage(cv::Mat& image, int rows, int cols, int type)
{
  if (image.u && image.u->refcount > 1)
    image.release();
  image.create(rows, cols, type);
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
RangeRasterImage::setParams(const RangeRasterParams& params)
{
  std::string why;
  if (!params.isValid(&why))
    throw std::invalid_argument("RangeRasterImage::setParams: " + why);
  params_ = params;
  computed_ = false;
}

void
RangeRasterImage::setInputCloud(const PointCloud::ConstPtr& cloud)
{
  if (!cloud)
    throw std::invalid_argument("RangeRasterImage::setInputCloud: cloud is null");
  input_ = cloud;
  computed_ = false;
}

void
RangeRasterImage::compute()
{
  if (!input_)
    throw std::invalid_argument("RangeRasterImage::compute: no input cloud (call setInputCloud)");
  const int w = width(), h = height();
  const std::size_t num_pixels = static_cast<std::size_t>(w) * static_cast<std::size_t>(h);
  prepareImage(height_image_, h, w, CV_32FC1);
  prepareImage(index_image_, h, w, CV_32SC1);
  prepareImage(gray_image_, h, w, CV_8UC1);
  auto* heights = height_image_.ptr<float>();
  auto* indices = index_image_.ptr<int>();
  auto* gray = gray_image_.ptr<std::uint8_t>();
  const float nan = std::numeric_limits<float>::quiet_NaN();
  std::fill(indices, indices + num_pixels, -1);
  std::fill(heights, heights + num_pixels, nan);
  std::fill(gray, gray + num_pixels, std::uint8_t(0));

  // One pass over the points: keep the highest point of every pixel. The occupied
  // pixels are listed on the way, so the gray values touch only those.
  num_projected_ = 0;
  std::vector<int> occupied;
  occupied.reserve(4096);
  const PointCloud& cloud = *input_;
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
    if (indices[k] < 0) {
      occupied.push_back(k);
      indices[k] = static_cast<int>(i);
      heights[k] = z;
    }
    else if (z > heights[k]) {
      indices[k] = static_cast<int>(i);
      heights[k] = z;
    }
  };
  if (params_.projection == RasterProjection::kOrthographic) {
    // projectToRaster's bird's-eye view, with the parameters hoisted out of the loop.
    const double half_extent = params_.orthographic.half_extent_m;
    const double resolution = params_.orthographic.resolution_m;
    for (std::size_t i = 0; i < cloud.size(); ++i) {
      const auto& p = cloud[i];
      if (!(std::isfinite(p.x) && std::isfinite(p.y) && std::isfinite(p.z)))
        continue;
      const float u = static_cast<float>((half_extent - p.y) / resolution - 0.5);
      const float v = static_cast<float>((half_extent - p.x) / resolution - 0.5);
      keep(i, u, v, p.z);
    }
  }
  else {
    Eigen::Vector2f uv;
    for (std::size_t i = 0; i < cloud.size(); ++i) {
      const Eigen::Vector3f p = cloud[i].getVector3fMap();
      if (projectToRaster(params_, p, uv))
        keep(i, uv.x(), uv.y(), p.z());
    }
  }

  // Gray values of the occupied pixels (empty ones stay 0 with a NaN height).
  num_occupied_ = occupied.size();
  for (const int k : occupied)
    gray[k] = heightToGray(params_, heights[k]);
  computed_ = true;
}

bool
RangeRasterImage::project(const Eigen::Vector3f& p, Eigen::Vector2f& uv) const
{
  if (!projectToRaster(params_, p, uv))
    return false;
  const int col = toPixel(uv.x()), row = toPixel(uv.y());
  return col >= 0 && row >= 0 && col < width() && row < height();
}

bool
RangeRasterImage::projectToPixel(const Eigen::Vector3f& p, int& col, int& row) const
{
  Eigen::Vector2f uv;
  if (!project(p, uv))
    return false;
  col = toPixel(uv.x());
  row = toPixel(uv.y());
  return true;
}

int
RangeRasterImage::pixelIndex(int col, int row) const
{
  if (!computed_ || col < 0 || row < 0 || col >= index_image_.cols ||
      row >= index_image_.rows)
    return -1;
  return index_image_.at<int>(row, col);
}

bool
RangeRasterImage::pixelToPoint(int col, int row, PointT& point) const
{
  const int index = pixelIndex(col, row);
  if (index < 0)
    return false;
  point = (*input_)[index];
  return true;
}

int
RangeRasterImage::nearestPixelIndex(int col, int row, int radius_px) const
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
