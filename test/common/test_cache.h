#pragma once
/// \file test_cache.h
/// \brief Folders that many test processes need and that take seconds to make (a
/// simulated drive on disk, a session mapped from a simulated drive), made once per
/// build and shared by the processes of a suite run. ctest starts every test case in a
/// process of its own, so a `static` made once per process was made again by each:
/// simulating alone was 30 % of the Release suite's CPU time in session 65.
///
/// A cached folder is made by the first process that asks for it, under a lock, in
/// `<build>/test_cache/<test program>`, and named by its key and by a stamp of the test
/// program and of every project library it loaded (path, size and modification time): any
/// rebuilt library or test program makes it again, and older ones of the same key are
/// removed. Each process gets a copy of its own, which its tests may change.

#include <cstdint>
#include <cstdio>
#include <fcntl.h>
#include <filesystem>
#include <fstream>
#include <functional>
#include <link.h>
#include <string>
#include <sys/file.h>
#include <sys/stat.h>
#include <unistd.h>

namespace pcl_rast_test {

namespace detail {

/// Folds the path, size and modification time of \a path into \a hash (FNV-1a).
inline void
foldFileStamp(const char* path, std::uint64_t& hash)
{
  struct ::stat st
  {
  };
  if (::stat(path, &st) != 0)
    return;
  const std::string s = std::string(path) + ":" + std::to_string(st.st_size) + ":" +
                        std::to_string(st.st_mtim.tv_sec) + "." +
                        std::to_string(st.st_mtim.tv_nsec) + ";";
  for (const unsigned char c : s) {
    hash ^= c;
    hash *= 1099511628211ull;
  }
}

} // namespace detail

/// \brief The build this process runs: a hash of the test program's file and of every
/// loaded library of the project (libpcl_rast_*), as 16 hex digits.
inline std::string
buildStamp()
{
  std::uint64_t hash = 14695981039346656037ull;
  detail::foldFileStamp("/proc/self/exe", hash);
  ::dl_iterate_phdr(
      [](struct dl_phdr_info* info, std::size_t, void* data) {
        const std::string name = info->dlpi_name ? info->dlpi_name : "";
        if (name.find("libpcl_rast_") != std::string::npos)
          detail::foldFileStamp(name.c_str(), *static_cast<std::uint64_t*>(data));
        return 0;
      },
      &hash);
  char hex[17];
  std::snprintf(hex, sizeof hex, "%016llx", static_cast<unsigned long long>(hash));
  return hex;
}

/// \brief Fills \a dir (removed first) with a copy of the folder \a make writes for
/// \a key, made once per build (see the file's doc) and shared by the test processes;
/// the tests may change the copy. Without a usable cache folder (no build folder to
/// write in) \a make writes \a dir itself.
inline void
copyCachedFolder(const std::string& key,
                 const std::filesystem::path& dir,
                 const std::function<void(const std::filesystem::path&)>& make)
{
  namespace fs = std::filesystem;
  fs::remove_all(dir);
  // A folder per test program: each makes its own, and replaces only those.
  std::error_code ec;
  const fs::path root = fs::path(PCL_RAST_BINARY_DIR) / "test_cache" /
                        fs::read_symlink("/proc/self/exe", ec).filename();
  if (!ec)
    fs::create_directories(root, ec);
  const int lock =
      ec ? -1
         : ::open((root / (key + ".lock")).c_str(), O_CREAT | O_RDWR | O_CLOEXEC, 0644);
  if (lock < 0) {
    make(dir);
    return;
  }
  struct Unlock
  {
    int fd;
    ~Unlock() { ::close(fd); } // closing the file releases the lock
  } unlock{lock};
  while (::flock(lock, LOCK_EX) != 0) {
  }
  const fs::path cached = root / (key + "_" + buildStamp());
  const fs::path complete = cached / ".complete";
  if (!fs::exists(complete)) {
    for (const fs::directory_entry& e : fs::directory_iterator(root)) {
      const std::string name = e.path().filename().string();
      if (e.is_directory() && name.rfind(key + "_", 0) == 0)
        fs::remove_all(e.path()); // another build's, or a make that failed
    }
    make(cached);
    std::ofstream(complete) << key << "\n";
  }
  fs::copy(cached, dir, fs::copy_options::recursive);
  fs::remove(dir / ".complete");
}

} // namespace pcl_rast_test
