/// \file blob_store.cpp
/// \brief BlobStore: in memory, or an anonymous (unlinked) file written with pwrite and
/// read with pread, so concurrent readers need no lock.

#include <pcl/slam/blob_store.h>

#include <cerrno>
#include <cstring>
#include <fcntl.h>
#include <stdexcept>
#include <sys/stat.h>
#include <unistd.h>

namespace pcl {
namespace rast {
namespace {

std::string
errnoText()
{
  return std::strerror(errno);
}

/// An anonymous file in \a directory: O_TMPFILE where the file system supports it,
/// else a named file unlinked right after creation.
int
openAnonymousFile(const std::string& directory)
{
#ifdef O_TMPFILE
  int fd = ::open(directory.c_str(), O_TMPFILE | O_RDWR | O_CLOEXEC, S_IRUSR | S_IWUSR);
  if (fd >= 0)
    return fd;
#endif
  std::string name = directory + "/.pcl_rast_spill_XXXXXX";
  std::vector<char> buffer(name.begin(), name.end());
  buffer.push_back('\0');
  const int fd_named = ::mkostemp(buffer.data(), O_CLOEXEC);
  if (fd_named < 0)
    throw std::runtime_error("BlobStore: cannot create a spill file in '" + directory +
                             "': " + errnoText());
  ::unlink(buffer.data());
  return fd_named;
}

} // namespace

BlobStore::BlobStore() = default;

BlobStore::BlobStore(const std::string& directory) : directory_(directory)
{
  if (!directory.empty())
    fd_ = openAnonymousFile(directory);
}

BlobStore::~BlobStore()
{
  if (fd_ >= 0)
    ::close(fd_);
}

BlobStore::Handle
BlobStore::put(const void* data, std::size_t bytes)
{
  Handle handle;
  handle.bytes = bytes;
  if (fd_ < 0) {
    const auto* begin = static_cast<const std::uint8_t*>(data);
    std::vector<std::uint8_t> blob(begin, begin + bytes);
    std::lock_guard<std::mutex> lock(mutex_);
    handle.offset = blobs_.size();
    blobs_.push_back(std::move(blob));
    memory_bytes_ += bytes;
    return handle;
  }
  {
    // Reserve the range under the lock; the write itself runs unlocked.
    std::lock_guard<std::mutex> lock(mutex_);
    handle.offset = file_size_;
    file_size_ += bytes;
  }
  const auto* p = static_cast<const char*>(data);
  std::size_t done = 0;
  while (done < bytes) {
    const ssize_t n = ::pwrite(fd_, p + done, bytes - done, static_cast<off_t>(handle.offset + done));
    if (n < 0 && errno == EINTR)
      continue;
    if (n <= 0)
      throw std::runtime_error("BlobStore: cannot write " + std::to_string(bytes) +
                               " bytes to the spill file in '" + directory_ +
                               "': " + (n < 0 ? errnoText() : std::string("no progress")));
    done += static_cast<std::size_t>(n);
  }
  return handle;
}

void
BlobStore::get(const Handle& handle, void* out) const
{
  if (fd_ < 0) {
    std::lock_guard<std::mutex> lock(mutex_);
    if (handle.offset >= blobs_.size() || blobs_[handle.offset].size() != handle.bytes)
      throw std::runtime_error("BlobStore::get: unknown blob " + std::to_string(handle.offset));
    std::memcpy(out, blobs_[handle.offset].data(), handle.bytes);
    return;
  }
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (handle.offset + handle.bytes > file_size_)
      throw std::runtime_error("BlobStore::get: blob at offset " + std::to_string(handle.offset) +
                               " lies beyond the spill file");
  }
  auto* p = static_cast<char*>(out);
  std::size_t done = 0;
  while (done < handle.bytes) {
    const ssize_t n =
        ::pread(fd_, p + done, handle.bytes - done, static_cast<off_t>(handle.offset + done));
    if (n < 0 && errno == EINTR)
      continue;
    if (n <= 0)
      throw std::runtime_error("BlobStore: cannot read the spill file in '" + directory_ +
                               "': " + (n < 0 ? errnoText() : std::string("unexpected end")));
    done += static_cast<std::size_t>(n);
  }
}

std::size_t
BlobStore::memoryBytes() const
{
  std::lock_guard<std::mutex> lock(mutex_);
  return memory_bytes_;
}

std::size_t
BlobStore::fileBytes() const
{
  std::lock_guard<std::mutex> lock(mutex_);
  return static_cast<std::size_t>(file_size_);
}

} // namespace rast
} // namespace pcl
