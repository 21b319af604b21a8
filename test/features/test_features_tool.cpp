// pcl_rast_features end to end: one scan gives a keypoint image, two scans a match
// image and the transform between them; bad arguments fail before any work.
#include "png_image.h"
#include "test_data.h"

#include <array>
#include <cstdio>
#include <filesystem>
#include <gtest/gtest.h>
#include <memory>
#include <regex>
#include <string>
#include <sys/wait.h>

// This file's names stay its own: a test program compiles several test files as
// one translation unit (test/CMakeLists.txt).
namespace test_features_tool {

namespace fs = std::filesystem;

namespace {

struct ToolRun
{
  int exit_code = -1;
  std::string output;
};

ToolRun
runTool(const std::string& args)
{
  const std::string command = pcl_rast_test::toolPath("pcl_rast_features") + " " + args + " 2>&1";
  ToolRun run;
  std::unique_ptr<FILE, int (*)(FILE*)> pipe(::popen(command.c_str(), "r"), ::pclose);
  if (!pipe)
    return run;
  std::array<char, 512> buffer{};
  while (std::fgets(buffer.data(), buffer.size(), pipe.get()))
    run.output += buffer.data();
  const int status = ::pclose(pipe.release());
  run.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  return run;
}

double
printedValue(const std::string& text, const std::string& key)
{
  const std::regex pattern(key + "=([-0-9.eE+]+)");
  std::smatch match;
  if (!std::regex_search(text, match, pattern))
    return -1.0;
  return std::stod(match[1]);
}

} // namespace

TEST(FeaturesTool, BadArgumentsFailBeforeAnyWork)
{
  ASSERT_TRUE(fs::exists(pcl_rast_test::toolPath("pcl_rast_features")))
      << "build pcl_rast_features first";
  EXPECT_EQ(runTool("").exit_code, 1);
  EXPECT_EQ(runTool("a.bin -output x.png -no_such_flag").exit_code, 1);
  EXPECT_EQ(runTool("a.bin -output x.png -projection fisheye").exit_code, 1);
  const ToolRun jpeg = runTool("a.bin -output /tmp/x.jpg");
  EXPECT_EQ(jpeg.exit_code, 1) << jpeg.output;
  EXPECT_NE(jpeg.output.find("bad -output '/tmp/x.jpg'"), std::string::npos)
      << jpeg.output;
  const ToolRun missing = runTool("/nonexistent/scan.bin -output /tmp/x.png");
  EXPECT_EQ(missing.exit_code, 2) << missing.output;
}

TEST(FeaturesTool, RealKittiScansGiveKeypointAndMatchImages)
{
  PCL_RAST_REQUIRE_SHARED_DATA(data);
  const fs::path out = pcl_rast_test::makeTempDir("features_tool");
  const std::string scan0 = (data / "kitti-raw-22/pcd/0000000000.pcd").string();
  const std::string scan1 = (data / "kitti-raw-22/pcd/0000000001.pcd").string();
  ASSERT_TRUE(fs::exists(scan0)) << scan0;

  const ToolRun one = runTool(scan0 + " -output " + (out / "one.png").string());
  ASSERT_EQ(one.exit_code, 0) << one.output;
  EXPECT_GT(printedValue(one.output, "features1"), 100.0) << one.output;
  const cv::Mat image = pcl_rast_test::readPngAsBgr((out / "one.png").string());
  ASSERT_FALSE(image.empty());
  EXPECT_EQ(image.cols, 512); // default raster: +-51.2 m at 0.2 m

  const ToolRun two = runTool(scan0 + " " + scan1 + " -output " + (out / "two.png").string());
  ASSERT_EQ(two.exit_code, 0) << two.output;
  EXPECT_GE(printedValue(two.output, "inliers"), 20.0) << two.output;
  const cv::Mat pair = pcl_rast_test::readPngAsBgr((out / "two.png").string());
  ASSERT_FALSE(pair.empty());
  EXPECT_GT(pair.cols, 2 * 512);
  // The car moves forward ~0.8 m per frame: scan 1 maps into scan 0 shifted along +x.
  const std::regex t_line("t=\\s*([-0-9.eE+]+)\\s+([-0-9.eE+]+)");
  std::smatch match;
  ASSERT_TRUE(std::regex_search(two.output, match, t_line)) << two.output;
  EXPECT_NEAR(std::stod(match[1]), 0.8, 0.2) << two.output;
  EXPECT_NEAR(std::stod(match[2]), 0.0, 0.2) << two.output;
}

} // namespace test_features_tool
