/// \file session.cpp
/// \brief Saving and loading sessions (session.h): the staged, all-or-nothing folder
/// write, session.json, and the checks a session passes before it is used.

#include <pcl/slam/session.h>

#include <pcl/features/raster_feature_types.h>
#include <pcl/io/pcd_io.h>
#include <pcl/io/sequence_reader.h>
#include <pcl/rast/atomic_file.h>
#include <pcl/rast/file_checksum.h>
#include <pcl/slam/g2o_io.h>
#include <pcl/slam/rast_slam.h>

#include <nlohmann/json.hpp>

#include <cerrno>
#include <cmath>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <fcntl.h>
#include <filesystem>
#include <fstream>
#include <functional>
#include <sstream>
#include <system_error>
#include <unistd.h>

namespace pcl {
namespace rast {

namespace fs = std::filesystem;
using nlohmann::json;

namespace {

constexpr const char* kFormatName = "pcl_rast_session";
constexpr const char* kJsonName = "session.json";
constexpr const char* kGraphName = "graph.g2o";
constexpr std::uintmax_t kMaxJsonBytes = 256u << 20; // 256 MiB: ~2 M key-frames

std::string
numbered(KeyFrameId id)
{
  char name[16];
  std::snprintf(name, sizeof name, "%06u", static_cast<unsigned>(id));
  return name;
}

json
poseJson(const Pose3d& T)
{
  const Eigen::Quaterniond q(T.rotation());
  const Eigen::Vector3d t = T.translation();
  return json::array({t.x(), t.y(), t.z(), q.x(), q.y(), q.z(), q.w()});
}

/// fsync a file or folder (the rename that publishes must not reach the disk first).
void
syncPath(const fs::path& path, bool directory)
{
  const int fd = ::open(path.c_str(), directory ? (O_RDONLY | O_DIRECTORY) : O_RDONLY);
  if (fd < 0 || ::fsync(fd) != 0) {
    const int error = errno;
    if (fd >= 0)
      ::close(fd);
    throw SessionError(path.string(), std::string("cannot sync: ") + std::strerror(error));
  }
  ::close(fd);
}

/// The folder a session is saved to, without a trailing separator.
fs::path
sessionFolder(const std::string& dir)
{
  if (dir.empty())
    throw SessionError(dir, "empty session folder name");
  fs::path path = fs::path(dir).lexically_normal();
  if (!path.has_filename())
    path = path.parent_path();
  if (path.empty() || path.filename() == "." || path.filename() == "..")
    throw SessionError(dir, "not a usable session folder name");
  return path;
}

/// Refuse to replace a folder that is not a session (a user's scans, say).
void
checkReplaceable(const fs::path& dir)
{
  std::error_code ec;
  const fs::file_status status = fs::status(dir, ec);
  if (!fs::exists(status)) {
    // It will be created: the nearest existing folder above it must be a folder.
    for (fs::path up = dir.parent_path(); !up.empty() && up != up.parent_path();
         up = up.parent_path()) {
      const fs::file_status s = fs::status(up, ec);
      if (!fs::exists(s))
        continue;
      if (!fs::is_directory(s))
        throw SessionError(dir.string(), up.string() + " is not a folder");
      break;
    }
    return;
  }
  if (!fs::is_directory(status))
    throw SessionError(dir.string(), "exists and is not a folder");
  if (fs::is_empty(dir, ec) || fs::exists(dir / kJsonName))
    return;
  throw SessionError(dir.string(), "holds files but no " + std::string(kJsonName) +
                                       ": not a session, refusing to replace it");
}

/// Writes a session into a staging folder beside its destination, then swaps it in.
class SessionWriter
{
  using PointCloudXYZIConstPtr = pcl::PointCloud<pcl::PointXYZI>::ConstPtr;

public:
  explicit SessionWriter(const std::string& dir) : dir_(sessionFolder(dir))
  {
    checkReplaceable(dir_);
    const fs::path parent = dir_.has_parent_path() ? dir_.parent_path() : fs::path(".");
    std::error_code ec;
    fs::create_directories(parent, ec);
    if (ec)
      throw SessionError(parent.string(), "cannot create the folder: " + ec.message());
    const auto stamp = std::chrono::steady_clock::now().time_since_epoch().count();
    staging_ = parent / ("." + dir_.filename().string() + ".staging-" +
                         std::to_string(::getpid()) + "-" + std::to_string(stamp));
    for (const char* sub : {"", "keyframes", "features"}) {
      fs::create_directories(staging_ / sub, ec);
      if (ec)
        throw SessionError((staging_ / sub).string(),
                           "cannot create the folder: " + ec.message());
    }
  }

