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

/// a . b summed as Eigen sums a 3-vector dot product, a0 b0 + (a1 b1 + a2 b2), so the
/// plain-float loops below classify exactly as Eigen's dot() did.
inline float
dot3(float a0, float a1, float a2, float b0, float b1, float b2)
{
  return a0 * b0 + (a1 * b1 + a2 * b2);
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
  const std::size_t size = cloud.size();
  const Eigen::Vector3f up = params_.up_axis.normalized();
  const float threshold = static_cast<float>(params_.distance_threshold_m);
  const float cos_max_tilt = static_cast<float>(std::cos(params_.max_tilt_deg * kDegToRad));
  const float max_plane_height = static_cast<float>(params_.max_plane_height_m);

  // 1. Count the finite points and collect the candidates for the subsample: points
  //    below the sensor. (The finite indices themselves are only listed when no
  //    ground is found: the passes below skip non-finite points on the fly, since a
  //    NaN distance fails every comparison.)
  pcl::Indices low;
  low.reserve(size / 2);
  std::size_t num_finite = 0;
  const float sample_max_height = static_cast<float>(params_.sample_max_height_m);
  for (std::size_t i = 0; i < size; ++i) {
    const auto& p = cloud[i];
    if (!isFinitePoint(p))
      continue;
    ++num_finite;
    if (dot3(p.x, p.y, p.z, up[0], up[1], up[2]) < sample_max_height)
      low.push_back(static_cast<pcl::index_t>(i));
  }
  result.num_non_finite = size - num_finite;
  if (num_finite == 0) {
    result.message = cloud.empty() ? "empty input cloud" : "input cloud has no finite point";
    return;
  }
  result.success = true;

  auto finiteIndices = [&]() {
    pcl::Indices finite;
    finite.reserve(num_finite);
    for (std::size_t i = 0; i < size; ++i)
      if (isFinitePoint(cloud[i]))
        finite.push_back(static_cast<pcl::index_t>(i));
    return finite;
  };
  auto reportNoGround = [&](const std::string& reason) {
    result.ground_found = false;
    result.plane_coefficients.setZero();
    result.ground_indices.clear();
    result.non_ground_indices = finiteIndices();
    auto& out = *result.non_ground;
    out.clear();
    out.points.reserve(num_finite);
    for (const auto i : result.non_ground_indices)
      out.points.push_back(cloud[i]);
    out.width = static_cast<std::uint32_t>(out.size());
    out.height = 1;
    out.is_dense = true;
    out.header = cloud.header;
    result.message = "no ground: " + reason;
  };

  // 2. Seeded random subsample (with replacement: O(sample), not O(cloud)), stored as
  //    contiguous coordinate arrays so the RANSAC scoring loop vectorizes.
  pcl::Indices finite_pool;
  if (low.size() < 3)
    finite_pool = finiteIndices();
  const pcl::Indices& pool = low.size() >= 3 ? low : finite_pool;
  if (pool.size() < 3) {
    reportNoGround("fewer than 3 finite points");
    return;
  }
  std::mt19937 rng(params_.seed);
  const std::size_t sample_size = std::min<std::size_t>(pool.size(), params_.max_sample_points);
  std::vector<float> sx(sample_size), sy(sample_size), sz(sample_size);
  auto store = [&](std::size_t k, pcl::index_t i) {
    sx[k] = cloud[i].x;
    sy[k] = cloud[i].y;
    sz[k] = cloud[i].z;
  };
  if (pool.size() <= params_.max_sample_points) {
    for (std::size_t k = 0; k < sample_size; ++k)
      store(k, pool[k]);
  }
  else {
    std::uniform_int_distribution<std::size_t> pick(0, pool.size() - 1);
    for (std::size_t k = 0; k < sample_size; ++k)
      store(k, pool[pick(rng)]);
  }
  auto samplePoint = [&](std::size_t k) { return Eigen::Vector3f(sx[k], sy[k], sz[k]); };

  // 3. RANSAC on the subsample, hypotheses restricted to near-horizontal planes
  //    below the sensor; stops early once a better plane is unlikely.
  std::uniform_int_distribution<std::size_t> pick_sample(0, sample_size - 1);
  Eigen::Vector4f best_plane = Eigen::Vector4f::Zero();
  std::size_t best_count = 0;
  int iterations = params_.max_iterations;
  for (int it = 0; it < iterations; ++it) {
    const std::size_t a = pick_sample(rng), b = pick_sample(rng), c = pick_sample(rng);
    if (a == b || a == c || b == c)
      continue;
    const Eigen::Vector3f pa = samplePoint(a);
    Eigen::Vector3f normal = (samplePoint(b) - pa).cross(samplePoint(c) - pa);
    const float norm = normal.norm();
    if (norm < 1e-6f)
      continue;
    Eigen::Vector4f plane;
    plane.head<3>() = normal / norm;
    plane[3] = -plane.head<3>().dot(pa);
    orientUp(plane, up);
    if (!isAcceptableGround(plane, up, cos_max_tilt, max_plane_height))
      continue;
    const float nx = plane[0], ny = plane[1], nz = plane[2], d = plane[3];
    std::size_t count = 0;
    for (std::size_t k = 0; k < sample_size; ++k)
      count += std::abs(dot3(nx, ny, nz, sx[k], sy[k], sz[k]) + d) < threshold;
    if (count > best_count) {
      best_count = count;
      best_plane = plane;
      iterations = std::max(it + 1, requiredIterations(static_cast<double>(count) / sample_size,
                                                       params_.max_iterations));
    }
  }
  if (best_count < 3) {
    reportNoGround("no near-horizontal plane below the sensor");
    return;
  }

  // 4. Refine by least squares on the inliers of the RANSAC plane over every finite
  //    point (the sums of fitPlaneLeastSquares, accumulated in the same order without
  //    listing the inliers).
  auto distance = [](const Eigen::Vector4f& plane, const pcl::PointXYZI& p) {
    return dot3(plane[0], plane[1], plane[2], p.x, p.y, p.z) + plane[3];
  };
  if (params_.refine) {
    Eigen::Vector3d sum = Eigen::Vector3d::Zero();
    double sxx = 0, sxy = 0, sxz = 0, syy = 0, syz = 0, szz = 0;
    std::size_t n = 0;
    for (std::size_t i = 0; i < size; ++i) {
      const auto& p = cloud[i];
      if (!(std::abs(distance(best_plane, p)) < threshold)) // NaN: not an inlier
        continue;
      const double x = p.x, y = p.y, z = p.z;
      sum += Eigen::Vector3d(x, y, z);
      sxx += x * x;
      sxy += x * y;
      sxz += x * z;
      syy += y * y;
      syz += y * z;
      szz += z * z;
      ++n;
    }
    if (n >= 3) {
      Eigen::Matrix3d sum_sq;
      sum_sq << sxx, sxy, sxz, sxy, syy, syz, sxz, syz, szz;
      const double nd = static_cast<double>(n);
      const Eigen::Vector3d centroid = sum / nd;
      const Eigen::Matrix3d covariance = sum_sq / nd - centroid * centroid.transpose();
      Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> solver(covariance);
      const Eigen::Vector3d normal = solver.eigenvectors().col(0); // smallest eigenvalue
      Eigen::Vector4f refined;
      refined.head<3>() = normal.cast<float>();
      refined[3] = static_cast<float>(-normal.dot(centroid));
      orientUp(refined, up);
      if (isAcceptableGround(refined, up, cos_max_tilt, max_plane_height))
        best_plane = refined;
    }
  }

  // 5. One classification pass writes every output: ground and non-ground indices and
  //    the non-ground cloud (levelled on request).
  if (params_.level_cloud) {
    result.T_level_lidar.linear() =
        Eigen::Quaternionf::FromTwoVectors(best_plane.head<3>(), Eigen::Vector3f::UnitZ())
            .toRotationMatrix();
  }
  const Eigen::Matrix3f R_level_lidar = result.T_level_lidar.linear();
  auto& out = *result.non_ground;
  out.points.reserve(num_finite);
  result.ground_indices.reserve(num_finite / 2);
  result.non_ground_indices.reserve(num_finite);
  double sum_sq_distance = 0.0;
  for (std::size_t i = 0; i < size; ++i) {
    const auto& p = cloud[i];
    const float d = distance(best_plane, p);
    if (std::abs(d) < threshold) {
      result.ground_indices.push_back(static_cast<pcl::index_t>(i));
      sum_sq_distance += d * d;
    }
    else if (std::isfinite(d)) { // d is finite exactly when the point is
      result.non_ground_indices.push_back(static_cast<pcl::index_t>(i));
      out.points.push_back(p);
      if (params_.level_cloud)
        out.points.back().getVector3fMap() = R_level_lidar * p.getVector3fMap();
    }
  }
  const std::size_t num_inliers = result.ground_indices.size();

  // 6. Enough support?
  const std::size_t min_count = std::max<std::size_t>(
      params_.min_inliers,
      static_cast<std::size_t>(std::ceil(params_.min_inlier_ratio * num_finite)));
  if (num_inliers < min_count) {
    std::ostringstream reason;
    reason << "best plane has " << num_inliers << " inliers, fewer than " << min_count;
    result.T_level_lidar = Eigen::Isometry3f::Identity();
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
    result.T_level_lidar = Eigen::Isometry3f::Identity();
    reportNoGround(reason.str());
    return;
  }

  result.ground_found = true;
  result.plane_coefficients = best_plane;
  out.width = static_cast<std::uint32_t>(out.size());
  out.height = 1;
  out.is_dense = true;
  out.header = cloud.header;

  std::ostringstream msg;
  msg << "ground: " << num_inliers << " of " << num_finite
      << " finite points, sensor height " << best_plane[3] << " m, inlier RMS " << rms
      << " m, tilt "
      << std::acos(std::min(1.0f, best_plane.head<3>().dot(up))) / kDegToRad << " deg";
  result.message = msg.str();
}

} // namespace rast
} // namespace pcl
