#pragma once
/// \file blob_store.h
/// \brief Write-once storage of byte blobs, in memory or spilled to an anonymous file.
/// The SLAM map keeps each key-frame's compact cloud and the loop detector each
/// key-frame's dense-check target here: data written once, read rarely (the merged map
/// at the end, a loop verification), and together the bulk of what a long sequence
/// accumulates. Spilled to disk, they no longer grow the process's memory.
/// \ingroup slam

#include <cstddef>
#include <cstdint>
#include <memory>
#include <mutex>
#include <string>
#include <type_traits>
#include <vector>

namespace pcl {
namespace rast {

/// \brief Write-once blob storage (see the file comment). Thread-safe: put() and get()
/// may be called concurrently from any thread.
///
/// With a directory, blobs go to a file created there and unlinked at once, so it
/// vanishes when the store is destroyed or the process ends, however it ends. Reads
/// go through the page cache: blobs read soon after they were written cost no disk I/O.
class BlobStore
{
public:
  using Ptr = std::shared_ptr<BlobStore>;
  using ConstPtr = std::shared_ptr<const BlobStore>;

  /// \brief Where a blob is: a byte range of the file, or an index in memory.
  struct Handle
  {
    std::uint64_t offset = 0; ///< file offset, or index of the in-memory blob
    std::uint64_t bytes = 0;
  };

  /// \brief A store in memory.
  BlobStore();
  /// \brief A store spilled to an anonymous file in \a directory (empty: in memory).
  /// \throws std::runtime_error naming the directory when no file can be created there.
  explicit BlobStore(const std::string& directory);
  ~BlobStore();
  BlobStore(const BlobStore&) = delete;
  BlobStore& operator=(const BlobStore&) = delete;

  /// \brief Store \a bytes bytes from \a data. \throws std::runtime_error when the file
  /// cannot be written (disk full, ...), naming the directory.
  Handle put(const void* data, std::size_t bytes);
  /// \brief Read blob \a handle into \a out (handle.bytes bytes).
  /// \throws std::runtime_error on a read error or a handle this store did not issue.
  void get(const Handle& handle, void* out) const;

  /// \brief Store a vector of trivially copyable values.
  template <typename T>
  Handle
  putVector(const std::vector<T>& values)
  {
    static_assert(std::is_trivially_copyable<T>::value, "blobs hold plain bytes");
    return put(values.data(), values.size() * sizeof(T));
  }
  /// \brief Read a vector stored with putVector.
  template <typename T>
  std::vector<T>
  getVector(const Handle& handle) const
  {
    static_assert(std::is_trivially_copyable<T>::value, "blobs hold plain bytes");
    std::vector<T> values(handle.bytes / sizeof(T));
    get(handle, values.data());
    return values;
  }

  /// \brief true when blobs go to a file.
  bool spilled() const { return fd_ >= 0; }
  /// \brief Bytes stored in memory (0 when spilled).
  std::size_t memoryBytes() const;
  /// \brief Bytes stored in the file (0 when in memory).
  std::size_t fileBytes() const;

private:
  int fd_ = -1;
  std::string directory_;
  mutable std::mutex mutex_;
  std::uint64_t file_size_ = 0;
  std::vector<std::vector<std::uint8_t>> blobs_; ///< in-memory store
  std::size_t memory_bytes_ = 0;
};

} // namespace rast
} // namespace pcl
