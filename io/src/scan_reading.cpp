/// \file scan_reading.cpp
/// \brief The per-format scan readers: KITTI .bin, and PCD / PLY through PCL with the
/// per-point time field found, validated and centred (doc/odometry.md).

#include "scan_reading.h"

#include "scan_parsing.h"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <map>
#include <memory>
#include <pcl/PCLPointCloud2.h>
#include <pcl/common/io.h> // getFieldSize
#include <pcl/io/pose_io.h>
#include <pcl/io/sequence_reader.h>
#include <sstream>
#include <string_view>
#include <system_error>
#include <utility>

namespace fs = std::filesystem;

namespace pcl {
namespace rast {
namespace io_detail {

std::string
lowerExtension(const fs::path& p)
{
  std::string ext = p.extension().string();
  for (char& c : ext)
    c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return ext;
}

bool
isScanExtension(const std::string& ext)
{
  return ext == ".bin" || ext == ".pcd" || ext == ".ply";
}

namespace {

constexpr std::size_t kKittiPointBytes = 4 * sizeof(float);

/// Fail early with a clear reason when the path is not a readable, non-empty file.
std::uintmax_t
checkRegularNonEmptyFile(const std::string& path)
{
  std::error_code ec;
  const fs::file_status status = fs::status(path, ec);
  if (ec || !fs::exists(status))
    throw ScanReadError(path, "file does not exist");
  if (fs::is_directory(status))
    throw ScanReadError(path, "cannot read scan: is a directory, not a file");
  const std::uintmax_t size = fs::file_size(path, ec);
  if (ec)
    throw ScanReadError(path, "cannot read scan: " + ec.message());
  if (size == 0)
    throw ScanReadError(path, "empty file (0 bytes)");
  std::ifstream probe(path, std::ios::binary);
  if (!probe)
    throw ScanReadError(path, "cannot open file for reading (permission denied?)");
  return size;
}

/// KITTI .bin: float32 x y z intensity, 16 bytes per point.
void
readKittiBin(const std::string& path,
             std::string_view bytes,
             pcl::PointCloud<pcl::PointXYZI>& cloud,
             std::size_t& num_dropped)
{
  if (bytes.size() % kKittiPointBytes != 0)
    throw ScanReadError(path,
                        "truncated KITTI .bin: size " + std::to_string(bytes.size()) +
                            " bytes is not a multiple of 16 (float32 x y z intensity)");
  const std::size_t num_points = bytes.size() / kKittiPointBytes;
  // A point whose coordinates are not finite is dropped and counted; a NaN or infinite
  // intensity is stored as 0, not a reason to drop (as convertPoints() does). Points
  // are built in place: PointCloud::push_back also set the width and height for every
  // point (1.25 against 0.66 ms a scan in bench_front_end); scanFromBytes() sets them
  // once.
  auto& points = cloud.points;
  points.reserve(num_points);
  for (std::size_t i = 0; i < num_points; ++i) {
    float v[4];
    std::memcpy(v, bytes.data() + i * kKittiPointBytes, kKittiPointBytes);
    if (!(std::isfinite(v[0]) && std::isfinite(v[1]) && std::isfinite(v[2]))) {
      ++num_dropped;
      continue;
    }
    points.emplace_back(v[0], v[1], v[2], std::isfinite(v[3]) ? v[3] : 0.0f);
  }
}

/// The value of type V stored (possibly unaligned) at \a p.
template <typename V>
inline V
load(const std::uint8_t* p)
{
  V v;
  std::memcpy(&v, p, sizeof v);
  return v;
}

/// Read one value of any PCLPointField numeric type as T (float for coordinates,
/// double for times: an absolute time like 1.7e9 s keeps its microseconds only in
/// double). NaN for an unknown type.
template <typename T>
inline T
fieldAs(const std::uint8_t* p, std::uint8_t datatype)
{
  switch (datatype) {
  case pcl::PCLPointField::INT8:
    return static_cast<T>(load<std::int8_t>(p));
  case pcl::PCLPointField::UINT8:
    return static_cast<T>(load<std::uint8_t>(p));
  case pcl::PCLPointField::INT16:
    return static_cast<T>(load<std::int16_t>(p));
  case pcl::PCLPointField::UINT16:
    return static_cast<T>(load<std::uint16_t>(p));
  case pcl::PCLPointField::INT32:
    return static_cast<T>(load<std::int32_t>(p));
  case pcl::PCLPointField::UINT32:
    return static_cast<T>(load<std::uint32_t>(p));
  case pcl::PCLPointField::INT64:
    return static_cast<T>(load<std::int64_t>(p));
  case pcl::PCLPointField::UINT64:
    return static_cast<T>(load<std::uint64_t>(p));
  case pcl::PCLPointField::FLOAT32:
    return static_cast<T>(load<float>(p));
  case pcl::PCLPointField::FLOAT64:
    return static_cast<T>(load<double>(p));
  default:
    return std::numeric_limits<T>::quiet_NaN();
  }
}

/// Whether a value of \a f lies inside a point of \a blob and has a numeric type.
bool
fieldFits(const pcl::PCLPointCloud2& blob, const pcl::PCLPointField& f)
{
  const std::size_t size = pcl::getFieldSize(f.datatype);
  return size != 0 && f.offset + size <= blob.point_step;
}

const pcl::PCLPointField*
findField(const pcl::PCLPointCloud2& blob, const std::vector<std::string>& names)
{
  for (const std::string& name : names)
    for (const pcl::PCLPointField& f : blob.fields)
      if (f.name == name)
        return &f;
  return nullptr;
}

/// Fields that may hold the time of each point, in the order they are looked for:
/// Velodyne / rslidar (s), Ouster (ns), Hesai and others (often absolute s), Livox (ns).
const std::vector<std::string> kTimeFieldNames = {
    "time", "t", "timestamp", "time_stamp", "offset_time", "ts"};

/// The raw times of the kept points, gathered while the blob is converted, with the
/// counts that checkAndCentreTimes() needs, so that the blob is read only once.
struct RawTimes
{
  /// The time field of the blob, or null when it has none or cannot read it.
  const pcl::PCLPointField* field = nullptr;
  /// Why a time field that is present cannot be read (empty otherwise).
  std::string warning;
  /// One raw value per kept point, in the cloud's order.
  std::vector<double> values;
  double min = std::numeric_limits<double>::infinity();
  double max = -std::numeric_limits<double>::infinity();
  std::size_t num_non_finite = 0;
  /// Pairs of consecutive kept points in the same row, and how many of them go back.
  std::size_t num_steps = 0;
  std::size_t num_backward = 0;

