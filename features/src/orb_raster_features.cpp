#include <pcl/features/orb_raster_features.h>

#include <opencv2/features2d.hpp>
#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <pcl/common/time.h>
#include <cstring>
#include <sstream>
#include <stdexcept>
#include <vector>

namespace pcl {
namespace rast {

namespace {

/// Keep at most \a max_per_cell keypoints per grid cell and \a max_total overall,
/// filling round-robin: the best of every cell first, then the second best, ...
/// so the features spread over the whole image.
std::vector<cv::KeyPoint>
bucketKeypoints(const std::vector<cv::KeyPoint>& keypoints,
                int cell_px,
                int max_per_cell,
                int max_total)
{
  struct Ranked
  {
    int rank;
    std::size_t index;
  };
  // Sort by cell, then by response: the rank inside the cell is then the position.
  std::vector<std::pair<long long, std::size_t>> by_cell(keypoints.size());
  for (std::size_t i = 0; i < keypoints.size(); ++i) {
    const long long cx = static_cast<long long>(keypoints[i].pt.x) / cell_px;
    const long long cy = static_cast<long long>(keypoints[i].pt.y) / cell_px;
    by_cell[i] = {(cy << 32) | cx, i};
  }
  std::sort(by_cell.begin(), by_cell.end(), [&](const auto& a, const auto& b) {
    if (a.first != b.first)
      return a.first < b.first;
    return keypoints[a.second].response > keypoints[b.second].response;
  });
  std::vector<Ranked> ranked;
  ranked.reserve(by_cell.size());
  int rank = 0;
  for (std::size_t k = 0; k < by_cell.size(); ++k) {
    rank = (k > 0 && by_cell[k].first == by_cell[k - 1].first) ? rank + 1 : 0;
    if (rank < max_per_cell)
      ranked.push_back({rank, by_cell[k].second});
  }
  std::sort(ranked.begin(), ranked.end(), [&](const Ranked& a, const Ranked& b) {
    if (a.rank != b.rank)
      return a.rank < b.rank;
    return keypoints[a.index].response > keypoints[b.index].response;
  });
  if (ranked.size() > static_cast<std::size_t>(max_total))
    ranked.resize(max_total);
  std::vector<cv::KeyPoint> kept;
  kept.reserve(ranked.size());
  for (const auto& r : ranked)
    kept.push_back(keypoints[r.index]);
  return kept;
}

} // namespace

bool
OrbRasterFeatureParams::isValid(std::string* why) const
{
  auto fail = [why](const std::string& msg) {
    if (why)
      *why = msg;
    return false;
  };
  if (max_features < 1)
    return fail("max_features must be >= 1, got " + std::to_string(max_features));
  if (grid_cell_px < 1)
    return fail("grid_cell_px must be >= 1, got " + std::to_string(grid_cell_px));
  if (max_per_cell < 1)
    return fail("max_per_cell must be >= 1, got " + std::to_string(max_per_cell));
  if (fast_threshold < 1 || fast_threshold > 255)
    return fail("fast_threshold must be in [1, 255], got " + std::to_string(fast_threshold));
  if (min_fast_threshold < 1 || min_fast_threshold > fast_threshold)
    return fail("min_fast_threshold must be in [1, fast_threshold], got " +
                std::to_string(min_fast_threshold));
  if (min_features < 0)
    return fail("min_features must be >= 0, got " + std::to_string(min_features));
  if (!(blur_sigma_px >= 0.0) || blur_sigma_px > 20.0)
    return fail("blur_sigma_px must be in [0, 20], got " + std::to_string(blur_sigma_px));
  if (num_levels < 1 || num_levels > 16)
    return fail("num_levels must be in [1, 16], got " + std::to_string(num_levels));
  if (!(scale_factor > 1.0) || scale_factor > 4.0)
    return fail("scale_factor must be in (1, 4], got " + std::to_string(scale_factor));
  if (patch_size_px < 3 || patch_size_px > 255)
    return fail("patch_size_px must be in [3, 255], got " + std::to_string(patch_size_px));
  if (lift_search_radius_px < 0 || lift_search_radius_px > 64)
    return fail("lift_search_radius_px must be in [0, 64], got " +
                std::to_string(lift_search_radius_px));
  return true;
}

struct OrbRasterDetector::Workspace
{
  cv::Mat padded, blurred;
};

OrbRasterDetector::OrbRasterDetector() : workspace_(std::make_unique<Workspace>()) {}

OrbRasterDetector::~OrbRasterDetector() = default;

OrbRasterDetector::OrbRasterDetector(const OrbRasterDetector& other)
: params_(other.params_)
, raster_params_(other.raster_params_)
, workspace_(std::make_unique<Workspace>())
{}

OrbRasterDetector&
OrbRasterDetector::operator=(const OrbRasterDetector& other)
{
  params_ = other.params_;
  raster_params_ = other.raster_params_;
  return *this;
}

void
OrbRasterDetector::setParams(const OrbRasterFeatureParams& params)
{
  std::string why;
  if (!params.isValid(&why))
    throw std::invalid_argument("OrbRasterFeatureEstimator::setParams: " + why);
  params_ = params;
}

void
OrbRasterDetector::setRasterParams(const RangeRasterParams& params)
{
  std::string why;
  if (!params.isValid(&why))
    throw std::invalid_argument("OrbRasterFeatureEstimator::setRasterParams: " + why);
  raster_params_ = params;
}

OrbRasterFeatureResult
OrbRasterDetector::detect(const RasterGrid& raster, std::vector<RasterKeypoint>& out)
{
  OrbRasterFeatureResult result;
  out.clear();

  // 1. Pad by the ORB border so keypoints near the image edge keep their descriptor,
  //    then Gaussian blur (paper: "First Gaussian blur is applied").
  pcl::StopWatch watch;
  const int pad = params_.patch_size_px + 1;
  const cv::Mat gray(raster.height(), raster.width(), CV_8UC1,
                     const_cast<std::uint8_t*>(raster.grayData()));
  cv::Mat& padded = workspace_->padded;
  cv::Mat& blurred = workspace_->blurred;
  cv::copyMakeBorder(gray, padded, pad, pad, pad, pad, cv::BORDER_CONSTANT, 0);
  if (params_.blur_sigma_px > 0.0)
    cv::GaussianBlur(padded, blurred, cv::Size(0, 0), params_.blur_sigma_px);
  else
    padded.copyTo(blurred);

  // 2. FAST corners (Harris-ranked, oriented by ORB's intensity centroid); the
  //    threshold is halved while too few are found.
  const int candidate_pool = 4 * params_.max_features; // before bucketing
  auto orb = cv::ORB::create(candidate_pool, static_cast<float>(params_.scale_factor),
                             params_.num_levels, params_.patch_size_px, 0, 2,
                             cv::ORB::HARRIS_SCORE, params_.patch_size_px,
                             params_.fast_threshold);
  std::vector<cv::KeyPoint> keypoints;
  int threshold = params_.fast_threshold;
  for (;;) {
    orb->setFastThreshold(threshold);
    orb->detect(blurred, keypoints);
    if (static_cast<int>(keypoints.size()) >= params_.min_features ||
        threshold <= params_.min_fast_threshold)
      break;
    threshold = std::max(params_.min_fast_threshold, threshold / 2);
  }
  result.fast_threshold = threshold;
  result.num_detected = keypoints.size();
  keypoints = bucketKeypoints(keypoints, params_.grid_cell_px, params_.max_per_cell,
                              params_.max_features);
  result.num_bucketed = keypoints.size();
  result.detect_ms = watch.getTime();

  // 3. Descriptors (the keypoints keep their orientation), then the input point behind
  //    every keypoint's pixel.
  watch.reset();
  cv::Mat descriptors;
  if (!keypoints.empty())
    orb->compute(blurred, keypoints, descriptors);
  out.reserve(keypoints.size());
  for (std::size_t k = 0; k < keypoints.size(); ++k) {
    const cv::KeyPoint& kp = keypoints[k];
    const float u = kp.pt.x - pad, v = kp.pt.y - pad;
    const int index = raster.nearestPixelIndex(static_cast<int>(std::lround(u)),
                                               static_cast<int>(std::lround(v)),
                                               params_.lift_search_radius_px);
    if (index < 0) {
      ++result.num_unlifted;
      continue;
    }
    RasterKeypoint lifted;
    lifted.u = u;
    lifted.v = v;
    lifted.response = kp.response;
    lifted.angle_deg = kp.angle;
    lifted.octave = kp.octave;
    lifted.index = index;
    std::memcpy(lifted.descriptor.data(), descriptors.ptr<std::uint8_t>(static_cast<int>(k)),
                32);
    out.push_back(lifted);
  }
  result.describe_ms = watch.getTime();
  result.num_features = out.size();
  return result;
}

namespace {

/// x, y, z and the raster keypoint fields, between RasterFeaturePoint and ORBSignature256.
template <typename PointIn, typename PointOut>
void
copyRasterKeypoint(const PointIn& in, PointOut& out)
{
  out.getVector4fMap() = in.getVector4fMap();
  out.u = in.u;
  out.v = in.v;
  out.response = in.response;
  out.angle_deg = in.angle_deg;
  out.octave = in.octave;
}

} // namespace

void
toSignatureCloud(const RasterFeatureSet& set, pcl::PointCloud<ORBSignature256>& cloud)
{
  if (set.points.size() != set.descriptors.size())
    throw std::invalid_argument("toSignatureCloud: " + std::to_string(set.points.size()) +
                                " points but " + std::to_string(set.descriptors.size()) +
                                " descriptors");
  cloud.resize(set.size());
  for (std::size_t i = 0; i < set.size(); ++i) {
    ORBSignature256& q = cloud[i];
    copyRasterKeypoint(set.points[i], q);
    std::memcpy(q.descriptor, set.descriptors[i].data(), 32);
  }
  cloud.width = static_cast<std::uint32_t>(cloud.size());
  cloud.height = 1;
  cloud.is_dense = set.points.is_dense;
  cloud.header = set.points.header;
}

void
fromSignatureCloud(const pcl::PointCloud<ORBSignature256>& cloud, RasterFeatureSet& set)
{
  set.points.resize(cloud.size());
  set.descriptors.resize(cloud.size());
  for (std::size_t i = 0; i < cloud.size(); ++i) {
    const ORBSignature256& q = cloud[i];
    copyRasterKeypoint(q, set.points[i]);
    std::memcpy(set.descriptors[i].data(), q.descriptor, 32);
  }
  set.points.width = static_cast<std::uint32_t>(cloud.size());
  set.points.height = 1;
  set.points.is_dense = cloud.is_dense;
  set.points.header = cloud.header;
}

} // namespace rast
} // namespace pcl
