#pragma once
/// \file range_raster_image.h
/// \brief Rasterization of the paper (Sec. "Rasterization"): a cloud becomes a
/// top-down gray image whose pixel value is the maximum height of the points in that
/// pixel, and every pixel remembers the 3D point behind it so an image keypoint lifts
/// back to 3D exactly. See doc/raster_projection.md.
/// \ingroup features

#include <pcl/pcl_base.h>
#include <pcl/point_cloud.h>
#include <pcl/point_types.h>

#include <Eigen/Core>

#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

namespace pcl {
namespace rast {

/// \brief How 3D points map to raster pixels.
enum class RasterProjection
{
  /// The paper's pinhole model, Eq. (1)-(3): P_c = R (I | t) P_l, u = f X/Z + t_u,
  /// v = f Y/Z + t_v, optical axis = LiDAR z axis, camera 70 m below the sensor.
  kPinhole,
  /// Metric bird's-eye view centred on the sensor: a fixed number of metres per pixel,
  /// row up = +x (forward), column left = +y (left).
  kOrthographic
};

/// \brief The paper's camera (Sec. 10, implementation details): principal point
/// (0, 0), focal length 500, R = I, t = [-25, -25, 70], 750 x 750 pixels.
/// With these values the image covers x, y in about [25, 130] m at z = 0 (see doc).
struct PinholeRasterParams
{
  double focal_px = 500.0;      ///< f [pixels]
  double principal_u_px = 0.0;  ///< t_u [pixels]
  double principal_v_px = 0.0;  ///< t_v [pixels]
  double t_x_m = -25.0;         ///< extrinsic translation t (R = I) [m]
  double t_y_m = -25.0;         ///< extrinsic translation t [m]
  double t_z_m = 70.0;          ///< extrinsic translation t [m]; Z = z + t_z must be > 0
  int width_px = 750;           ///< image columns
  int height_px = 750;          ///< image rows
};

/// \brief Metric bird's-eye view: the square [-half_extent_m, half_extent_m]^2 around
/// the sensor, resolution_m per pixel (defaults: 512 x 512 pixels of 0.2 m).
struct OrthographicRasterParams
{
  double resolution_m = 0.2;   ///< pixel size [m]
  double half_extent_m = 51.2; ///< half side of the covered square [m]
};

/// \brief Parameters of RangeRasterImage.
struct RangeRasterParams
{
  /// Projection; orthographic by default (better matches on KITTI, see the doc).
  RasterProjection projection = RasterProjection::kOrthographic;
  PinholeRasterParams pinhole;
  OrthographicRasterParams orthographic;
  /// Heights mapped to gray levels 1..255: z of the rasterized cloud, i.e. relative to
  /// the sensor (LiDAR frame, or the levelled frame of SACGroundRemoval). Heights
  /// outside the range are clamped; gray 0 means "no point". KITTI's sensor is 1.73 m
  /// above the road, so [-2, 3] m spans road level to 4.7 m above it.
  float min_height_m = -2.0f;
  float max_height_m = 3.0f;

  /// \brief Whether all values are usable; on failure \a why (if not null) says which.
  bool
  isValid(std::string* why = nullptr) const;

  /// \brief Image size in pixels for the chosen projection.
  int
  width() const;
  int
  height() const;
};

/// \brief Continuous pixel coordinates of a 3D point (pixel (c, r) is centred on
/// u = c, v = r, OpenCV's keypoint convention). Returns false when the point is not
/// finite or lies behind the pinhole camera; it does NOT check the image bounds.
/// \ingroup features
bool
projectToRaster(const RangeRasterParams& params, const Eigen::Vector3f& p, Eigen::Vector2f& uv);

/// \brief The inverse of projectToRaster for a known height \a z_m: the 3D point that
/// projects to \a uv and has z = z_m.
/// \ingroup features
Eigen::Vector3f
rasterToPoint(const RangeRasterParams& params, const Eigen::Vector2f& uv, float z_m);

/// \brief Gray level (1..255) of a height under \a params' height range.
inline std::uint8_t
heightToGray(const RangeRasterParams& params, float z_m)
{
  const float s = (z_m - params.min_height_m) / (params.max_height_m - params.min_height_m);
  const float g = 1.0f + 254.0f * (s < 0.0f ? 0.0f : (s > 1.0f ? 1.0f : s));
  return static_cast<std::uint8_t>(g + 0.5f);
}

/// \brief The images of a rasterized cloud, independent of the point type: a top-down
/// max-height image (gray), the max height per pixel and the input index of the highest
/// point per pixel. All three are row-major, width() x height(), row 0 at the top.
///
/// Copies are cheap (the buffers are shared); a later compute on the original does not
/// change the images of a copy. RangeRasterImage<PointT> adds the input cloud.
/// \ingroup features
class RasterGrid
{
public:
  RasterGrid() = default;
  /// \throws std::invalid_argument when !params.isValid().
  explicit RasterGrid(const RangeRasterParams& params) { setParams(params); }
  virtual ~RasterGrid() = default;

  /// \throws std::invalid_argument when !params.isValid().
  void
  setParams(const RangeRasterParams& params);
  const RangeRasterParams&
  getParams() const
  {
    return params_;
  }

  /// \brief Whether the images are computed for the current input and parameters.
  bool
  isComputed() const
  {
    return computed_;
  }

  /// \brief Continuous pixel coordinates of \a p (see projectToRaster); false when
  /// not projectable or outside the image.
  bool
  project(const Eigen::Vector3f& p, Eigen::Vector2f& uv) const;

