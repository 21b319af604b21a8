/// \file elevation_calibration.cpp
/// \brief The odometry's self-calibration of the beams' elevation angles
/// (ElevationCalibrationParams, doc/odometry.md "Beam elevation self-calibration").

#include "elevation_calibration.h"

#include <algorithm>
#include <cmath>
#include <string>

namespace pcl {
namespace rast {

bool
ElevationCalibrationParams::isValid(std::string* why) const
{
  std::string reason;
  if (!(bin_deg >= 0.005 && bin_deg <= 1.0))
    reason = "bin_deg must be in [0.005, 1], got " + std::to_string(bin_deg);
  else if (window_frames < 1)
    reason = "window_frames must be >= 1, got " + std::to_string(window_frames);
  else if (min_pairs < 1)
    reason = "min_pairs must be >= 1, got " + std::to_string(min_pairs);
  else if (!(min_mean_lever_m >= 0.0) || !std::isfinite(min_mean_lever_m))
    reason = "min_mean_lever_m must be finite and >= 0, got " +
             std::to_string(min_mean_lever_m);
  else if (!(max_residual_m > 0.0) || !std::isfinite(max_residual_m))
    reason =
        "max_residual_m must be finite and > 0, got " + std::to_string(max_residual_m);
  else if (!(max_scatter_ratio >= 1.0) || !std::isfinite(max_scatter_ratio))
    reason = "max_scatter_ratio must be finite and >= 1, got " +
             std::to_string(max_scatter_ratio);
  else if (!(max_correction_deg > 0.0 && max_correction_deg <= 5.0))
    reason =
        "max_correction_deg must be in (0, 5], got " + std::to_string(max_correction_deg);
  if (why)
    *why = reason;
  return reason.empty();
}

namespace odometry_detail {

namespace {
constexpr float kRadToDeg = 57.2957795f;
/// The least share of a window's step taken (ElevationCalibration::update).
constexpr double kMinGain = 0.2;
} // namespace

ElevationTable::ElevationTable(float bin) : bin_deg(bin)
{
  const auto n = static_cast<std::size_t>(std::ceil((kMaxDeg - kMinDeg) / bin_deg));
  delta_rad.assign(n, 0.0f);
  cos_delta.assign(n, 1.0f);
  sin_delta.assign(n, 0.0f);
  auto lut = std::make_shared<std::vector<std::int16_t>>(kTanSteps);
  for (int i = 0; i < kTanSteps; ++i) {
    // The step's middle: its elevation's bin.
    const double t = -1.0 + (i + 0.5) * 2.0 / kTanSteps;
    const double el_deg = std::atan(t) * kRadToDeg;
    const int b = static_cast<int>(std::floor((el_deg - kMinDeg) / bin_deg));
    (*lut)[static_cast<std::size_t>(i)] =
        static_cast<std::int16_t>(b >= 0 && b < static_cast<int>(n) ? b : -1);
  }
  bin_of_tan = std::move(lut);
}

void
ElevationTable::set(int b, double delta)
{
  delta_rad[b] = static_cast<float>(delta);
  cos_delta[b] = static_cast<float>(std::cos(delta));
  sin_delta[b] = static_cast<float>(std::sin(delta));
}

pcl::PointCloud<pcl::PointXYZI>::Ptr
applyElevationTable(const ElevationTable& table,
                    const pcl::PointCloud<pcl::PointXYZI>& scan)
{
  auto out = std::make_shared<pcl::PointCloud<pcl::PointXYZI>>(scan);
  for (auto& p : out->points) {
    // Turned up by delta in the plane of the point's azimuth: (rho, z) rotated, so
    // x and y scale by cos - tan(elevation) sin. (NaN fails rho_sq > 0, an infinite
    // coordinate the look-up's range.)
    const float rho_sq = p.x * p.x + p.y * p.y;
    if (!(rho_sq > 0.0f))
      continue;
    const float rho = std::sqrt(rho_sq);
    const float t = p.z / rho;
    const int b = table.binOfTan(t);
    if (b < 0)
      continue;
    const float c = table.cos_delta[b], s = table.sin_delta[b];
    const float scale = c - t * s;
    p.x *= scale;
    p.y *= scale;
    p.z = p.z * c + rho * s;
  }
  return out;
}

ElevationCalibration::ElevationCalibration(const ElevationCalibrationParams& params)
    : params_(params), layout_(static_cast<float>(params.bin_deg))
{
  const auto n = static_cast<std::size_t>(layout_.bins());
  total_rad_.assign(n, 0.0);
  info_.assign(n, 0.0);
  num_.assign(n, 0.0);
  den_.assign(n, 0.0);
  lever_.assign(n, 0.0);
  sq_.assign(n, 0.0);
  pairs_.assign(n, 0);
}

void
ElevationCalibration::observe(const pcl::PointCloud<pcl::PointXYZI>& raw,
                              const std::vector<int>& indices,
                              const Points3f& source,
                              const Eigen::Isometry3f& T_world_lidar,
                              const VoxelPlaneMap& map)
{
  const auto max_residual = static_cast<float>(params_.max_residual_m);
  const Eigen::Matrix3f R_world_lidar = T_world_lidar.linear();
  const std::size_t n = std::min(indices.size(), source.size());
  for (std::size_t k = 0; k < n; ++k) {
    const pcl::PointXYZI& r = raw[static_cast<std::size_t>(indices[k])];
    const float rho = std::sqrt(r.x * r.x + r.y * r.y);
    if (!(rho > 0.0f))
      continue;
    const float range = std::sqrt(rho * rho + r.z * r.z);
    const int b = layout_.binOfTan(r.z / rho); // binOf, with rho at hand
    if (b < 0)
      continue;
    const Eigen::Vector3f q = T_world_lidar * source[k];
    Eigen::Vector3f centroid, normal;
    if (!map.plane(q, centroid, normal))
      continue;
    const float d = normal.dot(q - centroid);
    if (!(std::abs(d) <= max_residual))
      continue;
    // A point placed delta below its beam's true elevation lies range * delta along
    // -e (the direction of rising elevation): d = -delta * a with a = range * n.e.
    const Eigen::Vector3f e_lidar(
        -r.z * r.x / (range * rho), -r.z * r.y / (range * rho), rho / range);
    const float a = range * normal.dot(R_world_lidar * e_lidar);
    if (std::abs(a) < 0.5f * range) // a surface seen edge-on to the beam's fan
      continue;
    num_[b] += static_cast<double>(d) * a;
    den_[b] += static_cast<double>(a) * a;
    lever_[b] += std::abs(a);
    sq_[b] += static_cast<double>(d) * d;
    ++pairs_[b];
  }
  if (++frames_ >= params_.window_frames)
    update();
}

void
ElevationCalibration::update()
{
  const double max_rad = params_.max_correction_deg * M_PI / 180.0;
  // The bins with enough pairs far enough out: the scatter of their residuals about
  // the step each would take.
  std::vector<std::size_t> candidates;
  std::vector<double> scatter;
  for (std::size_t b = 0; b < total_rad_.size(); ++b)
    if (pairs_[b] >= params_.min_pairs && den_[b] > 0.0 &&
        lever_[b] >= params_.min_mean_lever_m * pairs_[b]) {
      const double step = -num_[b] / den_[b];
      const double unexplained =
          (sq_[b] + 2.0 * step * num_[b] + step * step * den_[b]) / pairs_[b];
      candidates.push_back(b);
      scatter.push_back(std::sqrt(std::max(0.0, unexplained)));
    }
  // A bin whose residuals scatter far more than the typical bin's pairs with no plane
  // (the points of a tree's crown scatter through the foliage): not updated.
  bool changed = false;
  if (!candidates.empty()) {
    std::vector<double> sorted = scatter;
    std::nth_element(sorted.begin(), sorted.begin() + sorted.size() / 2, sorted.end());
    const double limit = params_.max_scatter_ratio * sorted[sorted.size() / 2];
    for (std::size_t i = 0; i < candidates.size(); ++i) {
      const std::size_t b = candidates[i];
      if (scatter[i] > limit)
        continue;
      // The step is what the window measured of the error left. Taken whole at first;
      // later windows are averaged in by their share of the bin's information, down to
      // kMinGain: the windows' own noise (another street, other surfaces) would
      // otherwise add up from window to window, while the share still lets the estimate
      // move on where the first windows fell short (the local map is made of points
      // corrected less, so a window sees only part of the error).
      const double gain = std::max(kMinGain, den_[b] / (info_[b] + den_[b]));
      total_rad_[b] -= gain * num_[b] / den_[b];
      info_[b] += den_[b];
      changed = true;
    }
  }
  std::fill(num_.begin(), num_.end(), 0.0);
  std::fill(den_.begin(), den_.end(), 0.0);
  std::fill(sq_.begin(), sq_.end(), 0.0);
  std::fill(lever_.begin(), lever_.end(), 0.0);
  std::fill(pairs_.begin(), pairs_.end(), 0);
  frames_ = 0;
  if (!changed)
    return;
  // Two patterns the residuals hardly tell: one offset of every beam (the ground a
  // shallow cone, the map made of the same cone) and one proportional to the
  // elevation (every height scaled, a world consistent with itself). Both are taken
  // out (weighted by each bin's information): only the beams' differences are
  // corrected.
  double s0 = 0, s1 = 0, s2 = 0, t0 = 0, t1 = 0;
  for (std::size_t b = 0; b < total_rad_.size(); ++b) {
    if (info_[b] <= 0.0)
      continue;
    const double w = info_[b];
    const double el = layout_.centreDeg(static_cast<int>(b)) * M_PI / 180.0;
    s0 += w;
    s1 += w * el;
    s2 += w * el * el;
    t0 += w * total_rad_[b];
    t1 += w * el * total_rad_[b];
  }
  const double det = s0 * s2 - s1 * s1;
  if (det > 1e-12 * s0 * s0) {
    const double a = (s2 * t0 - s1 * t1) / det, slope = (s0 * t1 - s1 * t0) / det;
    for (std::size_t b = 0; b < total_rad_.size(); ++b)
      if (info_[b] > 0.0) {
        const double el = layout_.centreDeg(static_cast<int>(b)) * M_PI / 180.0;
        total_rad_[b] -= a + slope * el;
      }
  }
  for (double& t : total_rad_)
    t = std::clamp(t, -max_rad, max_rad);
  ++updates_;
  auto table = std::make_shared<ElevationTable>(layout_);
  for (std::size_t b = 0; b < total_rad_.size(); ++b)
    table->set(static_cast<int>(b), total_rad_[b]);
  table_ = std::move(table);
}

ElevationCalibrationState
ElevationCalibration::state() const
{
  ElevationCalibrationState s;
  s.enabled = true;
  s.updates = updates_;
  double sum_sq = 0.0;
  for (std::size_t b = 0; b < total_rad_.size(); ++b) {
    if (total_rad_[b] == 0.0)
      continue;
    const double deg = total_rad_[b] * 180.0 / M_PI;
    s.corrections.emplace_back(layout_.centreDeg(static_cast<int>(b)), deg);
    sum_sq += deg * deg;
    s.max_abs_correction_deg = std::max(s.max_abs_correction_deg, std::abs(deg));
  }
  s.bins_corrected = static_cast<int>(s.corrections.size());
  if (s.bins_corrected > 0)
    s.rms_correction_deg = std::sqrt(sum_sq / s.bins_corrected);
  return s;
}

} // namespace odometry_detail
} // namespace rast
} // namespace pcl
