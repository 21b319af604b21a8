#pragma once
/// \file prefetcher.h
/// \brief Scans read on a thread of their own, a few frames ahead of the tool's work
/// (pcl_rast_slam, pcl_rast_localize): reading and parsing a 120k-point PCD costs
/// about 2 ms a frame, which then overlaps with the frame before.

#include <pcl/io/sequence_reader.h>

#include <condition_variable>
#include <cstddef>
#include <deque>
#include <mutex>
#include <string>
#include <thread>

namespace pcl_rast_tools {

/// \brief One scan read ahead, or the reason it could not be read.
struct ReadItem
{
  pcl::rast::ScanFrame frame;
  bool ok = false;          ///< read; else \a error says why (a ScanReadError's text)
  std::string error;
  std::string path;         ///< the scan's file
  double timestamp_s = 0.0; ///< the reader's time of the frame (also when unreadable)
  std::size_t sequence_index = 0;
};

/// \brief Reads the reader's scans in order on a thread (bounded queue). Stops reading
/// once a stop signal came (stopRequested); the items read so far are still handed out.
class Prefetcher
{
public:
  /// \param[in] reader kept by reference: it must outlive this
  /// \param[in] depth scans held ahead at most (>= 1)
  Prefetcher(pcl::rast::SequenceReader& reader, std::size_t depth);
  ~Prefetcher();
  Prefetcher(const Prefetcher&) = delete;
  Prefetcher& operator=(const Prefetcher&) = delete;

  /// \brief The next scan in order. \return false at the end of the sequence (or of
  /// what was read before a stop signal).
  bool next(ReadItem& item);

  /// \brief The scan next() will hand out, waiting for it to be read; null at the end.
  /// The item stays valid, unchanged, until next() is called.
  const ReadItem* peek();

private:
  void run();

  pcl::rast::SequenceReader& reader_;
  std::size_t depth_;
  std::mutex mutex_;
  std::condition_variable cv_;
  std::deque<ReadItem> items_;
  bool done_ = false, stop_ = false;
  std::thread thread_; ///< last: starts once the members above exist
};

} // namespace pcl_rast_tools
