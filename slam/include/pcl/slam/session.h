#pragma once
/// \file session.h
/// \brief A map that outlives its run (issue 13): everything a later run needs to
/// localize on it or extend it, saved as a folder of files other tools read.
///
/// \code
/// DIR/session.json          versioned: sensor preset, parameters, key-frames, loops,
///                           and every file below with its size and CRC-32
/// DIR/graph.g2o             key-frame poses (corrected) and the pose graph: odometry
///                           edges between consecutive key-frames, the active loops
/// DIR/keyframes/NNNNNN.pcd  each key-frame's cloud (PointXYZI, its LiDAR frame)
/// DIR/features/NNNNNN.pcd   its ORB features (ORBSignature256: point, raster position,
///                           response, angle, octave and the 256-bit descriptor)
/// \endcode
///
/// The appearance index is not stored: it is rebuilt from the feature clouds when a
/// session is used (KeyFrameDatabase, milliseconds per thousand key-frames).
///
/// Writing is all or nothing: the files go to a staging folder beside DIR, which then
/// replaces DIR in one rename (an atomic exchange where the file system has one). A
/// failed save leaves an earlier session in DIR as it was. Loading checks the version,
/// the sensor preset and every file's size and checksum before it reads any cloud.
/// \ingroup slam

#include <cstddef>
#include <functional>
#include <pcl/slam/keyframe.h>
#include <pcl/slam/pose_graph.h>
#include <pcl/slam/slam_map.h>
#include <stdexcept>
#include <string>
#include <vector>

