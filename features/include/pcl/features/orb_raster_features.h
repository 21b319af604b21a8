#pragma once
/// \file orb_raster_features.h
/// \brief Feature extraction of the paper (Sec. "Tracking / Feature Extraction"):
/// Gaussian blur, FAST corners with an adaptive threshold, ORB (rBRIEF) descriptors on
/// the rasterized image, every keypoint lifted back to the 3D point behind its pixel.
/// \ingroup features

#include <pcl/features/range_raster_image.h>
#include <pcl/features/raster_feature_types.h>
#include <pcl/keypoints/keypoint.h>

#include <cstddef>
#include <memory>
#include <string>
#include <vector>

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

/// \brief The point-type independent part of OrbRasterFeatureEstimator: parameters and
/// FAST/ORB on a computed raster (OpenCV stays inside the library).
/// \ingroup features
class OrbRasterDetector
{
public:
  /// \brief One keypoint of the raster with its descriptor and the input index of
  /// the point it lifts to.
  struct RasterKeypoint
  {
    float u, v;          ///< pixel coordinates in the raster
    float response;      ///< corner response
    float angle_deg;     ///< ORB orientation
    int octave;          ///< pyramid level
    int index;           ///< input index of the 3D point behind the pixel
    OrbDescriptor descriptor;
  };

  OrbRasterDetector();
  ~OrbRasterDetector();
  OrbRasterDetector(const OrbRasterDetector& other);
  OrbRasterDetector&
  operator=(const OrbRasterDetector& other);

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

  /// \brief Blur, FAST with the adaptive threshold, grid bucketing, ORB descriptors and
  /// lifting on a computed raster. Fills the counts and detect/describe timings of the
  /// result (not success or message).
  OrbRasterFeatureResult
  detect(const RasterGrid& raster, std::vector<RasterKeypoint>& keypoints);

protected:
  OrbRasterFeatureParams params_;
  RangeRasterParams raster_params_;

private:
  struct Workspace; ///< work images, reused across calls
  std::unique_ptr<Workspace> workspace_;
};

/// \brief ORB features of a rasterized cloud, lifted to 3D: a pcl::Keypoint whose
/// output points are ORBSignature256 (3D point, pixel and descriptor), with
/// getKeypointsIndices() naming the input point behind every feature. No search method
/// or radius is needed: neighbourhoods are pixels of the raster.
///
/// \code
/// pcl::rast::OrbRasterFeatureEstimator<pcl::PointXYZ> orb;
/// orb.setInputCloud(non_ground);   // rasterized internally with getRasterParams()
/// pcl::PointCloud<pcl::rast::ORBSignature256> features;
/// orb.compute(features);           // PCL's interface; or, with counts and timings:
/// pcl::rast::RasterFeatureSet set;
/// const pcl::rast::OrbRasterFeatureResult result = orb.compute(set);
/// \endcode
/// Feature x, y, z are the coordinates of the rasterized point, i.e. in the frame of
/// the input cloud; u, v are pixel coordinates in the raster (OpenCV convention).
/// setIndices restricts the rasterized points.
/// \ingroup features
template <typename PointInT>
class OrbRasterFeatureEstimator : public pcl::Keypoint<PointInT, ORBSignature256>,
                                  public OrbRasterDetector
{
public:
  using Ptr = std::shared_ptr<OrbRasterFeatureEstimator<PointInT>>;
  using ConstPtr = std::shared_ptr<const OrbRasterFeatureEstimator<PointInT>>;
  using PointCloud = pcl::PointCloud<PointInT>;
  using PointCloudConstPtr = typename PointCloud::ConstPtr;
  using PointCloudOut = pcl::PointCloud<ORBSignature256>;

  OrbRasterFeatureEstimator() { this->name_ = "OrbRasterFeatureEstimator"; }

  /// \brief The cloud to rasterize (usually the non-ground cloud).
  /// \throws std::invalid_argument when null.
  void
  setInputCloud(const PointCloudConstPtr& cloud) override;

  /// \brief An already computed raster (shared, not copied deeply); its cloud becomes
  /// the input cloud.
  /// \throws std::invalid_argument when \a raster has not been computed.
  void
  setInputRaster(const RangeRasterImage<PointInT>& raster);

  /// \brief PCL's pcl::Keypoint::compute(PointCloudOut&).
  using pcl::Keypoint<PointInT, ORBSignature256>::compute;

  /// \brief Extract the features into the SLAM's feature set.
  /// \param[out] features points (3D + pixel + angle) and their descriptors
  /// \return counts, the FAST threshold used, timings and a message
  /// \throws std::invalid_argument when neither an input cloud nor a raster was set.
  OrbRasterFeatureResult
  compute(RasterFeatureSet& features);

  /// \brief Counts, timings and message of the last extraction (either interface).
  const OrbRasterFeatureResult&
  getResult() const
  {
    return result_;
  }

  /// \brief The raster the last extraction used.
  const RangeRasterImage<PointInT>&
  getRaster() const
  {
    return raster_;
  }

protected:
  /// \brief PCLBase's checks only: the raster needs no search method.
  bool
  initCompute() override;
  void
  detectKeypoints(PointCloudOut& output) override;

  using pcl::Keypoint<PointInT, ORBSignature256>::input_;
  using pcl::Keypoint<PointInT, ORBSignature256>::indices_;
  using pcl::Keypoint<PointInT, ORBSignature256>::fake_indices_;
  using pcl::Keypoint<PointInT, ORBSignature256>::keypoints_indices_;

private:
  /// \brief Rasterize (unless given) and detect; fills result_.
  void
  extract(std::vector<OrbRasterDetector::RasterKeypoint>& keypoints);

  RangeRasterImage<PointInT> raster_;
  bool raster_given_ = false;
  OrbRasterFeatureResult result_;
  std::vector<OrbRasterDetector::RasterKeypoint> keypoints_;
};

} // namespace rast
} // namespace pcl

#ifdef PCL_NO_PRECOMPILE
#include <pcl/features/impl/orb_raster_features.hpp>
#endif
