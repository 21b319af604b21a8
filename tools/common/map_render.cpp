#include "map_render.h"

#include <algorithm>
#include <atomic>
#include <cctype>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fcntl.h>
#include <filesystem>
#include <limits>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <poll.h>
#include <signal.h>
#include <sstream>
#include <stdexcept>
#include <sys/prctl.h>
#include <sys/wait.h>
#include <thread>
#include <unistd.h>
#include <vtkActor.h>
#include <vtkAutoInit.h>
#include <vtkCallbackCommand.h>
#include <vtkCamera.h>
#include <vtkCellArray.h>
#include <vtkCommand.h>
#include <vtkImageData.h>
#include <vtkPointData.h>
#include <vtkPoints.h>
#include <vtkPolyData.h>
#include <vtkPolyDataMapper.h>
#include <vtkProperty.h>
#include <vtkRenderWindow.h>
#include <vtkRenderer.h>
#include <vtkSmartPointer.h>
#include <vtkUnsignedCharArray.h>
#include <vtkWindowToImageFilter.h>

// Xlib last: it defines macros (None, Status, Bool, ...) that clash with other headers.
#include <X11/Xlib.h>

VTK_MODULE_INIT(vtkRenderingOpenGL2);

namespace pcl_rast_tools {

namespace {

using Clock = std::chrono::steady_clock;

double
secondsSince(Clock::time_point start)
{
  return std::chrono::duration<double>(Clock::now() - start).count();
}

// ---------------------------------------------------------------------------
// The scene: everything both backends draw, prepared once in the parent.
// ---------------------------------------------------------------------------

/// World (x, y) [m] <-> image pixels, north up. The world point (cam_x, cam_y) is at
/// the image centre; pixel (u, v) has its centre at continuous (u + 0.5, v + 0.5).
struct TopDownView
{
  int width_px = 0, height_px = 0;
  double cam_x_m = 0.0, cam_y_m = 0.0;
  double m_per_px = 1.0;
  cv::Rect2d plot_px; ///< where the data bounds were fitted

  /// Pixel-centre coordinates (OpenCV convention) of a world point.
  cv::Point2d toPixel(double x_m, double y_m) const
  {
    return {0.5 * width_px + (x_m - cam_x_m) / m_per_px - 0.5,
            0.5 * height_px - (y_m - cam_y_m) / m_per_px - 0.5};
  }
};

struct Layout
{
  double scale = 1.0; ///< font and line scale relative to a 1600 x 1200 image
  double title_band_px = 0.0, bottom_band_px = 0.0, right_band_px = 0.0, margin_px = 0.0;
};

struct Scene
{
  std::vector<Eigen::Vector3f> points; ///< finite map points, sorted by increasing z
  std::size_t map_points_total = 0;    ///< points of the map shown (subtitle)
  std::vector<cv::Vec3b> point_bgr;    ///< colour of each point
  std::vector<Eigen::Vector3d> trajectory, ground_truth;
  std::vector<std::pair<Eigen::Vector3d, Eigen::Vector3d>> loop_edges;
  double value_low = 0.0, value_high = 1.0; ///< colour range
  std::string value_label;                  ///< "height [m]" or "intensity"
  std::vector<cv::Vec3b> lut_bgr;           ///< 256 colours
  double z_min_m = 0.0, z_top_m = 0.0;      ///< height range of everything drawn
  double path_length_m = 0.0;
  Layout layout;
  TopDownView view;
};

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

Scene
prepareScene(const MapRenderInput& input, const MapRenderParams& params)
{
  Scene s;
  s.map_points_total = input.map_points_total > 0 ? input.map_points_total : input.map->size();
  s.lut_bgr = makeLut(params.colour_map);
  s.layout = makeLayout(params);
  const bool by_height = params.colour_by == MapColourBy::kHeight;
  s.value_label = by_height ? "height [m]" : "intensity";

  // Finite map points, drawn from low to high so that, as in the VTK depth test,
  // higher structure covers lower structure when seen from above.
  std::vector<std::pair<float, std::size_t>> order;
  order.reserve(input.map->size());
  for (std::size_t i = 0; i < input.map->size(); ++i) {
    const auto& p = (*input.map)[i];
    if (std::isfinite(p.x) && std::isfinite(p.y) && std::isfinite(p.z) &&
        (by_height || std::isfinite(p.intensity)))
      order.emplace_back(p.z, i);
  }
  std::sort(order.begin(), order.end());
  std::vector<double> values, xs, ys;
  values.reserve(order.size());
  xs.reserve(order.size());
  ys.reserve(order.size());
  s.points.reserve(order.size());
  for (const auto& [z, i] : order) {
    const auto& p = (*input.map)[i];
    s.points.emplace_back(p.x, p.y, p.z);
    values.push_back(by_height ? p.z : p.intensity);
    xs.push_back(p.x);
    ys.push_back(p.y);
  }

  // Colour range from robust percentiles.
  if (!values.empty()) {
    std::vector<double> tmp = values;
    s.value_low = percentile(tmp, params.colour_low_percentile);
    s.value_high = percentile(tmp, params.colour_high_percentile);
  }
  if (!(s.value_high - s.value_low > 1e-9))
    s.value_high = s.value_low + 1.0;
  s.point_bgr.reserve(values.size());
  for (double v : values) {
    const double t =
        std::clamp((v - s.value_low) / (s.value_high - s.value_low), 0.0, 1.0);
    s.point_bgr.push_back(s.lut_bgr[static_cast<int>(std::lround(t * 255.0))]);
  }

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

  // Bounds: the bulk of the map (0.5 %..99.5 %, so stray points far away do not
  // shrink it) and everything else in full.
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
          s.points.front().z()});
    grow({percentile(xs, robust ? 99.5 : 100.0),
          percentile(ys, robust ? 99.5 : 100.0),
          s.points.back().z()});
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

