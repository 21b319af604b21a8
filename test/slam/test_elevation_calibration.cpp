/// The odometry's self-calibration of the beams' elevation (ElevationCalibrationParams):
/// its parameter checks, the presets that turn it off, the correction of a scan, and on
/// a simulated drive whose beams are each a little off their nominal elevation, the
/// estimate of those errors and the height the odometry keeps with it.

#include "../../slam/src/elevation_calibration.h"

#include <algorithm>
#include <cmath>
#include <gtest/gtest.h>
#include <iostream>
#include <limits>
#include <memory>
#include <numeric>
#include <pcl/simulation/lidar_simulator.h>
#include <pcl/slam/odometry.h>
#include <random>
#include <string>
#include <vector>

// This file's names stay its own: a test program compiles several test files as
// one translation unit (test/CMakeLists.txt).
namespace test_elevation_calibration {

namespace {

constexpr double kDegToRad = M_PI / 180.0;

TEST(ElevationCalibrationParams, RejectsBadValuesByName)
{
  EXPECT_TRUE(pcl::rast::ElevationCalibrationParams().isValid());
  const auto why = [](const pcl::rast::ElevationCalibrationParams& p) {
    std::string reason;
    EXPECT_FALSE(p.isValid(&reason));
    return reason;
  };
  pcl::rast::ElevationCalibrationParams p;
  p.bin_deg = 0.0;
  EXPECT_NE(why(p).find("bin_deg"), std::string::npos);
  p = {};
  p.window_frames = 0;
  EXPECT_NE(why(p).find("window_frames"), std::string::npos);
  p = {};
  p.min_mean_lever_m = std::numeric_limits<double>::quiet_NaN();
  EXPECT_NE(why(p).find("min_mean_lever_m"), std::string::npos);
  p = {};
  p.max_scatter_ratio = 0.5;
  EXPECT_NE(why(p).find("max_scatter_ratio"), std::string::npos);
  p = {};
  p.max_correction_deg = 10.0;
  EXPECT_NE(why(p).find("max_correction_deg"), std::string::npos);
  // Through the odometry's own check, with the member's path.
  pcl::rast::OdometryParams odometry;
  odometry.elevation_calibration.max_residual_m = -1.0;
  std::string reason;
  EXPECT_FALSE(odometry.isValid(&reason));
  EXPECT_NE(reason.find("elevation_calibration.max_residual_m"), std::string::npos)
      << reason;
  EXPECT_THROW(pcl::rast::Odometry{odometry}, std::invalid_argument);
}

TEST(ElevationCalibrationParams, OnForCarMountedDenseSensorsOnly)
{
  using pcl::rast::SensorPreset;
  for (const SensorPreset preset : {SensorPreset::kHdl64,
                                    SensorPreset::kOs1_64,
                                    SensorPreset::kVlp16,
                                    SensorPreset::kOs0_128}) {
    pcl::rast::OdometryParams p;
    pcl::rast::applySensorPreset(preset, p);
    const bool dense_car =
        preset == SensorPreset::kHdl64 || preset == SensorPreset::kOs1_64;
    EXPECT_EQ(p.elevation_calibration.enabled, dense_car) << pcl::rast::toString(preset);
  }
  // Off, the odometry says so and corrects nothing.
  pcl::rast::OdometryParams off;
  off.elevation_calibration.enabled = false;
  const pcl::rast::Odometry odometry(off);
  EXPECT_FALSE(odometry.elevationCalibration().enabled);
  EXPECT_EQ(odometry.elevationCalibration().bins_corrected, 0);
}

TEST(ElevationTable, TurnsEachPointByItsBinAndKeepsTheRest)
{
  using pcl::rast::odometry_detail::applyElevationTable;
  using pcl::rast::odometry_detail::ElevationTable;
  ElevationTable table(0.5f);
  // The bin of -5.2 deg is turned up by 0.1 deg.
  const int b =
      table.binOf(std::cos(-5.2f * kDegToRad), 0.0f, std::sin(-5.2f * kDegToRad));
  ASSERT_GE(b, 0);
  EXPECT_NEAR(table.centreDeg(b), -5.25, 1e-9);
  table.set(b, 0.1 * kDegToRad);
  pcl::PointCloud<pcl::PointXYZI> scan;
  const auto add = [&](double range, double elevation_deg, double azimuth_deg) {
    pcl::PointXYZI p;
    const double el = elevation_deg * kDegToRad, az = azimuth_deg * kDegToRad;
    p.x = static_cast<float>(range * std::cos(el) * std::cos(az));
    p.y = static_cast<float>(range * std::cos(el) * std::sin(az));
    p.z = static_cast<float>(range * std::sin(el));
    p.intensity = 7.0f;
    scan.push_back(p);
  };
  add(30.0, -5.2, 40.0); // in the turned bin
  add(30.0, -8.0, 40.0); // in another
  pcl::PointXYZI nan;
  nan.x = nan.y = nan.z = std::numeric_limits<float>::quiet_NaN();
  scan.push_back(nan);
  const auto out = applyElevationTable(table, scan);
  ASSERT_EQ(out->size(), scan.size());
  const auto elevationDeg = [](const pcl::PointXYZI& p) {
    return std::atan2(p.z, std::hypot(p.x, p.y)) / kDegToRad;
  };
  const auto range = [](const pcl::PointXYZI& p) {
    return std::sqrt(p.x * p.x + p.y * p.y + p.z * p.z);
  };
  EXPECT_NEAR(elevationDeg((*out)[0]), -5.1, 1e-4);
  EXPECT_NEAR(range((*out)[0]), 30.0, 1e-4);
  EXPECT_NEAR(std::atan2((*out)[0].y, (*out)[0].x) / kDegToRad, 40.0, 1e-4); // azimuth
  EXPECT_EQ((*out)[0].intensity, 7.0f);
  EXPECT_EQ((*out)[1].z, scan[1].z); // untouched bin
  EXPECT_EQ((*out)[1].x, scan[1].x);
  EXPECT_TRUE(std::isnan((*out)[2].x));
}

/// A simulated HDL-64 drive whose every point is placed off its beam's elevation by
/// that beam's bias (as a miscalibrated sensor does), tracked with and without the
/// calibration.
struct Drive
{
  std::vector<double> beam_elevation_deg, bias_deg;
  pcl::rast::ElevationCalibrationState state;
  double height_rmse_on = 0.0, height_rmse_off = 0.0;
};

Drive
driveWithBiasedBeams()
{
  pcl::rast::PathParams path;
  path.type = pcl::rast::PathType::kStraight;
  path.num_frames = 300;
  pcl::rast::LidarSimulatorParams params;
  params.seed = 57;
  params.num_threads = 2;
  params.world.scene = pcl::rast::SceneType::kSuburb;
  pcl::rast::LidarSimulator sim(params, pcl::rast::generatePath(path));
  Drive drive;
  std::mt19937 rng(2026);
  std::normal_distribution<double> bias(0.0, 0.08);
  for (const double el :
       pcl::rast::sensorSpec(pcl::rast::SensorModel::kHdl64).beam_elevations_rad) {
    drive.beam_elevation_deg.push_back(el / kDegToRad);
    drive.bias_deg.push_back(bias(rng));
  }
  // The beam nearest in elevation (the lower index on a tie), by bisection over the
  // beams sorted by elevation: a scan through all 64 for each of the drive's 36 million
  // points was most of this test's time.
  std::vector<std::size_t> by_elevation(drive.beam_elevation_deg.size());
  std::iota(by_elevation.begin(), by_elevation.end(), std::size_t{0});
  std::stable_sort(
      by_elevation.begin(), by_elevation.end(), [&](std::size_t a, std::size_t b) {
        return drive.beam_elevation_deg[a] < drive.beam_elevation_deg[b];
      });
  std::vector<double> sorted_deg;
  for (const std::size_t b : by_elevation)
    sorted_deg.push_back(drive.beam_elevation_deg[b]);
  const auto beamOf = [&](double elevation_deg) {
    const std::size_t hi = static_cast<std::size_t>(
        std::lower_bound(sorted_deg.begin(), sorted_deg.end(), elevation_deg) -
        sorted_deg.begin());
    if (hi == 0 || hi == sorted_deg.size())
      return by_elevation[hi == 0 ? 0 : hi - 1];
    const std::size_t below = by_elevation[hi - 1], above = by_elevation[hi];
    const double d_below = elevation_deg - sorted_deg[hi - 1];
    const double d_above = sorted_deg[hi] - elevation_deg;
    return d_below < d_above || (d_below == d_above && below < above) ? below : above;
  };
  // Windows of 25 frames: 11 updates in this drive (50 would give 5).
  pcl::rast::OdometryParams on;
  on.elevation_calibration.window_frames = 25;
  pcl::rast::OdometryParams off = on;
  off.elevation_calibration.enabled = false;
  pcl::rast::Odometry calibrated(on), plain(off);
  const pcl::rast::Pose3d T_first = sim.sensorPose(0);
  double sq_on = 0.0, sq_off = 0.0;
  for (std::size_t i = 0; i < sim.numFrames(); ++i) {
    auto cloud = std::make_shared<pcl::PointCloud<pcl::PointXYZI>>();
    sim.simulateFrame(i, *cloud);
    // The beam fires at its nominal elevation, the sensor reports it bias lower: the
    // correction to find is +bias.
    for (auto& p : cloud->points) {
      const double rho = std::hypot(p.x, p.y), range = std::hypot(rho, double(p.z));
      const double el = std::atan2(p.z, rho);
      const double placed = el - drive.bias_deg[beamOf(el / kDegToRad)] * kDegToRad;
      const double scale = range * std::cos(placed) / rho;
      p.x = static_cast<float>(p.x * scale);
      p.y = static_cast<float>(p.y * scale);
      p.z = static_cast<float>(range * std::sin(placed));
    }
    const double t = sim.timestamp(i);
    const double truth_z = (T_first.inverse() * sim.sensorPose(i)).translation().z();
    const auto a = calibrated.processFrame(cloud, t, i);
    const auto b = plain.processFrame(cloud, t, i);
    sq_on += std::pow(a.T_world_lidar.translation().z() - truth_z, 2);
    sq_off += std::pow(b.T_world_lidar.translation().z() - truth_z, 2);
  }
  drive.height_rmse_on = std::sqrt(sq_on / sim.numFrames());
  drive.height_rmse_off = std::sqrt(sq_off / sim.numFrames());
  drive.state = calibrated.elevationCalibration();
  return drive;
}

/// \a values less their least-squares line over \a x.
std::vector<double>
detrended(const std::vector<double>& x, const std::vector<double>& values)
{
  double s0 = 0, s1 = 0, s2 = 0, t0 = 0, t1 = 0;
  for (std::size_t i = 0; i < x.size(); ++i) {
    s0 += 1;
    s1 += x[i];
    s2 += x[i] * x[i];
    t0 += values[i];
    t1 += x[i] * values[i];
  }
  const double det = s0 * s2 - s1 * s1;
  const double a = (s2 * t0 - s1 * t1) / det, slope = (s0 * t1 - s1 * t0) / det;
  std::vector<double> out;
  for (std::size_t i = 0; i < x.size(); ++i)
    out.push_back(values[i] - a - slope * x[i]);
  return out;
}

TEST(ElevationCalibration, FindsTheBeamsBiasesAndKeepsTheHeight)
{
  const Drive drive = driveWithBiasedBeams();
  std::cout << "updates " << drive.state.updates << ", bins corrected "
            << drive.state.bins_corrected << "; height RMSE with " << drive.height_rmse_on
            << " m, without " << drive.height_rmse_off << " m\n";
  ASSERT_TRUE(drive.state.enabled);
  EXPECT_GE(drive.state.updates, 8);
  // The beams that see the ground beyond 15 m (nominal -6.3 to 0 deg): the correction
  // of their bin against their bias. The offset and the slope over the elevation are
  // left out by design (ElevationCalibration::update), so both are compared without.
  std::vector<double> el, truth, estimate;
  for (std::size_t b = 0; b < drive.beam_elevation_deg.size(); ++b) {
    const double e = drive.beam_elevation_deg[b];
    if (e < -6.3 || e > 0.0)
      continue;
    double sum = 0.0;
    int n = 0;
    for (const auto& [centre, correction] : drive.state.corrections)
      if (std::abs(centre - e) < 0.06) {
        sum += correction;
        ++n;
      }
    if (n == 0)
      continue; // too few pairs in this drive (no level surface at its range)
    el.push_back(e);
    truth.push_back(drive.bias_deg[b]);
    estimate.push_back(sum / n);
  }
  // Of the 20 beams from -6.3 to 0 deg, those with enough pairs: houses and trees
  // hide most of the ground beyond 30 m in this suburb (10 of them in this drive).
  ASSERT_GE(el.size(), 8u);
  const std::vector<double> t = detrended(el, truth), s = detrended(el, estimate);
  double sq_truth = 0.0, sq_error = 0.0;
  for (std::size_t i = 0; i < t.size(); ++i) {
    sq_truth += t[i] * t[i];
    sq_error += (s[i] - t[i]) * (s[i] - t[i]);
  }
  const double rms_truth = std::sqrt(sq_truth / t.size());
  const double rms_error = std::sqrt(sq_error / t.size());
  std::cout << el.size() << " beams: biases " << rms_truth << " deg RMS, estimate off by "
            << rms_error << " deg RMS\n";
  EXPECT_LT(rms_error, 0.3 * rms_truth);
  // No bin turned beyond the limit.
  EXPECT_LE(drive.state.max_abs_correction_deg,
            pcl::rast::ElevationCalibrationParams().max_correction_deg + 1e-9);
  // The height the odometry keeps: 0.28 against 0.34 m RMSE in this drive (the offset
  // and the slope of the biases, which are not corrected, still tilt it).
  EXPECT_LT(drive.height_rmse_on, 0.9 * drive.height_rmse_off);
}

} // namespace

} // namespace test_elevation_calibration