  ~SessionWriter()
  {
    std::error_code ec;
    if (!staging_.empty())
      fs::remove_all(staging_, ec); // a failed save leaves nothing behind
  }

  SessionWriter(const SessionWriter&) = delete;
  SessionWriter& operator=(const SessionWriter&) = delete;

  void
  addKeyFrame(const KeyFrame& kf, const Pose3d& T_world, const PointCloudXYZIConstPtr& cloud)
  {
    if (kf.id != keyframes_.size())
      throw std::invalid_argument("saveSession: key-frame " + std::to_string(kf.id) +
                                  " where " + std::to_string(keyframes_.size()) +
                                  " was expected (ids must be 0..n-1 in order)");
    json entry = {{"id", kf.id},
                  {"frame_index", kf.frame_index},
                  {"timestamp", kf.timestamp_s},
                  {"odometry_map_scans", kf.odometry_map_scans},
                  {"pose", poseJson(T_world)},
                  {"odometry_edge", poseJson(kf.T_previous_keyframe)},
                  {"cloud", nullptr},
                  {"points", 0},
                  {"features", nullptr},
                  {"num_features", 0}};
    if (cloud && !cloud->empty()) {
      const std::string name = "keyframes/" + numbered(kf.id) + ".pcd";
      writePcd(name, *cloud);
      entry["cloud"] = name;
      entry["points"] = cloud->size();
    }
    if (!kf.features.empty()) {
      pcl::PointCloud<ORBSignature256> signatures;
      toSignatureCloud(kf.features, signatures);
      const std::string name = "features/" + numbered(kf.id) + ".pcd";
      writePcd(name, signatures);
      entry["features"] = name;
      entry["num_features"] = signatures.size();
    }
    keyframes_.push_back(std::move(entry));
  }

