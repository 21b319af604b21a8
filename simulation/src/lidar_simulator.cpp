/// \file lidar_simulator.cpp
/// \brief LidarSimulator: frames and sequences (the sensors are in
/// simulator_sensors.cpp, the generated paths in simulator_paths.cpp).

#include <algorithm>
#include <numeric>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <pcl/io/pcd_io.h>
#include <pcl/simulation/lidar_simulator.h>

#include "simulator_hash.h"
#include "simulator_traffic.h"
#include <pcl/io/sequence_reader.h> // writeKittiBin
#include <sstream>
#include <stdexcept>
#include <thread>

namespace pcl {
namespace rast {

namespace {

using simulator_detail::kPi;

using simulator_detail::splitmix64;

/// A raw sweep's point as the Velodyne driver writes it: x y z intensity plus `time`,
/// seconds since the sweep start. Registered here only (PCD output of writeSequence).
struct EIGEN_ALIGN16 PointXYZIT
{
  PCL_ADD_POINT4D;
  float intensity;
  float time;
  PCL_MAKE_ALIGNED_OPERATOR_NEW
};

/// The seed of the drive: of the noise, the imperfections and the traffic.
std::uint64_t
driveSeed(const LidarSimulatorParams& params)
{
  return params.drive_seed != 0 ? params.drive_seed : params.seed;
}

/// Counter-based random numbers: the noise of ray k of frame i is a hash of
/// (seed, i, k) and depends on nothing else. Each 64-bit hash gives two uniforms.
std::uint64_t
frameKey(std::uint64_t seed, std::uint64_t frame)
{
  return splitmix64(splitmix64(seed ^ 0x5EED5EED5EED5EEDULL) ^ frame);
}

void
rayUniforms(std::uint64_t frame_key, std::uint64_t ray, double u[4])
{
  std::uint64_t h = splitmix64(frame_key ^ (ray * 0xD1B54A32D192ED03ULL));
  for (int k = 0; k < 4; k += 2) {
    u[k] = (static_cast<double>(h >> 32) + 0.5) * 0x1.0p-32;
    u[k + 1] = (static_cast<double>(h & 0xFFFFFFFFULL) + 0.5) * 0x1.0p-32;
    h = splitmix64(h);
  }
}

/// Key of the imperfections' own uniforms for frame \a frame: independent of the
/// clean sensor's (rayUniforms of frameKey), so switching imperfections on leaves the
/// clean draws (dropouts, noise) of every ray as they were.
std::uint64_t
imperfectionKey(std::uint64_t seed, std::uint64_t frame)
{
  return splitmix64(frameKey(seed, frame) ^ 0x1A9E4FEC7105A1EDULL);
}

/// Two uniforms in (0, 1) fixed per beam \a beam for the whole sequence: the beam's
/// calibration error depends on the seed only.
void
beamUniforms(std::uint64_t seed, std::uint64_t beam, double u[2])
{
  const std::uint64_t h = splitmix64(splitmix64(seed ^ 0xCA1BCA1BCA1BCA1BULL) ^
                                     (beam * 0x9E3779B97F4A7C15ULL));
  u[0] = (static_cast<double>(h >> 32) + 0.5) * 0x1.0p-32;
  u[1] = (static_cast<double>(h & 0xFFFFFFFFULL) + 0.5) * 0x1.0p-32;
}

/// Standard normal quantile of u in (0, 1) from a 4096-entry table of the inverse
/// CDF (linear between entries, tails clipped at ~3.5 sigma): deterministic and cheap.
double
gaussianFromUniform(double u)
{
  constexpr int kSize = 4096;
  static const std::vector<double> table = [] {
    std::vector<double> t(kSize + 1);
    for (int k = 0; k <= kSize; ++k) {
      const double p = (k + 0.5) / (kSize + 1.0);
      double lo = -10.0, hi = 10.0; // bisection on Phi(x) = erfc(-x / sqrt 2) / 2
      for (int it = 0; it < 80; ++it) {
        const double mid = 0.5 * (lo + hi);
        (0.5 * std::erfc(-mid / std::sqrt(2.0)) < p ? lo : hi) = mid;
      }
      t[k] = 0.5 * (lo + hi);
    }
    return t;
  }();
  const double f = u * kSize;
  const int k = std::min(kSize - 1, static_cast<int>(f));
  return table[k] + (f - k) * (table[k + 1] - table[k]);
}

/// The range a flawed sensor reads along a ray that hit \a hit, before the beam's
/// range bias and the gaussian noise (SensorImperfectionParams): a mixed pixel
/// interpolated towards \a next (the same beam's hit in the next column) when the two
/// lie across a depth edge, and a spurious early return in [min_range_m, hit range]
/// that replaces either. \a v are the ray's imperfection uniforms.
double
imperfectRange(const RayHit& hit,
               const RayHit& next,
               const double v[4],
               const SensorImperfectionParams& p,
               double min_range_m)
{
  double range = hit.range_m;
  if (next.range_m > 0.0 && std::abs(next.range_m - hit.range_m) > p.mixed_pixel_jump_m &&
      v[2] < p.mixed_pixel_probability)
    range = hit.range_m + v[3] * (next.range_m - hit.range_m);
  if (v[0] < p.outlier_rate && hit.range_m > min_range_m)
    range = min_range_m + v[1] * (hit.range_m - min_range_m);
  return range;
}

/// Firing-time offset of column \a column of \a steps (azimuth 2 pi column / steps)
/// from the frame's timestamp: tau(a) = -a / (2 pi) * period with a wrapped into
/// (-pi, pi], i.e. the column index wrapped into (-steps / 2, steps / 2].
double
columnTimeOffset(int column, int steps, double period_s)
{
  const int wrapped = 2 * column <= steps ? column : column - steps;
  return -period_s * static_cast<double>(wrapped) / static_cast<double>(steps);
}

} // namespace
} // namespace rast
} // namespace pcl

