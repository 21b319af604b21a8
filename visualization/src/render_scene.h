#pragma once
/// \file render_scene.h
/// \brief Internal to the visualization library: the scene both render backends draw
/// (prepared once in the calling process), the OpenCV rasterizer and overlays, the VTK
/// render in a child process, and the child-process helpers.

#include <pcl/visualization/map_render.h>

#include <opencv2/core.hpp>

#include <pcl/common/time.h>
#include <string>
#include <sys/types.h>
#include <utility>
#include <vector>

namespace pcl {
namespace rast {
namespace render_detail {

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

inline const RgbColour kStartColour{40, 180, 60};
inline const RgbColour kEndColour{20, 20, 20};
inline const RgbColour kMarkerOutline{255, 255, 255};

cv::Scalar
toBgr(const RgbColour& c);

/// Sub-pixel bits of OpenCV drawing, and a point in those fixed-point units.
constexpr int kShift = 4;
cv::Point
fixedPoint(const cv::Point2d& p);

/// Vertices of a marker: a disc (many sides) or an axis-aligned square (4 sides).
std::vector<Eigen::Vector2d>
markerPolygon(const Eigen::Vector3d& centre, double radius_m, bool square);

/// Everything to draw, in the world frame, with colours and the view fitted.
Scene
prepareScene(const MapRenderInput& input, const MapRenderParams& params);

/// The scene drawn with OpenCV (the fallback when VTK cannot render).
cv::Mat
rasterizeScene(const Scene& s, const MapRenderParams& params);

/// Title, colour bar, scale bar and legend, on either backend's image.
void
drawOverlays(cv::Mat& img,
             const Scene& s,
             const MapRenderParams& params,
             const std::string& title,
             const std::string& backend);

/// \a value with \a decimals digits after the point.
std::string
formatNumber(double value, int decimals);

/// Write \a img (8-bit) to \a path as a PNG, whole or not at all; false and \a why when
/// not.
bool
writePngAtomically(const cv::Mat& img, const std::string& path, std::string* why);

/// waitpid with a deadline; SIGKILL when it passes. Returns the wait status, or -1.
int
reapChild(pid_t pid, double grace_s);

/// "exit code N", "signal N (name)", ...
std::string
describeStatus(int status);

/// The scene rendered by VTK in a forked child on X display \a display (no overlays).
bool
renderSceneVtkIsolated(const Scene& s,
                       const MapRenderParams& params,
                       const std::string& display,
                       cv::Mat* bgr,
                       std::string* why);

} // namespace render_detail
} // namespace rast
} // namespace pcl
