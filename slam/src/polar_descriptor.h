#pragma once
/// \file polar_descriptor.h
/// \brief Internal to the slam library: a polar max-height descriptor of a scan, for
/// finding a key-frame of a saved map where the raster features retrieve none
/// (SessionLocalizer's polar candidates). The paper's raster keeps each pixel's
/// greatest height on a Cartesian grid; the same in polar cells around the sensor is a
/// Scan Context (Kim and Kim, IROS 2018): a turn of the sensor about its z axis only
/// shifts the columns (sectors), so the best column shift also gives the yaw between
/// two scans. Not installed.

#include <Eigen/Core>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <pcl/point_cloud.h>
#include <pcl/point_types.h>
#include <utility>
#include <vector>

namespace pcl {
namespace rast {
namespace slam_detail {

/// \brief Shape of a PolarDescriptor.
struct PolarDescriptorParams
{
  int rings = 20;            ///< radial cells out to max_range_m (>= 1)
  int sectors = 60;          ///< angular cells over 360 deg (>= 3)
  double max_range_m = 60.0; ///< points farther (in x-y) are left out (> 0)
  /// A cell holds the greatest z + height_offset_m of its points, at least 0 (0 also
  /// stands for an empty cell): the offset lifts the ground a sensor 1.7-2 m up sees
  /// above 0, as the raster's heights are taken from below the sensor.
  double height_offset_m = 2.5;
  bool isValid() const
  {
    return rings >= 1 && sectors >= 3 && max_range_m > 0.0 &&
           std::isfinite(max_range_m) && height_offset_m >= 0.0 &&
           std::isfinite(height_offset_m);
  }
};

/// \brief The descriptor of one scan: rings x sectors cells.
class PolarDescriptor
{
public:
  PolarDescriptor() = default;
  /// \brief Describe \a cloud (points in its sensor frame; non-finite ones skipped).
  /// \throws std::invalid_argument on invalid params
  PolarDescriptor(const pcl::PointCloud<pcl::PointXYZI>& cloud,
                  const PolarDescriptorParams& params);

  /// \brief The distance to \a other (same params) at the column shift that makes it
  /// least: the mean cosine distance (0 alike, 1 unrelated) of the sectors both hold,
  /// 1 when they share none. The shift s pairs this descriptor's sector j with
  /// \a other's sector j + s: this scan's frame is turned by yawDeg(s) against
  /// \a other's (T_other_this has that yaw).
  std::pair<double, int> distance(const PolarDescriptor& other) const;

  /// \brief The yaw [deg, -180..180) of a column shift found by distance().
  double yawDeg(int shift) const;

  bool empty() const { return sectors_ == 0; }
  /// \brief Bytes held.
  std::size_t bytes() const;

private:
  /// This descriptor's columns as floats in \a out (rings x sectors).
  void unpack(Eigen::MatrixXf& out) const;

  int rings_ = 0;
  int sectors_ = 0;
  /// Per sector (column, column-major) its ring heights scaled to unit length (all
  /// zero: empty) and stored in steps of 1/255: a session keeps one per key-frame,
  /// 1.2 kB instead of 4.8 kB as floats.
  std::vector<std::uint8_t> cells_;
  std::vector<std::uint8_t> occupied_; ///< per sector: the column holds a point
};

/// \brief A candidate of rankByPolarDescriptor().
struct PolarMatch
{
  std::size_t index = 0; ///< into the candidates
  double distance = 1.0;
  double yaw_deg = 0.0;
};

/// \brief The \a count of \a candidates nearest \a query by distance(), nearest first,
/// with their distance and yaw [deg]; those at distance 1 (sharing too little with it,
/// or unrelated) are left out. Every candidate is compared: a ring key (the share of
/// each ring's sectors that hold points, which a turn does not change) kept only the
/// nearest eighth and with it lost the right key-frame of a simulated VLP-16 scan that
/// the full comparison ranks first.
std::vector<PolarMatch>
rankByPolarDescriptor(const PolarDescriptor& query,
                      const std::vector<PolarDescriptor>& candidates,
                      std::size_t count);

} // namespace slam_detail
} // namespace rast
} // namespace pcl
