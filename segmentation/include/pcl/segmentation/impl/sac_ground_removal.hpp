#pragma once
/// \file sac_ground_removal.hpp
/// \brief Implementation of SACGroundRemoval<PointT> (explicitly instantiated in
/// sac_ground_removal.cpp for PCL_RAST_XYZ_POINT_TYPES).

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <pcl/common/point_tests.h>
#include <pcl/sample_consensus/sac_model_plane.h>
#include <pcl/segmentation/sac_ground_removal.h>
#include <random>
#include <sstream>
#include <stdexcept>
#include <vector>

namespace pcl {
namespace rast {
namespace ground_detail {

constexpr double kDegToRad = M_PI / 180.0;
/// RANSAC stops early once a better hypothesis is this unlikely to exist.
constexpr double kRansacConfidence = 0.999;

/// Number of RANSAC iterations needed to draw one all-inlier 3-point sample with
/// probability kRansacConfidence when a fraction \a inlier_ratio are inliers.
inline int
requiredIterations(double inlier_ratio, int max_iterations)
{
  const double w3 = inlier_ratio * inlier_ratio * inlier_ratio;
  if (w3 <= 1e-12)
    return max_iterations;
  if (w3 >= 1.0 - 1e-12)
    return 1;
  const double n = std::log(1.0 - kRansacConfidence) / std::log(1.0 - w3);
  return static_cast<int>(std::min<double>(max_iterations, std::ceil(n)));
}

/// Orient \a plane so its normal has a positive component along \a up.
inline void
orientUp(Eigen::Vector4f& plane, const Eigen::Vector3f& up)
{
  if (plane.head<3>().dot(up) < 0.0f)
    plane = -plane;
}

/// Whether an up-oriented unit-normal plane satisfies the tilt and height constraints.
inline bool
isAcceptableGround(const Eigen::Vector4f& plane,
                   const Eigen::Vector3f& up,
                   float cos_max_tilt,
                   float max_plane_height_m)
{
  const float cos_tilt = plane.head<3>().dot(up);
  if (cos_tilt < cos_max_tilt)
    return false;
  // The plane point closest to the origin is -d * n; its height along up is -d * (n.up).
  return -plane[3] * cos_tilt <= max_plane_height_m;
}

/// Signed distance of \a p to \a plane, summed as a0 b0 + (a1 b1 + a2 b2) like Eigen's
/// 3-vector dot product. NaN for a non-finite point.
template <typename PointT>
inline float
signedDistance(const Eigen::Vector4f& plane, const PointT& p)
{
  return plane[0] * p.x + (plane[1] * p.y + plane[2] * p.z) + plane[3];
}

/// Least-squares plane of the points at(0), ..., at(count - 1) that pass \a use, from
/// double sums.
template <typename PointT, typename At, typename Predicate>
bool
leastSquaresPlane(const pcl::PointCloud<PointT>& cloud,
                  std::size_t count,
                  At at,
                  Predicate use,
                  Eigen::Vector4f& plane)
{
  // Centroid and covariance in double: KITTI coordinates reach 80 m.
  Eigen::Vector3d sum = Eigen::Vector3d::Zero();
  double sxx = 0, sxy = 0, sxz = 0, syy = 0, syz = 0, szz = 0;
  std::size_t n = 0;
  for (std::size_t k = 0; k < count; ++k) {
    const pcl::index_t i = at(k);
    if (!use(i))
      continue;
    const double x = cloud[i].x, y = cloud[i].y, z = cloud[i].z;
    sum += Eigen::Vector3d(x, y, z);
    sxx += x * x;
    sxy += x * y;
    sxz += x * z;
    syy += y * y;
    syz += y * z;
    szz += z * z;
    ++n;
  }
  if (n < 3)
    return false;
  Eigen::Matrix3d sum_sq;
  sum_sq << sxx, sxy, sxz, sxy, syy, syz, sxz, syz, szz;
  const double nd = static_cast<double>(n);
  const Eigen::Vector3d centroid = sum / nd;
  const Eigen::Matrix3d covariance = sum_sq / nd - centroid * centroid.transpose();
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> solver(covariance);
  const Eigen::Vector3d normal = solver.eigenvectors().col(0); // smallest eigenvalue
  plane.head<3>() = normal.cast<float>();
  plane[3] = static_cast<float>(-normal.dot(centroid));
  return true;
}

/// The rotation taking the normal of \a plane to +z.
inline Eigen::Matrix3f
levellingRotation(const Eigen::Vector4f& plane)
{
  return Eigen::Quaternionf::FromTwoVectors(plane.head<3>(), Eigen::Vector3f::UnitZ())
      .toRotationMatrix();
}

/// The points a fit looks at: the whole cloud, or the indices of it.
template <typename PointT>
struct Candidates
{
  const pcl::PointCloud<PointT>& cloud;
  const pcl::Indices* indices; ///< null: every point
  std::size_t
  size() const
  {
    return indices ? indices->size() : cloud.size();
  }
  pcl::index_t
  operator()(std::size_t k) const
  {
    return indices ? (*indices)[k] : static_cast<pcl::index_t>(k);
  }
  /// The finite ones among them.
  pcl::Indices
  finite(std::size_t expected) const
  {
    pcl::Indices out;
    out.reserve(expected);
    for (std::size_t k = 0; k < size(); ++k)
      if (pcl::isXYZFinite(cloud[(*this)(k)]))
        out.push_back((*this)(k));
    return out;
  }
};

/// Step 1 of a fit: the finite candidates are counted, and those below
/// \a sample_max_height_m along \a up are the pool the subsample is drawn from.
template <typename PointT>
std::size_t
scanCandidates(const Candidates<PointT>& candidates,
               const Eigen::Vector3f& up,
               float sample_max_height_m,
               pcl::Indices& low)
{
  low.clear();
  low.reserve(candidates.size() / 2);
  std::size_t num_finite = 0;
  for (std::size_t k = 0; k < candidates.size(); ++k) {
    const auto i = candidates(k);
    const auto& p = candidates.cloud[i];
    if (!pcl::isXYZFinite(p))
      continue;
    ++num_finite;
    if (p.x * up[0] + (p.y * up[1] + p.z * up[2]) < sample_max_height_m)
      low.push_back(i);
  }
  return num_finite;
}

/// Step 2: a seeded random subsample of \a pool (with replacement: O(sample), not
/// O(cloud)), copied into a contiguous cloud for the sample-consensus model.
template <typename PointT>
pcl::PointCloud<pcl::PointXYZ>::Ptr
drawSample(const pcl::PointCloud<PointT>& cloud,
           const pcl::Indices& pool,
           std::size_t max_sample_points,
           std::mt19937& rng)
{
  const std::size_t sample_size = std::min<std::size_t>(pool.size(), max_sample_points);
  pcl::PointCloud<pcl::PointXYZ>::Ptr sample(new pcl::PointCloud<pcl::PointXYZ>);
  sample->resize(sample_size);
  auto store = [&](std::size_t k, pcl::index_t i) {
    (*sample)[k].getVector3fMap() = cloud[i].getVector3fMap();
  };
  if (pool.size() <= max_sample_points) {
    for (std::size_t k = 0; k < sample_size; ++k)
      store(k, pool[k]);
  } else {
    std::uniform_int_distribution<std::size_t> pick(0, pool.size() - 1);
    for (std::size_t k = 0; k < sample_size; ++k)
      store(k, pool[pick(rng)]);
  }
  return sample;
}

/// Step 3: RANSAC on the subsample. PCL's plane model makes each hypothesis from the
/// samples drawn here from the seed (and rejects collinear ones); planes too steep or
/// above the sensor are skipped. Stops early once a better plane is unlikely. Returns
/// the support of \a best_plane (0: none).
inline std::size_t
ransacPlane(const pcl::PointCloud<pcl::PointXYZ>::Ptr& sample,
            const SACGroundRemovalParams& params,
            const Eigen::Vector3f& up,
            std::mt19937& rng,
            Eigen::Vector4f& best_plane)
{
  const float threshold = static_cast<float>(params.distance_threshold_m);
  const float cos_max_tilt = static_cast<float>(std::cos(params.max_tilt_deg * kDegToRad));
  const float max_plane_height = static_cast<float>(params.max_plane_height_m);
  const std::size_t sample_size = sample->size();
  const pcl::SampleConsensusModelPlane<pcl::PointXYZ> model(sample, false);
  std::uniform_int_distribution<pcl::index_t> pick_sample(
      0, static_cast<pcl::index_t>(sample_size) - 1);
  best_plane = Eigen::Vector4f::Zero();
  std::size_t best_count = 0;
  int iterations = params.max_iterations;
  pcl::Indices hypothesis(3);
  Eigen::VectorXf coefficients;
  for (int it = 0; it < iterations; ++it) {
    for (auto& index : hypothesis)
      index = pick_sample(rng);
    if (hypothesis[0] == hypothesis[1] || hypothesis[0] == hypothesis[2] ||
        hypothesis[1] == hypothesis[2] ||
        !model.computeModelCoefficients(hypothesis, coefficients))
      continue;
    Eigen::Vector4f plane = coefficients.head<4>();
    orientUp(plane, up);
    if (!isAcceptableGround(plane, up, cos_max_tilt, max_plane_height))
      continue;
    // Scored here, not by model.countWithinDistance: PCL's loop goes through the
    // model's index list point by point; with it the whole ground removal of an
    // HDL-64 scan took 3.1 ms instead of 1.1 ms (session-7 note, issue 11).
    std::size_t support = 0;
    const float nx = plane[0], ny = plane[1], nz = plane[2], d = plane[3];
    for (const auto& p : sample->points)
      support += std::abs(nx * p.x + (ny * p.y + nz * p.z) + d) < threshold;
    if (support > best_count) {
      best_count = support;
      best_plane = plane;
      iterations = std::max(it + 1,
                            requiredIterations(static_cast<double>(support) / sample_size,
                                               params.max_iterations));
    }
  }
  return best_count;
}

/// Step 5: the candidates within \a threshold of \a plane are ground, the other finite
/// ones not; returns the sum of the ground points' squared distances.
template <typename PointT>
double
classify(const Candidates<PointT>& candidates,
         const Eigen::Vector4f& plane,
         float threshold,
         std::size_t num_finite,
         GroundRemovalResult<PointT>& result)
{
  result.ground_indices.clear();
  result.non_ground_indices.clear();
  result.ground_indices.reserve(num_finite / 2);
  result.non_ground_indices.reserve(num_finite);
  double sum_sq_distance = 0.0;
  for (std::size_t k = 0; k < candidates.size(); ++k) {
    const auto i = candidates(k);
    const float d = signedDistance(plane, candidates.cloud[i]);
    if (std::abs(d) < threshold) {
      result.ground_indices.push_back(i);
      sum_sq_distance += d * d;
    } else if (std::isfinite(d)) { // d is finite exactly when the point is
      result.non_ground_indices.push_back(i);
    }
  }
  return sum_sq_distance;
}

} // namespace ground_detail

template <typename PointT>
bool
fitPlaneLeastSquares(const pcl::PointCloud<PointT>& cloud,
                     const pcl::Indices& indices,
                     Eigen::Vector4f& plane)
{
  return ground_detail::leastSquaresPlane(
      cloud,
      indices.size(),
      [&indices](std::size_t k) { return indices[k]; },
      [](pcl::index_t) { return true; },
      plane);
}

template <typename PointT>
SACGroundRemoval<PointT>::SACGroundRemoval(bool extract_removed_indices)
    : pcl::FilterIndices<PointT>(extract_removed_indices)
{
  filter_name_ = "SACGroundRemoval";
}

template <typename PointT>
SACGroundRemoval<PointT>::SACGroundRemoval(const SACGroundRemovalParams& params,
                                           bool extract_removed_indices)
    : SACGroundRemoval(extract_removed_indices)
{
  setParams(params);
}

template <typename PointT>
void
SACGroundRemoval<PointT>::setInputCloud(const PointCloudConstPtr& cloud)
{
  if (!cloud)
    throw std::invalid_argument("SACGroundRemoval::setInputCloud: cloud is null");
  pcl::FilterIndices<PointT>::setInputCloud(cloud);
}

template <typename PointT>
void
SACGroundRemoval<PointT>::setParams(const SACGroundRemovalParams& params)
{
  std::string why;
  if (!params.isValid(&why))
    throw std::invalid_argument("SACGroundRemoval::setParams: " + why);
  params_ = params;
}

template <typename PointT>
Eigen::Isometry3f
SACGroundRemoval<PointT>::getLevellingTransform() const
{
  Eigen::Isometry3f T = Eigen::Isometry3f::Identity();
  if (ground_found_)
    T.linear() = ground_detail::levellingRotation(plane_);
  return T;
}

template <typename PointT>
void
SACGroundRemoval<PointT>::fit(const pcl::Indices* indices,
                              GroundRemovalResult<PointT>& result) const
{
  using namespace ground_detail;
  const PointCloud& cloud = *input_;
  const Candidates<PointT> candidates{cloud, indices};
  if (indices)
    for (const auto i : *indices)
      if (i < 0 || static_cast<std::size_t>(i) >= cloud.size())
        throw std::out_of_range("SACGroundRemoval: index " + std::to_string(i) +
                                " is outside the input cloud of " +
                                std::to_string(cloud.size()) + " points");
  const Eigen::Vector3f up = params_.up_axis.normalized();
  const float threshold = static_cast<float>(params_.distance_threshold_m);
  const float cos_max_tilt =
      static_cast<float>(std::cos(params_.max_tilt_deg * kDegToRad));
  const float max_plane_height = static_cast<float>(params_.max_plane_height_m);

  // 1. The finite candidates, and the low ones the subsample is drawn from. (The passes
  //    below skip non-finite points on the fly: a NaN distance fails every comparison.)
  pcl::Indices low;
  const std::size_t num_finite = scanCandidates(
      candidates, up, static_cast<float>(params_.sample_max_height_m), low);
  result.num_non_finite = candidates.size() - num_finite;
  if (num_finite == 0) {
    result.message =
        candidates.size() == 0 ? "empty input cloud" : "input cloud has no finite point";
    return;
  }
  result.success = true;
  auto reportNoGround = [&](const std::string& reason) {
    result.ground_found = false;
    result.plane_coefficients.setZero();
    result.ground_indices.clear();
    result.non_ground_indices = candidates.finite(num_finite);
    result.message = "no ground: " + reason;
  };

  // 2-3. Seeded subsample (of all finite points when fewer than 3 are low), RANSAC.
  const pcl::Indices pool = low.size() >= 3 ? std::move(low) : candidates.finite(num_finite);
  if (pool.size() < 3) {
    reportNoGround("fewer than 3 finite points");
    return;
  }
  std::mt19937 rng(params_.seed);
  const auto sample = drawSample(cloud, pool, params_.max_sample_points, rng);
  Eigen::Vector4f plane;
  if (ransacPlane(sample, params_, up, rng, plane) < 3) {
    reportNoGround("no near-horizontal plane below the sensor");
    return;
  }

  // 4. Refine by least squares (in double, over the whole candidate set, not the
  //    subsample the model holds) on the inliers of the RANSAC plane.
  if (params_.refine) {
    auto is_inlier = [&](pcl::index_t i) {
      return std::abs(signedDistance(plane, cloud[i])) < threshold; // NaN: no
    };
    Eigen::Vector4f refined;
    if (leastSquaresPlane(cloud, candidates.size(), candidates, is_inlier, refined)) {
      orientUp(refined, up);
      if (isAcceptableGround(refined, up, cos_max_tilt, max_plane_height))
        plane = refined;
    }
  }

  // 5. Classify; 6. enough support, and a thin surface?
  const double sum_sq_distance = classify(candidates, plane, threshold, num_finite, result);
  const std::size_t num_inliers = result.ground_indices.size();
  const std::size_t min_count = std::max<std::size_t>(
      params_.min_inliers,
      static_cast<std::size_t>(std::ceil(params_.min_inlier_ratio * num_finite)));
  if (num_inliers < min_count) {
    std::ostringstream reason;
    reason << "best plane has " << num_inliers << " inliers, fewer than " << min_count;
    reportNoGround(reason.str());
    return;
  }
  // A horizontal slab cutting through vertical structures (walls, poles) is filled
  // uniformly, RMS = threshold / sqrt(3); a real surface is much thinner.
  const double rms = std::sqrt(sum_sq_distance / num_inliers);
  if (rms > params_.max_rms_ratio * params_.distance_threshold_m) {
    std::ostringstream reason;
    reason << "best plane is not flat: inlier RMS distance " << rms << " m > "
           << params_.max_rms_ratio << " * distance_threshold_m";
    reportNoGround(reason.str());
    return;
  }

  result.ground_found = true;
  result.plane_coefficients = plane;
  if (params_.level_cloud)
    result.T_level_lidar.linear() = levellingRotation(plane);
  std::ostringstream msg;
  msg << "ground: " << num_inliers << " of " << num_finite
      << " finite points, sensor height " << plane[3] << " m, inlier RMS " << rms
      << " m, tilt "
      << std::acos(std::min(1.0f, plane.head<3>().dot(up))) / kDegToRad << " deg";
  result.message = msg.str();
}

template <typename PointT>
void
SACGroundRemoval<PointT>::segment(GroundRemovalResult<PointT>& result) const
{
  if (!input_)
    throw std::invalid_argument(
        "SACGroundRemoval::segment: no input cloud (call setInputCloud)");
  result = GroundRemovalResult<PointT>();
  fit(this->fake_indices_ || !indices_ ? nullptr : indices_.get(), result);

  // The non-ground cloud, levelled on request.
  result.non_ground.reset(new PointCloud);
  auto& out = *result.non_ground;
  out.reserve(result.non_ground_indices.size());
  const Eigen::Matrix3f R_level_lidar = result.T_level_lidar.linear();
  const bool level = result.ground_found && params_.level_cloud;
  for (const auto i : result.non_ground_indices) {
    out.push_back((*input_)[i]);
    if (level)
      out.back().getVector3fMap() = R_level_lidar * out.back().getVector3fMap();
  }
  out.width = static_cast<std::uint32_t>(out.size());
  out.height = 1;
  out.is_dense = true;
  out.header = input_->header;
}

template <typename PointT>
void
SACGroundRemoval<PointT>::applyFilter(pcl::Indices& indices)
{
  // initCompute() has set indices_: every point unless the user gave a subset.
  const pcl::Indices* candidates = this->fake_indices_ ? nullptr : indices_.get();
  GroundRemovalResult<PointT> result;
  fit(candidates, result);
  ground_found_ = result.ground_found;
  plane_ = result.plane_coefficients;
  message_ = result.message;
  indices =
      negative_ ? std::move(result.ground_indices) : std::move(result.non_ground_indices);
  if (!extract_removed_indices_)
    return;
  // Removed: every candidate not kept, non-finite points included.
  std::vector<bool> kept(input_->size(), false);
  for (const auto i : indices)
    kept[i] = true;
  removed_indices_->clear();
  const std::size_t count = candidates ? candidates->size() : input_->size();
  for (std::size_t k = 0; k < count; ++k) {
    const pcl::index_t i = candidates ? (*candidates)[k] : static_cast<pcl::index_t>(k);
    if (!kept[i])
      removed_indices_->push_back(i);
  }
}

} // namespace rast
} // namespace pcl

#define PCL_INSTANTIATE_SACGroundRemoval(T) template class pcl::rast::SACGroundRemoval<T>;
#define PCL_INSTANTIATE_fitPlaneLeastSquares(T)                                          \
  template bool pcl::rast::fitPlaneLeastSquares<T>(                                      \
      const pcl::PointCloud<T>&, const pcl::Indices&, Eigen::Vector4f&);
