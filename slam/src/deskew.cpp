/// \file deskew.cpp
/// \brief Motion compensation of raw sweeps: SE(3) log / exp, azimuth times, eq. (1).

#include "fast_math.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <pcl/slam/deskew.h>
#include <stdexcept>

namespace pcl {
namespace rast {
namespace {

/// Eq. (1)'s transform of each of the \a n bins of [lo, lo + span] at the bin's middle
/// time (deskewCloudInPlace(), deskewPointsAndNormals()).
std::vector<Pose3d, Eigen::aligned_allocator<Pose3d>>
binTransforms(double lo, double span, int n, const Twist& xi_per_s)
{
  std::vector<Pose3d, Eigen::aligned_allocator<Pose3d>> transforms;
  transforms.reserve(static_cast<std::size_t>(n));
  for (int b = 0; b < n; ++b)
    transforms.push_back(expSE3((lo + (b + 0.5) * span / n) * xi_per_s));
  return transforms;
}

constexpr double kPi = 3.14159265358979323846;

Eigen::Matrix3d
hat(const Eigen::Vector3d& w)
{
  Eigen::Matrix3d W;
  W << 0.0, -w.z(), w.y(), w.z(), 0.0, -w.x(), -w.y(), w.x(), 0.0;
  return W;
}

/// V(w) of the SE(3) exponential: t = V(w) v (Barfoot, State Estimation, eq. 7.86).
Eigen::Matrix3d
leftJacobian(const Eigen::Vector3d& w)
{
  const double theta = w.norm();
  const Eigen::Matrix3d W = hat(w);
  if (theta < 1e-6) // series: I + W/2 + W^2/6
    return Eigen::Matrix3d::Identity() + 0.5 * W + W * W / 6.0;
  const double t2 = theta * theta;
  return Eigen::Matrix3d::Identity() + (1.0 - std::cos(theta)) / t2 * W +
         (theta - std::sin(theta)) / (t2 * theta) * W * W;
}

} // namespace

Twist
logSE3(const Pose3d& T)
{
  const Eigen::AngleAxisd aa(T.linear());
  const Eigen::Vector3d w = aa.angle() * aa.axis();
  Twist xi;
  xi.head<3>() = leftJacobian(w).inverse() * T.translation();
  xi.tail<3>() = w;
  return xi;
}

Pose3d
expSE3(const Twist& xi)
{
  const Eigen::Vector3d w = xi.tail<3>();
  const double theta = w.norm();
  Pose3d T = Pose3d::Identity();
  if (theta > 0.0)
    T.linear() = Eigen::AngleAxisd(theta, w / theta).toRotationMatrix();
  T.translation() = leftJacobian(w) * xi.head<3>();
  return T;
}

bool
SweepParams::isValid(std::string* why) const
{
  if (!std::isfinite(reference_azimuth_deg) || std::abs(reference_azimuth_deg) > 360.0) {
    if (why)
      *why = "reference_azimuth_deg must be finite and within +-360, got " +
             std::to_string(reference_azimuth_deg);
    return false;
  }
  return true;
}

namespace {

using fast_math::fastAtan2;
using fast_math::pick;

/// azimuthTimes for the points \a point(k), k < n.
template <typename PointOf>
std::vector<float>
azimuthTimesOf(std::size_t n, PointOf&& point, double period_s, const SweepParams& sweep)
{
  if (!(period_s > 0.0) || !std::isfinite(period_s))
    throw std::invalid_argument("azimuthTimes: period_s must be > 0 and finite, got " +
                                std::to_string(period_s));
  std::string why;
  if (!sweep.isValid(&why))
    throw std::invalid_argument("azimuthTimes: " + why);
  // In (-pi, pi], so that one wrap below brings every azimuth difference there too.
  const double reference =
      std::remainder(sweep.reference_azimuth_deg * kPi / 180.0, 2.0 * kPi);
  // Clockwise: azimuth falls over time, so a point at +a (before the reference column
  // in the sweep) fired earlier: tau = -a / (2 pi) * period.
  const auto scale =
      static_cast<float>((sweep.clockwise ? -1.0 : 1.0) * period_s / (2.0 * kPi));
  const auto ref = static_cast<float>(reference);
  constexpr auto kPiF = static_cast<float>(kPi), k2PiF = static_cast<float>(2.0 * kPi);
  std::vector<float> times(n);
  // Blocks of x and y copied out of the points, so that the arithmetic runs on
  // contiguous floats and vectorizes.
  constexpr std::size_t kBlock = 256;
  float xs[kBlock], ys[kBlock];
  for (std::size_t i0 = 0; i0 < n; i0 += kBlock) {
    const std::size_t m = std::min(kBlock, n - i0);
    for (std::size_t k = 0; k < m; ++k) {
      const pcl::PointXYZI& p = point(i0 + k);
      xs[k] = p.x;
      ys[k] = p.y;
    }
    float* out = times.data() + i0;
    for (std::size_t k = 0; k < m; ++k) {
      float a = fastAtan2(ys[k], xs[k]) - ref;
      a = pick(a > kPiF, a - k2PiF, a); // into (-pi, pi]
      a = pick(a <= -kPiF, a + k2PiF, a);
      out[k] = scale * a;
    }
  }
  return times;
}

} // namespace

std::vector<float>
azimuthTimes(const pcl::PointCloud<pcl::PointXYZI>& cloud,
             double period_s,
             const SweepParams& sweep)
{
  return azimuthTimesOf(
      cloud.size(),
      [&cloud](std::size_t i) -> const pcl::PointXYZI& { return cloud.points[i]; },
      period_s,
      sweep);
}

std::vector<float>
azimuthTimes(const pcl::PointCloud<pcl::PointXYZI>& cloud,
             const pcl::Indices& indices,
             double period_s,
             const SweepParams& sweep)
{
  for (const auto i : indices)
    if (i < 0 || static_cast<std::size_t>(i) >= cloud.size())
      throw std::out_of_range("azimuthTimes: index " + std::to_string(i) +
                              " outside a cloud of " + std::to_string(cloud.size()) +
                              " points");
  return azimuthTimesOf(
      indices.size(),
      [&](std::size_t k) -> const pcl::PointXYZI& {
        return cloud.points[static_cast<std::size_t>(indices[k])];
      },
      period_s,
      sweep);
}

void
deskewCloudInPlace(pcl::PointCloud<pcl::PointXYZI>& cloud,
                   const std::vector<float>& times_s,
                   const Twist& xi_per_s,
                   int bins)
{
  if (times_s.size() != cloud.size())
    throw std::invalid_argument("deskewCloud: " + std::to_string(times_s.size()) +
                                " times for " + std::to_string(cloud.size()) + " points");
  if (bins < 1)
    throw std::invalid_argument("deskewCloud: bins must be >= 1, got " +
                                std::to_string(bins));
  // The range of the finite times; a point with a non-finite time (or coordinate) is
  // left as it is.
  // Eight running minima and maxima with selects, no branch: independent lanes that
  // the compiler vectorizes (one running pair is a chain of dependent loads).
  constexpr int kLanes = 8;
  constexpr float kInfF = std::numeric_limits<float>::infinity();
  float lo_lane[kLanes], hi_lane[kLanes];
  std::fill(lo_lane, lo_lane + kLanes, kInfF);
  std::fill(hi_lane, hi_lane + kLanes, -kInfF);
  const std::size_t n_times = times_s.size();
  std::size_t i = 0;
  for (; i + kLanes <= n_times; i += kLanes)
    for (int k = 0; k < kLanes; ++k) {
      const float t = times_s[i + k];
      const bool finite =
          std::abs(t) <= std::numeric_limits<float>::max(); // false for NaN
      lo_lane[k] = finite && t < lo_lane[k] ? t : lo_lane[k];
      hi_lane[k] = finite && t > hi_lane[k] ? t : hi_lane[k];
    }
  for (; i < n_times; ++i)
    if (std::isfinite(times_s[i])) {
      lo_lane[0] = std::min(lo_lane[0], times_s[i]);
      hi_lane[0] = std::max(hi_lane[0], times_s[i]);
    }
  const float lo_f = *std::min_element(lo_lane, lo_lane + kLanes);
  const float hi_f = *std::max_element(hi_lane, hi_lane + kLanes);
  if (!(lo_f <= hi_f) || !xi_per_s.allFinite())
    return;
  const double lo = lo_f, span = static_cast<double>(hi_f) - lo;
  const int n = span > 0.0 ? bins : 1;
  // One transform per bin, at the bin's middle time.
  std::vector<Eigen::Matrix<float, 3, 4>> transforms;
  transforms.reserve(static_cast<std::size_t>(n));
  for (const Pose3d& T : binTransforms(lo, span, n, xi_per_s))
    transforms.push_back(T.matrix().topRows<3>().cast<float>());
  const auto lo_t = static_cast<float>(lo);
  const auto to_bin = static_cast<float>(span > 0.0 ? n / span : 0.0);
  for (std::size_t i = 0; i < cloud.size(); ++i) {
    const float t = times_s[i];
    if (!std::isfinite(t))
      continue;
    const int b = std::min(n - 1, static_cast<int>((t - lo_t) * to_bin));
    const Eigen::Matrix<float, 3, 4>& T = transforms[static_cast<std::size_t>(b)];
    auto& p = cloud.points[i];
    p.getVector3fMap() = T.leftCols<3>() * p.getVector3fMap() + T.col(3);
  }
}

pcl::PointCloud<pcl::PointXYZI>::Ptr
deskewCloud(const pcl::PointCloud<pcl::PointXYZI>& cloud,
            const std::vector<float>& times_s,
            const Twist& xi_per_s,
            int bins)
{
  auto out = std::make_shared<pcl::PointCloud<pcl::PointXYZI>>(cloud);
  deskewCloudInPlace(*out, times_s, xi_per_s, bins);
  return out;
}

void
deskewPointsAndNormals(
    std::vector<Eigen::Vector3d, Eigen::aligned_allocator<Eigen::Vector3d>>& points,
    std::vector<Eigen::Vector3d, Eigen::aligned_allocator<Eigen::Vector3d>>& normals,
    const std::vector<float>& times_s,
    const Twist& xi_per_s,
    int bins)
{
  if (times_s.size() != points.size())
    throw std::invalid_argument(
        "deskewPointsAndNormals: " + std::to_string(times_s.size()) + " times for " +
        std::to_string(points.size()) + " points");
  if (!normals.empty() && normals.size() != points.size())
    throw std::invalid_argument(
        "deskewPointsAndNormals: " + std::to_string(normals.size()) + " normals for " +
        std::to_string(points.size()) + " points");
  if (bins < 1)
    throw std::invalid_argument("deskewPointsAndNormals: bins must be >= 1, got " +
                                std::to_string(bins));
  if (!xi_per_s.allFinite())
    return;
  double lo = std::numeric_limits<double>::infinity();
  double hi = -lo;
  for (const float t : times_s)
    if (std::isfinite(t)) {
      lo = std::min<double>(lo, t);
      hi = std::max<double>(hi, t);
    }
  if (!(lo <= hi))
    return;
  // One transform per bin at its middle time, as deskewCloudInPlace() bins them.
  const double span = hi - lo;
  const int n = span > 0.0 ? bins : 1;
  const auto transforms = binTransforms(lo, span, n, xi_per_s);
  const double to_bin = span > 0.0 ? n / span : 0.0;
  for (std::size_t i = 0; i < points.size(); ++i) {
    const float t = times_s[i];
    if (!std::isfinite(t))
      continue;
    const int b = std::min(n - 1, static_cast<int>((t - lo) * to_bin));
    const Pose3d& T = transforms[static_cast<std::size_t>(b)];
    points[i] = T * points[i];
    if (!normals.empty())
      normals[i] = T.linear() * normals[i];
  }
}

} // namespace rast
} // namespace pcl
