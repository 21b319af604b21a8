/// \file atomic_file.cpp
/// \brief Files that are complete or absent: write beside, flush, sync, rename.

#include <pcl/rast/atomic_file.h>

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
  std::FILE* file = std::fopen(tmp_path.c_str(), "wb");
  if (!file)
    throw std::runtime_error("writeFileAtomically: cannot create '" + tmp_path + "'");
  std::string why;
  bool ok = false;
  try {
    ok = write(file);
  } catch (const std::exception& e) {
    why = std::string(": ") + e.what();
  }
  ok = std::fflush(file) == 0 && ok;
  ok = ::fsync(::fileno(file)) == 0 && ok;
  ok = std::fclose(file) == 0 && ok;
  std::error_code ec;
  if (ok)
    std::filesystem::rename(tmp_path, path, ec);
  if (!ok || ec) {
    std::filesystem::remove(tmp_path, ec);
    throw std::runtime_error("writeFileAtomically: cannot write '" + path + "'" + why);
  }
}

} // namespace rast
} // namespace pcl