  /// A new row of an organized cloud: its first point is not compared to the last
  /// point of the previous row.
  void startRow() { row_started_ = false; }

  void add(double t)
  {
    if (std::isfinite(t)) {
      min = std::min(min, t);
      max = std::max(max, t);
    } else {
      ++num_non_finite;
    }
    if (row_started_) {
      ++num_steps;
      if (t < values.back())
        ++num_backward;
    }
    values.push_back(t);
    row_started_ = true;
  }

private:
  bool row_started_ = false;
};


/// Check the raw times, choose their unit and centre them on the middle of the sweep
/// (relative in double, then float). Leaves \a out.times_s empty and says why in
/// out.warning when they cannot be used.
void
checkAndCentreTimes(const RawTimes& raw, PointTimes& out)
{
  const std::string name = "field '" + raw.field->name + "'";
  auto reject = [&out](const std::string& why) {
    out.warning = "per-point times not used: " + why;
  };
  // Each check below ends with `return reject(...)`.
  if (raw.values.empty()) { // no kept points: nothing to time
    out.field = raw.field->name;
    return;
  }
  if (raw.num_non_finite > 0)
    return reject(name + " has " + std::to_string(raw.num_non_finite) + " of " +
                  std::to_string(raw.values.size()) + " values NaN or infinite");
  const double span = raw.max - raw.min;
  if (!(span > 0.0))
    return reject("all " + std::to_string(raw.values.size()) + " values of " + name +
                  " are equal (" + std::to_string(raw.min) + "): no sweep to time");

  // The unit: the first scale that makes the span a sweep of a 2-100 Hz LiDAR.
  constexpr double kMinSweepS = 0.005;
  constexpr double kMaxSweepS = 0.5;
  double scale = 0.0;
  for (double candidate : {1.0, 1e-3, 1e-6, 1e-9}) {
    if (span * candidate >= kMinSweepS && span * candidate <= kMaxSweepS) {
      scale = candidate;
      break;
    }
  }
  if (scale == 0.0) {
    std::ostringstream why;
    why << name << " spans " << span << " (from " << raw.min << " to " << raw.max
        << "), which fits no unit: as s, ms, us or ns it is no sweep of " << kMinSweepS
        << " to " << kMaxSweepS << " s";
    return reject(why.str());
  }

  // Firing order: a driver writes points as they are measured.
  constexpr double kMaxBackwardFraction = 0.01;
  if (raw.num_steps > 0 &&
      static_cast<double>(raw.num_backward) >
          kMaxBackwardFraction * static_cast<double>(raw.num_steps)) {
    std::ostringstream why;
    why << name << " is not monotonic in storage order: " << raw.num_backward << " of "
        << raw.num_steps << " steps between consecutive points go backwards (at most "
        << kMaxBackwardFraction * 100.0
        << " % allowed); the cloud was shuffled or filtered";
    return reject(why.str());
  }

  const double mid = 0.5 * (raw.min + raw.max);
  out.times_s.resize(raw.values.size());
  for (std::size_t k = 0; k < raw.values.size(); ++k)
    out.times_s[k] = static_cast<float>((raw.values[k] - mid) * scale);
  out.field = raw.field->name;
}

/// The fields blobToCloud reads (intensity and time may be null).
struct PointFields
{
  const pcl::PCLPointField *x, *y, *z, *intensity, *time;
};

/// The finite points of \a blob, whose point data starts at \a data, appended to
/// \a cloud, their raw times to \a times when fields.time is set; kFloat32: every field
/// is float32.
template <bool kFloat32>
void
convertPoints(const pcl::PCLPointCloud2& blob,
              const std::uint8_t* data,
              const PointFields& fields,
              pcl::PointCloud<pcl::PointXYZI>& cloud,
              std::size_t& num_dropped,
              RawTimes* times)
{
  const auto value = [](const std::uint8_t* pt, const pcl::PCLPointField& f) -> float {
    if constexpr (kFloat32)
      return load<float>(pt + f.offset);
    else
      return fieldAs<float>(pt + f.offset, f.datatype);
  };
  const auto time = [](const std::uint8_t* pt, const pcl::PCLPointField& f) -> double {
    if constexpr (kFloat32)
      return load<float>(pt + f.offset);
    else
      return fieldAs<double>(pt + f.offset, f.datatype);
  };
  // Each point constructed once, with its values (a resize would write them twice).
  auto& points = cloud.points;
  points.reserve(points.size() + static_cast<std::size_t>(blob.width) * blob.height);
  for (std::size_t r = 0; r < blob.height; ++r) {
    const std::uint8_t* row = data + r * blob.row_step;
    if (fields.time)
      times->startRow();
    for (std::size_t c = 0; c < blob.width; ++c) {
      const std::uint8_t* pt = row + c * blob.point_step;
      const float x = value(pt, *fields.x);
      const float y = value(pt, *fields.y);
      const float z = value(pt, *fields.z);
      if (!(std::isfinite(x) && std::isfinite(y) && std::isfinite(z))) {
        ++num_dropped;
        continue;
      }
      const float intensity = fields.intensity ? value(pt, *fields.intensity) : 0.0f;
      points.emplace_back(x, y, z, std::isfinite(intensity) ? intensity : 0.0f);
      if (fields.time)
        times->add(time(pt, *fields.time));
    }
  }
}

/// Convert a PCD/PLY blob to x y z intensity, whatever the field types are; when
/// \a times is not null and the blob has a time field, also gather the raw times of
/// the kept points in the same pass.
void
blobToCloud(const std::string& path,
            const pcl::PCLPointCloud2& blob,
            std::string_view data,
            pcl::PointCloud<pcl::PointXYZI>& cloud,
            std::size_t& num_dropped,
            RawTimes* times)
{
  const pcl::PCLPointField* fx = findField(blob, {"x"});
  const pcl::PCLPointField* fy = findField(blob, {"y"});
  const pcl::PCLPointField* fz = findField(blob, {"z"});
  if (!fx || !fy || !fz)
    throw ScanReadError(path, "no x, y and z fields");
  const pcl::PCLPointField* fi = findField(
      blob,
      {"intensity", "scalar_intensity", "reflectance", "remission", "i", "Intensity"});

  const std::size_t num_points = static_cast<std::size_t>(blob.width) * blob.height;
  for (const pcl::PCLPointField* f : {fx, fy, fz, fi}) {
    if (f && !fieldFits(blob, *f))
      throw ScanReadError(path,
                          "field '" + f->name + "' has an unsupported type or layout");
  }
  if (blob.height > 0 &&
      (blob.row_step < static_cast<std::size_t>(blob.width) * blob.point_step ||
       data.size() < static_cast<std::size_t>(blob.row_step) * blob.height))
    throw ScanReadError(path, "point data is shorter than the header says");

  // A bad time field costs the times, not the scan.
  const pcl::PCLPointField* ft = times ? findField(blob, kTimeFieldNames) : nullptr;
  if (ft && !fieldFits(blob, *ft)) {
    times->warning = "per-point times not used: field '" + ft->name +
                     "' has an unsupported type or layout";
    ft = nullptr;
  }
  if (ft) {
    times->field = ft;
    times->values.reserve(num_points);
  }

  // The common layout, every field float32 (as the simulator, most drivers and KITTI
  // conversions write them), is read without a type switch per value.
  const auto isFloat32 = [](const pcl::PCLPointField* f) {
    return !f || f->datatype == pcl::PCLPointField::FLOAT32;
  };
  const PointFields fields{fx, fy, fz, fi, ft};
  const auto* points = reinterpret_cast<const std::uint8_t*>(data.data());
  if (isFloat32(fx) && isFloat32(fy) && isFloat32(fz) && isFloat32(fi) && isFloat32(ft))
    convertPoints<true>(blob, points, fields, cloud, num_dropped, times);
  else
    convertPoints<false>(blob, points, fields, cloud, num_dropped, times);
}

/// A whole file's bytes, left uninitialized until the read fills them (a scan is
/// megabytes, and zero-filling them first cost as much as a copy).
struct FileBytes
{
  std::unique_ptr<char[]> data;
  std::size_t size = 0;
  std::string_view view() const { return {data.get(), size}; }
};

/// The whole file in memory, read with one call.
FileBytes
readWholeFile(const std::string& path, std::uintmax_t size_bytes)
{
  FileBytes bytes;
  bytes.size = static_cast<std::size_t>(size_bytes);
  bytes.data.reset(new char[bytes.size]);
  std::ifstream in(path, std::ios::binary);
  if (!in)
    throw ScanReadError(path, "cannot open file for reading");
  in.read(bytes.data.get(), static_cast<std::streamsize>(bytes.size));
  if (in.gcount() != static_cast<std::streamsize>(bytes.size))
    throw ScanReadError(path,
                        "read only " + std::to_string(in.gcount()) + " of " +
                            std::to_string(size_bytes) + " bytes");
  return bytes;
}

/// Parse a PCD or PLY file's bytes and convert them; \a times as in blobToCloud(). A
/// binary PCD's points are converted where they lie in \a bytes.
void
readPclBytes(const std::string& path,
             const std::string& ext,
             std::string_view bytes,
             pcl::PointCloud<pcl::PointXYZI>& cloud,
             std::size_t& num_dropped,
             PointTimes* times)
{
  pcl::PCLPointCloud2 blob;
  std::string_view binary;
  if (ext == ".pcd")
    parsePcd(path, bytes, blob, &binary);
  else
    parsePly(path, bytes, blob);
  const std::string_view data =
      binary.data() ? binary
                    : std::string_view(reinterpret_cast<const char*>(blob.data.data()),
                                       blob.data.size());
  RawTimes raw;
  blobToCloud(path, blob, data, cloud, num_dropped, times ? &raw : nullptr);
  if (!times)
    return;
  times->warning = raw.warning;
  if (raw.field)
    checkAndCentreTimes(raw, *times);
}

} // namespace

pcl::PointCloud<pcl::PointXYZI>::Ptr
scanFromBytes(const std::string& path,
              const std::string& ext,
              std::string_view bytes,
              std::size_t* num_dropped_non_finite,
              PointTimes* times)
{
  auto cloud = std::make_shared<pcl::PointCloud<pcl::PointXYZI>>();
  std::size_t num_dropped = 0;
  if (ext == ".bin")
    readKittiBin(path, bytes, *cloud, num_dropped);
  else if (ext == ".pcd" || ext == ".ply")
    readPclBytes(path, ext, bytes, *cloud, num_dropped, times);
  else
    throw ScanReadError(
        path, "unsupported scan extension '" + ext + "' (expected .bin, .pcd or .ply)");
  cloud->width = static_cast<std::uint32_t>(cloud->size());
  cloud->height = 1;
  cloud->is_dense = true;
  if (num_dropped_non_finite)
    *num_dropped_non_finite = num_dropped;
  return cloud;
}

pcl::PointCloud<pcl::PointXYZI>::Ptr
readScanAndTimes(const std::string& path,
                 std::size_t* num_dropped_non_finite,
                 PointTimes* times)
{
  const std::string ext = lowerExtension(path);
  if (!isScanExtension(ext))
    throw ScanReadError(
        path, "unsupported scan extension '" + ext + "' (expected .bin, .pcd or .ply)");
  const std::uintmax_t size_bytes = checkRegularNonEmptyFile(path);
  const FileBytes bytes = readWholeFile(path, size_bytes);
  return scanFromBytes(path, ext, bytes.view(), num_dropped_non_finite, times);
}

} // namespace io_detail

pcl::PointCloud<pcl::PointXYZI>::Ptr
readScan(const std::string& path, std::size_t* num_dropped_non_finite)
{
  return io_detail::readScanAndTimes(path, num_dropped_non_finite, nullptr);
}

void
writeKittiBin(const std::string& path, const pcl::PointCloud<pcl::PointXYZI>& cloud)
{
  // float32 x y z intensity per point, written through pose_io's atomic writer.
  std::string bytes(cloud.size() * 4 * sizeof(float), '\0');
  char* out = bytes.data();
  for (const pcl::PointXYZI& p : cloud) {
    const float values[4] = {p.x, p.y, p.z, p.intensity};
    std::memcpy(out, values, sizeof(values));
    out += sizeof(values);
  }
  writeFileAtomically(path, bytes);
}

} // namespace rast
} // namespace pcl
