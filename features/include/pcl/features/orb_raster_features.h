#pragma once
/// \file orb_raster_features.h
/// \brief Feature extraction of the paper (Sec. "Tracking / Feature Extraction"):
/// Gaussian blur, FAST corners with an adaptive threshold, ORB (rBRIEF) descriptors on
/// the rasterized image, every keypoint lifted back to the 3D point behind its pixel.
/// \ingroup features

#include <pcl/features/range_raster_image.h>
#include <pcl/features/raster_feature_types.h>

#include <cstddef>
#include <memory>
#include <string>

namespace pcl {
namespace rast {

/// \brief Parameters of OrbRasterFeatureEstimator. Pixel units refer to the raster.
struct OrbRasterFeatureParams
{
  /// Maximum number of features kept, spread over the grid (round-robin over cells,
  /// strongest first in each cell).
  int max_features = 1000;
  /// Side of the square bucketing cells [pixels] (16 px = 3.2 m at 0.2 m/px).
  int grid_cell_px = 16;
  /// At most this many features per cell.
  int max_per_cell = 4;
  /// Initial FAST threshold [gray levels] (one gray level = 2 cm of height by default).
  int fast_threshold = 10;
  /// The threshold is halved (down to this) while fewer than min_features are found.
  int min_fast_threshold = 5;
  /// Detections below this count trigger a lower FAST threshold.
  int min_features = 300;
  /// Sigma of the Gaussian blur applied before detection [pixels]; 0 disables it.
  double blur_sigma_px = 1.0;
  /// ORB pyramid levels. 1 by default: the raster is metric, scale does not change
  /// between scans, and one level is several times faster.
  int num_levels = 1;
  /// Pyramid scale factor (used only when num_levels > 1).
  double scale_factor = 1.2;
  /// ORB patch size [pixels] (orientation and descriptor window).
  int patch_size_px = 31;
  /// When a keypoint's pixel is empty, the nearest non-empty pixel within this radius
  /// gives its 3D point; keypoints with none are dropped [pixels].
  int lift_search_radius_px = 2;

  /// \brief Whether all values are usable; on failure \a why (if not null) says which.
  bool
  isValid(std::string* why = nullptr) const;
};

/// \brief Summary of OrbRasterFeatureEstimator::compute.
struct OrbRasterFeatureResult
{
  bool success = false;           ///< at least one feature was extracted
  std::size_t num_detected = 0;   ///< FAST/ORB keypoints before bucketing
  std::size_t num_bucketed = 0;   ///< keypoints kept by the grid bucketing
  std::size_t num_features = 0;   ///< features returned (lifted to 3D, with descriptor)
  std::size_t num_unlifted = 0;   ///< keypoints dropped: no 3D point near their pixel
  int fast_threshold = 0;         ///< FAST threshold finally used
  double raster_ms = 0.0;         ///< rasterization time (0 with setInputRaster)
  double detect_ms = 0.0;         ///< blur + FAST + bucketing
  double describe_ms = 0.0;       ///< ORB descriptors + lifting
  std::string message;
};

/// \brief ORB features of a rasterized cloud, lifted to 3D.
///
/// \code
/// pcl::rast::OrbRasterFeatureEstimator orb;
/// orb.setInputCloud(non_ground);   // rasterized internally with getRasterParams()
/// pcl::rast::RasterFeatureSet features;
/// const auto result = orb.compute(features);
/// \endcode
/// Feature x, y, z are the coordinates of the rasterized point, i.e. in the frame of
/// the input cloud; u, v are pixel coordinates in the raster (OpenCV convention).
/// \ingroup features
class OrbRasterFeatureEstimator
{
public:
  using Ptr = std::shared_ptr<OrbRasterFeatureEstimator>;
  using ConstPtr = std::shared_ptr<const OrbRasterFeatureEstimator>;
  using PointCloud = RangeRasterImage::PointCloud;

  OrbRasterFeatureEstimator() = default;

  /// \throws std::invalid_argument when !params.isValid().
  void
  setParams(const OrbRasterFeatureParams& params);
  const OrbRasterFeatureParams&
  getParams() const
  {
    return params_;
  }

  /// \brief Rasterization parameters used with setInputCloud.
  /// \throws std::invalid_argument when !params.isValid().
  void
  setRasterParams(const RangeRasterParams& params);
  const RangeRasterParams&
  getRasterParams() const
  {
    return raster_params_;
  }

  /// \brief The cloud to rasterize (usually the non-ground cloud).
  /// \throws std::invalid_argument when null.
  void
  setInputCloud(const PointCloud::ConstPtr& cloud);

  /// \brief An already computed raster (shared, not copied deeply).
  /// \throws std::invalid_argument when \a raster has not been computed.
  void
  setInputRaster(const RangeRasterImage& raster);

  /// \brief Extract the features.
  /// \param[out] features points (3D + pixel + angle) and their descriptors
  /// \return counts, the FAST threshold used, timings and a message
  /// \throws std::invalid_argument when neither an input cloud nor a raster was set.
  OrbRasterFeatureResult
  compute(RasterFeatureSet& features);

  /// \brief The raster the last compute() used.
  const RangeRasterImage&
  getRaster() const
  {
    return raster_;
  }

private:
  OrbRasterFeatureParams params_;
  RangeRasterParams raster_params_;
  PointCloud::ConstPtr input_;
  RangeRasterImage raster_;
  bool raster_given_ = false;
  cv::Mat padded_, blurred_; ///< work images, reused across calls
};

} // namespace rast
} // namespace pcl
