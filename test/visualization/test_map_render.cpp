// Tests of the top-down map render (tools/common/map_render.h): the VTK path on a
// private Xvfb, the OpenCV fallback, parameter validation and failure paths.

#include "png_image.h"
#include "test_data.h"

#include <cerrno>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <gtest/gtest.h>
#include <iostream>
#include <optional>
#include <pcl/visualization/map_render.h>
#include <pcl/visualization/png_io.h>
#include <random>
#include <set>
#include <signal.h>
#include <sstream>
#include <stdexcept>
#include <string>
#include <unistd.h>

// This file's names stay its own: a test program compiles several test files as
// one translation unit (test/CMakeLists.txt).
namespace test_map_render {

namespace {

using pcl::rast::MapRenderInput;
using pcl::rast::MapRenderParams;
using pcl::rast::MapRenderResult;
using pcl::rast::renderMapTopDown;

/// Sets (or unsets, with nullptr) an environment variable for the scope.
class ScopedEnv
{
public:
  ScopedEnv(const char* name, const char* value) : name_(name)
  {
    if (const char* old = std::getenv(name))
      old_ = old;
    if (value)
      ::setenv(name, value, 1);
    else
      ::unsetenv(name);
  }
  ~ScopedEnv()
  {
    if (old_)
      ::setenv(name_.c_str(), old_->c_str(), 1);
    else
      ::unsetenv(name_.c_str());
  }

private:
  std::string name_;
  std::optional<std::string> old_;
};

/// A generated scene: ground, four boxes of different heights, a 30 m square
/// trajectory around them driven twice, one loop closure back to the start.
struct TestScene
{
  pcl::PointCloud<pcl::PointXYZI> map;
  MapRenderInput input;

