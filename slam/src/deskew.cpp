/// \file deskew.cpp
/// \brief Motion compensation of raw sweeps: SE(3) log / exp, azimuth times, eq. (1).

#include <pcl/slam/deskew.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>

namespace pcl {
namespace rast {
namespace {

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

/// atan2 in single precision, to ~3e-7 rad (5 ns of a 0.1 s sweep) at a fraction of
/// std::atan2's cost: the polynomial of atan on [0, 1] of Abramowitz & Stegun 4.4.49
/// (2e-8 rad), then the octant.
inline float
fastAtan2(float y, float x)
{
  constexpr float kPiF = 3.14159265f;
  const float ax = std::abs(x), ay = std::abs(y);
  const float mx = std::max(ax, ay);
  if (mx == 0.0f)
    return 0.0f;
  const float a = std::min(ax, ay) / mx;
  const float s = a * a;
  float r =
      a * (1.0f + s * (-0.3333314528f +
                       s * (0.1999355085f +
                            s * (-0.1420889944f +
                                 s * (0.1065626393f +
                                      s * (-0.0752896400f +
                                           s * (0.0429096138f +
                                                s * (-0.0161657367f + s * 0.0028662257f))))))));
  if (ay > ax)
    r = 0.5f * kPiF - r;
  if (x < 0.0f)
    r = kPiF - r;
  return y < 0.0f ? -r : r;
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

std::vector<float>
azimuthTimes(const pcl::PointCloud<pcl::PointXYZI>& cloud,
             double period_s,
             const SweepParams& sweep)
{
  if (!(period_s > 0.0) || !std::isfinite(period_s))
    throw std::invalid_argument("azimuthTimes: period_s must be > 0 and finite, got " +
                                std::to_string(period_s));
  std::string why;
  if (!sweep.isValid(&why))
    throw std::invalid_argument("azimuthTimes: " + why);
  // In (-pi, pi], so that one wrap below brings every azimuth difference there too.
  const double reference = std::remainder(sweep.reference_azimuth_deg * kPi / 180.0, 2.0 * kPi);
  // Clockwise: azimuth falls over time, so a point at +a (before the reference column
  // in the sweep) fired earlier: tau = -a / (2 pi) * period.
  const auto scale = static_cast<float>((sweep.clockwise ? -1.0 : 1.0) * period_s / (2.0 * kPi));
  const auto ref = static_cast<float>(reference);
  constexpr auto kPiF = static_cast<float>(kPi), k2PiF = static_cast<float>(2.0 * kPi);
  std::vector<float> times(cloud.size());
  for (std::size_t i = 0; i < cloud.size(); ++i) {
    const auto& p = cloud.points[i];
    float a = fastAtan2(p.y, p.x) - ref;
    if (a > kPiF) // into (-pi, pi]
      a -= k2PiF;
    else if (a <= -kPiF)
      a += k2PiF;
    times[i] = scale * a;
  }
  return times;
}

pcl::PointCloud<pcl::PointXYZI>::Ptr
deskewCloud(const pcl::PointCloud<pcl::PointXYZI>& cloud,
            const std::vector<float>& times_s,
            const Twist& xi_per_s,
            int bins)
{
  if (times_s.size() != cloud.size())
    throw std::invalid_argument("deskewCloud: " + std::to_string(times_s.size()) +
                                " times for " + std::to_string(cloud.size()) + " points");
  if (bins < 1)
    throw std::invalid_argument("deskewCloud: bins must be >= 1, got " + std::to_string(bins));
  auto out = std::make_shared<pcl::PointCloud<pcl::PointXYZI>>(cloud);
  // The range of the finite times; a point with a non-finite time (or coordinate) is
  // left as it is.
  float lo_f = std::numeric_limits<float>::infinity(), hi_f = -lo_f;
  for (const float t : times_s)
    if (std::isfinite(t)) {
      lo_f = std::min(lo_f, t);
      hi_f = std::max(hi_f, t);
    }
  if (!(lo_f <= hi_f) || !xi_per_s.allFinite())
    return out;
  const double lo = lo_f, span = static_cast<double>(hi_f) - lo;
  const int n = span > 0.0 ? bins : 1;
  // One transform per bin, at the bin's middle time.
  std::vector<Eigen::Matrix<float, 3, 4>> transforms(static_cast<std::size_t>(n));
  for (int b = 0; b < n; ++b) {
    const double tau = lo + (b + 0.5) * span / n;
    transforms[static_cast<std::size_t>(b)] =
        expSE3(tau * xi_per_s).matrix().topRows<3>().cast<float>();
  }
  const double to_bin = span > 0.0 ? n / span : 0.0;
  for (std::size_t i = 0; i < cloud.size(); ++i) {
    if (!std::isfinite(times_s[i]))
      continue;
    const int b = std::min(n - 1, static_cast<int>((times_s[i] - lo) * to_bin));
    const Eigen::Matrix<float, 3, 4>& T = transforms[static_cast<std::size_t>(b)];
    auto& p = out->points[i];
    p.getVector3fMap() = T.leftCols<3>() * p.getVector3fMap() + T.col(3);
  }
  return out;
}

} // namespace rast
} // namespace pcl
