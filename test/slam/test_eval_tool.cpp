// pcl_rast_eval end to end: runs the built tool on generated pose files.
#include "temp_cleanup.h"
#include "test_data.h"

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <gtest/gtest.h>

#include <unistd.h>
#include <nlohmann/json.hpp>
#include <pcl/io/pose_io.h>
#include <string>
#include <sys/wait.h>

// This file's names stay its own: a test program compiles several test files as
// one translation unit (test/CMakeLists.txt).
namespace test_eval_tool {

namespace {

namespace fs = std::filesystem;
using namespace pcl::rast;

struct RunResult
{
  int exit_code = -1;
  std::string out; ///< stdout only; stderr goes to a file beside it
};

/// Runs pcl_rast_eval with \a args (already quoted where needed).
RunResult
runEval(const std::string& args)
{
  const std::string tool = pcl_rast_test::toolPath("pcl_rast_eval");
  RunResult result;
  if (!fs::exists(tool)) {
    ADD_FAILURE() << tool << " not found: build the pcl_rast_eval target first";
    return result;
  }
  const auto err = fs::temp_directory_path() / "pcl_rast_test" /
                   ("eval_tool_stderr_" + std::to_string(::getpid()) + ".txt");
  fs::create_directories(err.parent_path());
  pcl_rast_test::removeAtExit(err);
  const std::string command = "'" + tool + "' " + args + " 2>'" + err.string() + "'";
  FILE* pipe = popen(command.c_str(), "r");
  if (!pipe) {
    ADD_FAILURE() << "popen failed: " << command;
    return result;
  }
  char buffer[4096];
  std::size_t n = 0;
  while ((n = std::fread(buffer, 1, sizeof(buffer), pipe)) > 0)
    result.out.append(buffer, n);
  const int status = pclose(pipe);
  result.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  return result;
}

std::string
quoted(const fs::path& path)
{
  return "'" + path.string() + "'";
}

/// A 0.25 m/frame path with a gentle curve.
PoseVector
generatePath(std::size_t n)
{
  PoseVector poses;
  Eigen::Vector3d p = Eigen::Vector3d::Zero();
  for (std::size_t i = 0; i < n; ++i) {
    const double yaw = 0.05 * std::sin(0.25 * i / 100.0);
    Pose3d T = Pose3d::Identity();
    T.linear() = Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()).toRotationMatrix();
    T.translation() = p;
    poses.push_back(T);
    p += 0.25 * Eigen::Vector3d(std::cos(yaw), std::sin(yaw), 0.0);
  }
  return poses;
}

PoseVector
scaled(PoseVector poses, double factor)
{
  for (auto& T : poses)
    T.translation() *= factor;
  return poses;
}

class EvalTool : public ::testing::Test
{
protected:
  void SetUp() override
  {
    dir_ = pcl_rast_test::makeTempDir("eval_tool");
    gt_ = generatePath(2000); // 500 m
    writeKittiPoses((dir_ / "gt.txt").string(), gt_);
    writeKittiPoses((dir_ / "est.txt").string(), scaled(gt_, 1.01));
  }
  fs::path dir_;
  PoseVector gt_;
};

TEST_F(EvalTool, JsonOnKittiFiles)
{
  const auto run =
      runEval(quoted(dir_ / "est.txt") + " " + quoted(dir_ / "gt.txt") + " -json");
  ASSERT_EQ(run.exit_code, 0) << run.out;
  const auto j = nlohmann::json::parse(run.out);
  EXPECT_EQ(j.at("frames").get<int>(), 2000);
  for (const char* key : {"ate_rmse_m",
                          "ate_mean_m",
                          "ate_median_m",
                          "ate_std_m",
                          "ate_max_m",
                          "rpe_trans_rmse_m",
                          "rpe_rot_rmse_deg"})
    EXPECT_TRUE(j.at(key).is_number()) << key;
  EXPECT_NEAR(j.at("kitti_t_err_pct").get<double>(), 1.0, 0.01);
  EXPECT_NEAR(j.at("kitti_r_err_deg_per_100m").get<double>(), 0.0, 1e-3);
  EXPECT_EQ(j.at("kitti_per_length").size(), 8u);
  EXPECT_EQ(j.at("alignment").get<std::string>(), "se3");
  EXPECT_GT(j.at("ate_rmse_m").get<double>(), 0.1);

  // Sim(3) alignment removes the scale error from the ATE.
  const auto sim3 = runEval(quoted(dir_ / "est.txt") + " " + quoted(dir_ / "gt.txt") +
                            " -json -align sim3");
  ASSERT_EQ(sim3.exit_code, 0);
  EXPECT_NEAR(nlohmann::json::parse(sim3.out).at("ate_rmse_m").get<double>(), 0.0, 1e-6);
}

TEST_F(EvalTool, TumAgainstKittiAndTextOutput)
{
  writeTumPoses((dir_ / "est.tum").string(), scaled(gt_, 1.01));
  const auto run =
      runEval(quoted(dir_ / "est.tum") + " " + quoted(dir_ / "gt.txt") + " -json");
  ASSERT_EQ(run.exit_code, 0);
  EXPECT_NEAR(
      nlohmann::json::parse(run.out).at("kitti_t_err_pct").get<double>(), 1.0, 0.01);

  const auto text = runEval(quoted(dir_ / "est.tum") + " " + quoted(dir_ / "gt.txt"));
  ASSERT_EQ(text.exit_code, 0);
  EXPECT_NE(text.out.find("ATE"), std::string::npos) << text.out;
}

TEST_F(EvalTool, ShortTrajectoryGivesNullKittiError)
{
  const PoseVector short_gt(gt_.begin(), gt_.begin() + 200); // 50 m
  writeKittiPoses((dir_ / "short.txt").string(), short_gt);
  const auto run =
      runEval(quoted(dir_ / "short.txt") + " " + quoted(dir_ / "short.txt") + " -json");
  ASSERT_EQ(run.exit_code, 0);
  const auto j = nlohmann::json::parse(run.out);
  EXPECT_TRUE(j.at("kitti_t_err_pct").is_null());
  EXPECT_TRUE(j.at("kitti_r_err_deg_per_100m").is_null());
  EXPECT_NEAR(j.at("ate_rmse_m").get<double>(), 0.0, 1e-9);
}

TEST_F(EvalTool, ExitCodes)
{
  const std::string files = quoted(dir_ / "est.txt") + " " + quoted(dir_ / "gt.txt");
  EXPECT_EQ(runEval("-h").exit_code, 0);
  EXPECT_NE(runEval("-h").out.find("-align"), std::string::npos);
  EXPECT_EQ(runEval(files + " -bogus").exit_code, 1);
  EXPECT_EQ(runEval(files + " -align affine").exit_code, 1);
  EXPECT_EQ(runEval(files + " -max_dt abc").exit_code, 1);
  EXPECT_EQ(runEval(quoted(dir_ / "est.txt")).exit_code, 1); // GT missing
  EXPECT_EQ(
      runEval(quoted(dir_ / "missing.txt") + " " + quoted(dir_ / "gt.txt")).exit_code, 2);
  std::ofstream(dir_ / "broken.txt") << "1 0 0 0 0 1 0 0 0 0 1\n";
  EXPECT_EQ(
      runEval(quoted(dir_ / "broken.txt") + " " + quoted(dir_ / "gt.txt")).exit_code, 2);
  // Readable files that cannot be compared: evaluation failure.
  writeKittiPoses((dir_ / "fewer.txt").string(), PoseVector(gt_.begin(), gt_.end() - 1));
  EXPECT_EQ(runEval(quoted(dir_ / "fewer.txt") + " " + quoted(dir_ / "gt.txt")).exit_code,
            3);
}

} // namespace

} // namespace test_eval_tool