  /// Write the graph and session.json, then put the folder in place.
  void
  commit(const PoseGraph& graph,
         const std::vector<LoopEdge>& loops,
         const SessionInfo& info,
         const std::vector<SessionDrive>& drives)
  {
    if (graph.numNodes() != keyframes_.size())
      throw std::invalid_argument("saveSession: the pose graph has " +
                                  std::to_string(graph.numNodes()) + " nodes for " +
                                  std::to_string(keyframes_.size()) + " key-frames");
    const std::string graph_path = (staging_ / kGraphName).string();
    try {
      writeG2o(graph_path, graph);
    } catch (const std::exception& e) {
      throw SessionError(graph_path, e.what());
    }
    addFile(kGraphName);

    json parameters;
    try {
      parameters = json::parse(info.parameters_json);
    } catch (const json::exception& e) {
      throw std::invalid_argument("saveSession: parameters_json is not JSON: " +
                                  std::string(e.what()));
    }
    json loop_list = json::array();
    for (const LoopEdge& loop : loops)
      if (loop.active)
        loop_list.push_back({{"query", loop.query},
                             {"candidate", loop.candidate},
                             {"num_inliers", loop.num_inliers},
                             {"T_candidate_query", poseJson(loop.T_candidate_query)}});
    json drive_list = json::array();
    for (const SessionDrive& d : drives)
      drive_list.push_back({{"first_keyframe", d.first_keyframe},
                            {"keyframes", d.num_keyframes},
                            {"frames", d.num_frames},
                            {"created_by", d.created_by},
                            {"input", d.input},
                            {"component", d.component}});
    const json session = {{"format", kFormatName},
                          {"version", kSessionFormatVersion},
                          {"created_by", info.created_by},
                          {"sensor_preset", info.sensor_preset},
                          {"parameters", parameters},
                          {"frames", info.num_frames},
                          {"graph", kGraphName},
                          {"keyframes", keyframes_},
                          {"loops", loop_list},
                          {"drives", drive_list},
                          {"files", files_}};
    const std::string json_path = (staging_ / kJsonName).string();
    try {
      // error_handler_t::replace: a path or name with any bytes is still valid JSON.
      writeFileAtomically(json_path,
                          session.dump(1, ' ', false, json::error_handler_t::replace) + "\n");
    } catch (const std::exception& e) {
      throw SessionError(json_path, e.what());
    }
    syncPath(staging_, true);
    publish();
  }

private:
  /// Write \a cloud as a binary PCD (PCL's header and layout) through the project's
  /// atomic writer: PCL's own writer reports a full disk without its cause.
  template <typename PointT>
  void
  writePcd(const std::string& name, const pcl::PointCloud<PointT>& cloud)
  {
    const fs::path path = staging_ / name;
    // What pcl::PCDWriter::writeBinary writes: its header, then each point's fields
    // packed (no padding).
    std::string content = pcl::PCDWriter::generateHeader<PointT>(cloud) + "DATA binary\n";
    std::vector<pcl::PCLPointField> fields;
    std::size_t point_bytes = 0;
    for (const pcl::PCLPointField& f : pcl::getFields<PointT>())
      if (f.name != "_") {
        fields.push_back(f);
        point_bytes += f.count * pcl::getFieldSize(f.datatype);
      }
    content.reserve(content.size() + cloud.size() * point_bytes);
    for (const PointT& point : cloud.points) {
      const char* base = reinterpret_cast<const char*>(&point);
      for (const pcl::PCLPointField& f : fields)
        content.append(base + f.offset, f.count * pcl::getFieldSize(f.datatype));
    }
    try {
      writeFileAtomically(path.string(), content);
    } catch (const std::exception& e) {
      throw SessionError(path.string(), std::string("cannot write: ") + e.what());
    }
    syncPath(path, false);
    addFile(name);
  }

  void
  addFile(const std::string& name)
  {
    const fs::path path = staging_ / name;
    files_.push_back({{"name", name},
                      {"size", fs::file_size(path)},
                      {"crc32", fileCrc32(path.string())}});
  }

  /// Swap the staging folder with the destination: one atomic exchange where the file
  /// system supports it, else two renames (an earlier session is moved aside first and
  /// removed last).
  void
  publish()
  {
    std::error_code ec;
    const fs::path parent = dir_.has_parent_path() ? dir_.parent_path() : fs::path(".");
    if (!fs::exists(dir_, ec)) {
      fs::rename(staging_, dir_, ec);
      if (ec)
        throw SessionError(dir_.string(), "cannot move the session into place: " + ec.message());
    }
    else if (::renameat2(AT_FDCWD, staging_.c_str(), AT_FDCWD, dir_.c_str(), RENAME_EXCHANGE) ==
             0) {
      // staging_ now holds the earlier session; the destructor removes it.
      syncPath(parent, true);
      return;
    }
    else {
      const fs::path aside = staging_.string() + ".old";
      fs::rename(dir_, aside, ec);
      if (!ec)
        fs::rename(staging_, dir_, ec);
      if (ec)
        throw SessionError(dir_.string(), "cannot replace the session: " + ec.message());
      fs::remove_all(aside, ec);
    }
    staging_.clear();
    syncPath(parent, true);
  }