  TestScene()
  {
    std::mt19937 rng(42);
    std::uniform_real_distribution<float> unit(0.0f, 1.0f);
    std::normal_distribution<float> noise(0.0f, 0.02f);
    auto add = [&](float x, float y, float z) {
      pcl::PointXYZI p;
      p.x = x + noise(rng);
      p.y = y + noise(rng);
      p.z = z + noise(rng);
      p.intensity = 100.0f * unit(rng);
      map.push_back(p);
    };
    for (int i = 0; i < 20000; ++i) // ground, 50 x 50 m
      add(-10.0f + 50.0f * unit(rng), -10.0f + 50.0f * unit(rng), 0.0f);
    struct Box
    {
      float x0, y0, sx, sy, h;
    };
    for (const Box& b : {Box{4, 4, 6, 4, 3},
                         Box{20, 5, 4, 8, 6},
                         Box{5, 20, 10, 3, 9},
                         Box{19, 19, 6, 6, 12}}) {
      for (int i = 0; i < 6000; ++i) { // walls
        const float t = unit(rng), z = b.h * unit(rng);
        switch (i % 4) {
        case 0:
          add(b.x0 + b.sx * t, b.y0, z);
          break;
        case 1:
          add(b.x0 + b.sx * t, b.y0 + b.sy, z);
          break;
        case 2:
          add(b.x0, b.y0 + b.sy * t, z);
          break;
        default:
          add(b.x0 + b.sx, b.y0 + b.sy * t, z);
          break;
        }
      }
      for (int i = 0; i < 3000; ++i) // roof
        add(b.x0 + b.sx * unit(rng), b.y0 + b.sy * unit(rng), b.h);
    }
    map.width = static_cast<std::uint32_t>(map.size());
    map.height = 1;

    input.map = &map;
    const Eigen::Vector3d corners[4] = {
        {0, 0, 1.5}, {30, 0, 1.5}, {30, 30, 1.5}, {0, 30, 1.5}};
    for (int lap = 0; lap < 2; ++lap)
      for (int side = 0; side < 4; ++side)
        for (int k = 0; k < 30; ++k) {
          const double t = k / 30.0;
          // Odometry drift grows over the second lap, up to 2.4 m.
          const double f = lap * (side * 30 + k) / 120.0;
          const Eigen::Vector3d drift(1.8 * f, -1.6 * f, 0.0);
          input.trajectory.push_back((1 - t) * corners[side] +
                                     t * corners[(side + 1) % 4] + drift);
          input.ground_truth.push_back((1 - t) * corners[side] +
                                       t * corners[(side + 1) % 4]);
        }
    input.loop_edges.emplace_back(input.trajectory[239], input.trajectory[0]);
    input.loop_edges.emplace_back(input.trajectory[195], input.trajectory[75]);
    input.title = "test scene: 4 boxes, square loop";
  }
};

bool
xvfbInstalled()
{
  const char* path_env = std::getenv("PATH");
  std::stringstream dirs(path_env ? path_env : "");
  std::string dir;
  while (std::getline(dirs, dir, ':'))
    if (::access((dir + "/Xvfb").c_str(), X_OK) == 0)
      return true;
  return false;
}

bool
processExists(int pid)
{
  return std::filesystem::exists("/proc/" + std::to_string(pid));
}

/// The PNG exists, has the requested size, is not blank and shows the trajectory.
void
expectGoodPicture(const std::filesystem::path& png, const MapRenderParams& params)
{
  ASSERT_TRUE(std::filesystem::exists(png)) << png;
  const cv::Mat img = pcl_rast_test::readPngAsBgr(png.string());
  ASSERT_FALSE(img.empty());
  EXPECT_EQ(img.cols, params.width_px);
  EXPECT_EQ(img.rows, params.height_px);
  std::set<int> colours;
  int trajectory_px = 0, loop_px = 0;
  const auto& t = params.trajectory_colour;
  const auto& l = params.loop_edge_colour;
  for (int r = 0; r < img.rows; ++r)
    for (int c = 0; c < img.cols; ++c) {
      const cv::Vec3b px = img.at<cv::Vec3b>(r, c);
      colours.insert(px[0] | (px[1] << 8) | (px[2] << 16));
      if (std::abs(px[2] - t.r) <= 2 && std::abs(px[1] - t.g) <= 2 &&
          std::abs(px[0] - t.b) <= 2)
        ++trajectory_px;
      if (std::abs(px[2] - l.r) <= 2 && std::abs(px[1] - l.g) <= 2 &&
          std::abs(px[0] - l.b) <= 2)
        ++loop_px;
    }
  EXPECT_GT(colours.size(), 100u) << "picture looks blank";
  EXPECT_GT(trajectory_px, 1000) << "trajectory colour missing";
  EXPECT_GT(loop_px, 50) << "loop edge colour missing";
  // No temporary file left beside the PNG.
  for (const auto& entry : std::filesystem::directory_iterator(png.parent_path()))
    EXPECT_EQ(entry.path().filename().string().find(".tmp-"), std::string::npos)
        << entry.path();
}

TEST(MapRender, VtkOnPrivateXvfbWithoutDisplay)
{
  if (!xvfbInstalled())
    GTEST_SKIP() << "Xvfb is not installed: skipping the VTK-on-Xvfb render";
  ScopedEnv no_display("DISPLAY", nullptr);
  const TestScene scene;
  const MapRenderParams params;
  const auto png = pcl_rast_test::makeTempDir("map_render") / "render.png";
  const MapRenderResult result = renderMapTopDown(scene.input, params, png.string());
  ASSERT_TRUE(result.success) << result.message;
  EXPECT_EQ(result.backend, "vtk-xvfb") << result.message;
  expectGoodPicture(png, params);
  // The private Xvfb was started, then stopped and reaped (no zombie in /proc).
  ASSERT_GT(result.xvfb_pid, 0);
  EXPECT_FALSE(processExists(result.xvfb_pid));
  EXPECT_EQ(::kill(result.xvfb_pid, 0), -1);
  std::cout << "vtk-xvfb render: " << result.render_time_ms << " ms -> " << png << "\n";
}

TEST(MapRender, VtkOnPrivateXvfbWhenDisplayIsBroken)
{
  if (!xvfbInstalled())
    GTEST_SKIP() << "Xvfb is not installed: skipping the VTK-on-Xvfb render";
  ScopedEnv broken_display("DISPLAY", ":4711"); // nobody listens there
  const TestScene scene;
  MapRenderParams params;
  params.width_px = 640;
  params.height_px = 480;
  const auto png = pcl_rast_test::makeTempDir("map_render") / "render.png";
  const MapRenderResult result = renderMapTopDown(scene.input, params, png.string());
  ASSERT_TRUE(result.success) << result.message;
  EXPECT_EQ(result.backend, "vtk-xvfb");
  EXPECT_NE(result.message.find(":4711"), std::string::npos) << result.message;
  EXPECT_FALSE(processExists(result.xvfb_pid));
}

TEST(MapRender, ForcedOpenCvFallback)
{
  const TestScene scene;
  MapRenderParams params;
  params.force_software_fallback = true;
  const auto png = pcl_rast_test::makeTempDir("map_render") / "render.png";
  const MapRenderResult result = renderMapTopDown(scene.input, params, png.string());
  ASSERT_TRUE(result.success) << result.message;
  EXPECT_EQ(result.backend, "opencv-fallback");
  EXPECT_FALSE(result.message.empty());
  EXPECT_EQ(result.xvfb_pid, -1);
  expectGoodPicture(png, params);
  std::cout << "opencv render: " << result.render_time_ms << " ms -> " << png << "\n";
}

TEST(MapRender, FallbackWhenNoDisplayAndNoXvfb)
{
  ScopedEnv no_display("DISPLAY", nullptr);
  const TestScene scene;
  MapRenderParams params;
  params.width_px = 800;
  params.height_px = 600;
  params.xvfb_executable = "/nonexistent/Xvfb";
  const auto png = pcl_rast_test::makeTempDir("map_render") / "render.png";
  const MapRenderResult result = renderMapTopDown(scene.input, params, png.string());
  ASSERT_TRUE(result.success) << result.message;
  EXPECT_EQ(result.backend, "opencv-fallback");
  EXPECT_NE(result.message.find("Xvfb"), std::string::npos) << result.message;
  expectGoodPicture(png, params);

  // Without the fallback the same call fails cleanly and writes nothing.
  params.allow_software_fallback = false;
  std::filesystem::remove(png);
  const MapRenderResult strict = renderMapTopDown(scene.input, params, png.string());
  EXPECT_FALSE(strict.success);
  EXPECT_FALSE(strict.message.empty());
  EXPECT_FALSE(std::filesystem::exists(png));
}

TEST(MapRender, InvalidArgumentsThrow)
{
  const TestScene scene;
  const std::string png =
      (pcl_rast_test::makeTempDir("map_render") / "render.png").string();
  auto expect_throw = [&](const MapRenderParams& p) {
    EXPECT_THROW(renderMapTopDown(scene.input, p, png), std::invalid_argument);
  };
  MapRenderParams p;
  p.width_px = 0;
  expect_throw(p);
  p = MapRenderParams();
  p.height_px = 100000;
  expect_throw(p);
  p = MapRenderParams();
  p.point_size_px = 0.0f;
  expect_throw(p);
  p = MapRenderParams();
  p.colour_low_percentile = 90.0;
  p.colour_high_percentile = 10.0;
  expect_throw(p);
  p = MapRenderParams();
  p.trajectory_width_px = -1.0f;
  expect_throw(p);
  p = MapRenderParams();
  p.vtk_render_timeout_s = 0.0;
  expect_throw(p);
  std::string why;
  p = MapRenderParams();
  p.width_px = 0;
  EXPECT_FALSE(p.isValid(&why));
  EXPECT_NE(why.find("width_px"), std::string::npos);
  EXPECT_TRUE(MapRenderParams().isValid());

  MapRenderInput no_map = scene.input;
  no_map.map = nullptr;
  EXPECT_THROW(renderMapTopDown(no_map, MapRenderParams(), png), std::invalid_argument);
  EXPECT_THROW(renderMapTopDown(scene.input, MapRenderParams(), ""),
               std::invalid_argument);
}

TEST(MapRender, UnwritablePathReportsFailure)
{
  const TestScene scene;
  MapRenderParams params;
  params.width_px = 320;
  params.height_px = 240;
  params.force_software_fallback = true; // the write path is what is tested
  const auto dir = pcl_rast_test::makeTempDir("map_render");
  // A folder that does not exist, and a regular file used as a folder: both fail
  // even when the tests run as root.
  const auto missing = dir / "no_such_folder" / "render.png";
  const auto file_as_dir = dir / "plain_file";
  std::ofstream(file_as_dir) << "x";
  for (const auto& path : {missing, file_as_dir / "render.png"}) {
    const MapRenderResult result = renderMapTopDown(scene.input, params, path.string());
    EXPECT_FALSE(result.success) << path;
    EXPECT_FALSE(result.message.empty());
    EXPECT_NE(result.message.find("cannot write"), std::string::npos) << result.message;
  }
}

/// A picture drawn by the OpenCV fallback into a fresh folder: the result and the
/// picture read back (empty when none was written).
struct FallbackPicture
{
  MapRenderResult result;
  cv::Mat image;
};

FallbackPicture
renderWithFallback(const MapRenderInput& input,
                   int width_px,
                   int height_px,
                   const std::string& name)
{
  MapRenderParams params;
  params.width_px = width_px;
  params.height_px = height_px;
  params.force_software_fallback = true;
  const auto png = pcl_rast_test::makeTempDir("map_render") / name;
  FallbackPicture picture;
  picture.result = renderMapTopDown(input, params, png.string());
  picture.image = pcl_rast_test::readPngAsBgr(png.string());
  return picture;
}

TEST(MapRender, EmptyMapStillRendersTrajectory)
{
  const TestScene scene;
  const pcl::PointCloud<pcl::PointXYZI> empty;
  MapRenderInput input = scene.input;
  input.map = &empty;
  const FallbackPicture picture = renderWithFallback(input, 640, 480, "render.png");
  ASSERT_TRUE(picture.result.success) << picture.result.message;
  ASSERT_FALSE(picture.image.empty());
  EXPECT_EQ(picture.image.cols, 640);
}

/// A dense map reaches the renderer as at most one point per pixel, the top-most: a
/// roof over dense ground looks the same as the roof alone over the ground around it.
TEST(MapRender, DenseMapDrawsTheTopPointOfEachPixel)
{
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> unit(0.0f, 1.0f);
  const auto under_roof = [](float x, float y) {
    return std::abs(x) < 5.0f && std::abs(y) < 5.0f;
  };
  const auto makeMap = [&](bool ground_under_roof) {
    pcl::PointCloud<pcl::PointXYZI> map;
    for (int i = 0; i < 400000; ++i) { // ground, 40 x 40 m
      pcl::PointXYZI p;
      p.x = 40.0f * unit(rng) - 20.0f;
      p.y = 40.0f * unit(rng) - 20.0f;
      p.z = 0.05f * unit(rng);
      if (ground_under_roof || !under_roof(p.x, p.y))
        map.push_back(p);
    }
    for (int i = 0; i < 20000; ++i) { // a flat roof 6 m up, 10 x 10 m
      pcl::PointXYZI p;
      p.x = 10.0f * unit(rng) - 5.0f;
      p.y = 10.0f * unit(rng) - 5.0f;
      p.z = 6.0f;
      map.push_back(p);
    }
    return map;
  };
  constexpr int kWidthPx = 320, kHeightPx = 240;
  const auto roofPixels = [&](const pcl::PointCloud<pcl::PointXYZI>& map,
                              const std::string& name,
                              std::size_t& drawn) {
    MapRenderInput input;
    input.map = &map;
    const FallbackPicture picture = renderWithFallback(input, kWidthPx, kHeightPx, name);
    EXPECT_TRUE(picture.result.success) << picture.result.message;
    drawn = picture.result.map_points_drawn;
    const cv::Mat& img = picture.image;
    int count = 0;
    for (int r = 0; r < img.rows; ++r)
      for (int c = 0; c < img.cols; ++c) {
        const cv::Vec3b bgr = img.at<cv::Vec3b>(r, c);
        count += bgr[2] > 200 && bgr[1] > 180 && bgr[0] < 120; // viridis' yellow end
      }
    return count;
  };
  const pcl::PointCloud<pcl::PointXYZI> dense = makeMap(true);
  std::size_t drawn = 0, drawn_open = 0;
  const int roof = roofPixels(dense, "dense.png", drawn);
  const int roof_open = roofPixels(makeMap(false), "open.png", drawn_open);
  EXPECT_LE(drawn, static_cast<std::size_t>(kWidthPx * kHeightPx))
      << "more map points drawn than the picture has pixels";
  EXPECT_GT(drawn, 5000u);
  EXPECT_LT(drawn, dense.size() / 4);
  // The roof hides the ground under it: as many roof-coloured pixels either way.
  EXPECT_GT(roof_open, 500);
  EXPECT_NEAR(roof, roof_open, 0.02 * roof_open);
}

/// Map points that fall outside the fitted view (the bounds are robust percentiles) are
/// not drawn under the title, where the text would be written over them.
TEST(MapRender, NoMapPointsUnderTheTitle)
{
  std::mt19937 rng(11);
  std::uniform_real_distribution<float> unit(0.0f, 1.0f);
  pcl::PointCloud<pcl::PointXYZI> map;
  const auto add = [&map](float x, float y) {
    pcl::PointXYZI p;
    p.x = x;
    p.y = y;
    p.z = 0.0f;
    p.intensity = 0.0f;
    map.push_back(p);
  };
  for (int i = 0; i < 100000; ++i) // ground, 100 x 100 m
    add(100.0f * unit(rng), 100.0f * unit(rng));
  for (int i = 0; i < 400; ++i) // beyond the 99.5th percentile: north of the view
    add(100.0f * unit(rng), 100.0f + 10.0f * unit(rng));
  MapRenderInput input;
  input.map = &map;
  const FallbackPicture picture = renderWithFallback(input, 640, 480, "title.png");
  ASSERT_TRUE(picture.result.success) << picture.result.message;
  const cv::Mat& img = picture.image;
  ASSERT_FALSE(img.empty());
  // All map points have one height: the dark purple end of viridis (B - G > 40); the
  // title and subtitle are grey or black (B = G = R).
  const auto purple = [&img](int r0, int r1) {
    int n = 0;
    for (int r = r0; r < r1; ++r)
      for (int c = 0; c < img.cols; ++c) {
        const cv::Vec3b bgr = img.at<cv::Vec3b>(r, c);
        n += bgr[0] > bgr[1] + 40;
      }
    return n;
  };
  EXPECT_GT(purple(img.rows / 3, 2 * img.rows / 3), 10000) << "the map is missing";
  EXPECT_EQ(purple(0, 30), 0) << "map points drawn under the title";
}

/// The pixels of \a image at column \a x, row \a y (row 0 at the top).
std::vector<int>
pixelAt(const pcl::rast::Image8& image, int x, int y)
{
  const auto* p = image.pixels.data() + (static_cast<std::size_t>(y) * image.width + x) *
                                            static_cast<std::size_t>(image.channels);
  return std::vector<int>(p, p + image.channels);
}

TEST(PngIo, ReadsAPngWrittenElsewhereTopRowFirstInBgrOrder)
{
  // test/data/rgb_3x2.png, written by a few lines of Python (zlib, no filters): top row
  // red, green, blue; bottom row white, black and RGB (10, 20, 30).
  const auto path = std::filesystem::path(PCL_RAST_SOURCE_DIR) / "test/data/rgb_3x2.png";
  const pcl::rast::Image8 image = pcl::rast::loadPng(path.string());
  ASSERT_EQ(image.width, 3);
  ASSERT_EQ(image.height, 2);
  ASSERT_EQ(image.channels, 3);
  EXPECT_EQ(pixelAt(image, 0, 0), (std::vector<int>{0, 0, 255}));
  EXPECT_EQ(pixelAt(image, 1, 0), (std::vector<int>{0, 255, 0}));
  EXPECT_EQ(pixelAt(image, 2, 0), (std::vector<int>{255, 0, 0}));
  EXPECT_EQ(pixelAt(image, 0, 1), (std::vector<int>{255, 255, 255}));
  EXPECT_EQ(pixelAt(image, 2, 1), (std::vector<int>{30, 20, 10}));
}

TEST(PngIo, WrittenImagesReadBackExactly)
{
  const auto dir = pcl_rast_test::makeTempDir("png_io");
  std::mt19937 rng(7);
  for (const int channels : {1, 2, 3, 4}) {
    pcl::rast::Image8 image;
    image.width = 37; // odd sizes: no row padding can hide
    image.height = 23;
    image.channels = channels;
    image.pixels.resize(static_cast<std::size_t>(37 * 23 * channels));
    for (auto& v : image.pixels)
      v = static_cast<std::uint8_t>(rng() & 0xff);
    const std::string path = (dir / ("c" + std::to_string(channels) + ".png")).string();
    pcl::rast::savePng(path, image);
    const pcl::rast::Image8 back = pcl::rast::loadPng(path);
    EXPECT_EQ(back.width, image.width);
    EXPECT_EQ(back.height, image.height);
    EXPECT_EQ(back.channels, channels);
    EXPECT_TRUE(back.pixels == image.pixels) << channels << " channels";
  }
  // Only the pictures: no temporary file is left beside them.
  EXPECT_EQ(std::distance(std::filesystem::directory_iterator(dir),
                          std::filesystem::directory_iterator()),
            4);
}

TEST(PngIo, BadImagesAndPathsAreNamed)
{
  const auto dir = pcl_rast_test::makeTempDir("png_io");
  pcl::rast::Image8 image;
  image.width = 4;
  image.height = 3;
  image.channels = 3;
  image.pixels.assign(4 * 3 * 3, 128);
  const auto message = [](const auto& call) -> std::string {
    try {
      call();
    } catch (const std::exception& e) {
      return e.what();
    }
    return "no exception";
  };
  const std::string ok = (dir / "ok.png").string();
  pcl::rast::Image8 bad = image;
  bad.channels = 5;
  EXPECT_THROW(pcl::rast::savePng(ok, bad), std::invalid_argument);
  EXPECT_NE(message([&] { pcl::rast::savePng(ok, bad); }).find("channel count 5"),
            std::string::npos);
  bad = image;
  bad.height = 0;
  EXPECT_THROW(pcl::rast::savePng(ok, bad), std::invalid_argument);
  bad = image;
  bad.pixels.pop_back();
  EXPECT_NE(message([&] { pcl::rast::savePng(ok, bad); }).find("35 pixel bytes"),
            std::string::npos);
  EXPECT_FALSE(std::filesystem::exists(ok));

  const std::string missing_folder = (dir / "no_such_folder" / "a.png").string();
  const std::string write_error =
      message([&] { pcl::rast::savePng(missing_folder, image); });
  EXPECT_NE(write_error.find("cannot write '" + missing_folder + "'"), std::string::npos)
      << write_error;

  // A picture is replaced whole: an old file stays when the new one cannot be written.
  pcl::rast::savePng(ok, image);
  bad = image;
  bad.width = -1;
  EXPECT_THROW(pcl::rast::savePng(ok, bad), std::invalid_argument);
  EXPECT_EQ(pcl::rast::loadPng(ok).pixels, image.pixels);

  const std::string not_png = (dir / "text.png").string();
  std::ofstream(not_png) << "not a picture";
  EXPECT_NE(message([&] {
              pcl::rast::loadPng(not_png);
            }).find("'" + not_png + "': Not a PNG file"),
            std::string::npos);
  // A PNG cut short: an error naming the file, not a crash or a half-read picture.
  const std::string cut = (dir / "cut.png").string();
  pcl::rast::Image8 large = image;
  large.width = 300;
  large.height = 200;
  large.pixels.resize(300 * 200 * 3);
  std::mt19937 rng(11);
  for (auto& v : large.pixels)
    v = static_cast<std::uint8_t>(rng() & 0xff); // noise: it does not compress away
  pcl::rast::savePng(cut, large);
  std::filesystem::resize_file(cut, std::filesystem::file_size(cut) / 2);
  EXPECT_NE(message([&] { pcl::rast::loadPng(cut); }).find("cannot read '" + cut + "'"),
            std::string::npos);
  const std::string absent = (dir / "absent.png").string();
  EXPECT_NE(message([&] { pcl::rast::loadPng(absent); }).find("'" + absent + "'"),
            std::string::npos);
}

} // namespace

} // namespace test_map_render
