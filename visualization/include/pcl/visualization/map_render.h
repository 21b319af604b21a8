#pragma once
/// \file map_render.h
/// \ingroup visualization
/// \brief Top-down picture of a SLAM result (merged map, trajectory, loop closures)
/// written as a PNG, on machines with or without a display.
///
/// Plain data in, file out: fill a MapRenderInput and call renderMapTopDown()
/// (pcl_rast_slam does exactly that). The scene is rendered offscreen with VTK; without a usable
/// X display a private Xvfb server is started (and always stopped) for the render,
/// and if VTK still cannot render, the same picture is rasterized with OpenCV.
/// VTK runs in a forked child process, so an abort or an X I/O error inside
/// VTK/Xlib cannot take the calling tool down: it only leads to the fallback.

#include <Eigen/Core>
#include <cstdint>
#include <pcl/point_cloud.h>
#include <pcl/point_types.h>
#include <string>
#include <utility>
#include <vector>

namespace pcl {
namespace rast {

/// \brief An 8-bit RGB colour.
struct RgbColour
{
  std::uint8_t r = 0, g = 0, b = 0;
};

/// \brief Which per-point value drives the map colours.
enum class MapColourBy
{
  kHeight,   ///< z in the world frame [m]
  kIntensity ///< the point's intensity field
};

/// \brief Perceptual colour maps (all from OpenCV's tables).
enum class MapColourMap
{
  kViridis,
  kCividis,
  kInferno
};

/// \brief How the picture looks and how it may be produced.
struct MapRenderParams
{
  int width_px = 1600;        ///< image width [px], 64..16384
  int height_px = 1200;       ///< image height [px], 64..16384
  float point_size_px = 2.0f; ///< map point size [px]
  MapColourBy colour_by = MapColourBy::kHeight;
  MapColourMap colour_map = MapColourMap::kViridis;
  /// Colour range: these percentiles of the values map to the ends of the colour
  /// map, so a few outliers do not wash the map out [%].
  double colour_low_percentile = 2.0;
  double colour_high_percentile = 98.0;
  RgbColour background{255, 255, 255};
  RgbColour trajectory_colour{215, 25, 28}; ///< estimated trajectory (red)
  float trajectory_width_px = 4.0f;
  RgbColour ground_truth_colour{60, 60, 60}; ///< reference trajectory (dark grey)
  float ground_truth_width_px = 2.0f;
  RgbColour loop_edge_colour{255, 0, 220}; ///< accepted loop closures (magenta)
  float loop_edge_width_px = 3.0f;
  bool draw_start_end_markers =
      true;                     ///< green disc at the start, black square at the end
  float marker_size_px = 11.0f; ///< marker radius / half side [px]
  bool draw_colour_bar = true;  ///< colour legend on the right
  bool draw_scale_bar = true;   ///< metric scale bar and line legend at the bottom
  /// If VTK cannot render (no X server, no GLX, crash), rasterize with OpenCV.
  bool allow_software_fallback = true;
  /// Skip VTK and rasterize with OpenCV directly (fast; tests, huge batches).
  bool force_software_fallback = false;
  /// Without a usable DISPLAY, start a private Xvfb for the render.
  bool allow_private_xvfb = true;
  std::string xvfb_executable = "Xvfb"; ///< name (searched in PATH) or path
  double xvfb_startup_timeout_s = 10.0; ///< wait for Xvfb to accept clients [s]
  double vtk_render_timeout_s =
      120.0; ///< the VTK render process is killed after this [s]

  /// \brief Whether every field is in range; \a why (optional) names the first bad one.
  bool isValid(std::string* why = nullptr) const;
};

/// \brief What to draw, all in the world frame [m].
struct MapRenderInput
{
  /// The merged map; must not be null (may be empty).
  const pcl::PointCloud<pcl::PointXYZI>* map = nullptr;
  /// Points of the map the picture stands for, when \a map is a reduced copy of it
  /// (shown in the subtitle); 0: map->size().
  std::size_t map_points_total = 0;
  std::vector<Eigen::Vector3d> trajectory;   ///< estimated positions, in order
  std::vector<Eigen::Vector3d> ground_truth; ///< optional reference positions, in order
  /// Accepted loop closures, each as the positions of its two key-frames.
  std::vector<std::pair<Eigen::Vector3d, Eigen::Vector3d>> loop_edges;
  std::string title; ///< printed at the top (ASCII)
};

/// \brief Outcome of renderMapTopDown().
struct MapRenderResult
{
  bool success = false;
  /// Who drew the picture: "vtk-x" (the user's DISPLAY), "vtk-xvfb" (a private
  /// Xvfb) or "opencv-fallback"; empty if nothing was drawn.
  std::string backend;
  /// Why a fallback was used, or why the render failed.
  std::string message;
  /// Pid of the private Xvfb started for this call (already stopped and reaped),
  /// -1 if none was started.
  int xvfb_pid = -1;
  /// Map points drawn: the top-most of each pixel, which is what a top-down picture
  /// shows there; a map of millions of points reaches the renderer as at most one
  /// point per pixel.
  std::size_t map_points_drawn = 0;
  double render_time_ms = 0.0; ///< wall time of the whole call [ms]
};

/// \brief Render \a input seen from above (orthographic, north up) into the PNG
/// \a png_path: map points coloured by height or intensity with a perceptual colour
/// map, trajectory as a thick polyline, loop closures as lines, start/end markers,
/// title, colour bar, scale bar [m] and legend.
///
/// The PNG is written atomically (temporary file in the same folder, then rename).
/// Never exits or aborts: failures are reported in the result.
/// \param[in] input what to draw (input.map must not be null)
/// \param[in] params look and backend choices (must be valid)
/// \param[in] png_path output file (non-empty)
/// \return success, backend used, message
/// \throws std::invalid_argument on invalid params, a null map or an empty path
MapRenderResult renderMapTopDown(const MapRenderInput& input,
                                 const MapRenderParams& params,
                                 const std::string& png_path);

} // namespace rast
} // namespace pcl
