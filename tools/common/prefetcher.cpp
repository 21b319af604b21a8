/// \file prefetcher.cpp
/// \brief Prefetcher: scans read ahead on a thread of their own.

#include "prefetcher.h"
#include "stop_signals.h"

#include <algorithm>
#include <exception>

namespace pcl_rast_tools {

Prefetcher::Prefetcher(pcl::rast::SequenceReader& reader, std::size_t depth)
  : reader_(reader), depth_(std::max<std::size_t>(depth, 1)), thread_([this] { run(); })
{}

Prefetcher::~Prefetcher()
{
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stop_ = true;
  }
  cv_.notify_all();
  thread_.join();
}

bool
Prefetcher::next(ReadItem& item)
{
  std::unique_lock<std::mutex> lock(mutex_);
  cv_.wait(lock, [&] { return done_ || !items_.empty(); });
  if (items_.empty())
    return false;
  item = std::move(items_.front());
  items_.pop_front();
  cv_.notify_all();
  return true;
}

const ReadItem*
Prefetcher::peek()
{
  std::unique_lock<std::mutex> lock(mutex_);
  cv_.wait(lock, [&] { return done_ || !items_.empty(); });
  // The reading thread only appends: a deque keeps its elements where they are.
  return items_.empty() ? nullptr : &items_.front();
}

void
Prefetcher::run()
{
  for (std::size_t i = 0; i < reader_.size(); ++i) {
    if (stopRequested())
      break;
    ReadItem item;
    item.sequence_index = i;
    item.path = reader_.path(i);
    item.timestamp_s = reader_.timestamp(i);
    try {
      item.frame = reader_.read(i);
      item.ok = true;
    } catch (const std::exception& e) { // a ScanReadError, or out of memory
      item.error = e.what();
    }
    std::unique_lock<std::mutex> lock(mutex_);
    cv_.wait(lock, [&] { return stop_ || items_.size() < depth_; });
    if (stop_)
      break;
    items_.push_back(std::move(item));
    cv_.notify_all();
  }
  std::lock_guard<std::mutex> lock(mutex_);
  done_ = true;
  cv_.notify_all();
}

} // namespace pcl_rast_tools