  /// \brief The pixel (column, row) containing \a p; false when outside the image.
  bool
  projectToPixel(const Eigen::Vector3f& p, int& col, int& row) const;

  /// \brief Input-cloud index of the highest point of pixel (col, row), or -1 when
  /// the pixel is empty, outside the image or nothing is computed.
  int
  pixelIndex(int col, int row) const;

  /// \brief Nearest non-empty pixel to (col, row) within a square of \a radius_px
  /// (Chebyshev rings, nearest Euclidean within the first ring that has one);
  /// returns the input index or -1.
  int
  nearestPixelIndex(int col, int row, int radius_px) const;

  /// \brief Gray level of pixel (col, row): 0 = empty, 1..255 = max height (see
  /// heightToGray); 0 outside the image.
  std::uint8_t
  grayAt(int col, int row) const;
  /// \brief Max height [m] of pixel (col, row); NaN where empty or outside.
  float
  heightAt(int col, int row) const;

  /// \brief The gray image, row-major (null before the first compute). An 8-bit
  /// single-channel image for any image library, e.g.
  /// `cv::Mat(h, w, CV_8UC1, const_cast<std::uint8_t*>(grid.grayData()))`.
  const std::uint8_t*
  grayData() const
  {
    return buffers_ ? buffers_->gray.data() : nullptr;
  }
  /// \brief Max height per pixel [m], row-major; NaN where empty.
  const float*
  heightData() const
  {
    return buffers_ ? buffers_->height.data() : nullptr;
  }
  /// \brief Input index of the max-height point per pixel, row-major; -1 where empty.
  const int*
  indexData() const
  {
    return buffers_ ? buffers_->index.data() : nullptr;
  }

  int
  width() const
  {
    return width_;
  }
  int
  height() const
  {
    return height_;
  }
  /// \brief Number of input points that fell inside the image.
  std::size_t
  numProjectedPoints() const
  {
    return num_projected_;
  }
  /// \brief Number of non-empty pixels.
  std::size_t
  numOccupiedPixels() const
  {
    return num_occupied_;
  }

protected:
  /// \brief Rasterize points whose x, y, z floats start at \a xyz and repeat every
  /// \a stride_bytes (any PCL point type with PCL_ADD_POINT4D). When \a indices is
  /// given only those points are used; the index image holds point indices either way.
  void
  rasterize(const float* xyz,
            std::size_t stride_bytes,
            std::size_t num_points,
            const pcl::Indices* indices);

  /// \brief Forget the images (after a new input or parameters).
  void
  invalidate()
  {
    computed_ = false;
  }

private:
  struct Buffers
  {
    std::vector<std::uint8_t> gray;
    std::vector<float> height;
    std::vector<int> index;
  };

  RangeRasterParams params_;
  int width_ = params_.width();   ///< params_.width(), cached: pixel lookups use it
  int height_ = params_.height(); ///< params_.height(), cached
  std::shared_ptr<Buffers> buffers_;
  std::size_t num_projected_ = 0;
  std::size_t num_occupied_ = 0;
  bool computed_ = false;
};

/// \brief A cloud rasterized to a top-down max-height image, with the index of the
/// highest point of every pixel. The name is the paper's; the image is not a range
/// image but a bird's-eye view (or the paper's pinhole view from 70 m below) whose
/// pixel value is the maximum height of the points in it.
///
/// A pcl::PCLBase: setInputCloud and setIndices as everywhere in PCL (with indices,
/// only those points are rasterized). Instantiated for PCL_RAST_XYZ_POINT_TYPES
/// (pcl/rast/point_types.h); other types with x, y, z work with
/// PCL_NO_PRECOMPILE.
/// \code
/// pcl::rast::RangeRasterImage<pcl::PointXYZ> raster(params);
/// raster.setInputCloud(non_ground);
/// raster.compute();
/// cv::Mat gray(raster.height(), raster.width(), CV_8UC1,
///              const_cast<std::uint8_t*>(raster.grayData()));
/// \endcode
/// \ingroup features
template <typename PointT>
class RangeRasterImage : public pcl::PCLBase<PointT>, public RasterGrid
{
public:
  using Ptr = std::shared_ptr<RangeRasterImage<PointT>>;
  using ConstPtr = std::shared_ptr<const RangeRasterImage<PointT>>;
  using PointCloud = pcl::PointCloud<PointT>;
  using PointCloudConstPtr = typename PointCloud::ConstPtr;

  RangeRasterImage() = default;
  /// \throws std::invalid_argument when !params.isValid().
  explicit RangeRasterImage(const RangeRasterParams& params) : RasterGrid(params) {}

  /// \brief \throws std::invalid_argument when null.
  void
  setInputCloud(const PointCloudConstPtr& cloud) override;

  /// \brief Rasterize the input cloud (one pass over the points). Non-finite points
  /// and points outside the image are skipped.
  /// \throws std::invalid_argument when no input cloud was set.
  void
  compute();

  /// \brief The highest point of pixel (col, row): exactly the input point with that
  /// index. False when the pixel is empty or outside the image.
  bool
  pixelToPoint(int col, int row, PointT& point) const;

protected:
  using pcl::PCLBase<PointT>::input_;
  using pcl::PCLBase<PointT>::indices_;
  using pcl::PCLBase<PointT>::fake_indices_;
};

} // namespace rast
} // namespace pcl

#ifdef PCL_NO_PRECOMPILE
#include <pcl/features/impl/range_raster_image.hpp>
#endif
