/// \file atomic_file.cpp
/// \brief Files that are complete or absent: write beside, flush, sync, rename.

#include <atomic>
#include <cerrno>
#include <cstring>
#include <fcntl.h>
#include <filesystem>
#include <pcl/rast/atomic_file.h>
#include <stdexcept>
#include <system_error>
#include <unistd.h>

namespace pcl {
namespace rast {

void
writeFileAtomically(const std::string& path, const std::string& content)
{
  writeFileAtomically(path, [&content](std::FILE* file) {
    return std::fwrite(content.data(), 1, content.size(), file) == content.size();
  });
}

void
writeFileAtomically(const std::string& path, const std::function<bool(std::FILE*)>& write)
{
  // A name of its own for every write (process, count): two writers of one path, in two
  // processes or threads, never truncate or rename each other's temporary file, and a
  // file of the user's called PATH.tmp is not touched. O_EXCL refuses one that exists.
  static std::atomic<unsigned long> writes{0};
  const std::string tmp_path =
      path + ".tmp-" + std::to_string(::getpid()) + "-" + std::to_string(writes++);
  errno = 0;
  const int fd = ::open(tmp_path.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0666);
  std::FILE* file = fd >= 0 ? ::fdopen(fd, "wb") : nullptr;
  if (!file) {
    const int error = errno;
    if (fd >= 0) {
      ::close(fd);
      std::error_code ignored;
      std::filesystem::remove(tmp_path, ignored);
    }
    throw std::runtime_error("writeFileAtomically: cannot create '" + tmp_path +
                             "': " + std::strerror(error));
  }
  std::string why;
  int error = 0; // the first errno of a failed step: names the cause (disk full...)
  const auto step = [&error](bool ok) {
    if (!ok && error == 0)
      error = errno;
    return ok;
  };
  bool ok = false;
  try {
    ok = step(write(file));
  } catch (const std::exception& e) {
    why = std::string(": ") + e.what();
  }
  ok = step(std::fflush(file) == 0) && ok;
  ok = step(::fsync(::fileno(file)) == 0) && ok;
  ok = step(std::fclose(file) == 0) && ok;
  std::error_code ec;
  if (ok)
    std::filesystem::rename(tmp_path, path, ec);
  if (!ok || ec) {
    if (ec)
      why += ": " + ec.message();
    else if (why.empty() && error != 0)
      why = std::string(": ") + std::strerror(error);
    std::filesystem::remove(tmp_path, ec);
    throw std::runtime_error("writeFileAtomically: cannot write '" + path + "'" + why);
  }
}

} // namespace rast
} // namespace pcl
