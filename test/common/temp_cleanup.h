#pragma once
/// \file temp_cleanup.h
/// \brief Temporary folders that a test process makes once (named by its pid) and
/// removes when it exits: each holds a simulated drive of ~75 MB, and a suite run
/// starts hundreds of test processes.

#include <filesystem>
#include <system_error>
#include <vector>

namespace pcl_rast_test {

/// \brief Remove \a path (file or folder) when the process exits normally.
inline void
removeAtExit(const std::filesystem::path& path)
{
  struct Registry
  {
    std::vector<std::filesystem::path> paths;
    ~Registry()
    {
      for (const auto& p : paths) {
        std::error_code ignored; // best effort: a leftover must not fail the test
        std::filesystem::remove_all(p, ignored);
      }
    }
  };
  static Registry registry;
  registry.paths.push_back(path);
}

} // namespace pcl_rast_test
