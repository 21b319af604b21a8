/// \file polar_descriptor.cpp
/// \brief The polar max-height descriptor (polar_descriptor.h).

#include "polar_descriptor.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>

namespace pcl {
namespace rast {
namespace slam_detail {

namespace {
constexpr double kTwoPi = 2.0 * 3.14159265358979323846;
} // namespace

PolarDescriptor::PolarDescriptor(const pcl::PointCloud<pcl::PointXYZI>& cloud,
                                 const PolarDescriptorParams& params)
    : rings_(params.rings), sectors_(params.sectors)
{
  if (!params.isValid())
    throw std::invalid_argument(
        "PolarDescriptor: rings must be >= 1, sectors >= 3, max_range_m > 0 and "
        "height_offset_m >= 0, got " +
        std::to_string(params.rings) + ", " + std::to_string(params.sectors) + ", " +
        std::to_string(params.max_range_m) + " and " +
        std::to_string(params.height_offset_m));
  Eigen::MatrixXf heights = Eigen::MatrixXf::Zero(rings_, sectors_);
  const double ring_m = params.max_range_m / rings_;
  const double sector_rad = kTwoPi / sectors_;
  const double max_range2 = params.max_range_m * params.max_range_m;
  for (const pcl::PointXYZI& p : cloud.points) {
    if (!std::isfinite(p.x) || !std::isfinite(p.y) || !std::isfinite(p.z))
      continue;
    const double x = p.x, y = p.y;
    const double range2 = x * x + y * y;
    if (!(range2 < max_range2))
      continue;
    double azimuth = std::atan2(y, x);
    if (azimuth < 0.0)
      azimuth += kTwoPi;
    const int ring = std::min(rings_ - 1, static_cast<int>(std::sqrt(range2) / ring_m));
    const int sector = std::min(sectors_ - 1, static_cast<int>(azimuth / sector_rad));
    float& cell = heights(ring, sector);
    cell = std::max(cell, static_cast<float>(p.z + params.height_offset_m));
  }
  cells_.assign(static_cast<std::size_t>(heights.size()), 0);
  occupied_.assign(static_cast<std::size_t>(sectors_), 0);
  for (int j = 0; j < sectors_; ++j) {
    // In double: the squares of heights beyond 1e19 m overflow a float.
    const double norm = heights.col(j).cast<double>().norm();
    if (!(norm > 0.0) || !std::isfinite(norm))
      continue;
    occupied_[j] = 1;
    for (int r = 0; r < rings_; ++r)
      cells_[static_cast<std::size_t>(j) * rings_ + r] =
          static_cast<std::uint8_t>(std::lround(255.0 * heights(r, j) / norm));
  }
}

void
PolarDescriptor::unpack(Eigen::MatrixXf& out) const
{
  out = Eigen::Map<const Eigen::Matrix<std::uint8_t, Eigen::Dynamic, Eigen::Dynamic>>(
            cells_.data(), rings_, sectors_)
            .cast<float>() *
        (1.0f / 255.0f);
}

std::pair<double, int>
PolarDescriptor::distance(const PolarDescriptor& other) const
{
  if (empty() || other.sectors_ != sectors_ || other.rings_ != rings_)
    return {1.0, 0};
  // The cosine of every pair of sectors (this one's j, the other's k) at once, in
  // buffers each thread keeps: a ranking compares thousands of key-frames.
  thread_local Eigen::MatrixXf a, b, cosines;
  unpack(a);
  other.unpack(b);
  cosines.noalias() = a.transpose() * b;
  // Sectors both hold, fewer than a quarter: too little seen in common to compare.
  const int min_shared = std::max(1, sectors_ / 4);
  double best = 1.0;
  int best_shift = 0;
  for (int s = 0; s < sectors_; ++s) {
    double sum = 0.0;
    int shared = 0;
    for (int j = 0, k = s; j < sectors_; ++j, k = k + 1 == sectors_ ? 0 : k + 1) {
      if (!occupied_[j] || !other.occupied_[k])
        continue;
      sum += 1.0 - cosines(j, k);
      ++shared;
    }
    if (shared < min_shared)
      continue;
    const double d = sum / shared;
    if (d < best) {
      best = d;
      best_shift = s;
    }
  }
  return {best, best_shift};
}

double
PolarDescriptor::yawDeg(int shift) const
{
  if (sectors_ == 0)
    return 0.0;
  double yaw = 360.0 * shift / sectors_;
  if (yaw >= 180.0)
    yaw -= 360.0;
  return yaw;
}

std::size_t
PolarDescriptor::bytes() const
{
  return sizeof(*this) + cells_.capacity() + occupied_.capacity();
}

std::vector<PolarMatch>
rankByPolarDescriptor(const PolarDescriptor& query,
                      const std::vector<PolarDescriptor>& candidates,
                      std::size_t count)
{
  std::vector<PolarMatch> matches;
  matches.reserve(candidates.size());
  for (std::size_t i = 0; i < candidates.size(); ++i) {
    const auto [d, shift] = query.distance(candidates[i]);
    if (d < 1.0)
      matches.push_back(PolarMatch{i, d, query.yawDeg(shift)});
  }
  const std::size_t n = std::min(count, matches.size());
  std::partial_sort(matches.begin(),
                    matches.begin() + static_cast<std::ptrdiff_t>(n),
                    matches.end(),
                    [](const PolarMatch& a, const PolarMatch& b) {
                      return a.distance < b.distance ||
                             (a.distance == b.distance && a.index < b.index);
                    });
  matches.resize(n);
  return matches;
}

} // namespace slam_detail
} // namespace rast
} // namespace pcl