POINT_CLOUD_REGISTER_POINT_STRUCT(pcl::rast::PointXYZIT,
                                  (float, x, x)(float, y, y)(float, z, z)(
                                      float, intensity, intensity)(float, time, time))

namespace pcl {
namespace rast {

// ---- simulator ----

bool
SensorImperfectionParams::isValid(std::string* why) const
{
  auto fail = [why](const std::string& msg) {
    if (why)
      *why = "SensorImperfectionParams: " + msg;
    return false;
  };
  if (!(elevation_bias_std_rad >= 0.0 && elevation_bias_std_rad <= 0.01))
    return fail("elevation_bias_std_rad must be in [0, 0.01], got " +
                std::to_string(elevation_bias_std_rad));
  if (!(range_bias_std_m >= 0.0 && range_bias_std_m <= 1.0))
    return fail("range_bias_std_m must be in [0, 1], got " +
                std::to_string(range_bias_std_m));
  if (!(outlier_rate >= 0.0 && outlier_rate <= 1.0))
    return fail("outlier_rate must be in [0, 1], got " + std::to_string(outlier_rate));
  if (!(mixed_pixel_probability >= 0.0 && mixed_pixel_probability <= 1.0))
    return fail("mixed_pixel_probability must be in [0, 1], got " +
                std::to_string(mixed_pixel_probability));
  if (!(mixed_pixel_jump_m > 0.0 && mixed_pixel_jump_m < 1e3))
    return fail("mixed_pixel_jump_m must be in (0, 1000), got " +
                std::to_string(mixed_pixel_jump_m));
  if (!(intensity_noise_std >= 0.0 && intensity_noise_std <= 1.0))
    return fail("intensity_noise_std must be in [0, 1], got " +
                std::to_string(intensity_noise_std));
  return true;
}

bool
LidarSimulatorParams::isValid(std::string* why) const
{
  auto fail = [why](const std::string& msg) {
    if (why)
      *why = "LidarSimulatorParams: " + msg;
    return false;
  };
  if (!world.isValid(why))
    return false;
  if (!imperfection_params.isValid(why))
    return false;
  if (!(frame_period_s > 0.0 && frame_period_s < 1e3))
    return fail("frame_period_s must be in (0, 1000)");
  if (!(range_noise_std_m < 1.0))
    return fail("range_noise_std_m must be < 1 (negative: sensor default)");
  if (!(dropout_rate < 1.0))
    return fail("dropout_rate must be < 1 (negative: sensor default)");
  if (num_threads < 1 || num_threads > 256)
    return fail("num_threads must be in [1, 256], got " + std::to_string(num_threads));
  return true;
}

LidarSimulator::LidarSimulator(const LidarSimulatorParams& params,
                               const PoseVector& T_world_body,
                               const std::vector<double>& timestamps_s)
    : params_(params), spec_(::pcl::rast::sensorSpec(params.sensor)),
      T_world_body_(T_world_body), timestamps_s_(timestamps_s)
{
  std::string why;
  if (!params.isValid(&why))
    throw std::invalid_argument("LidarSimulator: " + why);
  if (T_world_body.empty())
    throw std::invalid_argument("LidarSimulator: empty trajectory");
  if (!timestamps_s.empty() && timestamps_s.size() != T_world_body.size())
    throw std::invalid_argument("LidarSimulator: " + std::to_string(timestamps_s.size()) +
                                " timestamps for " + std::to_string(T_world_body.size()) +
                                " poses");
  if (params.range_noise_std_m >= 0.0)
    spec_.range_noise_std_m = params.range_noise_std_m;
  if (params.dropout_rate >= 0.0)
    spec_.dropout_rate = params.dropout_rate;
  if (params.raw_sweep) // a sweep lasts until the next frame: times must increase
    for (std::size_t k = 0; k < timestamps_s.size(); ++k)
      if (!std::isfinite(timestamps_s[k]) ||
          (k > 0 && !(timestamps_s[k] > timestamps_s[k - 1])))
        throw std::invalid_argument(
            "LidarSimulator: raw_sweep needs finite, increasing timestamps, got "
            "timestamps_s[" +
            std::to_string(k) + "] = " + std::to_string(timestamps_s[k]) +
            (k > 0 ? " after " + std::to_string(timestamps_s[k - 1]) : std::string()));

  const int beams = static_cast<int>(spec_.beam_elevations_rad.size());
  ray_dirs_sensor_.reserve(spec_.raysPerFrame());
  for (int a = 0; a < spec_.azimuth_steps; ++a) {
    const double az = 2 * kPi * a / spec_.azimuth_steps;
    for (int b = 0; b < beams; ++b) {
      const double el = spec_.beam_elevations_rad[b];
      ray_dirs_sensor_.emplace_back(
          std::cos(el) * std::cos(az), std::cos(el) * std::sin(az), std::sin(el));
    }
  }
  if (params.imperfections) {
    // Per-beam calibration error, fixed for the sequence: rays are cast along the
    // biased elevation, points are placed along the nominal one.
    const SensorImperfectionParams& ip = params.imperfection_params;
    std::vector<double> elevation_bias_rad(static_cast<std::size_t>(beams));
    beam_range_bias_m_.resize(static_cast<std::size_t>(beams));
    for (int b = 0; b < beams; ++b) {
      double u[2];
      beamUniforms(driveSeed(params), static_cast<std::uint64_t>(b), u);
      elevation_bias_rad[b] = ip.elevation_bias_std_rad * gaussianFromUniform(u[0]);
      beam_range_bias_m_[b] = ip.range_bias_std_m * gaussianFromUniform(u[1]);
    }
    ray_dirs_cast_.reserve(spec_.raysPerFrame());
    for (int a = 0; a < spec_.azimuth_steps; ++a) {
      const double az = 2 * kPi * a / spec_.azimuth_steps;
      for (int b = 0; b < beams; ++b) {
        const double el = spec_.beam_elevations_rad[b] + elevation_bias_rad[b];
        ray_dirs_cast_.emplace_back(
            std::cos(el) * std::cos(az), std::cos(el) * std::sin(az), std::sin(el));
      }
    }
  }
  std::vector<double> times_s(T_world_body_.size());
  for (std::size_t i = 0; i < times_s.size(); ++i)
    times_s[i] = timestamp(i);
  world_ = std::make_shared<SimulatedWorld>(params.world,
                                            T_world_body_,
                                            spec_.mount_height_m,
                                            params.seed,
                                            times_s,
                                            params.drive_seed);
}

double
LidarSimulator::timestamp(std::size_t i) const
{
  if (i >= numFrames())
    throw std::out_of_range("LidarSimulator::timestamp: frame " + std::to_string(i) +
                            " of " + std::to_string(numFrames()));
  return timestamps_s_.empty() ? params_.frame_period_s * static_cast<double>(i)
                               : timestamps_s_[i];
}

Pose3d
LidarSimulator::sensorPose(std::size_t i) const
{
  return T_world_body_.at(i) * bodyToSensor(spec_, timestamp(i));
}

double
LidarSimulator::framePeriod(std::size_t i) const
{
  if (i >= numFrames())
    throw std::out_of_range("LidarSimulator::framePeriod: frame " + std::to_string(i) +
                            " of " + std::to_string(numFrames()));
  if (numFrames() == 1)
    return params_.frame_period_s;
  const std::size_t k = i + 1 < numFrames() ? i : i - 1;
  const double period = timestamp(k + 1) - timestamp(k);
  if (!(period > 0.0))
    throw std::invalid_argument("LidarSimulator::framePeriod: timestamps do not increase "
                                "at frame " +
                                std::to_string(i) + ": " + std::to_string(timestamp(k)) +
                                " then " + std::to_string(timestamp(k + 1)));
  return period;
}

Pose3d
LidarSimulator::sensorPoseAt(double time_s) const
{
  if (!std::isfinite(time_s))
    throw std::invalid_argument("LidarSimulator::sensorPoseAt: time " +
                                std::to_string(time_s) + " is not finite");
  const std::size_t n = numFrames();
  if (n == 1)
    return T_world_body_[0] * bodyToSensor(spec_, time_s);
  // Segment [k, k + 1] with timestamp(k) <= time_s < timestamp(k + 1), clamped to the
  // first / last segment (extrapolation).
  std::size_t lo = 0, hi = n - 1;
  while (hi - lo > 1) {
    const std::size_t mid = (lo + hi) / 2;
    (timestamp(mid) <= time_s ? lo : hi) = mid;
  }
  const double t0 = timestamp(lo), t1 = timestamp(lo + 1);
  const double s = t1 > t0 ? (time_s - t0) / (t1 - t0) : 0.0;
  return interpolatePose(T_world_body_[lo], T_world_body_[lo + 1], s) *
         bodyToSensor(spec_, time_s);
}

void
LidarSimulator::simulateFrame(std::size_t i,
                              pcl::PointCloud<pcl::PointXYZI>& cloud,
                              std::vector<float>* point_times_s) const
{
  if (i >= numFrames())
    throw std::out_of_range("LidarSimulator::simulateFrame: frame " + std::to_string(i) +
                            " of " + std::to_string(numFrames()));
  const double time_s = timestamp(i);
  const int steps = spec_.azimuth_steps;
  const bool raw = params_.raw_sweep;

  // 0. Firing-time offset of each column (spin convention in the header) and, for a
  // raw sweep, the sensor pose at that time: once per column, not per ray.
  std::vector<double> column_tau_s;
  PoseVector T_world_column;
  if (raw || point_times_s) {
    const double period_s = framePeriod(i);
    column_tau_s.resize(static_cast<std::size_t>(steps));
    for (int a = 0; a < steps; ++a)
      column_tau_s[a] = columnTimeOffset(a, steps, period_s);
  }
  if (raw) {
    T_world_column.reserve(static_cast<std::size_t>(steps));
    for (int a = 0; a < steps; ++a)
      T_world_column.push_back(sensorPoseAt(time_s + column_tau_s[a]));
  }
  const std::vector<RayHit> hits = castFrame(i, T_world_column);
  sensorEffects(i, hits, column_tau_s, cloud, point_times_s);
}

std::vector<RayHit>
LidarSimulator::castFrame(std::size_t i, const PoseVector& T_world_column) const
{
  const Pose3d T_world_sensor = sensorPose(i);
  const double time_s = timestamp(i);
  const Eigen::Matrix3d R = T_world_sensor.linear();
  const Eigen::Vector3d origin = T_world_sensor.translation();
  const std::size_t n = ray_dirs_sensor_.size();
  const std::size_t beams = spec_.beam_elevations_rad.size();
  const bool raw = params_.raw_sweep;
  // Cast rays [lo, hi) into hits (from the frame's pose, or from each column's
  // pose for a raw sweep; moving cars at the frame's time either way), split into
  // contiguous chunks (threads only change speed).
  std::vector<RayHit> hits(n);
  const std::vector<Eigen::Vector3d>& cast_dirs =
      ray_dirs_cast_.empty() ? ray_dirs_sensor_ : ray_dirs_cast_;
  auto castRange = [&](std::size_t lo, std::size_t hi) {
    std::vector<Eigen::Vector3d> dirs(hi - lo);
    std::vector<RayHit> part;
    std::vector<RayHit>& out = lo == 0 && hi == n ? hits : part;
    if (!raw) {
      for (std::size_t k = lo; k < hi; ++k)
        dirs[k - lo] = R * cast_dirs[k];
      world_->castRays(origin, dirs, spec_.max_range_m, time_s, out);
    } else {
      std::vector<Eigen::Vector3d> origins(hi - lo);
      for (std::size_t k = lo; k < hi; ++k) {
        const Pose3d& T = T_world_column[k / beams];
        dirs[k - lo] = T.linear() * cast_dirs[k];
        origins[k - lo] = T.translation();
      }
      world_->castRays(origins, dirs, spec_.max_range_m, time_s, out);
    }
    if (&out != &hits)
      std::copy(part.begin(), part.end(), hits.begin() + lo);
  };
  const std::size_t chunks = static_cast<std::size_t>(params_.num_threads);
  if (chunks == 1) {
    castRange(0, n);
  } else {
    std::vector<std::thread> pool;
    for (std::size_t c = 0; c < chunks; ++c)
      pool.emplace_back(castRange, n * c / chunks, n * (c + 1) / chunks);
    for (auto& t : pool)
      t.join();
  }
  return hits;
}

void
LidarSimulator::sensorEffects(std::size_t i,
                              const std::vector<RayHit>& hits,
                              const std::vector<double>& column_tau_s,
                              pcl::PointCloud<pcl::PointXYZI>& cloud,
                              std::vector<float>* point_times_s) const
{
  const std::size_t n = ray_dirs_sensor_.size();
  const std::size_t beams = spec_.beam_elevations_rad.size();
  const int steps = spec_.azimuth_steps;
  const bool raw = params_.raw_sweep;
  // Sensor effects per ray from a hash of (seed, frame, ray): range noise,
  // dropouts (more at long range and grazing incidence), intensity from the
  // material's reflectivity, the incidence angle and the range. With imperfections
  // also mixed pixels, early outliers, the beam's range bias (imperfectRange, own
  // uniforms) and multiplicative intensity noise (the clean draws' spare u[3]).
  cloud.clear();
  cloud.reserve(n);
  if (point_times_s) {
    point_times_s->clear();
    point_times_s->reserve(n);
  }
  const double max_r = spec_.max_range_m;
  const std::uint64_t frame_key = frameKey(driveSeed(params_), i);
  const bool imperfect = params_.imperfections;
  const SensorImperfectionParams& ip = params_.imperfection_params;
  const std::uint64_t imperfection_key = imperfectionKey(driveSeed(params_), i);
  // A raw sweep comes out in firing order, as a driver writes it (the reader checks
  // that a time field is in order); an instantaneous scan column by column from
  // azimuth 0, as before.
  std::vector<std::size_t> columns(n / beams);
  std::iota(columns.begin(), columns.end(), std::size_t{0});
  if (raw)
    std::stable_sort(columns.begin(), columns.end(), [&](std::size_t a, std::size_t b) {
      return column_tau_s[a] < column_tau_s[b];
    });
  for (std::size_t k_index = 0; k_index < n; ++k_index) {
    const std::size_t k = columns[k_index / beams] * beams + k_index % beams;
    const RayHit& h = hits[k];
    if (h.range_m <= 0.0)
      continue;
    double u[4];
    rayUniforms(frame_key, k, u);
    const double rel = h.range_m / max_r;
    const double p_drop = spec_.dropout_rate * (1.0 + 3.0 * rel * rel) +
                          (h.cos_incidence < 0.05 ? 0.3 : 0.0);
    if (u[0] < p_drop)
      continue;
    const double gauss = gaussianFromUniform(u[1]);
    double range = h.range_m + spec_.range_noise_std_m * gauss;
    if (imperfect) {
      double v[4];
      rayUniforms(imperfection_key, k, v);
      const std::size_t next =
          (k / beams + 1) % static_cast<std::size_t>(steps) * beams + k % beams;
      range = imperfectRange(h, hits[next], v, ip, spec_.min_range_m) +
              beam_range_bias_m_[k % beams] + spec_.range_noise_std_m * gauss;
    }
    if (range < spec_.min_range_m || range > max_r)
      continue;
    double intensity =
        h.reflectivity * (0.3 + 0.7 * h.cos_incidence) * (1.0 - 0.3 * rel) +
        0.03 * (u[2] - 0.5);
    if (imperfect)
      intensity *= 1.0 + ip.intensity_noise_std * gaussianFromUniform(u[3]);
    const Eigen::Vector3d p = range * ray_dirs_sensor_[k];
    pcl::PointXYZI pt;
    pt.x = static_cast<float>(p.x());
    pt.y = static_cast<float>(p.y());
    pt.z = static_cast<float>(p.z());
    pt.intensity = static_cast<float>(std::clamp(intensity, 0.0, 1.0));
    cloud.push_back(pt);
    if (point_times_s)
      point_times_s->push_back(static_cast<float>(column_tau_s[k / beams]));
  }
  cloud.width = static_cast<std::uint32_t>(cloud.size());
  cloud.height = 1;
  cloud.is_dense = true;
}

std::size_t
LidarSimulator::writeSequence(const std::string& dir,
                              ScanFormat format,
                              std::size_t first,
                              std::size_t last,
                              std::size_t every,
                              const ProgressCallback& progress,
                              const std::function<bool()>& stop) const
{
  if (first > last || last >= numFrames() || every < 1)
    throw std::invalid_argument(
        "LidarSimulator::writeSequence: bad range first=" + std::to_string(first) +
        " last=" + std::to_string(last) + " every=" + std::to_string(every) + " for " +
        std::to_string(numFrames()) + " frames");
  namespace fs = std::filesystem;
  const fs::path scan_dir =
      fs::path(dir) / (format == ScanFormat::kBin ? "velodyne" : "pcd");
  std::error_code ec;
  fs::create_directories(scan_dir, ec);
  if (ec)
    throw std::runtime_error("LidarSimulator::writeSequence: cannot create '" +
                             scan_dir.string() + "': " + ec.message());

  const std::size_t total = (last - first) / every + 1;
  const Pose3d T_sensor0_world = sensorPose(first).inverse();
  // A raw sweep's PCD carries each point's time since the sweep start.
  const bool with_time = params_.raw_sweep && format == ScanFormat::kPcd;
  PoseVector poses;
  std::ostringstream times;
  pcl::PointCloud<pcl::PointXYZI> cloud;
  std::vector<float> point_times_s;
  pcl::PointCloud<PointXYZIT> timed;
  std::size_t written = 0;
  for (std::size_t k = 0; k < total && !(stop && stop()); ++k, ++written) {
    const std::size_t i = first + k * every;
    simulateFrame(i, cloud, with_time ? &point_times_s : nullptr);
    char name[32];
    std::snprintf(
        name, sizeof(name), "%06zu.%s", k, format == ScanFormat::kBin ? "bin" : "pcd");
    const std::string path = (scan_dir / name).string();
    int status = 0;
    if (format == ScanFormat::kBin) {
      writeKittiBin(path, cloud);
    } else if (with_time) {
      const double half_period_s = 0.5 * framePeriod(i);
      timed.resize(cloud.size());
      for (std::size_t p = 0; p < cloud.size(); ++p) {
        timed[p].getVector4fMap() = cloud[p].getVector4fMap();
        timed[p].intensity = cloud[p].intensity;
        // tau + period / 2, clamped: -period / 2 rounded to float may end below 0.
        timed[p].time = static_cast<float>(
            std::clamp(point_times_s[p] + half_period_s, 0.0, 2.0 * half_period_s));
      }
      timed.width = static_cast<std::uint32_t>(timed.size());
      timed.height = 1;
      timed.is_dense = true;
      status = pcl::io::savePCDFileBinary(path, timed);
    } else {
      status = pcl::io::savePCDFileBinary(path, cloud);
    }
    if (status < 0)
      throw std::runtime_error("LidarSimulator::writeSequence: cannot write '" + path +
                               "'");
    poses.push_back(k == 0 ? Pose3d::Identity()
                           : Pose3d(T_sensor0_world * sensorPose(i)));
    char line[64];
    std::snprintf(line, sizeof(line), "%e\n", timestamp(i) - timestamp(first));
    times << line;
    if (progress)
      progress(k + 1, total);
  }
  writeKittiPoses((fs::path(dir) / "poses.txt").string(), poses);
  writeFileAtomically((fs::path(dir) / "times.txt").string(), times.str());
  return written;
}

} // namespace rast
} // namespace pcl
