/// \file rast_features.cpp
/// \brief pcl_rast_features: ground removal, rasterization and ORB features of one
/// scan (PNG with keypoints), or of two scans with their matches side by side.
///
///   pcl_rast_features SCAN [SCAN2] -output OUT.png [options]
///
/// With two scans SCAN is the target and SCAN2 the source: the printed transform is
/// T_scan_scan2 (maps SCAN2 points into SCAN's frame), estimated by the registration
/// module: Hamming matching (mutual check, Lowe's ratio test) and rigid RANSAC. Kept by
/// RANSAC are drawn green, the rejected ones red.

#include "cli.h"

#include <Eigen/Geometry>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <opencv2/imgproc.hpp>
#include <pcl/common/time.h>
#include <pcl/features/orb_raster_features.h>
#include <pcl/io/sequence_reader.h>
#include <pcl/registration/hamming_correspondence_estimation.h>
#include <pcl/registration/rigid_ransac.h>
#include <pcl/segmentation/sac_ground_removal.h>
#include <pcl/visualization/png_io.h>
#include <string>
#include <strings.h>
#include <vector>

namespace {

struct Options
{
  std::string scan, scan2, output, projection = "orthographic", reference;
  pcl::rast::SACGroundRemovalParams ground;
  pcl::rast::RangeRasterParams raster;
  pcl::rast::OrbRasterFeatureParams orb;
  bool no_ground_removal = false;
  double ratio = 0.8;
  double ransac_threshold_m = 0.3;
  int ransac_iterations = 2000;
  int repeat = 1;
};

/// One scan through the front end, with per-stage timings.
struct FrameFeatures
{
  pcl::rast::RasterFeatureSet features;
  cv::Mat image;
  double ground_ms = 0.0;
  pcl::rast::OrbRasterFeatureResult orb;
};

FrameFeatures
processScan(const std::string& path, const Options& options)
{
  const pcl::StopWatch watch;
  std::size_t dropped = 0;
  const auto cloud = pcl::rast::readScan(path, &dropped);
  std::cerr << "Loading " << path << " [done, " << static_cast<int>(watch.getTime()) << " ms : "
            << cloud->size() << " points]\n";
  FrameFeatures frame;
  // Reused across repeats, as a pipeline reuses them across frames.
  pcl::rast::SACGroundRemoval<pcl::PointXYZI> ground(options.ground);
  pcl::rast::OrbRasterFeatureEstimator<pcl::PointXYZI> orb;
  orb.setParams(options.orb);
  orb.setRasterParams(options.raster);
  for (int run = 0; run < options.repeat; ++run) { // repeat > 1: best-of timings
    pcl::PointCloud<pcl::PointXYZI>::ConstPtr input = cloud;
    pcl::StopWatch t0;
    if (!options.no_ground_removal) {
      ground.setInputCloud(cloud);
      pcl::rast::GroundRemovalResult<pcl::PointXYZI> result;
      ground.segment(result);
      if (run == 0)
        std::cerr << "  " << result.message << "\n";
      input = result.non_ground;
    }
    const double ground_ms = t0.getTime();
    orb.setInputCloud(input);
    pcl::rast::RasterFeatureSet features;
    const auto result = orb.compute(features);
    if (run == 0 || ground_ms + result.raster_ms + result.detect_ms + result.describe_ms <
                        frame.ground_ms + frame.orb.raster_ms + frame.orb.detect_ms +
                            frame.orb.describe_ms) {
      frame.ground_ms = ground_ms;
      frame.orb = result;
    }
    frame.features = std::move(features);
    const auto& raster = orb.getRaster();
    frame.image = cv::Mat(raster.height(), raster.width(), CV_8UC1,
                          const_cast<std::uint8_t*>(raster.grayData()))
                      .clone();
  }
  std::cerr << "  " << frame.orb.message << "\n";
  std::cout << "timing_ms ground=" << frame.ground_ms << " raster=" << frame.orb.raster_ms
            << " detect=" << frame.orb.detect_ms << " describe=" << frame.orb.describe_ms
            << " total="
            << frame.ground_ms + frame.orb.raster_ms + frame.orb.detect_ms + frame.orb.describe_ms
            << "\n";
  return frame;
}

/// Gray raster as colour, empty pixels black, with contrast stretched for viewing.
cv::Mat
toColour(const cv::Mat& gray)
{
  cv::Mat colour;
  cv::cvtColor(gray, colour, cv::COLOR_GRAY2BGR);
  return colour;
}

void
drawKeypoints(cv::Mat& image, const pcl::rast::RasterFeatureSet& features, int offset_x)
{
  for (const auto& p : features.points) {
    const cv::Point2f centre(p.u + offset_x, p.v);
    cv::circle(image, centre, 3, cv::Scalar(0, 200, 255), 1, cv::LINE_AA);
    const float a = p.angle_deg * static_cast<float>(M_PI) / 180.0f;
    cv::line(image, centre, centre + 6.0f * cv::Point2f(std::cos(a), std::sin(a)),
             cv::Scalar(0, 200, 255), 1, cv::LINE_AA);
  }
}

Eigen::Matrix4f
readMatrix4(const std::string& path)
{
  std::ifstream in(path);
  Eigen::Matrix4f T;
  for (int i = 0; i < 16; ++i)
    in >> T(i / 4, i % 4);
  if (!in)
    throw std::runtime_error("cannot read a 4x4 matrix from " + path);
  return T;
}

int
run(int argc, char** argv)
{
  Options options;
  pcl_rast_tools::ArgParser parser(
      "pcl_rast_features",
      "Ground removal, rasterization and ORB features of a scan (PNG with keypoints);\n"
      "with two scans, their matches side by side (RANSAC inliers green, outliers red)\n"
      "and T_scan_scan2 on stdout.");
  parser.addPositional("SCAN", "scan file (.pcd, .ply, .bin); the target with two scans",
                       &options.scan);
  parser.addPositional("SCAN2", "second scan (the source)", &options.scan2, true);
  parser.addString("output", "output PNG", &options.output, true);
  parser.addChoice("projection",
                   "raster projection (pinhole: the paper's camera exactly; pinhole_centred: "
                   "its principal point moved to the image centre, t = [0, 0, 70])",
                   &options.projection,
                   {"orthographic", "pinhole", "pinhole_centred"});
  parser.addDouble("resolution", "orthographic pixel size [m]",
                   &options.raster.orthographic.resolution_m);
  parser.addDouble("extent", "orthographic half extent [m]",
                   &options.raster.orthographic.half_extent_m);
  double min_height = options.raster.min_height_m, max_height = options.raster.max_height_m;
  parser.addDouble("min_height", "height of gray level 1 [m, sensor frame]", &min_height);
  parser.addDouble("max_height", "height of gray level 255 [m, sensor frame]", &max_height);
  parser.addSwitch("no_ground_removal", "rasterize the whole scan", &options.no_ground_removal);
  parser.addSwitch("level", "level the cloud on the ground plane before rasterizing",
                   &options.ground.level_cloud);
  parser.addDouble("ground_threshold", "ground inlier distance [m]",
                   &options.ground.distance_threshold_m);
  parser.addInt("max_features", "maximum features per scan", &options.orb.max_features);
  parser.addInt("fast_threshold", "initial FAST threshold", &options.orb.fast_threshold);
  parser.addInt("min_features", "lower the FAST threshold below this many detections",
                &options.orb.min_features);
  parser.addInt("cell", "bucketing cell size [px]", &options.orb.grid_cell_px);
  parser.addInt("per_cell", "maximum features per cell", &options.orb.max_per_cell);
  parser.addDouble("blur", "Gaussian blur sigma [px]", &options.orb.blur_sigma_px);
  parser.addInt("levels", "ORB pyramid levels", &options.orb.num_levels);
  parser.addDouble("ratio", "Lowe ratio test threshold", &options.ratio);
  parser.addDouble("ransac_threshold", "RANSAC inlier distance [m]",
                   &options.ransac_threshold_m);
  parser.addString("reference", "4x4 reference T_scan_scan2 file: print the error",
                   &options.reference);
  parser.addInt("repeat", "process each scan this many times (best-of timings)",
                &options.repeat);
  if (!parser.parse(argc, argv))
    return pcl_rast_tools::kExitOk;
  options.raster.projection = options.projection == "orthographic"
                                  ? pcl::rast::RasterProjection::kOrthographic
                                  : pcl::rast::RasterProjection::kPinhole;
  if (options.projection == "pinhole_centred") {
    // The paper's f = 500 and camera 70 m below the sensor, but the principal point at
    // the image centre and no lateral offset: the 750 px image covers +-52.5 m.
    auto& c = options.raster.pinhole;
    c.principal_u_px = 0.5 * c.width_px;
    c.principal_v_px = 0.5 * c.height_px;
    c.t_x_m = c.t_y_m = 0.0;
  }
  options.raster.min_height_m = static_cast<float>(min_height);
  options.raster.max_height_m = static_cast<float>(max_height);
  std::string why;
  if (!options.raster.isValid(&why) || !options.orb.isValid(&why) ||
      !options.ground.isValid(&why))
    throw std::invalid_argument(why);
  // The picture is always a PNG: another extension would name a file it is not.
  if (::strcasecmp(std::filesystem::path(options.output).extension().c_str(), ".png") !=
      0)
    throw std::invalid_argument("bad -output '" + options.output +
                                "': the picture is a PNG, name it *.png");
  if (options.repeat < 1)
    throw std::invalid_argument("-repeat must be >= 1");
  if (!options.reference.empty() && options.scan2.empty())
    throw std::invalid_argument("-reference needs two scans");

  const FrameFeatures a = processScan(options.scan, options);
  std::cout << "features1=" << a.features.size() << "\n";
  cv::Mat canvas;
  int status = a.features.empty() ? pcl_rast_tools::kExitAlgorithmFailure : pcl_rast_tools::kExitOk;
  if (options.scan2.empty()) {
    canvas = toColour(a.image);
    drawKeypoints(canvas, a.features, 0);
  }
  else {
    const FrameFeatures b = processScan(options.scan2, options);
    std::cout << "features2=" << b.features.size() << "\n";
    const pcl::StopWatch watch;
    // The registration module's own chain, as the odometry uses it: Hamming matching
    // (mutual check + ratio test), then rigid RANSAC. Source = scan 2, target = scan 1.
    pcl::rast::HammingMatchParams match_params;
    match_params.ratio = options.ratio;
    const pcl::Correspondences matches =
        pcl::rast::matchHamming(b.features, a.features, match_params);
    pcl::rast::RigidRansacParams ransac_params;
    ransac_params.inlier_threshold_m = options.ransac_threshold_m;
    ransac_params.max_iterations = options.ransac_iterations;
    ransac_params.min_inliers = 3;
    std::vector<bool> is_inlier(matches.size(), false);
    Eigen::Matrix4f T = Eigen::Matrix4f::Identity();
    if (matches.size() >= 3) {
      const pcl::rast::RigidRansacResult ransac = pcl::rast::estimateRigidRansac(
          b.features.points, a.features.points, matches, ransac_params);
      if (ransac.success) {
        T = ransac.T_target_source.matrix().cast<float>();
        for (const int m : ransac.inlier_indices)
          is_inlier[m] = true;
      }
    }
    const double match_ms = watch.getTime();
    const auto num_inliers = std::count(is_inlier.begin(), is_inlier.end(), true);
    const float yaw_deg = std::atan2(T(1, 0), T(0, 0)) * 180.0f / static_cast<float>(M_PI);
    std::cout << "matches=" << matches.size() << " inliers=" << num_inliers
              << " match_ms=" << match_ms << "\n"
              << "t=" << T.topRightCorner<3, 1>().transpose() << " yaw_deg=" << yaw_deg << "\n";
    if (!options.reference.empty()) {
      const Eigen::Matrix4f error = readMatrix4(options.reference).inverse() * T;
      const float r_error_deg =
          Eigen::AngleAxisf(Eigen::Matrix3f(error.topLeftCorner<3, 3>())).angle() * 180.0f /
          static_cast<float>(M_PI);
      std::cout << "t_error_m=" << error.topRightCorner<3, 1>().norm()
                << " r_error_deg=" << r_error_deg << "\n";
    }
    if (num_inliers < 3)
      status = pcl_rast_tools::kExitAlgorithmFailure;

    const int gap = 8;
    const cv::Mat left = toColour(a.image), right = toColour(b.image);
    canvas = cv::Mat(std::max(left.rows, right.rows), left.cols + gap + right.cols, CV_8UC3,
                     cv::Scalar(60, 60, 60));
    left.copyTo(canvas(cv::Rect(0, 0, left.cols, left.rows)));
    right.copyTo(canvas(cv::Rect(left.cols + gap, 0, right.cols, right.rows)));
    drawKeypoints(canvas, a.features, 0);
    drawKeypoints(canvas, b.features, left.cols + gap);
    for (std::size_t m = 0; m < matches.size(); ++m) {
      const auto& pa = a.features.points[matches[m].index_match];
      const auto& pb = b.features.points[matches[m].index_query];
      cv::line(canvas, cv::Point2f(pa.u, pa.v), cv::Point2f(pb.u + left.cols + gap, pb.v),
               is_inlier[m] ? cv::Scalar(0, 220, 0) : cv::Scalar(0, 0, 255), 1, cv::LINE_AA);
    }
  }
  pcl::rast::Image8 png;
  png.width = canvas.cols;
  png.height = canvas.rows;
  png.channels = canvas.channels();
  if (!canvas.isContinuous())
    canvas = canvas.clone();
  png.pixels.assign(canvas.data, canvas.data + canvas.total() * canvas.elemSize());
  pcl::rast::savePng(options.output, png);
  std::cerr << "Saved " << options.output << "\n";
  return status;
}

} // namespace

int
main(int argc, char** argv)
{
  return pcl_rast_tools::runTool("pcl_rast_features", [&] { return run(argc, argv); });
}
