/// \file render_overlays.cpp
/// \brief The overlays of a map render, on either backend's image: title, colour bar,
/// scale bar, legend and backend tag.

#include "render_scene.h"

#include <algorithm>
#include <cmath>
#include <opencv2/imgproc.hpp>
#include <sstream>

namespace pcl {
namespace rast {
namespace render_detail {

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

namespace {

/// The colours and line widths of the overlays, for the background.
struct OverlayStyle
{
  double k;         ///< layout scale
  cv::Scalar ink;   ///< text and frames
  cv::Scalar faint; ///< secondary text
  int thin;         ///< thin line width [px]
};

OverlayStyle
overlayStyle(const Scene& s, const MapRenderParams& params)
{
  const double k = s.layout.scale;
  const auto& bg = params.background;
  const bool dark_bg = 0.299 * bg.r + 0.587 * bg.g + 0.114 * bg.b < 128.0;
  return {k,
          dark_bg ? cv::Scalar(235, 235, 235) : cv::Scalar(25, 25, 25),
          dark_bg ? cv::Scalar(150, 150, 150) : cv::Scalar(110, 110, 110),
          std::max(1, static_cast<int>(std::lround(k)))};
}

/// The title band: the title and a line of figures.
void
drawTitle(cv::Mat& img, const Scene& s, const OverlayStyle& st, const std::string& title)
{
  const Layout& l = s.layout;
  const double k = st.k;
  const cv::Scalar& ink = st.ink;
  const cv::Scalar& faint = st.faint;
  const int thin = st.thin;
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
}

/// The colour bar on the right, with its ticks.
void
drawColourBar(cv::Mat& img, const Scene& s, const OverlayStyle& st)
{
  const Layout& l = s.layout;
  const double k = st.k;
  const cv::Scalar& ink = st.ink;
  const int thin = st.thin;
  const int W = img.cols;
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
    const int idx =
        static_cast<int>(std::lround(255.0 * (bar_h - 1 - row) / std::max(1, bar_h - 1)));
    cv::line(img,
             {bar_x, bar_top + row},
             {bar_x + bar_w - 1, bar_top + row},
             cv::Scalar(s.lut_bgr[idx][0], s.lut_bgr[idx][1], s.lut_bgr[idx][2]),
             1);
  }
  cv::rectangle(img, {bar_x - 1, bar_top - 1}, {bar_x + bar_w, bar_top + bar_h}, ink, 1);
  const double range = s.value_high - s.value_low;
  const int decimals = range >= 20.0 ? 0 : (range >= 2.0 ? 1 : 2);
  const int ticks = 5;
  for (int t = 0; t < ticks; ++t) {
    const double f = static_cast<double>(t) / (ticks - 1);
    const int y = bar_top + static_cast<int>(std::lround((1.0 - f) * (bar_h - 1)));
    cv::line(
        img, {bar_x + bar_w, y}, {bar_x + bar_w + static_cast<int>(6 * k), y}, ink, thin);
    drawText(img,
             formatNumber(s.value_low + f * range, decimals),
             {bar_x + bar_w + static_cast<int>(10 * k), y + static_cast<int>(6 * k)},
             0.55 * k,
             ink,
             thin);
  }
}

/// The bottom band: scale bar, line legend, backend tag.
void
drawBottomBand(cv::Mat& img,
               const Scene& s,
               const MapRenderParams& params,
               const OverlayStyle& st,
               const std::string& backend)
{
  const Layout& l = s.layout;
  const double k = st.k;
  const cv::Scalar& ink = st.ink;
  const cv::Scalar& faint = st.faint;
  const int thin = st.thin;
  const int W = img.cols, H = img.rows;
  const double width_m = s.view.plot_px.width * s.view.m_per_px;
  const int base_y = H - static_cast<int>(26 * k);
  int x = static_cast<int>(l.margin_px);
  const double bar_m = niceLength(0.2 * width_m);
  const int bar_px = static_cast<int>(std::lround(bar_m / s.view.m_per_px));
  const int tick = static_cast<int>(7 * k);
  const int bar_thick = std::max(2, static_cast<int>(std::lround(3 * k)));
  cv::line(img, {x, base_y}, {x + bar_px, base_y}, ink, bar_thick);
  cv::line(img, {x, base_y - tick}, {x, base_y + tick}, ink, thin + 1);
  cv::line(img, {x + bar_px, base_y - tick}, {x + bar_px, base_y + tick}, ink, thin + 1);
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
    legend_line(params.ground_truth_colour, params.ground_truth_width_px, "ground truth");
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

} // namespace

void
drawOverlays(cv::Mat& img,
             const Scene& s,
             const MapRenderParams& params,
             const std::string& title,
             const std::string& backend)
{
  const OverlayStyle st = overlayStyle(s, params);
  drawTitle(img, s, st, title);
  if (params.draw_colour_bar)
    drawColourBar(img, s, st);
  if (params.draw_scale_bar)
    drawBottomBand(img, s, params, st, backend);
}

} // namespace render_detail
} // namespace rast
} // namespace pcl
