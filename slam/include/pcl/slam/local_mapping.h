#pragma once
/// \file local_mapping.h
/// \brief The mapping stage (the paper's section 8): each new key-frame's features are
/// matched against the local map (unmatched ones become map points), then local bundle
/// adjustment refines the newest n key-frames and the map points they see, and
/// key-frame / map-point culling keep the problem bounded.
/// \ingroup slam

#include <pcl/slam/bundle_adjustment.h>
#include <pcl/slam/keyframe.h>
#include <pcl/slam/slam_map.h>

#include <cstddef>
#include <memory>
#include <string>
#include <vector>

namespace pcl {
namespace rast {

/// \brief Settings of LocalMapping.
struct LocalMappingParams
{
  /// Run local bundle adjustment (off: key-frame poses stay those of tracking). Default
  /// chosen by measurement, see doc/slam.md. RastSlam runs local mapping (map points)
  /// only when this or the global bundle adjustment is on: nothing else uses them.
  bool enable_bundle_adjustment = false;
  /// n: the newest n key-frames are optimized (paper 8.1); older ones leave the local
  /// graph (key-frame culling) and map points seen by none of the n are removed.
  int window_size = 8;
  /// At most this many older key-frames that see the window's points are added as
  /// constant poses (the window's border).
  int max_border_keyframes = 8;
  /// Map-point association: largest distance between a map point (predicted into the
  /// key-frame by its pose) and a feature's 3D point [m].
  double match_radius_m = 0.6;
  /// Largest Hamming distance of a map-point association [bits].
  int max_hamming_distance = 50;
  /// Bundle-adjustment settings (projection, robust loss, iterations).
  BundleAdjustmentParams bundle_adjustment;

  bool isValid(std::string* why = nullptr) const;
};

/// \brief What local mapping did with one key-frame.
struct LocalMappingResult
{
  KeyFrameId keyframe = 0;
  int num_matched = 0;       ///< features associated with existing map points
  int num_created = 0;       ///< new map points
  int num_culled = 0;        ///< map points removed
  int num_map_points = 0;    ///< live map points after culling
  bool ba_run = false;
  bool ba_applied = false;   ///< false when a loop correction made the result stale
  BundleAdjustmentSummary ba;
  double total_ms = 0.0;
};

/// \brief Local mapping over a shared SlamMap (one instance per map; its
/// processKeyFrame() is called by one thread at a time, key-frames in id order).
class LocalMapping
{
public:
  using Ptr = std::shared_ptr<LocalMapping>;

  /// \throws std::invalid_argument on invalid params or a null map.
  LocalMapping(const LocalMappingParams& params, SlamMap::Ptr map);

  /// \brief Process a key-frame already added to the map.
  /// \throws std::invalid_argument on a null key-frame or one unknown to the map.
  LocalMappingResult processKeyFrame(const KeyFrame::Ptr& kf);

  const LocalMappingParams& params() const { return params_; }

private:
  /// Steps 1-2: the key-frame's features matched with the local map's points (predicted
  /// into it, nearest descriptor within match_radius_m); the others make new points.
  void associate(const KeyFrame::Ptr& kf, LocalMappingResult& result);
  /// Step 3: the newest window_size key-frames up to \a newest.
  std::vector<KeyFrameId> windowOf(KeyFrameId newest) const;
  /// Step 4: local bundle adjustment of the window, its border held constant.
  void adjustWindow(const std::vector<KeyFrameId>& window, LocalMappingResult& result);

  LocalMappingParams params_;
  SlamMap::Ptr map_;
};

} // namespace rast
} // namespace pcl
