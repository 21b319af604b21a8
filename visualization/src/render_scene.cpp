/// \file render_scene.cpp
/// \brief The scene of a map render and its OpenCV rasterization (the overlays are in
/// render_overlays.cpp).

#include "render_scene.h"

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fcntl.h>
#include <limits>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>
#include <pcl/visualization/png_io.h>
#include <poll.h>
#include <signal.h>
#include <sstream>
#include <stdexcept>
#include <sys/prctl.h>
#include <sys/wait.h>
#include <thread>
#include <unistd.h>

namespace pcl {
namespace rast {
namespace render_detail {

cv::Scalar
toBgr(const RgbColour& c)
{
  return cv::Scalar(c.b, c.g, c.r);
}

std::vector<cv::Vec3b>
makeLut(MapColourMap map)
{
  int cv_map = cv::COLORMAP_VIRIDIS;
  if (map == MapColourMap::kCividis)
    cv_map = cv::COLORMAP_CIVIDIS;
  else if (map == MapColourMap::kInferno)
    cv_map = cv::COLORMAP_INFERNO;
  cv::Mat ramp(1, 256, CV_8UC1);
  for (int i = 0; i < 256; ++i)
    ramp.at<std::uint8_t>(0, i) = static_cast<std::uint8_t>(i);
  cv::Mat colours;
  cv::applyColorMap(ramp, colours, cv_map);
  std::vector<cv::Vec3b> lut(256);
  for (int i = 0; i < 256; ++i)
    lut[i] = colours.at<cv::Vec3b>(0, i);
  return lut;
}

/// The p-th percentile (0..100) of \a values (reordered).
double
percentile(std::vector<double>& values, double p)
{
  if (values.empty())
    return 0.0;
  const auto k = static_cast<std::size_t>(
      std::llround(p / 100.0 * static_cast<double>(values.size() - 1)));
  std::nth_element(values.begin(), values.begin() + k, values.end());
  return values[k];
}

bool
isFinite(const Eigen::Vector3d& p)
{
  return p.allFinite();
}

Layout
makeLayout(const MapRenderParams& params)
{
  Layout l;
  l.scale = std::max(0.35, std::min(params.width_px / 1600.0, params.height_px / 1200.0));
  l.title_band_px = 84.0 * l.scale;
  l.bottom_band_px = params.draw_scale_bar ? 64.0 * l.scale : 16.0 * l.scale;
  l.right_band_px = params.draw_colour_bar ? 170.0 * l.scale : 24.0 * l.scale;
  l.margin_px = 24.0 * l.scale;
  return l;
}

namespace {

/// What the whole map contributes before the view is known: the height range of its
/// finite points, and a sample of their coordinates and colour values (every
/// stride-th point, at most about kMaxSamples) for the robust bounds and colour range.
/// A map of millions of points is not copied whole.
struct MapSample
{
  std::vector<double> xs, ys, values;
  double z_min = std::numeric_limits<double>::infinity();
  double z_max = -std::numeric_limits<double>::infinity();
};

constexpr std::size_t kMaxSamples = std::size_t(1) << 20;

bool
isDrawable(const pcl::PointXYZI& p, bool by_height)
{
  return std::isfinite(p.x) && std::isfinite(p.y) && std::isfinite(p.z) &&
         (by_height || std::isfinite(p.intensity));
}

MapSample
sampleMap(const MapRenderInput& input, const MapRenderParams& params, Scene& s)
{
  const bool by_height = params.colour_by == MapColourBy::kHeight;
  const pcl::PointCloud<pcl::PointXYZI>& map = *input.map;
  const std::size_t stride = std::max<std::size_t>(1, map.size() / kMaxSamples);
  MapSample sample;
  sample.xs.reserve(map.size() / stride + 1);
  sample.ys.reserve(map.size() / stride + 1);
  sample.values.reserve(map.size() / stride + 1);
  std::size_t finite = 0;
  for (const auto& p : map) {
    if (!isDrawable(p, by_height))
      continue;
    sample.z_min = std::min<double>(sample.z_min, p.z);
    sample.z_max = std::max<double>(sample.z_max, p.z);
    if (finite++ % stride != 0)
      continue;
    sample.xs.push_back(p.x);
    sample.ys.push_back(p.y);
    sample.values.push_back(by_height ? p.z : p.intensity);
  }
  // Colour range from robust percentiles.
  if (!sample.values.empty()) {
    std::vector<double> tmp = sample.values;
    s.value_low = percentile(tmp, params.colour_low_percentile);
    s.value_high = percentile(tmp, params.colour_high_percentile);
  }
  if (!(s.value_high - s.value_low > 1e-9))
    s.value_high = s.value_low + 1.0;
  return sample;
}

/// The map points drawn: the top-most of each pixel (none off the picture, and none
/// under the title, legend and colour bar, which would be written over them), which is
/// what a picture looking straight down shows there, sorted by increasing height so
/// that, as in the VTK depth test, higher structure covers lower structure; and their
/// colours. A map of millions of points would otherwise cost VTK's render process
/// gigabytes (a 2474 key-frame session: 1.4 GB).
void
colourTopPoints(const MapRenderInput& input, const MapRenderParams& params, Scene& s)
{
  const bool by_height = params.colour_by == MapColourBy::kHeight;
  const pcl::PointCloud<pcl::PointXYZI>& map = *input.map;
  // Off-picture margin: a point drawn this far outside still reaches into the image.
  const int margin = static_cast<int>(std::ceil(params.point_size_px)) + 1;
  const int w = params.width_px + 2 * margin, h = params.height_px + 2 * margin;
  // Grid cells (pixels shifted by the margin) clear of the text bands.
  const Layout& l = s.layout;
  const double u_end = std::min<double>(w, params.width_px - l.right_band_px + margin);
  const double v_begin = std::floor(l.title_band_px) + margin;
  const double v_end = std::min<double>(h, params.height_px - l.bottom_band_px + margin);
  constexpr std::uint32_t kNone = std::numeric_limits<std::uint32_t>::max();
  if (map.size() >= kNone)
    throw std::invalid_argument(
        "renderMapTopDown: a map of " + std::to_string(map.size()) +
        " points, more than can be drawn (" + std::to_string(kNone - 1) + ")");
  std::vector<std::uint32_t> top(
      static_cast<std::size_t>(w) * static_cast<std::size_t>(h), kNone);
  for (std::size_t i = 0; i < map.size(); ++i) {
    const auto& p = map[i];
    if (!isDrawable(p, by_height))
      continue;
    const cv::Point2d px = s.view.toPixel(p.x, p.y);
    const double u = std::floor(px.x + 0.5) + margin, v = std::floor(px.y + 0.5) + margin;
    if (!(u >= 0.0 && u < u_end && v >= v_begin && v < v_end))
      continue;
    std::uint32_t& t = top[static_cast<std::size_t>(v) * w + static_cast<std::size_t>(u)];
    if (t == kNone || p.z >= map[t].z) // equal heights: the later point, drawn last
      t = static_cast<std::uint32_t>(i);
  }
  std::vector<std::uint32_t> drawn;
  for (const std::uint32_t t : top)
    if (t != kNone)
      drawn.push_back(t);
  std::sort(drawn.begin(), drawn.end(), [&map](std::uint32_t a, std::uint32_t b) {
    return map[a].z != map[b].z ? map[a].z < map[b].z : a < b;
  });
  s.points.reserve(drawn.size());
  s.point_bgr.reserve(drawn.size());
  for (const std::uint32_t i : drawn) {
    const auto& p = map[i];
    s.points.emplace_back(p.x, p.y, p.z);
    const double value = by_height ? p.z : p.intensity;
    const double t =
        std::clamp((value - s.value_low) / (s.value_high - s.value_low), 0.0, 1.0);
    s.point_bgr.push_back(s.lut_bgr[static_cast<int>(std::lround(t * 255.0))]);
  }
}

/// The finite trajectory, ground truth and loop edges, and the path length.
void
copyLines(const MapRenderInput& input, Scene& s)
{
  for (const auto& p : input.trajectory)
    if (isFinite(p))
      s.trajectory.push_back(p);
  for (const auto& p : input.ground_truth)
    if (isFinite(p))
      s.ground_truth.push_back(p);
  for (const auto& e : input.loop_edges)
    if (isFinite(e.first) && isFinite(e.second))
      s.loop_edges.push_back(e);
  for (std::size_t i = 1; i < s.trajectory.size(); ++i)
    s.path_length_m += (s.trajectory[i] - s.trajectory[i - 1]).norm();
}

/// The view: the bounds (the bulk of the map, 0.5 %..99.5 %, so that stray points far
/// away do not shrink it, and everything else in full) fitted into the plot area
/// between the title, legend and colour bar bands.
void
fitView(const MapRenderParams& params, MapSample& sample, Scene& s)
{
  std::vector<double>& xs = sample.xs;
  std::vector<double>& ys = sample.ys;
  double x0 = std::numeric_limits<double>::infinity(), x1 = -x0, y0 = x0, y1 = -x0;
  double z0 = x0, z1 = -x0;
  auto grow = [&](const Eigen::Vector3d& p) {
    x0 = std::min(x0, p.x()), x1 = std::max(x1, p.x());
    y0 = std::min(y0, p.y()), y1 = std::max(y1, p.y());
    z0 = std::min(z0, p.z()), z1 = std::max(z1, p.z());
  };
  if (!xs.empty()) {
    const bool robust = xs.size() > 1000;
    grow({percentile(xs, robust ? 0.5 : 0.0),
          percentile(ys, robust ? 0.5 : 0.0),
          sample.z_min});
    grow({percentile(xs, robust ? 99.5 : 100.0),
          percentile(ys, robust ? 99.5 : 100.0),
          sample.z_max});
  }
  for (const auto& p : s.trajectory)
    grow(p);
  for (const auto& p : s.ground_truth)
    grow(p);
  for (const auto& e : s.loop_edges)
    grow(e.first), grow(e.second);
  if (!std::isfinite(x0)) // nothing to draw at all
    x0 = y0 = z0 = -1.0, x1 = y1 = z1 = 1.0;
  const double min_extent_m = 1.0;
  const double cx = 0.5 * (x0 + x1), cy = 0.5 * (y0 + y1);
  const double ex = std::max(x1 - x0, min_extent_m), ey = std::max(y1 - y0, min_extent_m);
  s.z_min_m = z0;
  s.z_top_m = z1;

  const Layout& l = s.layout;
  TopDownView& v = s.view;
  v.width_px = params.width_px;
  v.height_px = params.height_px;
  const double plot_x = l.margin_px, plot_y = l.title_band_px + 0.5 * l.margin_px;
  const double plot_w = std::max(8.0, params.width_px - l.margin_px - l.right_band_px);
  const double plot_h =
      std::max(8.0, params.height_px - plot_y - l.bottom_band_px - 0.5 * l.margin_px);
  v.plot_px = cv::Rect2d(plot_x, plot_y, plot_w, plot_h);
  v.m_per_px = std::max(ex / plot_w, ey / plot_h);
  const double plot_cx = plot_x + 0.5 * plot_w, plot_cy = plot_y + 0.5 * plot_h;
  v.cam_x_m = cx - (plot_cx - 0.5 * params.width_px) * v.m_per_px;
  v.cam_y_m = cy + (plot_cy - 0.5 * params.height_px) * v.m_per_px;
}

} // namespace

Scene
prepareScene(const MapRenderInput& input, const MapRenderParams& params)
{
  Scene s;
  s.map_points_total =
      input.map_points_total > 0 ? input.map_points_total : input.map->size();
  s.lut_bgr = makeLut(params.colour_map);
  s.layout = makeLayout(params);
  s.value_label = params.colour_by == MapColourBy::kHeight ? "height [m]" : "intensity";
  MapSample sample = sampleMap(input, params, s);
  copyLines(input, s);
  fitView(params, sample, s);
  colourTopPoints(input, params, s);
  return s;
}

/// Vertices of a marker: a disc (many sides) or an axis-aligned square (4 sides).
std::vector<Eigen::Vector2d>
markerPolygon(const Eigen::Vector3d& centre, double radius_m, bool square)
{
  std::vector<Eigen::Vector2d> poly;
  const int sides = square ? 4 : 40;
  const double start = square ? M_PI / 4.0 : 0.0;
  const double r = square ? radius_m * std::sqrt(2.0) : radius_m;
  for (int i = 0; i < sides; ++i) {
    const double a = start + 2.0 * M_PI * i / sides;
    poly.emplace_back(centre.x() + r * std::cos(a), centre.y() + r * std::sin(a));
  }
  return poly;
}

// ---------------------------------------------------------------------------
// OpenCV rasterization of the scene (the fallback) and the overlays (both backends).
// ---------------------------------------------------------------------------

constexpr double kShiftScale = 1 << kShift;

cv::Point
fixedPoint(const cv::Point2d& p)
{
  return {static_cast<int>(std::lround(p.x * kShiftScale)),
          static_cast<int>(std::lround(p.y * kShiftScale))};
}

void
drawPolyline(cv::Mat& img,
             const TopDownView& v,
             const std::vector<Eigen::Vector3d>& line,
             const RgbColour& colour,
             float width_px)
{
  if (line.size() < 2)
    return;
  std::vector<cv::Point> pts;
  pts.reserve(line.size());
  for (const auto& p : line)
    pts.push_back(fixedPoint(v.toPixel(p.x(), p.y())));
  cv::polylines(img,
                pts,
                false,
                toBgr(colour),
                std::max(1, static_cast<int>(std::lround(width_px))),
                cv::LINE_AA,
                kShift);
}

void
drawMarker(cv::Mat& img,
           const TopDownView& v,
           const Eigen::Vector3d& centre,
           double radius_px,
           bool square,
           const RgbColour& fill,
           double scale)
{
  std::vector<cv::Point> pts;
  for (const auto& q : markerPolygon(centre, radius_px * v.m_per_px, square))
    pts.push_back(fixedPoint(v.toPixel(q.x(), q.y())));
  cv::fillPoly(
      img, std::vector<std::vector<cv::Point>>{pts}, toBgr(fill), cv::LINE_AA, kShift);
  cv::polylines(img,
                pts,
                true,
                toBgr(kMarkerOutline),
                std::max(1, static_cast<int>(std::lround(2.0 * scale))),
                cv::LINE_AA,
                kShift);
}

cv::Mat
rasterizeScene(const Scene& s, const MapRenderParams& params)
{
  const TopDownView& v = s.view;
  cv::Mat img(v.height_px, v.width_px, CV_8UC3, toBgr(params.background));

  // Points as squares of point_size_px, like VTK's point sprites.
  const int size = std::max(1, static_cast<int>(std::lround(params.point_size_px)));
  for (std::size_t i = 0; i < s.points.size(); ++i) {
    const cv::Point2d c = v.toPixel(s.points[i].x(), s.points[i].y());
    const int u0 = static_cast<int>(std::floor(c.x + 0.5 - 0.5 * size + 0.5));
    const int v0 = static_cast<int>(std::floor(c.y + 0.5 - 0.5 * size + 0.5));
    for (int row = std::max(0, v0); row < std::min(img.rows, v0 + size); ++row) {
      auto* px = img.ptr<cv::Vec3b>(row);
      for (int col = std::max(0, u0); col < std::min(img.cols, u0 + size); ++col)
        px[col] = s.point_bgr[i];
    }
  }
  drawPolyline(
      img, v, s.ground_truth, params.ground_truth_colour, params.ground_truth_width_px);
  drawPolyline(
      img, v, s.trajectory, params.trajectory_colour, params.trajectory_width_px);
  for (const auto& e : s.loop_edges)
    drawPolyline(
        img, v, {e.first, e.second}, params.loop_edge_colour, params.loop_edge_width_px);
  if (params.draw_start_end_markers && !s.trajectory.empty()) {
    drawMarker(img,
               v,
               s.trajectory.back(),
               params.marker_size_px,
               true,
               kEndColour,
               s.layout.scale);
    drawMarker(img,
               v,
               s.trajectory.front(),
               params.marker_size_px,
               false,
               kStartColour,
               s.layout.scale);
  }
  return img;
}

/// Write \a img to \a path as a PNG, whole or not at all (savePng).
bool
writePngAtomically(const cv::Mat& img, const std::string& path, std::string* why)
{
  CV_Assert(img.depth() == CV_8U);
  Image8 image;
  image.width = img.cols;
  image.height = img.rows;
  image.channels = img.channels();
  const cv::Mat continuous = img.isContinuous() ? img : img.clone();
  image.pixels.assign(continuous.data,
                      continuous.data + continuous.total() * continuous.elemSize());
  try {
    savePng(path, image);
  } catch (const std::exception& e) {
    *why = e.what();
    return false;
  }
  return true;
}

} // namespace render_detail
} // namespace rast
} // namespace pcl
