#pragma once
/// \file test_data.h
/// \brief Locating test data without depending on the current directory.

#include <gtest/gtest.h>

#include <cstdlib>
#include <filesystem>
#include <string>

namespace pcl_rast_test {

/// \brief The real-data folder `../shared/data` beside the checkout, or the folder
/// named by the environment variable PCL_RAST_DATA_DIR. Empty when absent.
inline std::filesystem::path
sharedDataDir()
{
  if (const char* env = std::getenv("PCL_RAST_DATA_DIR"))
    if (std::filesystem::is_directory(env))
      return env;
  const std::filesystem::path dir(PCL_RAST_SHARED_DATA_DIR);
  return std::filesystem::is_directory(dir) ? dir : std::filesystem::path();
}

/// \brief A fresh, empty temporary folder unique to the running test.
inline std::filesystem::path
makeTempDir(const std::string& tag)
{
  const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
  std::string name = tag;
  if (info)
    name += std::string("_") + info->test_suite_name() + "_" + info->name();
  for (char& c : name)
    if (c == '/')
      c = '_';
  const auto dir = std::filesystem::temp_directory_path() / "pcl_rast_test" / name;
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  return dir;
}

/// \brief Path of a built tool, e.g. toolPath("pcl_rast_eval").
inline std::string
toolPath(const std::string& name)
{
  return std::string(PCL_RAST_BINARY_DIR) + "/tools/" + name;
}

} // namespace pcl_rast_test

/// Skip the current test with a message when ../shared/data is absent.
#define PCL_RAST_REQUIRE_SHARED_DATA(dir_var)                                          \
  const std::filesystem::path dir_var = ::pcl_rast_test::sharedDataDir();              \
  if (dir_var.empty())                                                                 \
  GTEST_SKIP() << "../shared/data not found (set PCL_RAST_DATA_DIR): skipping real-data test"
