#include <pcl/segmentation/sac_ground_removal.h>

#include <Eigen/Eigenvalues>

#include <algorithm>
#include <cmath>
#include <random>
#include <sstream>
#include <stdexcept>
#include <vector>

namespace pcl {
namespace rast {

namespace {

constexpr double kDegToRad = M_PI / 180.0;
/// RANSAC stops early once a better hypothesis is this unlikely to exist.
constexpr double kRansacConfidence = 0.999;

inline bool
isFinitePoint(const pcl::PointXYZI& p)
{
  return std::isfinite(p.x) && std::isfinite(p.y) && std::isfinite(p.z);
}

/// Number of RANSAC iterations needed to draw one all-inlier 3-point sample with
/// probability kRansacConfidence when a fraction \a inlier_ratio are inliers.
int
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
void
orientUp(Eigen::Vector4f& plane, const Eigen::Vector3f& up)
{
  if (plane.head<3>().dot(up) < 0.0f)
    plane = -plane;
}

/// Whether an up-oriented unit-normal plane satisfies the tilt and height constraints.
bool
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

} // namespace

bool
SACGroundRemovalParams::isValid(std::string* why) const
{
  auto fail = [why](const std::string& msg) {
    if (why)
      *why = msg;
    return false;
  };
  if (!(distance_threshold_m > 0.0) || !std::isfinite(distance_threshold_m))
    return fail("distance_threshold_m must be > 0, got " + std::to_string(distance_threshold_m));
  if (!(max_tilt_deg >= 0.0 && max_tilt_deg < 90.0))
    return fail("max_tilt_deg must be in [0, 90), got " + std::to_string(max_tilt_deg));
  if (!up_axis.allFinite() || up_axis.norm() < 1e-6f)
    return fail("up_axis must be a finite non-zero vector");
  if (!std::isfinite(max_plane_height_m))
    return fail("max_plane_height_m must be finite");
  if (!std::isfinite(sample_max_height_m))
    return fail("sample_max_height_m must be finite");
  if (max_iterations < 1)
    return fail("max_iterations must be >= 1, got " + std::to_string(max_iterations));
  if (max_sample_points < 3)
    return fail("max_sample_points must be >= 3, got " + std::to_string(max_sample_points));
  if (min_inliers < 3)
    return fail("min_inliers must be >= 3, got " + std::to_string(min_inliers));
  if (!(max_rms_ratio > 0.0 && max_rms_ratio <= 1.0))
    return fail("max_rms_ratio must be in (0, 1], got " + std::to_string(max_rms_ratio));
  if (!(min_inlier_ratio >= 0.0 && min_inlier_ratio <= 1.0))
    return fail("min_inlier_ratio must be in [0, 1], got " + std::to_string(min_inlier_ratio));
  return true;
}

bool
fitPlaneLeastSquares(const pcl::PointCloud<pcl::PointXYZI>& cloud,
                     const pcl::Indices& indices,
                     Eigen::Vector4f& plane)
{
  if (indices.size() < 3)
    return false;
  // Centroid and covariance in double: KITTI coordinates reach 80 m.
  Eigen::Vector3d sum = Eigen::Vector3d::Zero();
  Eigen::Matrix3d sum_sq = Eigen::Matrix3d::Zero();
  for (const auto i : indices) {
    const Eigen::Vector3d p = cloud[i].getVector3fMap().cast<double>();
    sum += p;
    sum_sq.noalias() += p * p.transpose();
  }
  const double n = static_cast<double>(indices.size());
  const Eigen::Vector3d centroid = sum / n;
  const Eigen::Matrix3d covariance = sum_sq / n - centroid * centroid.transpose();
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> solver(covariance);
  const Eigen::Vector3d normal = solver.eigenvectors().col(0); // smallest eigenvalue
  plane.head<3>() = normal.cast<float>();
  plane[3] = static_cast<float>(-normal.dot(centroid));
  return true;
}

void
SACGroundRemoval::setInputCloud(const PointCloud::ConstPtr& cloud)
{
  if (!cloud)
    throw std::invalid_argument("SACGroundRemoval::setInputCloud: cloud is null");
  input_ = cloud;
}

void
SACGroundRemoval::setParams(const SACGroundRemovalParams& params)
{
  std::string why;
  if (!params.isValid(&why))
    throw std::invalid_argument("SACGroundRemoval::setParams: " + why);
  params_ = params;
}

void
SACGroundRemoval::segment(GroundRemovalResult& result) const
{
  if (!input_)
    throw std::invalid_argument("SACGroundRemoval::segment: no input cloud (call setInputCloud)");
  result = GroundRemovalResult();
  result.non_ground.reset(new PointCloud);
  const PointCloud& cloud = *input_;
  const Eigen::Vector3f up = params_.up_axis.normalized();
  const float threshold = static_cast<float>(params_.distance_threshold_m);
  const float cos_max_tilt = static_cast<float>(std::cos(params_.max_tilt_deg * kDegToRad));
  const float max_plane_height = static_cast<float>(params_.max_plane_height_m);

  // 1. Finite points, and the candidates for the subsample: points below the sensor.
  pcl::Indices finite, low;
  finite.reserve(cloud.size());
  low.reserve(cloud.size());
  const float sample_max_height = static_cast<float>(params_.sample_max_height_m);
  for (std::size_t i = 0; i < cloud.size(); ++i) {
    const auto& p = cloud[i];
    if (!isFinitePoint(p))
      continue;
    finite.push_back(static_cast<pcl::index_t>(i));
    if (p.getVector3fMap().dot(up) < sample_max_height)
      low.push_back(static_cast<pcl::index_t>(i));
  }
  result.num_non_finite = cloud.size() - finite.size();
  if (finite.empty()) {
    result.message = cloud.empty() ? "empty input cloud" : "input cloud has no finite point";
    return;
  }
  result.success = true;

  auto reportNoGround = [&](const std::string& reason) {
    result.ground_found = false;
    result.plane_coefficients.setZero();
    result.ground_indices.clear();
    result.non_ground_indices = finite;
    result.non_ground->reserve(finite.size());
    for (const auto i : finite)
      result.non_ground->push_back(cloud[i]);
    result.message = "no ground: " + reason;
  };

  // 2. Seeded random subsample (with replacement: O(sample), not O(cloud)).
  const pcl::Indices& pool = low.size() >= 3 ? low : finite;
  if (pool.size() < 3) {
    reportNoGround("fewer than 3 finite points");
    return;
  }
  std::mt19937 rng(params_.seed);
  std::vector<Eigen::Vector3f> sample;
  if (pool.size() <= params_.max_sample_points) {
    sample.reserve(pool.size());
    for (const auto i : pool)
      sample.push_back(cloud[i].getVector3fMap());
  }
  else {
    std::uniform_int_distribution<std::size_t> pick(0, pool.size() - 1);
    sample.reserve(params_.max_sample_points);
    for (std::size_t k = 0; k < params_.max_sample_points; ++k)
      sample.push_back(cloud[pool[pick(rng)]].getVector3fMap());
  }

  // 3. RANSAC on the subsample, hypotheses restricted to near-horizontal planes
  //    below the sensor.
  std::uniform_int_distribution<std::size_t> pick_sample(0, sample.size() - 1);
  Eigen::Vector4f best_plane = Eigen::Vector4f::Zero();
  std::size_t best_count = 0;
  int iterations = params_.max_iterations;
  for (int it = 0; it < iterations; ++it) {
    const std::size_t a = pick_sample(rng), b = pick_sample(rng), c = pick_sample(rng);
    if (a == b || a == c || b == c)
      continue;
    Eigen::Vector3f normal = (sample[b] - sample[a]).cross(sample[c] - sample[a]);
    const float norm = normal.norm();
    if (norm < 1e-6f)
      continue;
    Eigen::Vector4f plane;
    plane.head<3>() = normal / norm;
    plane[3] = -plane.head<3>().dot(sample[a]);
    orientUp(plane, up);
    if (!isAcceptableGround(plane, up, cos_max_tilt, max_plane_height))
      continue;
    std::size_t count = 0;
    for (const auto& p : sample)
      count += std::abs(plane.head<3>().dot(p) + plane[3]) < threshold;
    if (count > best_count) {
      best_count = count;
      best_plane = plane;
      iterations = std::max(it + 1, requiredIterations(static_cast<double>(count) / sample.size(),
                                                       params_.max_iterations));
    }
  }
  if (best_count < 3) {
    reportNoGround("no near-horizontal plane below the sensor");
    return;
  }

  // 4. Classify every finite point; refine by least squares on the inliers.
  double sum_sq_distance = 0.0;
  auto classify = [&](const Eigen::Vector4f& plane, pcl::Indices& inliers) {
    inliers.clear();
    sum_sq_distance = 0.0;
    for (const auto i : finite) {
      const float d = plane.head<3>().dot(cloud[i].getVector3fMap()) + plane[3];
      if (std::abs(d) < threshold) {
        inliers.push_back(i);
        sum_sq_distance += d * d;
      }
    }
  };
  pcl::Indices inliers;
  inliers.reserve(finite.size());
  classify(best_plane, inliers);
  if (params_.refine) {
    Eigen::Vector4f refined;
    if (fitPlaneLeastSquares(cloud, inliers, refined)) {
      orientUp(refined, up);
      if (isAcceptableGround(refined, up, cos_max_tilt, max_plane_height)) {
        best_plane = refined;
        classify(best_plane, inliers);
      }
    }
  }

  // 5. Enough support?
  const std::size_t min_count = std::max<std::size_t>(
      params_.min_inliers,
      static_cast<std::size_t>(std::ceil(params_.min_inlier_ratio * finite.size())));
  if (inliers.size() < min_count) {
    std::ostringstream reason;
    reason << "best plane has " << inliers.size() << " inliers, fewer than " << min_count;
    reportNoGround(reason.str());
    return;
  }
  // A horizontal slab cutting through vertical structures (walls, poles) is filled
  // uniformly, RMS = threshold / sqrt(3); a real surface is much thinner.
  const double rms = std::sqrt(sum_sq_distance / inliers.size());
  if (rms > params_.max_rms_ratio * params_.distance_threshold_m) {
    std::ostringstream reason;
    reason << "best plane is not flat: inlier RMS distance " << rms << " m > "
           << params_.max_rms_ratio << " * distance_threshold_m";
    reportNoGround(reason.str());
    return;
  }

  // 6. Outputs: ground indices, non-ground indices and cloud (levelled on request).
  result.ground_found = true;
  result.plane_coefficients = best_plane;
  result.ground_indices = std::move(inliers);
  result.non_ground_indices.reserve(finite.size() - result.ground_indices.size());
  {
    std::size_t g = 0; // both index lists are sorted: a merge finds the complement
    for (const auto i : finite) {
      if (g < result.ground_indices.size() && result.ground_indices[g] == i) {
        ++g;
        continue;
      }
      result.non_ground_indices.push_back(i);
    }
  }
  if (params_.level_cloud) {
    result.T_level_lidar.linear() =
        Eigen::Quaternionf::FromTwoVectors(best_plane.head<3>(), Eigen::Vector3f::UnitZ())
            .toRotationMatrix();
  }
  const Eigen::Matrix3f R_level_lidar = result.T_level_lidar.linear();
  auto& out = *result.non_ground;
  out.points.reserve(result.non_ground_indices.size());
  for (const auto i : result.non_ground_indices) {
    out.points.push_back(cloud[i]);
    if (params_.level_cloud)
      out.points.back().getVector3fMap() = R_level_lidar * cloud[i].getVector3fMap();
  }
  out.width = static_cast<std::uint32_t>(out.size());
  out.height = 1;
  out.is_dense = true;
  out.header = cloud.header;

  std::ostringstream msg;
  msg << "ground: " << result.ground_indices.size() << " of " << finite.size()
      << " finite points, sensor height " << best_plane[3] << " m, inlier RMS " << rms
      << " m, tilt "
      << std::acos(std::min(1.0f, best_plane.head<3>().dot(up))) / kDegToRad << " deg";
  result.message = msg.str();
}

} // namespace rast
} // namespace pcl
