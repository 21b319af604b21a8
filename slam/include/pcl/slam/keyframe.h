#pragma once
/// \file keyframe.h
/// \brief The key-frame, the unit of data the tracking, local-mapping and
/// loop-closing stages hand to each other (the paper's section 7.3: a key-frame keeps
/// its 6-DoF pose, the 3D positions of its feature points and their descriptors).
/// \ingroup slam

#include <pcl/features/raster_feature_types.h>
#include <pcl/rast/rigid_pose.h>

#include <pcl/point_cloud.h>
#include <pcl/point_types.h>

#include <cstddef>
#include <cstdint>
#include <memory>
#include <vector>

namespace pcl {
namespace rast {

/// \brief Identifier of a key-frame: 0, 1, 2, ... in creation order.
using KeyFrameId = std::uint32_t;
/// \brief Identifier of a map point; kNoMapPoint marks a feature without one.
using MapPointId = std::int64_t;
constexpr MapPointId kNoMapPoint = -1;

/// \brief A key-frame. Everything but the pose is immutable once the key-frame has
/// left tracking; the pose T_world_keyframe is owned by the SLAM map and read or written
/// only under its lock (local BA and pose-graph optimisation update it).
struct KeyFrame
{
  using Ptr = std::shared_ptr<KeyFrame>;
  using ConstPtr = std::shared_ptr<const KeyFrame>;

  KeyFrameId id = 0;            ///< creation order
  std::size_t frame_index = 0;  ///< index of the input scan it was made from
  double timestamp_s = 0.0;     ///< time of that scan

  /// Pose of the key-frame's LiDAR frame in the world (the first scan's LiDAR frame).
  Pose3d T_world_keyframe = Pose3d::Identity();
  /// Relative motion from the previous key-frame as measured by tracking (odometry edge
  /// of the pose graph); identity for the first key-frame.
  Pose3d T_previous_keyframe = Pose3d::Identity();
  /// Scans tracking had put into its local map when this key-frame's pose was registered
  /// against it (0 for the first; a count, not what the map still holds): a young map
  /// is a weaker reference (LoopClosingParams::young_map_sigma_scale).
  int odometry_map_scans = 0;

  /// ORB features; points in this key-frame's LiDAR frame, descriptors index-aligned.
  RasterFeatureSet features;
  /// Per feature, the map point it observes, or kNoMapPoint (filled by local mapping).
  std::vector<MapPointId> map_point_ids;

  /// The voxelized scan in this key-frame's LiDAR frame (for the merged map, dense
  /// loop verification and refinement targets). Never modified; RastSlam releases it
  /// (null) once loop closing is done with the key-frame unless
  /// SlamParams::keep_keyframe_clouds is set: the SLAM map keeps a compact copy.
  pcl::PointCloud<pcl::PointXYZI>::ConstPtr cloud;
};

} // namespace rast
} // namespace pcl
