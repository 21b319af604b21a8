#pragma once
/// \file test_data.h
/// \brief Locating test data without depending on the current directory.

#include <gtest/gtest.h>

#include <Eigen/Geometry>

#include <cstdlib>
#include <iterator>
#include <sys/wait.h>
#include <filesystem>
#include <fstream>
#include <stdexcept>
#include <string>

namespace pcl_rast_test {

/// \brief A 4x4 rigid transform as 16 numbers, row by row (the scan pairs' references).
/// \throws std::runtime_error when the file does not hold 16 numbers.
inline Eigen::Isometry3d
readMatrix4(const std::filesystem::path& path)
{
  std::ifstream in(path);
  Eigen::Isometry3d T;
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 4; ++c)
      in >> T.matrix()(r, c);
  if (!in)
    throw std::runtime_error("cannot read a 4x4 matrix from " + path.string());
  return T;
}

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

/// \brief Run the built tool \a name with \a args (shell words, quoted by the caller),
/// its stdout and stderr into \a log. \return its exit code, -1 when it did not exit.
inline int
runTool(const std::string& name, const std::string& args, const std::filesystem::path& log)
{
  const std::string cmd =
      "'" + toolPath(name) + "' " + args + " > '" + log.string() + "' 2>&1";
  const int status = std::system(cmd.c_str());
  return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

/// \brief The bytes of a file (empty when it cannot be read).
inline std::string
readFile(const std::filesystem::path& path)
{
  std::ifstream in(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

/// \brief Write \a bytes as the whole file \a path.
inline void
writeFile(const std::filesystem::path& path, const std::string& bytes)
{
  std::ofstream(path, std::ios::binary) << bytes;
}

/// \brief Entries of folder \a dir (0 when it is no folder).
inline std::size_t
countFiles(const std::filesystem::path& dir)
{
  if (!std::filesystem::is_directory(dir))
    return 0;
  return static_cast<std::size_t>(
      std::distance(std::filesystem::directory_iterator(dir), std::filesystem::directory_iterator()));
}

} // namespace pcl_rast_test

/// Skip the current test with a message when ../shared/data is absent.
#define PCL_RAST_REQUIRE_SHARED_DATA(dir_var)                                          \
  const std::filesystem::path dir_var = ::pcl_rast_test::sharedDataDir();              \
  if (dir_var.empty())                                                                 \
  GTEST_SKIP() << "../shared/data not found (set PCL_RAST_DATA_DIR): skipping real-data test"