namespace pcl {
namespace rast {

class RastSlam;
struct LoopClosingParams;

/// \brief The session format this library writes and the newest it reads.
constexpr int kSessionFormatVersion = 1;

/// \brief A session that cannot be written or used: names the file and what is wrong.
class SessionError : public std::runtime_error
{
public:
  SessionError(const std::string& path, const std::string& what_failed)
      : std::runtime_error(path + ": " + what_failed), path_(path)
  {}
  /// \brief The file or folder at fault.
  const std::string&
  path() const
  {
    return path_;
  }

private:
  std::string path_;
};

/// \brief What a session records about the run that made it.
struct SessionInfo
{
  std::string sensor_preset;        ///< preset name ("hdl64", ...); checked on load
  std::string created_by = "pcl_rast"; ///< the program that saved it
  std::string parameters_json = "{}";   ///< the run's parameters, a JSON object
  std::size_t num_frames = 0;           ///< input frames of the run
};

/// \brief One drive of a session: a run of consecutive key-frames. A session from one
/// run has one; each multi-session merge (session_merge.h) appends the new drive's.
struct SessionDrive
{
  KeyFrameId first_keyframe = 0; ///< its key-frames are first_keyframe.. + num_keyframes
  std::size_t num_keyframes = 0;
  std::size_t num_frames = 0;    ///< input frames of that run
  std::string created_by;        ///< the program that made it
  std::string input;             ///< its scan folder, when known
  /// 0: anchored in the session's world frame (the first drive and every drive joined
  /// to it by inter-session loops). Above 0: a drive that never met the map, a
  /// separate map in its own frame (its first scan's); localization ignores it.
  int component = 0;
};

/// \brief A key-frame cloud file of a loaded session.
struct SessionCloudFile
{
  std::string path;       ///< empty: the key-frame has no cloud
  std::size_t points = 0; ///< as session.json lists them
};

/// \brief A saved session in memory.
struct Session
{
  int version = kSessionFormatVersion;
  SessionInfo info;
  /// The drives, in key-frame order, covering every key-frame once. Empty in a session
  /// built by hand: then all key-frames are one drive of component 0.
  std::vector<SessionDrive> drives;
  /// Key-frames in id order (id == index): T_world_keyframe is the corrected pose,
  /// T_previous_keyframe the odometry edge, features and cloud as saved (a key-frame
  /// whose features the run had released has none).
  std::vector<KeyFrame::Ptr> keyframes;
  std::vector<LoopEdge> loops; ///< the active loop edges
  /// The pose graph as saved (nodes = key-frame ids).
  PoseGraph graph;
  /// Where loadSession found each key-frame's cloud (index = id; an empty path: none).
  /// A session loaded without its clouds (SessionLoadOptions::load_clouds = false)
  /// reads them from here when they are needed (sessionCloud). Empty in a session
  /// built in memory.
  std::vector<SessionCloudFile> cloud_files;
  /// Where the clouds of key-frames that neither hold one nor have a file come from
  /// (sessionFromSlam with clouds_on_demand: read from the run's map when needed, not
  /// copied): the key-frame's cloud, or null when it has none. Empty: no such source.
  std::function<pcl::PointCloud<pcl::PointXYZI>::ConstPtr(KeyFrameId)> cloud_source;
};

/// \brief The cloud of key-frame \a id: the one it holds, else the one its session
/// file holds (read now; the file was checked by loadSession), else the one
/// Session::cloud_source gives, else null.
/// \throws SessionError naming the file when it cannot be read or no longer holds the
/// points session.json lists; std::out_of_range for an id beyond the key-frames.
pcl::PointCloud<pcl::PointXYZI>::ConstPtr
sessionCloud(const Session& session, KeyFrameId id);

/// \brief Whether key-frame \a id has a cloud, held or in its session file (or may have
/// one from Session::cloud_source, which is only known once it is read).
bool
sessionHasCloud(const Session& session, KeyFrameId id);

/// \brief The drives of \a session, or all its key-frames as one drive of component 0
/// when it lists none.
std::vector<SessionDrive>
sessionDrives(const Session& session);

/// \brief The component of key-frame \a id (SessionDrive::component; 0 when the session
/// lists no drives). \throws std::out_of_range for an id beyond the key-frames.
int
sessionComponentOf(const Session& session, KeyFrameId id);

/// \brief The merged map of \a keyframes that hold a cloud (those of a loaded or merged
/// session), each at its T_world_keyframe, voxelized with \a leaf_m one square world
/// tile at a time, as SlamMap::forEachMapTile does for a run.
/// \throws std::invalid_argument unless leaf_m > 0.
void
forEachSessionMapTile(const std::vector<KeyFrame::Ptr>& keyframes,
                      double leaf_m,
                      const SlamMap::MapTileSink& sink);

/// \brief forEachSessionMapTile for key-frames of \a session, whose clouds not in memory
/// (a session loaded without them, SessionLoadOptions::load_clouds) are read from its
/// files when a tile needs them (sessionCloud): the map is built without holding every
/// cloud. \a session must list the key-frames' ids.
/// \throws std::invalid_argument unless leaf_m > 0; SessionError when a cloud file no
/// longer reads as loadSession checked it
void forEachSessionMapTile(const Session& session,
                           const std::vector<KeyFrame::Ptr>& keyframes,
                           double leaf_m,
                           const SlamMap::MapTileSink& sink);

/// \brief The pose graph of a SLAM map's key-frames as loop closing optimizes it:
/// nodes at the corrected poses (key-frame 0 fixed), odometry edges between
/// consecutive key-frames and the \a loops that are active, with the information loop
/// closing gives them.
PoseGraph
keyFrameGraph(const SlamMap& map,
              const std::vector<LoopEdge>& loops,
              const LoopClosingParams& params);

/// \brief Check, before any work, that a session can be saved in \a dir: a usable
/// name, and a folder that is missing, empty or holds a session (which a save replaces).
/// \throws SessionError naming the folder otherwise.
void
checkSessionDestination(const std::string& dir);

/// \brief Save the finished \a slam (RastSlam::finish() called) as a session in \a dir.
/// Key-frame clouds are the map's compact copies (SlamMap::keyFrameCloud), written one
/// at a time. \a dir is created, or replaced when it holds a session; a folder that
/// holds something else is refused.
/// \throws SessionError naming the folder or file and the cause (nothing is then
/// changed in \a dir).
void
saveSession(const RastSlam& slam, const std::string& dir, SessionInfo info);

/// \brief The finished \a slam as a session in memory (what saveSession(slam, ...) would
/// write): key-frame clouds are expanded from the map's compact copies, key-frames whose
/// features the run released have none. With \a clouds_on_demand the clouds are not
/// copied: Session::cloud_source expands one when it is needed (from the run's map,
/// which the session keeps alive). A whole KITTI 00 drive's clouds copied are 600 MB.
Session
sessionFromSlam(const RastSlam& slam, SessionInfo info, bool clouds_on_demand = false);

/// \brief Save a session held in memory (a loaded or merged one) in \a dir, as above.
/// \throws SessionError, or std::invalid_argument when key-frame ids are not 0..n-1 or
/// a key-frame has no cloud.
void
saveSession(const Session& session, const std::string& dir);

/// \brief How loadSession checks and what it reads.
struct SessionLoadOptions
{
  /// When set, a session saved with another sensor preset is an error.
  std::string expected_sensor_preset;
  bool load_clouds = true; ///< read the key-frame clouds (else KeyFrame::cloud is null)
};

/// \brief Load the session in \a dir. Before reading any cloud it checks session.json
/// (format, version no newer than kSessionFormatVersion, sensor preset) and the size
/// and CRC-32 of every file it lists.
/// \throws SessionError naming the file and what is wrong with it.
Session
loadSession(const std::string& dir, const SessionLoadOptions& options = SessionLoadOptions());

} // namespace rast
} // namespace pcl