  // Fit the bounds into the plot area (between the title, legend and colour bar bands).
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

const RgbColour kStartColour{40, 180, 60};
const RgbColour kEndColour{20, 20, 20};
const RgbColour kMarkerOutline{255, 255, 255};

// ---------------------------------------------------------------------------
// OpenCV rasterization of the scene (the fallback) and the overlays (both backends).
// ---------------------------------------------------------------------------

constexpr int kShift = 4; // sub-pixel bits for cv drawing
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

constexpr int kFont = cv::FONT_HERSHEY_DUPLEX;

/// Text with its baseline-left corner at \a org; returns its width [px].
int
drawText(cv::Mat& img,
         const std::string& text,
         cv::Point org,
         double font_scale,
         const cv::Scalar& colour,
         int thickness = 1)
{
  cv::putText(img, text, org, kFont, font_scale, colour, thickness, cv::LINE_AA);
  int baseline = 0;
  return cv::getTextSize(text, kFont, font_scale, thickness, &baseline).width;
}

int
textWidth(const std::string& text, double font_scale, int thickness = 1)
{
  int baseline = 0;
  return cv::getTextSize(text, kFont, font_scale, thickness, &baseline).width;
}

std::string
formatNumber(double value, int decimals)
{
  char buf[64];
  std::snprintf(buf, sizeof(buf), "%.*f", decimals, value);
  if (std::strcmp(buf, "-0") == 0 || (std::strncmp(buf, "-0.", 3) == 0 &&
                                      std::strspn(buf + 3, "0") == std::strlen(buf + 3)))
    return buf + 1; // no "-0.0"
  return buf;
}

/// 1, 2 or 5 times a power of ten, not above \a max_value.
double
niceLength(double max_value)
{
  const double p = std::pow(10.0, std::floor(std::log10(max_value)));
  for (double m : {5.0, 2.0, 1.0})
    if (m * p <= max_value)
      return m * p;
  return p;
}

void
drawOverlays(cv::Mat& img,
             const Scene& s,
             const MapRenderParams& params,
             const std::string& title,
             const std::string& backend)
{
  const Layout& l = s.layout;
  const double k = l.scale;
  const auto& bg = params.background;
  const bool dark_bg = 0.299 * bg.r + 0.587 * bg.g + 0.114 * bg.b < 128.0;
  const cv::Scalar ink = dark_bg ? cv::Scalar(235, 235, 235) : cv::Scalar(25, 25, 25);
  const cv::Scalar faint =
      dark_bg ? cv::Scalar(150, 150, 150) : cv::Scalar(110, 110, 110);
  const int thin = std::max(1, static_cast<int>(std::lround(k)));
  const int W = img.cols, H = img.rows;

  // Title band.
  const std::string heading = title.empty() ? std::string("pcl_rast map") : title;
  drawText(img,
           heading,
           {static_cast<int>(l.margin_px), static_cast<int>(44 * k)},
           1.15 * k,
           ink,
           std::max(1, static_cast<int>(std::lround(1.6 * k))));
  const double width_m = s.view.plot_px.width * s.view.m_per_px;
  const double height_m = s.view.plot_px.height * s.view.m_per_px;
  std::ostringstream sub;
  sub << s.map_points_total << " map points, " << s.trajectory.size() << " poses, path "
      << formatNumber(s.path_length_m, 1) << " m, " << s.loop_edges.size()
      << (s.loop_edges.size() == 1 ? " loop closure" : " loop closures")
      << " | top-down orthographic view, " << formatNumber(width_m, 0) << " x "
      << formatNumber(height_m, 0) << " m";
  drawText(img,
           sub.str(),
           {static_cast<int>(l.margin_px), static_cast<int>(72 * k)},
           0.55 * k,
           faint,
           thin);

  // Colour bar on the right.
  if (params.draw_colour_bar) {
    const int bar_w = static_cast<int>(26 * k);
    const int bar_x = W - static_cast<int>(l.right_band_px) + static_cast<int>(18 * k);
    const int bar_top = static_cast<int>(s.view.plot_px.y + 40 * k);
    const int bar_h = static_cast<int>(std::min(s.view.plot_px.height * 0.6, 520.0 * k));
    drawText(img,
             s.value_label,
             {bar_x, bar_top - static_cast<int>(14 * k)},
             0.6 * k,
             ink,
             thin);
    for (int row = 0; row < bar_h; ++row) {
      const int idx = static_cast<int>(
          std::lround(255.0 * (bar_h - 1 - row) / std::max(1, bar_h - 1)));
      cv::line(img,
               {bar_x, bar_top + row},
               {bar_x + bar_w - 1, bar_top + row},
               cv::Scalar(s.lut_bgr[idx][0], s.lut_bgr[idx][1], s.lut_bgr[idx][2]),
               1);
    }
    cv::rectangle(
        img, {bar_x - 1, bar_top - 1}, {bar_x + bar_w, bar_top + bar_h}, ink, 1);
    const double range = s.value_high - s.value_low;
    const int decimals = range >= 20.0 ? 0 : (range >= 2.0 ? 1 : 2);
    const int ticks = 5;
    for (int t = 0; t < ticks; ++t) {
      const double f = static_cast<double>(t) / (ticks - 1);
      const int y = bar_top + static_cast<int>(std::lround((1.0 - f) * (bar_h - 1)));
      cv::line(img,
               {bar_x + bar_w, y},
               {bar_x + bar_w + static_cast<int>(6 * k), y},
               ink,
               thin);
      drawText(img,
               formatNumber(s.value_low + f * range, decimals),
               {bar_x + bar_w + static_cast<int>(10 * k), y + static_cast<int>(6 * k)},
               0.55 * k,
               ink,
               thin);
    }
  }

  // Bottom band: scale bar, line legend, backend tag.
  if (params.draw_scale_bar) {
    const int base_y = H - static_cast<int>(26 * k);
    int x = static_cast<int>(l.margin_px);
    const double bar_m = niceLength(0.2 * width_m);
    const int bar_px = static_cast<int>(std::lround(bar_m / s.view.m_per_px));
    const int tick = static_cast<int>(7 * k);
    const int bar_thick = std::max(2, static_cast<int>(std::lround(3 * k)));
    cv::line(img, {x, base_y}, {x + bar_px, base_y}, ink, bar_thick);
    cv::line(img, {x, base_y - tick}, {x, base_y + tick}, ink, thin + 1);
    cv::line(
        img, {x + bar_px, base_y - tick}, {x + bar_px, base_y + tick}, ink, thin + 1);
    const std::string bar_text =
        formatNumber(bar_m, bar_m >= 1.0 ? 0 : (bar_m >= 0.1 ? 1 : 2)) + " m";
    drawText(img,
             bar_text,
             {x + bar_px / 2 - textWidth(bar_text, 0.6 * k, thin) / 2,
              base_y - static_cast<int>(12 * k)},
             0.6 * k,
             ink,
             thin);
    x += bar_px + static_cast<int>(40 * k);

    const double fs = 0.55 * k;
    const int sample = static_cast<int>(34 * k);
    const int text_y = base_y + static_cast<int>(6 * k);
    auto legend_line = [&](const RgbColour& c, float width, const std::string& text) {
      cv::line(img,
               {x, base_y},
               {x + sample, base_y},
               toBgr(c),
               std::max(1, static_cast<int>(std::lround(width))),
               cv::LINE_AA);
      x += sample + static_cast<int>(8 * k);
      x += drawText(img, text, {x, text_y}, fs, ink, thin) + static_cast<int>(26 * k);
    };
    auto legend_marker = [&](bool square, const RgbColour& c, const std::string& text) {
      const double r = params.marker_size_px;
      const Eigen::Vector2d centre(x + r, base_y);
      std::vector<cv::Point> pts;
      const int sides = square ? 4 : 40;
      for (int i = 0; i < sides; ++i) {
        const double a = (square ? M_PI / 4.0 : 0.0) + 2.0 * M_PI * i / sides;
        const double rr = square ? r * std::sqrt(2.0) : r;
        pts.push_back(
            fixedPoint({centre.x() + rr * std::cos(a), centre.y() + rr * std::sin(a)}));
      }
      cv::fillPoly(
          img, std::vector<std::vector<cv::Point>>{pts}, toBgr(c), cv::LINE_AA, kShift);
      cv::polylines(img, pts, true, ink, 1, cv::LINE_AA, kShift);
      x += static_cast<int>(2 * r + 8 * k);
      x += drawText(img, text, {x, text_y}, fs, ink, thin) + static_cast<int>(26 * k);
    };
    if (!s.trajectory.empty())
      legend_line(params.trajectory_colour, params.trajectory_width_px, "trajectory");
    if (!s.ground_truth.empty())
      legend_line(
          params.ground_truth_colour, params.ground_truth_width_px, "ground truth");
    if (!s.loop_edges.empty())
      legend_line(params.loop_edge_colour, params.loop_edge_width_px, "loop closure");
    if (params.draw_start_end_markers && !s.trajectory.empty()) {
      legend_marker(false, kStartColour, "start");
      legend_marker(true, kEndColour, "end");
    }
    const std::string tag = "rendered by " + backend;
    drawText(img,
             tag,
             {W - static_cast<int>(l.margin_px) - textWidth(tag, 0.45 * k, thin), text_y},
             0.45 * k,
             faint,
             thin);
  }
}

/// Write \a img to \a path through a temporary file in the same folder and a rename.
bool
writePngAtomically(const cv::Mat& img, const std::string& path, std::string* why)
{
  static std::atomic<int> counter{0};
  const std::filesystem::path target(path);
  const std::filesystem::path tmp =
      target.parent_path() /
      ("." + target.filename().string() + ".tmp-" + std::to_string(::getpid()) + "-" +
       std::to_string(counter++) + ".png");
  bool written = false;
  try {
    written = cv::imwrite(tmp.string(), img);
  } catch (const cv::Exception& e) {
    *why = "cannot write '" + tmp.string() + "': " + e.what();
  }
  if (!written) {
    if (why->empty())
      *why = "cannot write '" + tmp.string() + "' (missing folder or no permission?)";
    std::error_code ignored;
    std::filesystem::remove(tmp, ignored);
    return false;
  }
  std::error_code ec;
  std::filesystem::rename(tmp, target, ec);
  if (ec) {
    *why = "cannot rename '" + tmp.string() + "' to '" + path + "': " + ec.message();
    std::filesystem::remove(tmp, ec);
    return false;
  }
  return true;
}

// ---------------------------------------------------------------------------
// Child processes: a private Xvfb and the VTK render.
// ---------------------------------------------------------------------------

/// Full path of an executable: \a name itself if it contains '/', else searched in PATH.
std::string
findExecutable(const std::string& name)
{
  if (name.find('/') != std::string::npos)
    return ::access(name.c_str(), X_OK) == 0 ? name : std::string();
  const char* path_env = std::getenv("PATH");
  std::stringstream dirs(path_env ? path_env : "/usr/local/bin:/usr/bin:/bin");
  std::string dir;
  while (std::getline(dirs, dir, ':')) {
    const std::string candidate = (dir.empty() ? std::string(".") : dir) + "/" + name;
    if (::access(candidate.c_str(), X_OK) == 0)
      return candidate;
  }
  return {};
}

/// waitpid with a deadline; SIGKILL when it passes. Returns the wait status, or -1.
int
reapChild(pid_t pid, double grace_s)
{
  const auto start = Clock::now();
  int status = 0;
  while (true) {
    const pid_t r = ::waitpid(pid, &status, WNOHANG);
    if (r == pid)
      return status;
    if (r < 0 && errno != EINTR)
      return -1; // ECHILD: already reaped (e.g. SIGCHLD ignored)
    if (secondsSince(start) > grace_s) {
      ::kill(pid, SIGKILL);
      while (::waitpid(pid, &status, 0) < 0)
        if (errno != EINTR)
          return -1;
      return status;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
}

std::string
describeStatus(int status)
{
  if (status < 0)
    return "unknown status";
  if (WIFEXITED(status))
    return "exit code " + std::to_string(WEXITSTATUS(status));
  if (WIFSIGNALED(status))
    return std::string("signal ") + std::to_string(WTERMSIG(status)) + " (" +
           ::strsignal(WTERMSIG(status)) + ")";
  return "status " + std::to_string(status);
}

/// A private Xvfb server, stopped (SIGTERM, then SIGKILL) and reaped on destruction.
class PrivateXServer
{
public:
  PrivateXServer() = default;
  PrivateXServer(const PrivateXServer&) = delete;
  PrivateXServer& operator=(const PrivateXServer&) = delete;
  ~PrivateXServer() { stop(); }

  /// Start `Xvfb -displayfd` and wait until it reports its display (it is then ready).
  bool start(const std::string& executable,
             int width_px,
             int height_px,
             double timeout_s,
             std::string* why)
  {
    const std::string exe = findExecutable(executable);
    if (exe.empty()) {
      *why = "'" + executable + "' not found (install the xvfb package)";
      return false;
    }
    int fds[2];
    if (::pipe2(fds, O_CLOEXEC) != 0) {
      *why = std::string("pipe: ") + std::strerror(errno);
      return false;
    }
    constexpr int kChildFd = 3;
    const std::string screen = std::to_string(std::max(width_px, 640)) + "x" +
                               std::to_string(std::max(height_px, 480)) + "x24";
    std::vector<std::string> args = {exe,
                                     "-displayfd",
                                     std::to_string(kChildFd),
                                     "-screen",
                                     "0",
                                     screen,
                                     "-nolisten",
                                     "tcp"};
    std::vector<char*> argv;
    for (auto& a : args)
      argv.push_back(a.data());
    argv.push_back(nullptr);

    const pid_t pid = ::fork();
    if (pid < 0) {
      *why = std::string("fork: ") + std::strerror(errno);
      ::close(fds[0]);
      ::close(fds[1]);
      return false;
    }
    if (pid == 0) {
      // Child: async-signal-safe calls only, then exec.
      ::prctl(PR_SET_PDEATHSIG, SIGKILL); // never outlive the tool
      const int devnull = ::open("/dev/null", O_RDWR);
      if (devnull >= 0) {
        ::dup2(devnull, 0);
        ::dup2(devnull, 1);
        ::dup2(devnull, 2);
      }
      if (fds[1] == kChildFd)
        ::fcntl(kChildFd, F_SETFD, 0);
      else
        ::dup2(fds[1], kChildFd);
      ::execv(exe.c_str(), argv.data());
      ::_exit(127);
    }
    pid_ = pid;
    ::close(fds[1]);

    // The display number arrives as "N\n" once the server accepts clients.
    std::string text;
    const auto start = Clock::now();
    bool eof = false;
    while (text.find('\n') == std::string::npos && !eof) {
      const double left_s = timeout_s - secondsSince(start);
      if (left_s <= 0.0)
        break;
      pollfd pfd{fds[0], POLLIN, 0};
      const int r = ::poll(&pfd, 1, static_cast<int>(std::ceil(left_s * 1000.0)));
      if (r < 0 && errno == EINTR)
        continue;
      if (r <= 0)
        break;
      char buf[64];
      const ssize_t n = ::read(fds[0], buf, sizeof(buf));
      if (n < 0 && errno == EINTR)
        continue;
      if (n <= 0)
        eof = true;
      else
        text.append(buf, static_cast<std::size_t>(n));
    }
    ::close(fds[0]);
    if (text.find('\n') == std::string::npos) {
      if (eof) {
        const int status = reapChild(pid_, 1.0);
        pid_ = -1;
        *why = "Xvfb exited (" + describeStatus(status) + ") before reporting a display";
      } else {
        *why =
            "Xvfb did not report a display within " + formatNumber(timeout_s, 1) + " s";
        stop();
      }
      return false;
    }
    display_ = ":" + text.substr(0, text.find('\n'));
    return true;
  }

  void stop()
  {
    if (pid_ <= 0)
      return;
    ::kill(pid_, SIGTERM);
    reapChild(pid_, 3.0);
    pid_ = -1;
  }

  const std::string& display() const { return display_; }

  pid_t pid() const { return pid_; }

private:
  pid_t pid_ = -1;
  std::string display_;
};

vtkSmartPointer<vtkActor>
makeActor(vtkPolyData* data, const RgbColour& colour, float width_px, bool direct_colours)
{
  auto mapper = vtkSmartPointer<vtkPolyDataMapper>::New();
  mapper->SetInputData(data);
  if (direct_colours) {
    mapper->SetColorModeToDirectScalars();
    mapper->SetScalarModeToUsePointData();
    mapper->ScalarVisibilityOn();
  } else
    mapper->ScalarVisibilityOff();
  auto actor = vtkSmartPointer<vtkActor>::New();
  actor->SetMapper(mapper);
  vtkProperty* prop = actor->GetProperty();
  prop->LightingOff(); // exact colours, as in the legend
  prop->SetColor(colour.r / 255.0, colour.g / 255.0, colour.b / 255.0);
  prop->SetPointSize(width_px);
  prop->SetLineWidth(width_px);
  return actor;
}

/// Polyline(s) at height \a z_m; \a segments: consecutive pairs, else one polyline.
vtkSmartPointer<vtkPolyData>
makeLines(const std::vector<Eigen::Vector3d>& pts, double z_m, bool segments, bool closed)
{
  auto points = vtkSmartPointer<vtkPoints>::New();
  auto lines = vtkSmartPointer<vtkCellArray>::New();
  for (const auto& p : pts)
    points->InsertNextPoint(p.x(), p.y(), z_m);
  if (segments) {
    for (vtkIdType i = 0; i + 1 < static_cast<vtkIdType>(pts.size()); i += 2) {
      const vtkIdType ids[2] = {i, i + 1};
      lines->InsertNextCell(2, ids);
    }
  } else if (pts.size() >= 2) {
    lines->InsertNextCell(static_cast<vtkIdType>(pts.size() + (closed ? 1 : 0)));
    for (vtkIdType i = 0; i < static_cast<vtkIdType>(pts.size()); ++i)
      lines->InsertCellPoint(i);
    if (closed)
      lines->InsertCellPoint(0);
  }
  auto data = vtkSmartPointer<vtkPolyData>::New();
  data->SetPoints(points);
  data->SetLines(lines);
  return data;
}

void
addMarker(vtkRenderer* renderer,
          const Eigen::Vector3d& centre,
          double radius_m,
          bool square,
          const RgbColour& fill,
          double z_m,
          float outline_px)
{
  std::vector<Eigen::Vector3d> ring;
  for (const auto& q : markerPolygon(centre, radius_m, square))
    ring.emplace_back(q.x(), q.y(), 0.0);
  auto polygon = makeLines(ring, z_m, false, false);
  auto polys = vtkSmartPointer<vtkCellArray>::New();
  polys->InsertNextCell(static_cast<vtkIdType>(ring.size()));
  for (vtkIdType i = 0; i < static_cast<vtkIdType>(ring.size()); ++i)
    polys->InsertCellPoint(i);
  auto disc = vtkSmartPointer<vtkPolyData>::New();
  disc->SetPoints(polygon->GetPoints());
  disc->SetPolys(polys);
  renderer->AddActor(makeActor(disc, fill, 1.0f, false));
  renderer->AddActor(makeActor(
      makeLines(ring, z_m + 0.5, false, true), kMarkerOutline, outline_px, false));
}

/// Render the scene (points, lines, markers; no overlays) with VTK offscreen on the X
/// display \a display. Fills \a bgr. Runs in the forked child.
bool
renderSceneVtk(const Scene& s,
               const MapRenderParams& params,
               const std::string& display,
               cv::Mat* bgr,
               std::string* why)
{
  ::setenv("DISPLAY", display.c_str(), 1); // the child is single-threaded
  Display* x_display = XOpenDisplay(display.c_str());
  if (!x_display) {
    *why = "cannot open X display '" + display + "'";
    return false;
  }
  int opcode = 0, event = 0, error = 0;
  if (!XQueryExtension(x_display, "GLX", &opcode, &event, &error)) {
    XCloseDisplay(x_display);
    *why = "X display '" + display + "' has no GLX extension";
    return false;
  }

  bool ok = true;
  {
    std::string vtk_errors;
    auto on_error = vtkSmartPointer<vtkCallbackCommand>::New();
    on_error->SetClientData(&vtk_errors);
    on_error->SetCallback([](vtkObject*, unsigned long, void* client, void* call) {
      auto* text = static_cast<std::string*>(client);
      *text += call ? static_cast<const char*>(call) : "VTK error";
      *text += "; ";
    });

    const TopDownView& v = s.view;
    auto window = vtkSmartPointer<vtkRenderWindow>::New();
    window->AddObserver(vtkCommand::ErrorEvent, on_error);
    window->SetDisplayId(x_display);
    window->SetOffScreenRendering(1);
    window->SetMultiSamples(8); // smooth lines; line centres keep their exact colour
    window->SetSize(v.width_px, v.height_px);
    auto renderer = vtkSmartPointer<vtkRenderer>::New();
    renderer->AddObserver(vtkCommand::ErrorEvent, on_error);
    renderer->SetBackground(params.background.r / 255.0,
                            params.background.g / 255.0,
                            params.background.b / 255.0);
    window->AddRenderer(renderer);

    // Map points: one poly-vertex cell, direct RGB colours.
    if (!s.points.empty()) {
      auto points = vtkSmartPointer<vtkPoints>::New();
      points->SetDataTypeToFloat();
      points->SetNumberOfPoints(static_cast<vtkIdType>(s.points.size()));
      auto colours = vtkSmartPointer<vtkUnsignedCharArray>::New();
      colours->SetNumberOfComponents(3);
      colours->SetNumberOfTuples(static_cast<vtkIdType>(s.points.size()));
      auto verts = vtkSmartPointer<vtkCellArray>::New();
      verts->InsertNextCell(static_cast<vtkIdType>(s.points.size()));
      for (std::size_t i = 0; i < s.points.size(); ++i) {
        const auto id = static_cast<vtkIdType>(i);
        points->SetPoint(id, s.points[i].x(), s.points[i].y(), s.points[i].z());
        const cv::Vec3b& c = s.point_bgr[i];
        const unsigned char rgb[3] = {c[2], c[1], c[0]};
        colours->SetTypedTuple(id, rgb);
        verts->InsertCellPoint(id);
      }
      auto cloud = vtkSmartPointer<vtkPolyData>::New();
      cloud->SetPoints(points);
      cloud->SetVerts(verts);
      cloud->GetPointData()->SetScalars(colours);
      renderer->AddActor(makeActor(cloud, RgbColour{}, params.point_size_px, true));
    }

    // Lines and markers float above the map, in drawing order.
    const double z = s.z_top_m;
    if (s.ground_truth.size() >= 2)
      renderer->AddActor(makeActor(makeLines(s.ground_truth, z + 1.0, false, false),
                                   params.ground_truth_colour,
                                   params.ground_truth_width_px,
                                   false));
    if (s.trajectory.size() >= 2)
      renderer->AddActor(makeActor(makeLines(s.trajectory, z + 2.0, false, false),
                                   params.trajectory_colour,
                                   params.trajectory_width_px,
                                   false));
    if (!s.loop_edges.empty()) {
      std::vector<Eigen::Vector3d> ends;
      for (const auto& e : s.loop_edges)
        ends.push_back(e.first), ends.push_back(e.second);
      renderer->AddActor(makeActor(makeLines(ends, z + 3.0, true, false),
                                   params.loop_edge_colour,
                                   params.loop_edge_width_px,
                                   false));
    }
    if (params.draw_start_end_markers && !s.trajectory.empty()) {
      const double r_m = params.marker_size_px * v.m_per_px;
      const auto outline = static_cast<float>(std::max(1.0, 2.0 * s.layout.scale));
      addMarker(renderer, s.trajectory.back(), r_m, true, kEndColour, z + 4.0, outline);
      addMarker(
          renderer, s.trajectory.front(), r_m, false, kStartColour, z + 6.0, outline);
    }

    // Orthographic camera looking down -z, north (+y) up, fitted by prepareScene().
    vtkCamera* camera = renderer->GetActiveCamera();
    const double cam_z = z + 20.0;
    camera->ParallelProjectionOn();
    camera->SetFocalPoint(v.cam_x_m, v.cam_y_m, s.z_min_m);
    camera->SetPosition(v.cam_x_m, v.cam_y_m, cam_z);
    camera->SetViewUp(0.0, 1.0, 0.0);
    camera->SetParallelScale(0.5 * v.height_px * v.m_per_px);
    camera->SetClippingRange(0.1, cam_z - s.z_min_m + 1.0);

    window->Render();
    auto grab = vtkSmartPointer<vtkWindowToImageFilter>::New();
    grab->SetInput(window);
    grab->SetInputBufferTypeToRGB();
    grab->ReadFrontBufferOff();
    grab->Update();
    vtkImageData* image = grab->GetOutput();
    int dims[3] = {0, 0, 0};
    image->GetDimensions(dims);
    auto* scalars = image->GetPointData() ? image->GetPointData()->GetScalars() : nullptr;
    if (!vtk_errors.empty()) {
      *why = "VTK: " + vtk_errors;
      ok = false;
    } else if (dims[0] != v.width_px || dims[1] != v.height_px || !scalars ||
               scalars->GetNumberOfComponents() != 3) {
      *why = "VTK returned a " + std::to_string(dims[0]) + " x " +
             std::to_string(dims[1]) + " image instead of " + std::to_string(v.width_px) +
             " x " + std::to_string(v.height_px);
      ok = false;
    } else {
      // VTK rows run bottom-up, RGB; OpenCV top-down, BGR.
      const auto* rgb = static_cast<const unsigned char*>(image->GetScalarPointer());
      *bgr = cv::Mat(v.height_px, v.width_px, CV_8UC3);
      for (int row = 0; row < v.height_px; ++row) {
        const unsigned char* src =
            rgb + 3 * static_cast<std::size_t>(v.width_px) *
                      static_cast<std::size_t>(v.height_px - 1 - row);
        auto* dst = bgr->ptr<cv::Vec3b>(row);
        for (int col = 0; col < v.width_px; ++col)
          dst[col] = cv::Vec3b(src[3 * col + 2], src[3 * col + 1], src[3 * col]);
      }
    }
    window->Finalize();
  }
  XCloseDisplay(x_display);
  return ok;
}

bool
writeAll(int fd, const void* data, std::size_t size)
{
  const auto* p = static_cast<const char*>(data);
  while (size > 0) {
    const ssize_t n = ::write(fd, p, size);
    if (n < 0 && errno == EINTR)
      continue;
    if (n <= 0)
      return false;
    p += n;
    size -= static_cast<std::size_t>(n);
  }
  return true;
}

/// Run renderSceneVtk() in a forked child, so that an abort(), exit() or crash inside
/// VTK, Mesa or Xlib (they do all three on a broken display) only fails this call.
/// The child sends [int32 ok][int32 n][n bytes message][W*H*3 BGR pixels if ok].
bool
renderSceneVtkIsolated(const Scene& s,
                       const MapRenderParams& params,
                       const std::string& display,
                       cv::Mat* bgr,
                       std::string* why)
{
  int data_pipe[2], err_pipe[2];
  if (::pipe2(data_pipe, O_CLOEXEC) != 0) {
    *why = std::string("pipe: ") + std::strerror(errno);
    return false;
  }
  if (::pipe2(err_pipe, O_CLOEXEC) != 0) {
    *why = std::string("pipe: ") + std::strerror(errno);
    ::close(data_pipe[0]);
    ::close(data_pipe[1]);
    return false;
  }
  std::fflush(nullptr);
  const pid_t pid = ::fork();
  if (pid < 0) {
    *why = std::string("fork: ") + std::strerror(errno);
    for (int fd : {data_pipe[0], data_pipe[1], err_pipe[0], err_pipe[1]})
      ::close(fd);
    return false;
  }
  if (pid == 0) {
    ::prctl(PR_SET_PDEATHSIG, SIGKILL);
    ::close(data_pipe[0]);
    ::close(err_pipe[0]);
    ::dup2(err_pipe[1], 2); // VTK, Mesa and Xlib complain on stderr
    std::int32_t ok = 0;
    std::string message;
    cv::Mat image;
    try {
      ok = renderSceneVtk(s, params, display, &image, &message) ? 1 : 0;
    } catch (const std::exception& e) {
      message = e.what();
    } catch (...) {
      message = "unknown exception";
    }
    message = message.substr(0, 4000);
    const auto n = static_cast<std::int32_t>(message.size());
    bool sent = writeAll(data_pipe[1], &ok, sizeof(ok)) &&
                writeAll(data_pipe[1], &n, sizeof(n)) &&
                writeAll(data_pipe[1], message.data(), message.size());
    if (sent && ok)
      sent = writeAll(data_pipe[1], image.data, image.total() * image.elemSize());
    ::_exit(sent ? 0 : 1); // no atexit handlers, no flushing of the parent's buffers
  }
  ::close(data_pipe[1]);
  ::close(err_pipe[1]);

  // Read both pipes until the data pipe closes or the deadline passes.
  std::string data, errors;
  const auto start = Clock::now();
  bool data_open = true, err_open = true, timed_out = false;
  while (data_open) {
    const double left_s = params.vtk_render_timeout_s - secondsSince(start);
    if (left_s <= 0.0) {
      timed_out = true;
      break;
    }
    pollfd pfds[2] = {{data_pipe[0], POLLIN, 0},
                      {err_open ? err_pipe[0] : -1, POLLIN, 0}};
    const int r =
        ::poll(pfds, 2, static_cast<int>(std::min(1000.0, std::ceil(left_s * 1000.0))));
    if (r < 0 && errno != EINTR)
      break;
    char buf[1 << 16];
    if (pfds[0].revents) {
      const ssize_t n = ::read(data_pipe[0], buf, sizeof(buf));
      if (n > 0)
        data.append(buf, static_cast<std::size_t>(n));
      else if (n == 0 || errno != EINTR)
        data_open = false;
    }
    if (err_open && pfds[1].revents) {
      const ssize_t n = ::read(err_pipe[0], buf, sizeof(buf));
      if (n > 0) {
        errors.append(buf, static_cast<std::size_t>(n));
        if (errors.size() > 8192)
          errors.erase(0, errors.size() - 8192);
      } else if (n == 0 || errno != EINTR)
        err_open = false;
    }
  }
  ::close(data_pipe[0]);
  ::close(err_pipe[0]);
  if (timed_out)
    ::kill(pid, SIGKILL);
  const int status = reapChild(pid, 5.0);

  // A short excerpt of what the child printed, for the message.
  auto stderr_tail = [&errors]() {
    std::string t;
    for (std::size_t i = 0; i < errors.size(); ++i) { // drop ANSI colour codes
      if (errors[i] == '\x1b' && i + 1 < errors.size() && errors[i + 1] == '[') {
        i += 2;
        while (i < errors.size() && !std::isalpha(static_cast<unsigned char>(errors[i])))
          ++i;
      } else
        t += errors[i];
    }
    while (!t.empty() && std::isspace(static_cast<unsigned char>(t.back())))
      t.pop_back();
    if (t.size() > 400)
      t = "..." + t.substr(t.size() - 400);
    for (char& c : t)
      if (c == '\n')
        c = ' ';
    return t.empty() ? std::string() : " [stderr: " + t + "]";
  };
  if (timed_out) {
    *why = "VTK render did not finish within " +
           formatNumber(params.vtk_render_timeout_s, 0) + " s" + stderr_tail();
    return false;
  }
  std::int32_t ok = 0, n = 0;
  if (data.size() < 2 * sizeof(std::int32_t)) {
    *why = "VTK render process died (" + describeStatus(status) + ")" + stderr_tail();
    return false;
  }
  std::memcpy(&ok, data.data(), sizeof(ok));
  std::memcpy(&n, data.data() + sizeof(ok), sizeof(n));
  const std::size_t header = 2 * sizeof(std::int32_t);
  if (n < 0 || data.size() < header + static_cast<std::size_t>(n)) {
    *why = "VTK render process sent a truncated reply (" + describeStatus(status) + ")";
    return false;
  }
  const std::string message = data.substr(header, static_cast<std::size_t>(n));
  if (!ok) {
    *why = message + stderr_tail();
    return false;
  }
  const std::size_t pixels =
      3 * static_cast<std::size_t>(s.view.width_px) * s.view.height_px;
  if (data.size() != header + n + pixels) {
    *why = "VTK render process sent " + std::to_string(data.size() - header - n) +
           " pixel bytes instead of " + std::to_string(pixels);
    return false;
  }
  cv::Mat(s.view.height_px,
          s.view.width_px,
          CV_8UC3,
          const_cast<char*>(data.data() + header + n))
      .copyTo(*bgr);
  return true;
}

} // namespace

bool
MapRenderParams::isValid(std::string* why) const
{
  auto fail = [why](const std::string& text) {
    if (why)
      *why = text;
    return false;
  };
  if (width_px < 64 || width_px > 16384)
    return fail("width_px must be in [64, 16384], got " + std::to_string(width_px));
  if (height_px < 64 || height_px > 16384)
    return fail("height_px must be in [64, 16384], got " + std::to_string(height_px));
  if (!(point_size_px >= 1.0f && point_size_px <= 64.0f))
    return fail("point_size_px must be in [1, 64], got " + std::to_string(point_size_px));
  if (!(colour_low_percentile >= 0.0 && colour_low_percentile < colour_high_percentile &&
        colour_high_percentile <= 100.0))
    return fail("colour percentiles must satisfy 0 <= low < high <= 100, got " +
                std::to_string(colour_low_percentile) + ", " +
                std::to_string(colour_high_percentile));
  for (const auto& [name, w] :
       {std::pair<const char*, float>{"trajectory_width_px", trajectory_width_px},
        {"ground_truth_width_px", ground_truth_width_px},
        {"loop_edge_width_px", loop_edge_width_px},
        {"marker_size_px", marker_size_px}})
    if (!(w >= 1.0f && w <= 64.0f))
      return fail(std::string(name) + " must be in [1, 64], got " + std::to_string(w));
  if (!(xvfb_startup_timeout_s > 0.0) || !std::isfinite(xvfb_startup_timeout_s))
    return fail("xvfb_startup_timeout_s must be > 0, got " +
                std::to_string(xvfb_startup_timeout_s));
  if (!(vtk_render_timeout_s > 0.0) || !std::isfinite(vtk_render_timeout_s))
    return fail("vtk_render_timeout_s must be > 0, got " +
                std::to_string(vtk_render_timeout_s));
  if (allow_private_xvfb && xvfb_executable.empty())
    return fail("xvfb_executable must not be empty when allow_private_xvfb is set");
  if (force_software_fallback && !allow_software_fallback)
    return fail("force_software_fallback needs allow_software_fallback");
  return true;
}

MapRenderResult
renderMapTopDown(const MapRenderInput& input,
                 const MapRenderParams& params,
                 const std::string& png_path)
{
  std::string why;
  if (!params.isValid(&why))
    throw std::invalid_argument("renderMapTopDown: invalid MapRenderParams: " + why);
  if (!input.map)
    throw std::invalid_argument("renderMapTopDown: input.map is null");
  if (png_path.empty())
    throw std::invalid_argument("renderMapTopDown: png_path is empty");

  const auto start = Clock::now();
  MapRenderResult result;
  auto finish = [&](MapRenderResult& r) -> MapRenderResult {
    r.render_time_ms = 1000.0 * secondsSince(start);
    return r;
  };
  try {
    const Scene scene = prepareScene(input, params);
    cv::Mat image;
    std::vector<std::string> failures;

    if (params.force_software_fallback)
      failures.push_back("VTK skipped (force_software_fallback)");
    else {
      // 1. The user's display, if any.
      const char* env_display = std::getenv("DISPLAY");
      if (env_display && *env_display) {
        std::string reason;
        if (renderSceneVtkIsolated(scene, params, env_display, &image, &reason))
          result.backend = "vtk-x";
        else
          failures.push_back("DISPLAY '" + std::string(env_display) + "': " + reason);
      } else
        failures.push_back("DISPLAY not set");
      // 2. A private Xvfb, stopped before we leave this block, whatever happens.
      if (result.backend.empty() && params.allow_private_xvfb) {
        PrivateXServer xvfb;
        std::string reason;
        if (xvfb.start(params.xvfb_executable,
                       params.width_px,
                       params.height_px,
                       params.xvfb_startup_timeout_s,
                       &reason)) {
          result.xvfb_pid = xvfb.pid();
          if (renderSceneVtkIsolated(scene, params, xvfb.display(), &image, &reason))
            result.backend = "vtk-xvfb";
          else
            failures.push_back("Xvfb " + xvfb.display() + ": " + reason);
        } else
          failures.push_back("Xvfb: " + reason);
        xvfb.stop();
      }
    }

    std::string failure_text;
    for (const auto& f : failures)
      failure_text += (failure_text.empty() ? "" : "; ") + f;
    if (result.backend.empty()) {
      if (!params.allow_software_fallback) {
        result.message = "VTK could not render: " + failure_text;
        return finish(result);
      }
      image = rasterizeScene(scene, params);
      result.backend = "opencv-fallback";
      result.message = "software rasterization: " + failure_text;
    } else if (result.backend == "vtk-xvfb")
      result.message = "private Xvfb used: " + failure_text;
    drawOverlays(image, scene, params, input.title, result.backend);

    std::string write_error;
    if (!writePngAtomically(image, png_path, &write_error)) {
      result.message =
          write_error + (result.message.empty() ? "" : " (" + result.message + ")");
      return finish(result);
    }
    result.success = true;
  } catch (const std::exception& e) {
    result.success = false;
    result.message = std::string("rendering failed: ") + e.what();
  }
  return finish(result);
}

} // namespace pcl_rast_tools