  fs::path dir_;
  fs::path staging_;
  json keyframes_ = json::array();
  json files_ = json::array();
};

// ---- loading ----

Pose3d
poseFromJson(const json& value, const std::string& path, const std::string& what)
{
  if (!value.is_array() || value.size() != 7)
    throw SessionError(path, what + " is not a pose [x y z qx qy qz qw]");
  double v[7];
  for (int i = 0; i < 7; ++i) {
    if (!value[i].is_number())
      throw SessionError(path, what + " has a value that is not a number");
    v[i] = value[i].get<double>();
    if (!std::isfinite(v[i]))
      throw SessionError(path, what + " is not finite");
  }
  Eigen::Quaterniond q(v[6], v[3], v[4], v[5]);
  if (std::abs(q.norm() - 1.0) > 1e-3)
    throw SessionError(path, what + " has a quaternion of norm " + std::to_string(q.norm()));
  Pose3d T = Pose3d::Identity();
  T.linear() = q.normalized().toRotationMatrix();
  T.translation() = Eigen::Vector3d(v[0], v[1], v[2]);
  return T;
}

json
readSessionJson(const fs::path& path)
{
  std::error_code ec;
  if (!fs::is_regular_file(path, ec))
    throw SessionError(path.string(), "missing: not a session folder, or an incomplete one");
  const std::uintmax_t size = fs::file_size(path, ec);
  if (ec || size > kMaxJsonBytes)
    throw SessionError(path.string(), ec ? "cannot read: " + ec.message()
                                         : "larger than " + std::to_string(kMaxJsonBytes) +
                                               " bytes");
  std::ifstream in(path, std::ios::binary);
  std::stringstream text;
  text << in.rdbuf();
  if (!in && !in.eof())
    throw SessionError(path.string(), "cannot read");
  try {
    return json::parse(text.str());
  } catch (const json::exception& e) {
    throw SessionError(path.string(), std::string("not valid JSON: ") + e.what());
  }
}

/// A relative file name inside the session folder, or an error.
fs::path
sessionFile(const fs::path& dir, const json& name, const std::string& json_path)
{
  if (!name.is_string())
    throw SessionError(json_path, "a file name is not a string");
  const fs::path relative = fs::path(name.get<std::string>()).lexically_normal();
  if (relative.empty() || relative.is_absolute() || *relative.begin() == "..")
    throw SessionError(json_path, "file '" + name.get<std::string>() +
                                      "' is outside the session folder");
  return dir / relative;
}

void
checkFiles(const fs::path& dir, const json& session, const std::string& json_path)
{
  const json& files = session.at("files");
  if (!files.is_array())
    throw SessionError(json_path, "'files' is not a list");
  for (const json& file : files) {
    const fs::path path = sessionFile(dir, file.at("name"), json_path);
    std::error_code ec;
    if (!fs::is_regular_file(path, ec))
      throw SessionError(path.string(), "missing (listed in " + json_path + ")");
    const std::uintmax_t size = fs::file_size(path, ec);
    if (ec || size != file.at("size").get<std::uintmax_t>())
      throw SessionError(path.string(), "size " + std::to_string(size) + " bytes, " +
                                            json_path + " lists " +
                                            std::to_string(file.at("size").get<std::uintmax_t>()) +
                                            ": truncated or replaced");
    const std::string crc = fileCrc32(path.string());
    if (crc != file.at("crc32").get<std::string>())
      throw SessionError(path.string(), "checksum " + crc + ", " + json_path + " lists " +
                                            file.at("crc32").get<std::string>() +
                                            ": the file is corrupted");
  }
}

void
readFeatures(const fs::path& path, std::size_t expected, RasterFeatureSet& features)
{
  pcl::PointCloud<ORBSignature256> signatures;
  pcl::PCDReader reader;
  pcl::PCLPointCloud2 header;
  Eigen::Vector4f origin;
  Eigen::Quaternionf orientation;
  int version = 0, type = 0;
  unsigned int offset = 0;
  if (reader.readHeader(path.string(), header, origin, orientation, version, type, offset) < 0 ||
      static_cast<std::size_t>(header.width) * header.height != expected)
    throw SessionError(path.string(), "not a feature cloud of " + std::to_string(expected) +
                                          " points");
  if (reader.read(path.string(), signatures) < 0 || signatures.size() != expected)
    throw SessionError(path.string(), "cannot read the feature cloud");
  fromSignatureCloud(signatures, features);
}

/// A key-frame's cloud file, which must hold the points \a json_path lists.
pcl::PointCloud<pcl::PointXYZI>::Ptr
readCloudFile(const SessionCloudFile& file, const std::string& json_path)
{
  pcl::PointCloud<pcl::PointXYZI>::Ptr cloud;
  try {
    cloud = readScan(file.path);
  } catch (const std::exception& e) {
    throw SessionError(file.path, e.what());
  }
  if (cloud->size() != file.points)
    throw SessionError(file.path, "holds " + std::to_string(cloud->size()) + " points, " +
                                      json_path + " lists " + std::to_string(file.points));
  return cloud;
}

} // namespace

pcl::PointCloud<pcl::PointXYZI>::ConstPtr
sessionCloud(const Session& session, KeyFrameId id)
{
  const KeyFrame::Ptr& kf = session.keyframes.at(id);
  if (kf && kf->cloud)
    return kf->cloud;
  if (id < session.cloud_files.size() && !session.cloud_files[id].path.empty())
    return readCloudFile(session.cloud_files[id], "session.json");
  return session.cloud_source ? session.cloud_source(id) : nullptr;
}

bool
sessionHasCloud(const Session& session, KeyFrameId id)
{
  const KeyFrame::Ptr& kf = session.keyframes.at(id);
  return (kf && kf->cloud && !kf->cloud->empty()) ||
         (id < session.cloud_files.size() && session.cloud_files[id].points > 0) ||
         (kf && !kf->cloud && session.cloud_source);
}

void
checkSessionDestination(const std::string& dir)
{
  checkReplaceable(sessionFolder(dir));
}

namespace {

/// A session's drives must cover its key-frames in order, each once.
void
checkDrives(const std::vector<SessionDrive>& drives, std::size_t num_keyframes,
            const std::function<void(const std::string&)>& fail)
{
  std::size_t next = 0;
  for (const SessionDrive& d : drives) {
    if (d.first_keyframe != next || d.component < 0)
      fail("drive at key-frame " + std::to_string(d.first_keyframe) + " (component " +
           std::to_string(d.component) + ") does not follow key-frame " + std::to_string(next));
    next += d.num_keyframes;
  }
  if (next != num_keyframes)
    fail("the drives cover " + std::to_string(next) + " key-frames of " +
         std::to_string(num_keyframes));
}

} // namespace

std::vector<SessionDrive>
sessionDrives(const Session& session)
{
  if (!session.drives.empty())
    return session.drives;
  SessionDrive all;
  all.num_keyframes = session.keyframes.size();
  all.num_frames = session.info.num_frames;
  all.created_by = session.info.created_by;
  return {all};
}

int
sessionComponentOf(const Session& session, KeyFrameId id)
{
  if (id >= session.keyframes.size())
    throw std::out_of_range("sessionComponentOf: key-frame " + std::to_string(id) + " of " +
                            std::to_string(session.keyframes.size()));
  for (const SessionDrive& d : session.drives)
    if (id >= d.first_keyframe && id < d.first_keyframe + d.num_keyframes)
      return d.component;
  return 0;
}

Session
sessionFromSlam(const RastSlam& slam, SessionInfo info, bool clouds_on_demand)
{
  const SlamMap::ConstPtr map = slam.map();
  Session session;
  const PoseVector poses = map->keyFramePoses();
  for (const KeyFrame::Ptr& kf : map->keyFrames()) {
    auto copy = std::make_shared<KeyFrame>();
    copy->id = kf->id;
    copy->frame_index = kf->frame_index;
    copy->timestamp_s = kf->timestamp_s;
    copy->T_world_keyframe = poses.at(kf->id);
    copy->T_previous_keyframe = map->odometryEdge(kf->id); // as local BA left it
    copy->odometry_map_scans = kf->odometry_map_scans;
    copy->features = kf->features;
    if (!clouds_on_demand)
      copy->cloud = map->keyFrameCloud(kf->id);
    session.keyframes.push_back(std::move(copy));
  }
  if (clouds_on_demand)
    session.cloud_source =
        [map](KeyFrameId id) -> pcl::PointCloud<pcl::PointXYZI>::ConstPtr {
      return map->keyFrameCloud(id);
    };
  session.loops = map->loopEdges();
  session.graph = keyFrameGraph(*map, session.loops, slam.params().loop_closing);
  if (info.num_frames == 0)
    info.num_frames = map->numFrames();
  session.info = std::move(info);
  session.drives = sessionDrives(session);
  return session;
}

void
saveSession(const RastSlam& slam, const std::string& dir, SessionInfo info)
{
  const SlamMap::ConstPtr map = slam.map();
  SessionWriter writer(dir);
  const std::vector<KeyFrame::Ptr> keyframes = map->keyFrames();
  const PoseVector poses = map->keyFramePoses();
  for (const KeyFrame::Ptr& kf : keyframes) {
    KeyFrame meta = *kf; // the odometry edge as local BA left it
    meta.T_previous_keyframe = map->odometryEdge(kf->id);
    writer.addKeyFrame(meta, poses.at(kf->id), map->keyFrameCloud(kf->id));
  }
  const std::vector<LoopEdge> loops = map->loopEdges();
  if (info.num_frames == 0)
    info.num_frames = map->numFrames();
  Session shape; // the one drive, without holding the key-frames
  shape.info = info;
  shape.keyframes.resize(keyframes.size());
  writer.commit(keyFrameGraph(*map, loops, slam.params().loop_closing), loops, info,
                sessionDrives(shape));
}

void
saveSession(const Session& session, const std::string& dir)
{
  SessionWriter writer(dir);
  for (std::size_t i = 0; i < session.keyframes.size(); ++i) {
    const KeyFrame::Ptr& kf = session.keyframes[i];
    if (!kf)
      throw std::invalid_argument("saveSession: a null key-frame");
    // A cloud not held is read from the file it was loaded from, one at a time.
    writer.addKeyFrame(*kf, kf->T_world_keyframe, sessionCloud(session, static_cast<KeyFrameId>(i)));
  }
  const std::vector<SessionDrive> drives = sessionDrives(session);
  checkDrives(drives, session.keyframes.size(), [](const std::string& why) {
    throw std::invalid_argument("saveSession: " + why);
  });
  writer.commit(session.graph, session.loops, session.info, drives);
}

Session
loadSession(const std::string& dir_name, const SessionLoadOptions& options)
{
  const fs::path dir = sessionFolder(dir_name);
  std::error_code ec;
  if (!fs::is_directory(dir, ec))
    throw SessionError(dir.string(), "no such session folder");
  const fs::path json_path = dir / kJsonName;
  const std::string jp = json_path.string();
  const json session = readSessionJson(json_path);

  Session result;
  try {
    if (!session.is_object() || session.value("format", "") != kFormatName)
      throw SessionError(jp, "not a pcl_rast session (format is not '" +
                                 std::string(kFormatName) + "')");
    result.version = session.at("version").get<int>();
    if (result.version > kSessionFormatVersion)
      throw SessionError(jp, "session version " + std::to_string(result.version) +
                                 " comes from a newer pcl_rast; this one reads up to version " +
                                 std::to_string(kSessionFormatVersion));
    if (result.version < 1)
      throw SessionError(jp, "session version " + std::to_string(result.version) +
                                 " is not valid");
    result.info.sensor_preset = session.at("sensor_preset").get<std::string>();
    result.info.created_by = session.value("created_by", "");
    result.info.parameters_json = session.value("parameters", json::object()).dump();
    result.info.num_frames = session.value("frames", std::size_t{0});
    if (!options.expected_sensor_preset.empty() &&
        options.expected_sensor_preset != result.info.sensor_preset)
      throw SessionError(jp, "made with sensor preset '" + result.info.sensor_preset +
                                 "', this run uses '" + options.expected_sensor_preset +
                                 "' (give -sensor " + result.info.sensor_preset +
                                 " to use this session)");
    checkFiles(dir, session, jp);

    const fs::path graph_path = sessionFile(dir, session.at("graph"), jp);
    try {
      result.graph = readG2o(graph_path.string());
    } catch (const std::exception& e) {
      throw SessionError(graph_path.string(), e.what());
    }
    const json& keyframes = session.at("keyframes");
    if (!keyframes.is_array() || keyframes.size() != result.graph.numNodes())
      throw SessionError(jp, "lists " + std::to_string(keyframes.size()) +
                                 " key-frames, the graph has " +
                                 std::to_string(result.graph.numNodes()) + " nodes");
    for (std::size_t i = 0; i < keyframes.size(); ++i) {
      const json& entry = keyframes[i];
      const std::string what = "key-frame " + std::to_string(i);
      auto kf = std::make_shared<KeyFrame>();
      kf->id = entry.at("id").get<KeyFrameId>();
      if (kf->id != i || !result.graph.hasNode(static_cast<int>(i)))
        throw SessionError(jp, what + " has id " + std::to_string(kf->id) +
                                   " or no node in the graph");
      kf->frame_index = entry.at("frame_index").get<std::size_t>();
      kf->timestamp_s = entry.at("timestamp").get<double>();
      kf->odometry_map_scans = entry.at("odometry_map_scans").get<int>();
      kf->T_world_keyframe = poseFromJson(entry.at("pose"), jp, what + " pose");
      kf->T_previous_keyframe = poseFromJson(entry.at("odometry_edge"), jp, what + " edge");
      if (!entry.at("features").is_null())
        readFeatures(sessionFile(dir, entry.at("features"), jp),
                     entry.at("num_features").get<std::size_t>(), kf->features);
      SessionCloudFile cloud_file;
      if (!entry.at("cloud").is_null()) {
        cloud_file.path = sessionFile(dir, entry.at("cloud"), jp).string();
        cloud_file.points = entry.at("points").get<std::size_t>();
      }
      if (options.load_clouds && !cloud_file.path.empty())
        kf->cloud = readCloudFile(cloud_file, jp);
      result.keyframes.push_back(std::move(kf));
      result.cloud_files.push_back(std::move(cloud_file));
    }
    for (const json& entry : session.at("loops")) {
      LoopEdge loop;
      loop.query = entry.at("query").get<KeyFrameId>();
      loop.candidate = entry.at("candidate").get<KeyFrameId>();
      loop.num_inliers = entry.at("num_inliers").get<int>();
      loop.T_candidate_query = poseFromJson(entry.at("T_candidate_query"), jp, "a loop");
      if (loop.query >= result.keyframes.size() || loop.candidate >= result.keyframes.size())
        throw SessionError(jp, "a loop between unknown key-frames");
      result.loops.push_back(loop);
    }
    if (session.contains("drives")) { // absent in sessions saved before multi-session
      for (const json& entry : session.at("drives")) {
        SessionDrive d;
        d.first_keyframe = entry.at("first_keyframe").get<KeyFrameId>();
        d.num_keyframes = entry.at("keyframes").get<std::size_t>();
        d.num_frames = entry.value("frames", std::size_t{0});
        d.created_by = entry.value("created_by", "");
        d.input = entry.value("input", "");
        d.component = entry.value("component", 0);
        result.drives.push_back(d);
      }
      checkDrives(result.drives, result.keyframes.size(),
                  [&jp](const std::string& why) { throw SessionError(jp, why); });
    }
    result.drives = sessionDrives(result);
  } catch (const json::exception& e) {
    throw SessionError(jp, std::string("malformed: ") + e.what());
  }
  return result;
}

} // namespace rast
} // namespace pcl
