/// \file atomic_file.cpp
/// \brief Files that are complete or absent: write beside, flush, sync, rename.

#include <pcl/rast/atomic_file.h>

#include <cerrno>
#include <cstring>
#include <filesystem>
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
  const std::string tmp_path = path + ".tmp";
  errno = 0;
  std::FILE* file = std::fopen(tmp_path.c_str(), "wb");
  if (!file)
    throw std::runtime_error("writeFileAtomically: cannot create '" + tmp_path +
                             "': " + std::strerror(errno));
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
